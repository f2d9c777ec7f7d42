"""``calibration.cameras(..., robust=...)``: the fitted pixel noise ``sigma`` (its chi2/dof)
counts the inliers as ``fitting.Estimate.chi2`` does (mend14).

Before, a robust calibration's chi2 was the IRLS-weighted sum :math:`\\sum w_i e_i^2` over
every corner and ``dof = 2 n - m``: each gross outlier added about ``k^2`` (6 px^2 for the
default Cauchy scale), so 2 % of misdetected corners read a 0.3 px noise as 0.4 px and
scaled every standard deviation by as much. Now only the inliers count (the self-consistent
99.9 % cutoff of ``torch_dq.fitting._robust.inliers``): ``sigma`` is the corners' noise
whatever the outliers. The corners: a pinhole camera written here in numpy (``K [R | t]``)
viewing a planar grid from poses drawn with scipy; the reference noise is the one drawn.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torch_dq import calibration

K = np.array([[460.0, 0.0, 370.0], [0.0, 458.0, 245.0], [0.0, 0.0, 1.0]])
SIGMA = 0.3


def _views(outlier_share, seed=0):
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(8) * 0.05, np.arange(6) * 0.05)
    P = np.c_[gx.ravel() - 0.175, gy.ravel() - 0.125, np.zeros(gx.size)]
    ts, ps, us = [], [], []
    for f in range(25):
        R = Rotation.from_rotvec(rng.normal(0.0, 0.35, 3)).as_matrix()
        t = np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.uniform(0.5, 0.8)])
        pc = P @ R.T + t
        uv = (pc @ K.T)[:, :2] / pc[:, 2:]
        uv += rng.normal(0.0, SIGMA, uv.shape)
        ok = (uv[:, 0] > 0) & (uv[:, 0] < 751) & (uv[:, 1] > 0) & (uv[:, 1] < 479)
        ts.append(np.full(ok.sum(), 1.0 + 0.05 * f))
        ps.append(P[ok])
        us.append(uv[ok])
    t, p, uv = (np.concatenate(x) for x in (ts, ps, us))
    bad = rng.choice(len(t), int(outlier_share * len(t)), replace=False)
    angle = rng.uniform(0, 2 * np.pi, bad.size)
    uv[bad] += rng.uniform(20.0, 40.0, (bad.size, 1)) * np.c_[np.cos(angle), np.sin(angle)]
    uv = np.clip(uv, 0.0, [751.0, 479.0])
    return (torch.as_tensor(t), torch.as_tensor(p), torch.as_tensor(uv)), bad.size


# Huber's outliers keep a pull (linear influence): its fit, and so its inliers' spread, is
# a little wider (1.08 here; the weighted sum of before read 9.6, Cauchy's 1.64)
@pytest.mark.parametrize("robust, high", [("cauchy", 1.1), ("huber", 1.2)])
def test_sigma_of_the_inliers_with_gross_outliers(robust, high):
    obs, n_bad = _views(0.02)
    res = calibration.cameras([obs], ["pinhole"], [(752, 480)], robust=robust)
    # chi2/dof in px^2 is sigma^2: about 1 in units of the drawn noise
    ratio = (res.sigma / SIGMA) ** 2
    assert 0.9 < ratio < high, (res.sigma, ratio)
    assert n_bad <= int(res.outliers[0]) <= n_bad + 0.005 * int(res.used[0])
    np.testing.assert_allclose(res.cameras[0].params.numpy(), K[[0, 1, 0, 1], [0, 1, 2, 2]],
                               rtol=5e-3)


def test_without_kernel_every_corner_counts():
    obs, _ = _views(0.0)
    res = calibration.cameras([obs], ["pinhole"], [(752, 480)])
    assert 0.9 < (res.sigma / SIGMA) ** 2 < 1.1
    assert int(res.outliers[0]) == 0
    # dof = 2 n - m (4 intrinsics, 6 per frame): sigma^2 * dof is the sum of squared errors
    m = 4 + 6 * 25
    n = int(res.used[0])
    sq = float(res.reprojection_rms[0]) ** 2 * n
    assert abs(res.sigma ** 2 * (2 * n - m) - sq) <= 1e-9 * sq

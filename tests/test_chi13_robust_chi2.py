"""With a robust kernel a term's chi2 counts its inliers only (chi13): the cutoff against
scipy's chi-square quantiles and a fixed point written here in numpy; chi2/dof near 1 with
gross outliers and the right sigmas, near 4 / 0.25 with sigmas 2x too small / large (Monte
Carlo against scipy's chi-square band); without a kernel the plain sum of squares."""

from __future__ import annotations

import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist

import torch_dq.dualquat as dq
from torch_dq.fitting import Gyro, Poses, estimate
from torch_dq.fitting._robust import inliers
from torch_dq.nn import BSpline

sys.path.insert(0, str(Path(__file__).parent))
from test_honest8_chi2 import BIAS, GYRO, ROT, TRANS, _job, _truth

F64 = torch.float64


def _reference(s2: np.ndarray, d: int, taken: float) -> tuple[np.ndarray, float]:
    """The inliers and chi2/dof by the fixed point, in numpy and scipy (``taken``: the
    residual components the parameters take, dof14)."""
    q = chi2_dist.ppf(0.999, d)
    kappa = chi2_dist.cdf(q, d + 2) / chi2_dist.cdf(q, d)
    f = np.median(s2) / chi2_dist.ppf(0.5, d)
    keep = np.zeros_like(s2, dtype=bool)
    for _ in range(100):
        new = s2 <= q * f
        if (new == keep).all():
            break
        keep = new
        f = s2[keep].sum() / (kappa * (keep.sum() * d - taken))
    return keep, f


def _samples(rng, n: int, d: int, scale: float, frac: float) -> np.ndarray:
    """Squared norms of ``d`` normal components of std ``scale``, a fraction ``frac`` of them
    gross outliers (20 to 50 sigma)."""
    e = scale * rng.standard_normal((n, d))
    out = rng.random(n) < frac
    e[out] += rng.uniform(20, 50, (out.sum(), d)) * rng.choice([-1, 1], (out.sum(), d))
    return (e * e).sum(-1)


@pytest.mark.parametrize("d", [3, 6])
@pytest.mark.parametrize("scale", [1.0, 2.0, 0.5])
@pytest.mark.parametrize("frac", [0.0, 0.1])
def test_inliers_fixed_point_and_its_ratio(d, scale, frac):
    """The same inliers as the numpy fixed point; the ratio within 4.5 standard deviations
    of the chi-square's (sqrt(2 / nu)) of the true variance factor scale**2 (the kernel's
    sigmas 1/scale of the noise's); the outliers all left out, about 0.1 % of the inliers
    too."""
    rng = np.random.default_rng(d + int(10 * scale) + int(100 * frac))
    n = 20000
    taken = 0.05 * n * d
    s2 = _samples(rng, n, d, scale, frac)
    keep, kappa = inliers(torch.from_numpy(s2), torch.ones(n, dtype=torch.bool), d, taken)
    ref_keep, ref_f = _reference(s2, d, taken)
    assert kappa == pytest.approx(chi2_dist.cdf(chi2_dist.ppf(0.999, d), d + 2) / 0.999,
                                  rel=1e-9)
    np.testing.assert_array_equal(keep.numpy(), ref_keep)
    k = keep.numpy()
    f = s2[k].sum() / kappa / (k.sum() * d - taken)
    assert f == pytest.approx(ref_f, rel=1e-12)
    nu = k.sum() * d  # the fixed point's bias, -0.3 % at d = 3 (40 seeds), is 0.5 sd here
    assert abs(f * (1 - taken / nu) / scale**2 - 1) < 4.5 * math.sqrt(2 / nu)
    inl = n - round(frac * n)
    assert abs((n - k.sum()) - (n - inl) - 1e-3 * inl) < 5 * math.sqrt(1e-3 * n) + 0.02 * frac * n


def test_inliers_masked_and_batched():
    """A batch of two with a masked sample: each row its own fixed point, masked samples
    never inliers."""
    rng = np.random.default_rng(3)
    s2 = np.stack((_samples(rng, 500, 3, 1.0, 0.1), _samples(rng, 500, 3, 2.0, 0.0)))
    mask = np.ones_like(s2, dtype=bool)
    mask[0, :50] = False
    keep, _ = inliers(torch.from_numpy(s2), torch.from_numpy(mask), 3,
                      torch.tensor([135.0, 300.0]))
    for b, taken in ((0, 135.0), (1, 300.0)):
        ref, _ = _reference(s2[b][mask[b]], 3, taken)
        np.testing.assert_array_equal(keep[b].numpy()[mask[b]], ref)
    assert not keep[0, :50].any()


def _with_outliers(kind, scale, frac=0.08, seed=5):
    """honest8's 4 s of poses and 50 Hz gyroscope with a bias (scipy rotations), gross
    outliers (0.2-0.5 rad/s per axis, 20-50 sigma) on ``frac`` of the gyro samples, the
    terms' sigmas ``scale`` times the noise's, kernel ``kind``."""
    rng = np.random.default_rng(seed)
    tc, ti = np.linspace(0, 4, 41), np.linspace(0.1, 3.9, 191)
    R, p, _ = _truth(tc)
    Rm = R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    pm = p + TRANS * rng.standard_normal(p.shape)
    gy = _truth(ti)[2] + BIAS + GYRO * rng.standard_normal((len(ti), 3))
    out = rng.random(len(ti)) < frac
    gy[out] += rng.uniform(0.2, 0.5, (out.sum(), 3)) * rng.choice([-1, 1], (out.sum(), 3))
    x = dq.from_rt(torch.from_numpy(Rm.as_quat(scalar_first=True)), torch.from_numpy(pm))
    t = torch.from_numpy(tc)
    spline = BSpline.from_dualquats(x, t, n_ctrl=23, form="cumulative")
    cam = Poses(t, x, rot_sigma=ROT * scale, trans_sigma=TRANS * scale, robust=kind)
    gyro = Gyro(torch.from_numpy(ti), torch.from_numpy(gy), sigma=GYRO * scale, bias=True,
                robust=kind)
    return spline, cam, gyro, int(out.sum())


def _ratio(est, term) -> float:
    return float(est.chi2[term] / est.dof[term])


@pytest.mark.parametrize("kind", ["cauchy", "huber"])
def test_outliers_right_sigmas_read_one(kind):
    """Right sigmas, 8 % gross outliers: the gyro's chi2 within scipy's 99.9 % band of its
    dof (today's plain sum read ~100x), no chi2 warning, the outliers left out and said."""
    spline, cam, gyro, n_out = _with_outliers(kind, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = estimate(spline, [cam, gyro], verbose=False)
        est.std(gyro, "bias")
    nu = float(est.dof[gyro])
    assert chi2_dist.ppf(0.0005, nu) < float(est.chi2[gyro]) < chi2_dist.ppf(0.9995, nu)
    left = int(est._left_out()[gyro])
    assert n_out <= left <= n_out + 3
    assert f"{left} beyond the {kind} kernel's inlier cutoff left out" in est.summary()
    plain = (gyro(spline) ** 2).sum().item() / nu  # numpy-free: the residuals' own sum
    assert plain > 30


def test_sigmas_too_small_flagged_with_kernel():
    """Sigmas 2x too small with a kernel and outliers: chi2/dof about 4 (3 to 5.5), the
    warning says far above and how many were left out."""
    spline, cam, gyro, _ = _with_outliers("cauchy", 0.5)
    est = estimate(spline, [cam, gyro], verbose=False)
    with pytest.warns(RuntimeWarning, match=r"far above 1 \(.*Gyro [0-9.]+ \(\d+ outliers left"):
        est.std(gyro, "bias")
    assert 3.0 < _ratio(est, gyro) < 5.5


def test_sigmas_too_large_flagged_with_kernel():
    """Sigmas 2x too large with a kernel and outliers: chi2/dof about 0.25, warned below."""
    spline, cam, gyro, _ = _with_outliers("huber", 2.0)
    est = estimate(spline, [cam, gyro], verbose=False)
    with pytest.warns(RuntimeWarning, match="far below 1"):
        est.std(gyro, "bias")
    assert 0.2 < _ratio(est, gyro) < 0.35


def test_no_kernel_is_the_plain_sum():
    """robust=None: chi2 is the sum of the unmasked samples' squared whitened residuals
    (the terms' own residuals, summed in numpy), dof their count less the parameters they
    take: summed, the residual count less every parameter (all determined here; dof14: no
    longer a share proportional to the counts, tests/test_dof14_leverage.py)."""
    spline, cam, gyro = _job(2)
    est = estimate(spline, [cam, gyro], verbose=False)
    for term in (cam, gyro):
        r = term(spline).detach().numpy()
        assert float(est.chi2[term]) == pytest.approx((r * r).sum(), rel=1e-9)
    n = 6 * cam.N + 3 * gyro.N
    p = 6 * spline.control_points.shape[0] + 3
    assert float(est.dof[cam] + est.dof[gyro]) == pytest.approx(n - p, abs=1e-6)
    assert 0 < float(est.dof[cam]) < 6 * cam.N and 0 < float(est.dof[gyro]) < 3 * gyro.N
    assert "left out" not in est.summary()

"""``Estimate.outliers`` (mend14): per term, the samples beyond the robust kernel's inlier
cutoff that ``chi2`` leaves out (zero for a term without a kernel). Gross gyroscope outliers
(30 to 60 sigma per axis) injected at known samples are all counted, and few honest ones
(the 99.9 % cutoff: about 0.1 % of them); the count is the one the summary prints. The
motion and readings: ``test_honest8_chi2``'s (scipy rotations, numpy rates)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Gyro, Poses, estimate
from torch_dq.nn import BSpline

sys.path.insert(0, str(Path(__file__).parent))
from test_honest8_chi2 import BIAS, GYRO, ROT, TRANS, _truth


def test_outliers_counts_the_injected_ones():
    rng = np.random.default_rng(5)
    tc, ti = np.linspace(0, 4, 41), np.linspace(0.1, 3.9, 381)
    R, p, _ = _truth(tc)
    Rm = R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    pm = p + TRANS * rng.standard_normal(p.shape)
    gy = _truth(ti)[2] + BIAS + GYRO * rng.standard_normal((len(ti), 3))
    bad = rng.choice(len(ti), 8, replace=False)
    gy[bad] += GYRO * rng.uniform(30, 60, (8, 3)) * rng.choice([-1, 1], (8, 3))
    x = dq.from_rt(torch.from_numpy(Rm.as_quat(scalar_first=True)), torch.from_numpy(pm))
    t = torch.from_numpy(tc)
    spline = BSpline.from_dualquats(x, t, n_ctrl=math.ceil(4 / 0.2) + 3, form="cumulative")
    cam = Poses(t, x, rot_sigma=ROT, trans_sigma=TRANS)
    gyro = Gyro(torch.from_numpy(ti), torch.from_numpy(gy), sigma=GYRO, bias=True,
                robust="cauchy")
    est = estimate(spline, [cam, gyro], verbose=False)
    out = est.outliers
    assert set(out) == {cam, gyro}
    assert int(out[cam]) == 0 and out[cam].dtype == torch.int64
    assert 8 <= int(out[gyro]) <= 9, int(out[gyro])
    assert f"({int(out[gyro])} beyond the cauchy kernel's inlier cutoff" in est.summary()
    # the counted ones are the injected: their whitened norms beyond every honest sample's
    with torch.no_grad():
        s = gyro(spline).norm(dim=-1)
    assert set(bad.tolist()) <= set(s.argsort(descending=True)[:int(out[gyro])].tolist())
    assert 0.8 < float(est.chi2[gyro] / est.dof[gyro]) < 1.25

"""A clock offset whose optimum lies beyond ``max_time_offset`` (or ``max_time_offset=0``):
``estimate`` stops within a few steps with a reason naming the parameter on its bound, warns,
and leaves interior offsets alone (chi13). Data: a gyroscope reading numpy's angular velocity
(honest8's motion, scipy rotations) at ``t + dt``, poses at ``t``."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Gyro, Poses, estimate
from torch_dq.nn import BSpline

sys.path.insert(0, str(Path(__file__).parent))
from test_honest8_chi2 import BIAS, GYRO, ROT, TRANS, _truth


def _job(dt: float, bound: float, seed: int = 0):
    """4 s of 10 Hz poses and a 50 Hz gyroscope (bias BIAS) stamped ``dt`` early: the
    sample stamped ``t`` reads the rate at ``t + dt``; offset and bias estimated."""
    rng = np.random.default_rng(seed)
    tc, ti = np.linspace(0, 4, 41), np.linspace(0.5, 3.5, 151)
    R, p, _ = _truth(tc)
    Rm = R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    pm = p + TRANS * rng.standard_normal(p.shape)
    gy = _truth(ti + dt)[2] + BIAS + GYRO * rng.standard_normal((len(ti), 3))
    x = dq.from_rt(torch.from_numpy(Rm.as_quat(scalar_first=True)), torch.from_numpy(pm))
    t = torch.from_numpy(tc)
    spline = BSpline.from_dualquats(x, t, n_ctrl=23, degree=4, form="cumulative")
    cam = Poses(t, x, rot_sigma=ROT, trans_sigma=TRANS)
    gyro = Gyro(torch.from_numpy(ti), torch.from_numpy(gy), sigma=GYRO, bias=True,
                time_offset=True, max_time_offset=bound)
    return spline, [cam, gyro]


@pytest.mark.parametrize(("dt", "bound"), [(0.2, 0.1), (-0.2, 0.1), (0.05, 0.0)])
def test_offset_beyond_its_bound_stops_early(dt, bound):
    """The data put the offset beyond the bound (a fit with a wide bound says so, 4 std out):
    the bounded fit stops within 10 steps (it ran 50), unconverged, the reason naming
    Gyro.time_offset on its bound, the bound warned; the offset on the bound."""
    spline, terms = _job(dt, 0.3)
    wide = estimate(spline, terms, verbose=False)
    free = float(terms[1].time_offset)
    assert abs(free) - bound > 4 * float(wide.std(terms[1], "time_offset"))
    spline, terms = _job(dt, bound)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = estimate(spline, terms, verbose=False)
    assert est.steps <= 10
    assert not bool(est.converged)
    assert f"Gyro.time_offset on its bound {np.sign(dt) * bound:g}" in est.reason, est.reason
    assert "raise max_time_offset" in est.reason
    messages = [str(w.message) for w in caught]
    assert any("ended on its bound" in m for m in messages), messages
    assert not any("steps=" in m for m in messages), messages
    assert float(terms[1].time_offset) == pytest.approx(np.sign(dt) * bound, abs=1e-12)


def test_interior_offset_converges_unchanged():
    """An offset inside its bound: the scaled gradient test passes, the estimate within 4
    std of the truth, nothing about bounds in the reason."""
    spline, terms = _job(0.03, 0.2, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = estimate(spline, terms, verbose=False)
        std = float(est.std(terms[1], "time_offset"))
    assert est.reason.startswith("the scaled gradient test passed"), est.reason
    assert abs(float(terms[1].time_offset) - 0.03) < 4 * std

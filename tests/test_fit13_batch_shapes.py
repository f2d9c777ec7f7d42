"""Batch shapes of the terms' data and nuisance values against the trajectory's batch
(fit13, outside testing with the public API).

Found here: a fixed bias ``(3, 3)``, a ``Free`` start ``(3, 3)``, a fixed time offset
``(3,)``, a gravity ``(3, 3)`` or a lever arm ``(2, 1, 3)`` with a batch of 2 trajectories,
a ``(2, 3)`` bias with one trajectory, and data of 3 trajectories on shared times with a
batch of 2 all failed deep inside with a ``RuntimeError`` of ``expand`` (or a ``ValueError``
of ``dualquat.mul``), naming nothing of the user's; readings ``(2, 1, N, 3)`` on shared
``(N,)`` times failed so at construction. Each now names the term, the argument and the
shapes expected; the shapes that fit (one value, or one per trajectory) still solve.
"""

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses, Positions, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
XI = torch.tensor([0.3, -0.2, 0.5, 0.4, 0.1, -0.3], dtype=F64)  # constant screw (rad/s, m/s)
T = torch.linspace(0.0, 2.0, 21, dtype=F64)
TI = torch.linspace(0.2, 1.8, 40, dtype=F64)


def _spline(batch):
    x = dq.exp(T[:, None] * XI).expand(*batch, len(T), 8)
    return BSpline.from_dualquats(x, T, n_ctrl=6, form="cumulative", degree=4)


def _poses(batch=(2,)):
    return Poses(T, dq.exp(T[:, None] * XI).expand(*batch, len(T), 8), rot_sigma=1e-3,
                 trans_sigma=1e-3)


def _gyro(batch=(2,), **kw):
    return Gyro(TI, XI[:3].expand(*batch, len(TI), 3), sigma=1e-3, **kw)


def _accel(**kw):
    return Accel(TI, torch.zeros(2, len(TI), 3, dtype=F64), sigma=1e-2, **kw)


def _positions(**kw):
    return Positions(T, torch.zeros(2, len(T), 3, dtype=F64), sigma=1e-2, **kw)


def _zeros(*shape):
    return torch.zeros(*shape, dtype=F64)


@pytest.mark.parametrize("batch, terms, match", [
    ((2,), lambda: [_poses(), _gyro(bias=_zeros(3, 3))], r"Gyro's bias \(3, 3\).*\(2, 3\)"),
    ((2,), lambda: [_poses(), _gyro(bias=Free(start=_zeros(3, 3)))], r"Gyro's bias start"),
    ((2,), lambda: [_poses(), _gyro(time_offset=_zeros(3))], r"Gyro's time_offset \(3,\)"),
    ((2,), lambda: [_poses(), _gyro(), _accel(gravity=torch.tensor([[0.0, 0.0, -9.81]] * 3,
                                                                   dtype=F64))],
     r"Accel's gravity \(3, 3\)"),
    ((2,), lambda: [_poses(), _positions(lever_arm=_zeros(2, 1, 3))],
     r"Positions's lever_arm \(2, 1, 3\)"),
    ((2,), lambda: [_poses(batch=(3,))], r"Poses data of batch \(3,\)"),
    ((), lambda: [_poses(batch=()), _gyro(batch=(), bias=_zeros(2, 3))],
     r"Gyro's bias \(2, 3\) does not match the trajectory's batch \(\): expected \(3,\)$"),
])
def test_a_batch_that_does_not_fit_is_named(batch, terms, match):
    with pytest.raises(ValueError, match=r"fitting\.estimate: " + match):
        estimate(_spline(batch), terms(), verbose=False)


def test_batches_that_fit_still_solve():
    """One value for all, or one per trajectory; one trajectory's data broadcast."""
    gyro = _gyro(bias=Free(start=_zeros(2, 3)), time_offset=_zeros(2))
    est = estimate(_spline((2,)), [_poses(batch=(1,)), gyro], verbose=False)
    assert est.converged.tolist() == [True, True] and gyro.bias.shape == (2, 3)
    torch.testing.assert_close(gyro.bias, _zeros(2, 3), atol=1e-9, rtol=0)


def test_readings_of_a_two_dim_batch_on_shared_times_are_built():
    g = Gyro(TI, XI[:3].expand(2, 1, len(TI), 3), sigma=1e-3)
    assert g.mask.shape == (2, 1, len(TI))
    with pytest.raises(ValueError, match=r"times must be non-decreasing"):
        Gyro(TI.flip(0), XI[:3].expand(2, 1, len(TI), 3), sigma=1e-3)

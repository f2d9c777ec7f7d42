"""The inertial terms' closed-form Jacobians (``fitting/_imu_jacobians.py``) build the same
Gauss-Newton system as the reverse pass over the residual code they replace, in the cases
the harness of ``test_term_jacobians.py`` (central differences of the public forward) does
not cover: batches of trajectories, masks, per-axis sigmas, gravity fixed or estimated, a
time offset, a motion at rest over a stretch (zero rates and accelerations), float32.
"""

from __future__ import annotations

import pytest
import torch
from test_term_jacobians import motion

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses
from torch_dq.fitting import _imu as imu
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._problem import Problem
from torch_dq.nn import BSpline

F64 = torch.float64


def _problem(batch: bool, rest: bool, gravity: str):
    t = torch.linspace(0.0, 2.0, 41, dtype=F64)
    x = motion(t)
    if rest:  # the first half at rest: equal control points there
        x = torch.where((t < 1.0)[:, None], x[20], x)
    traj = BSpline.from_dualquats(x, t, n_ctrl=12, form="cumulative", margin=0.1)
    ctrl = traj.control_points.detach()
    if batch:
        ctrl = torch.stack((ctrl, dq.mul(ctrl, dq.exp(0.01 * torch.randn(
            12, 6, generator=torch.Generator().manual_seed(1), dtype=F64)))))
        traj = BSpline(ctrl, knots=traj.knots, form="cumulative")
    ti = torch.linspace(0.1, 1.9, 37, dtype=F64)
    g = torch.Generator().manual_seed(2)
    shape = (2, 37, 3) if batch else (37, 3)
    mask = torch.rand(shape[:-1], generator=g) > 0.2
    grav = {"fixed": torch.tensor([0.1, 0.2, -9.8], dtype=F64), "free": 9.81,
            "start": Free(torch.tensor([0.3, -0.2, -9.8], dtype=F64))}[gravity]
    terms = [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01),
             Gyro(ti, torch.randn(shape, generator=g, dtype=F64), sigma=[0.01, 0.02, 0.03],
                  bias=True, time_offset=Free(0.01), mask=mask),
             Accel(ti, torch.randn(shape, generator=g, dtype=F64) + torch.tensor(
                 [0.0, 0.0, 9.8], dtype=F64), sigma=0.1, bias=True, gravity=grav, mask=mask)]
    problem = Problem(traj, terms, ctrl.shape[:-2])
    return problem, ctrl, _starts("test", problem, ctrl)


def _systems(problem, ctrl, values, monkeypatch):
    w = problem.width(values)
    closed = problem.system(ctrl, values, w)
    with monkeypatch.context() as m:
        m.setattr(imu.Gyro, "residual_jacobians", lambda self, *a: None)
        m.setattr(imu.Accel, "residual_jacobians", lambda self, *a: None)
        generic = problem.system(ctrl, values, w)
    return closed, generic


@pytest.mark.parametrize("gravity", ["fixed", "free", "start"])
@pytest.mark.parametrize(("batch", "rest"), [(False, False), (True, False), (False, True)])
def test_the_closed_form_builds_the_reverse_pass_system(batch, rest, gravity, monkeypatch):
    problem, ctrl, values = _problem(batch, rest, gravity)
    closed, generic = _systems(problem, ctrl, values, monkeypatch)
    for name in ("band", "cn", "nn", "gc", "gn"):
        a, b = getattr(closed, name), getattr(generic, name)
        assert float(b.abs().max()) > 0
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12 * float(b.abs().max()))
    for a, b in zip(closed.residuals, generic.residuals, strict=True):
        # the closed form's residuals by the compiled loop where built (rest18), the reverse
        # pass's by the PyTorch code (autograd): the same to rounding, not to the bit
        torch.testing.assert_close(a, b, rtol=0, atol=1e-14 * float(b.abs().max()))


def test_the_rows_vanish_where_masked_and_at_rest():
    """Masked samples' rows are zero; at rest (zero rates) the gyroscope's rows with respect
    to the pose are zero and those to the rate are ``2 r e_j`` (unit norm 2)."""
    problem, ctrl, values = _problem(False, True, "fixed")
    gyro = problem.terms[1]
    x = problem.spans.trajectory(gyro.times, ctrl=ctrl).detach()
    dx = torch.zeros_like(x)
    p = gyro.per_sample(problem.term_values(1, values))
    r, (rows, bias) = gyro.residual_jacobians([(x, dx)], p, ["bias"])
    sigma = torch.tensor([0.01, 0.02, 0.03], dtype=F64)
    on = gyro.mask
    assert float(rows[~on].abs().max()) == 0 and float(bias[~on].abs().max()) == 0
    assert float(r[~on].abs().max()) == 0
    torch.testing.assert_close(rows[on][:, :, 0], torch.zeros_like(rows[on][:, :, 0]))
    torch.testing.assert_close(rows[on][:, :, 1, :4].norm(dim=-1),
                               (2.0 / sigma).expand(int(on.sum()), 3))
    torch.testing.assert_close(bias[on], torch.diag(1 / sigma).expand(int(on.sum()), 3, 3))

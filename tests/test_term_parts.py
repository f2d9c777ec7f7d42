"""Streaming a long term a part at a time (``Term.parts``, ``fitting._linearize.PART``): the
Gauss-Newton system and the trial costs assembled part by part equal those of the whole
term (the same per-sample arithmetic, summed in another order), for every term class,
the random-walk IMU terms of the calibration, a batch with per-trajectory times and a term
defined outside the library (which is never cut: its buffers' sample dims are unknown)."""

from __future__ import annotations

import pytest
import torch
from test_term_jacobians import TERMS, ClockDrift, curve, motion

import torch_dq.dualquat as dq
from torch_dq.calibration._walk import WalkAccel, WalkGyro
from torch_dq.fitting import Free, Poses, _linearize
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._problem import Problem

F64 = torch.float64


def _walk_gyro(traj):
    t = torch.linspace(0.2, 1.8, 11, dtype=F64)
    g = torch.Generator().manual_seed(11)
    return WalkGyro(t, 0.3 + 0.05 * torch.randn(11, 3, generator=g, dtype=F64), sigma=0.01,
                    edges=torch.tensor([0.2, 0.8, 1.4, 1.81], dtype=F64), walk=0.01,
                    starts=torch.zeros(3, 3, dtype=F64))


def _walk_accel(traj):
    t = torch.linspace(0.2, 1.8, 11, dtype=F64)
    g = torch.Generator().manual_seed(12)
    return WalkAccel(t, torch.tensor([0.0, 0.0, 9.81], dtype=F64) + torch.randn(
        11, 3, generator=g, dtype=F64), sigma=0.1, edges=torch.tensor([0.2, 1.0, 1.81],
                                                                      dtype=F64),
        walk=0.01, starts=torch.zeros(2, 3, dtype=F64),
        gravity=Free(torch.tensor([0.3, -0.2, -9.8], dtype=F64)))


def _batched(traj):
    """Two trajectories, each with its own times and poses."""
    t = torch.stack((torch.linspace(0.3, 1.7, 9, dtype=F64),
                     torch.linspace(0.35, 1.65, 9, dtype=F64)))
    x = dq.mul(motion(t.reshape(-1)).reshape(2, 9, 8), dq.exp(
        0.02 * torch.randn(2, 9, 6, generator=torch.Generator().manual_seed(13), dtype=F64)))
    return Poses(t, x, rot_sigma=0.01, trans_sigma=0.02, time_offset=Free(0.01))


CASES = {**TERMS, "WalkGyro": _walk_gyro, "WalkAccel": _walk_accel, "batched": _batched}


def _system(term, traj, monkeypatch, part: int):
    monkeypatch.setattr(_linearize, "PART", part)
    ctrl = traj.control_points.detach()
    if term.mask.dim() > 1:  # a batch of trajectories
        ctrl = ctrl.expand(term.mask.shape[0], *ctrl.shape).clone()
    problem = Problem(traj, [term], ctrl.shape[:-2])
    values = _starts("test", problem, ctrl)
    s = problem.linearization.system(ctrl, values, problem.width(values))
    return s, _linearize.residuals(problem, 0, ctrl, values)


@pytest.mark.parametrize("name", sorted(CASES))
def test_system_in_parts_equals_the_whole(name, monkeypatch):
    traj = curve("cumulative")
    term = CASES[name](traj)
    whole, r_whole = _system(term, traj, monkeypatch, 1 << 20)
    if not isinstance(term, ClockDrift):
        assert len(term.parts(4)) == -(-term.N // 4) >= 2
    cut, r_cut = _system(term, traj, monkeypatch, 4)
    for field in ("band", "cn", "nn", "gc", "gn"):
        a, b = getattr(whole, field), getattr(cut, field)
        assert float(a.abs().amax()) > 0, field
        torch.testing.assert_close(b, a, atol=1e-12 * float(a.abs().amax()), rtol=0,
                                   msg=field)
    torch.testing.assert_close(cut.residuals[0], whole.residuals[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(cut.weights[0], whole.weights[0], atol=1e-12, rtol=0)
    torch.testing.assert_close(r_cut, r_whole, atol=1e-12, rtol=0)
    assert r_cut.shape == (*term.mask.shape, term.dim)


def test_parts_are_views_and_leave_the_term_alone():
    traj = curve("cumulative")
    term = TERMS["Reprojections"](traj)
    before = {k: v.clone() for k, v in term.state_dict().items()}
    parts = term.parts(3)
    assert [p.N for p in parts] == [3, 3, 2]
    for a, part in zip((0, 3, 6), parts, strict=True):
        assert part.pixels.data_ptr() == term.pixels[a:].data_ptr()  # a view, no copy
        torch.testing.assert_close(part.points, term.points[a:a + part.N])
        torch.testing.assert_close(part.rows, term.rows[a:a + part.N])
        torch.testing.assert_close(part.times, term.times[a:a + part.N])
        assert part.camera_params is term.camera_params and part.sigma is term.sigma
        assert part.slots() == term.slots()
    assert term.N == 8 and term.pixels.shape == (8, 2)
    for k, v in term.state_dict().items():
        assert torch.equal(v, before[k]), k
    assert term.parts(8) == [term]


def test_a_term_defined_outside_is_not_cut():
    """Its buffers were registered with ``register_buffer``: their sample dims are unknown,
    so the term is linearised whole."""
    term = TERMS["ClockDrift"](curve("cumulative"))
    assert term.parts(2) == [term]

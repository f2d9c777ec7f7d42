"""The torch-optimizer path (``term(trajectory)``, ``term.evaluate``, ``term.cost``) at UNIX
stamps reads the trajectory at ``(t - origin) + dt``, as ``estimate`` does.

At stamps near 1.4e9 s the float64 spacing is 2.4e-7 s: ``t + dt`` rounded there makes the
residuals a staircase in a clock offset ``dt`` (Adam on an offset sees zero gradients
between steps, the finite differences of the cost jumps). The same control points and
knots from origin 0 s and from 1403709395 s (stamps on a grid of powers of two, exact at
both) must give the same residuals at every offset, and their gradient with respect to the
offset must be the central difference of the residuals at origin 0 (well conditioned
there).
"""

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.fitting import Accel, Gyro, Poses
from torch_dq.nn import BSpline

F64 = torch.float64
T0 = 1403709395.0
SPACING = 0.125


def _ctrl(n=40):
    """Smooth unit control points: a random walk of rotations and positions."""
    rng = np.random.default_rng(7)
    rv = np.cumsum(0.15 * rng.standard_normal((n, 3)), 0)
    p = np.cumsum(0.2 * rng.standard_normal((n, 3)), 0)
    return dq.from_rt(quat.from_rotvec(torch.as_tensor(rv)), torch.as_tensor(p))


def _spline(t0, n=40):
    knots = torch.arange(-3, n + 1, dtype=F64) * SPACING + t0  # uniform, exact at t0
    return BSpline(_ctrl(n), knots=knots, form="cumulative")


def _terms(t0, dt=0.0):
    rng = np.random.default_rng(1)
    tg = torch.as_tensor(t0 + 0.5 + np.arange(512) / 256.0)
    tp = torch.as_tensor(t0 + 0.5 + np.arange(64) / 32.0)
    r3 = torch.as_tensor(rng.standard_normal((512, 3)))
    poses = dq.from_rt(quat.from_rotvec(torch.as_tensor(rng.standard_normal((64, 3)))),
                       torch.as_tensor(rng.standard_normal((64, 3))))
    return [Gyro(tg, r3, sigma=1e-3, time_offset=dt),
            Accel(tg, 9.81 * r3, sigma=1e-2, time_offset=dt),
            Poses(tp, poses, rot_sigma=1e-3, trans_sigma=1e-3, time_offset=dt)]


def _residuals(spline, term, dt):
    values = term.values(spline)
    values["time_offset"] = dt
    return term.evaluate(spline, None, values)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_residuals_at_unix_stamps_equal_those_from_zero(k):
    s0, s1 = _spline(0.0), _spline(T0)
    a, b = _terms(0.0)[k], _terms(T0)[k]
    offsets = 0.0037 + 1e-8 * torch.arange(30, dtype=F64)  # 24 steps of 2.4e-7 s would hide
    r0 = torch.stack([_residuals(s0, a, dt) for dt in offsets])
    r1 = torch.stack([_residuals(s1, b, dt) for dt in offsets])
    scale = r0.abs().max()
    assert (r1 - r0).abs().max() <= 1e-9 * scale, (r1 - r0).abs().max() / scale
    # smooth in the offset: second differences of 1e-8 s steps are tiny
    moved = (r1[1:] - r1[:-1]).abs().amax((1, 2))
    assert bool((moved > 0).all()), "a flat step: the residuals ignore a 1e-8 s change"


@pytest.mark.parametrize("k", [0, 1, 2])
def test_offset_gradient_matches_central_difference(k):
    s0, s1 = _spline(0.0), _spline(T0)
    a, b = _terms(0.0)[k], _terms(T0)[k]
    weights = torch.as_tensor(np.random.default_rng(2).standard_normal(
        tuple(_residuals(s0, a, torch.zeros((), dtype=F64)).shape)))
    dt = torch.tensor(0.0037, dtype=F64, requires_grad=True)
    (g,) = torch.autograd.grad((_residuals(s1, b, dt) * weights).sum(), dt)
    h = 1e-6
    fd = ((_residuals(s0, a, torch.tensor(0.0037 + h, dtype=F64))
           - _residuals(s0, a, torch.tensor(0.0037 - h, dtype=F64))) * weights).sum() / (2 * h)
    g, fd = float(g), float(fd.detach())
    assert abs(g - fd) <= 1e-6 * abs(fd), (g, fd)


def test_cost_at_unix_stamps_equals_cost_from_zero():
    s0, s1 = _spline(0.0), _spline(T0)
    for dt in (0.0011, 0.0011 + 3e-8):
        for a, b in zip(_terms(0.0, dt), _terms(T0, dt), strict=True):
            c0, c1 = a.cost(s0).detach(), b.cost(s1).detach()
            assert abs(float(c1 - c0)) <= 1e-9 * float(c0), (type(a).__name__, dt)

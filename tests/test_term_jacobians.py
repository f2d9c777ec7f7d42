"""The per-term Jacobian harness (basalt's ``test_jacobian``): for every term class and every
estimated parameter, the Jacobians that ``fitting.estimate`` uses (exact, chained through the
curve's spans) against central differences of an independent evaluation, the term's public
forward through the layer (``term.evaluate``, the curve's own ``derivatives``), with the
control points moved by ``c_k exp(h e_j)`` and the parameters by their charts. The terms
read the curve's value (Poses, Positions, RelativePoses, Reprojections), its first
(Gyro) and second (Accel) derivatives; parameters that move the samples' times (a time
offset, a line delay, the toy term's clock drift) go through the curve's time derivative.

The charts are checked against formulas written here (numpy, scipy); a toy term defined here
with a time-moving parameter of its own (a clock drift, ``t' = t + dt + d (t - t_0)``) runs
through ``estimate`` and recovers its value.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.camera import Camera
from torch_dq.fitting import (
    Accel,
    Free,
    Gyro,
    Poses,
    Positions,
    RelativePoses,
    Reprojections,
    Term,
    estimate,
)
from torch_dq.fitting._charts import CHARTS, Direction, Pose, Scalar, Vector
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._nuisance import Slot
from torch_dq.fitting._problem import Problem
from torch_dq.fitting._terms import Options
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64
XI = torch.tensor([0.3, -0.2, 0.9, 0.4, 0.1, -0.2], dtype=F64)  # rad/s, m/s


def motion(t: torch.Tensor) -> torch.Tensor:
    """A smooth screw motion with a wobble: ``(T, 8)``."""
    wob = torch.stack((0.2 * torch.sin(1.3 * t), 0.1 * torch.cos(0.7 * t), 0 * t,
                       0.05 * torch.sin(t), 0 * t, 0.1 * torch.cos(1.1 * t)), -1)
    return dq.mul(dq.exp(t[:, None] * XI), dq.exp(wob))


def curve(kind: str):
    t = torch.linspace(0.0, 2.0, 41, dtype=F64)
    if kind == "bezier":
        return Bezier.from_dualquats(motion(t), t, n_ctrl=6)
    return BSpline.from_dualquats(motion(t), t, n_ctrl=9, form=kind)


def generic_dq(seed: int, scale: float = 0.2) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return dq.exp(scale * torch.randn(6, generator=g, dtype=F64))


# ----------------------------------------------------------------------------- the terms

def _camera():
    params = np.array([460.0, 458.0, 376.0, 240.0, -0.28, 0.07, 2e-4, 2e-5])
    return Camera("pinhole-radtan", torch.from_numpy(params), (752, 480))


def _reprojections(traj):
    """Points 1-2 m ahead of a camera looking along the body's x axis."""
    t = torch.linspace(0.4, 1.6, 8, dtype=F64)
    e = dq.from_rt(quat.from_matrix(torch.from_numpy(
        Rotation.from_euler("yz", [90.0, -90.0], degrees=True).as_matrix())),
        torch.tensor([0.02, -0.01, 0.03], dtype=F64))
    g = torch.Generator().manual_seed(3)
    cam_pts = torch.cat((0.3 * torch.randn(8, 2, generator=g, dtype=F64),
                         1.5 + 0.3 * torch.rand(8, 1, generator=g, dtype=F64)), -1)
    with torch.no_grad():
        world = dq.apply(dq.mul(traj(t), e), cam_pts)
    cam = _camera()
    pix = torch.tensor([[376.0, 240.0]], dtype=F64) + 3 * torch.randn(8, 2, generator=g,
                                                                      dtype=F64)
    return Reprojections(t, world, pix, camera=cam, sigma=0.5,
                         extrinsic=Free(dq.mul(e, generic_dq(4, 0.02))),
                         target=Free(generic_dq(5, 0.02)), intrinsics=True,
                         time_offset=Free(0.004), line_delay=Free(2e-5), max_line_delay=1e-3)


def _poses(traj):
    t = torch.linspace(0.3, 1.7, 7, dtype=F64)
    x = dq.mul(motion(t), generic_dq(1, 0.05))
    return Poses(t, x, rot_sigma=0.01, trans_sigma=0.02, extrinsic=Free(generic_dq(2)),
                 time_offset=Free(0.01))


def _positions(traj):
    t = torch.linspace(0.3, 1.7, 7, dtype=F64)
    p = dq.to_rt(motion(t))[1] + 0.01
    return Positions(t, p, sigma=0.01, lever_arm=Free(torch.tensor([0.1, -0.2, 0.05],
                                                                    dtype=F64)),
                     time_offset=Free(-0.02))


def _relative(traj):
    t0 = torch.linspace(0.3, 1.2, 5, dtype=F64)
    t1 = t0 + torch.tensor([0.1, 0.3, 0.45, 0.2, 0.5], dtype=F64)
    x = dq.mul(dq.mul(dq.conj(motion(t0)), motion(t1)), generic_dq(6, 0.03))
    return RelativePoses(t0, t1, x, rot_sigma=0.02, trans_sigma=0.02, time_offset=Free(0.01))


def _gyro(traj):
    t = torch.linspace(0.2, 1.8, 9, dtype=F64)
    g = torch.Generator().manual_seed(7)
    return Gyro(t, XI[:3].expand(9, 3) + 0.05 * torch.randn(9, 3, generator=g, dtype=F64),
                sigma=0.01, bias=Free(torch.tensor([0.01, -0.02, 0.03], dtype=F64)),
                time_offset=Free(0.015))


def _accel(traj):
    t = torch.linspace(0.2, 1.8, 9, dtype=F64)
    g = torch.Generator().manual_seed(8)
    return Accel(t, torch.tensor([0.0, 0.0, 9.81], dtype=F64) + torch.randn(
        9, 3, generator=g, dtype=F64), sigma=0.1,
        bias=Free(torch.tensor([0.1, -0.05, 0.02], dtype=F64)),
        gravity=Free(torch.tensor([0.3, -0.2, -9.8], dtype=F64)), time_offset=Free(-0.01))


class ClockDrift(Term):
    r"""A toy term defined outside the library: positions stamped by a clock that runs
    fast by ``drift`` (a time-moving parameter of its own): ``t' = t + dt + drift (t -
    t_0)``, residual ``p(t') - p_m`` over ``sigma``."""

    dim = 3
    _fn = "test.ClockDrift"

    def __init__(self, times, positions, *, sigma, drift=None, time_offset=None) -> None:
        super().__init__([times], ["times"], positions, 1,
                         torch.full((3,), float(sigma), dtype=F64), Options(time_offset))
        self.register_buffer("positions", positions.detach())
        self.t0 = float(times[0])
        self._slots["drift"] = Slot(self._fn, "drift", Scalar(-0.05, 0.05), drift)

    def time_rates(self):
        rates = dict(super().time_rates())
        if self._slots["drift"].present:
            rates["drift"] = self.times - self.t0
        return rates

    def _residual(self, ev, p):
        return dq.to_rt(ev[0][0])[1] - self.positions.to(ev[0][0].dtype)


def _drift(traj):
    t = torch.linspace(0.3, 1.6, 9, dtype=F64)
    p = dq.to_rt(motion(t + 0.02 * (t - 0.3)))[1]
    return ClockDrift(t, p, sigma=0.01, drift=Free(0.01), time_offset=Free(0.005))


TERMS = {"Poses": _poses, "Positions": _positions, "RelativePoses": _relative,
         "Gyro": _gyro, "Accel": _accel, "Reprojections": _reprojections,
         "ClockDrift": _drift}
ORDERS = {"Poses": 0, "Positions": 0, "RelativePoses": 0, "Gyro": 1, "Accel": 2,
          "Reprojections": 0, "ClockDrift": 0}


# ----------------------------------------------------------------------------- the harness

def _solver_jacobian(problem, ctrl, values):
    """The dense ``(N k, 6 n + m)`` Jacobian the solver uses for term 0, and ``r``."""
    lin = problem.linearization
    w = problem.width(values)
    r, f0, Jc, Jn = lin._chained(0, problem.terms[0], ctrl, values, w)
    N, k = r.shape[-2:]
    n, m = ctrl.shape[-2], problem.m
    J = torch.zeros(N, k, 6 * n + m, dtype=F64)
    for i in range(N):
        for a in range(w):
            c = int(f0[i]) + a
            if c < n:
                J[i, :, 6 * c:6 * c + 6] += Jc[i, :, a]
    for name, Ji in Jn.items():
        q = problem.index[(0, name)]
        J[..., 6 * n + q.offset:6 * n + q.offset + q.dim] += Ji
    return J.reshape(N * k, -1), r


def _central(problem, traj, ctrl, values, h=1e-6):
    """Central differences of the term's public forward through the layer."""
    term, n, m = problem.terms[0], ctrl.shape[-2], problem.m

    def residual(x):
        c, v = problem.retract(ctrl, values, x[:6 * n].reshape(n, 6), x[6 * n:])
        with torch.no_grad():
            return term.evaluate(traj, c, problem.term_values(0, v)).reshape(-1)

    cols = []
    for e in torch.eye(6 * n + m, dtype=F64):
        cols.append((residual(h * e) - residual(-h * e)) / (2 * h))
    return torch.stack(cols, -1), residual(torch.zeros(6 * n + m, dtype=F64))


@pytest.mark.parametrize("kind", ["de_boor", "cumulative", "bezier"])
@pytest.mark.parametrize("name", sorted(TERMS))
def test_solver_jacobians_match_central_differences(name, kind):
    traj = curve(kind)
    term = TERMS[name](traj)
    assert term.order == ORDERS[name]
    ctrl = traj.control_points.detach()
    problem = Problem(traj, [term], ctrl.shape[:-2])
    values = _starts("test", problem, ctrl)
    J, r = _solver_jacobian(problem, ctrl, values)
    ref, r_ref = _central(problem, traj, ctrl, values)
    torch.testing.assert_close(r.reshape(-1), r_ref, atol=1e-9, rtol=1e-9)
    scale = ref.abs().amax(0, keepdim=True).clamp_min(1.0)
    torch.testing.assert_close(J / scale, ref / scale, atol=2e-6, rtol=0)
    n = ctrl.shape[-2]
    for q in problem.params:  # every estimated parameter moves the residuals
        cols = slice(6 * n + q.offset, 6 * n + q.offset + q.dim)
        assert float(ref[:, cols].abs().amax()) > 1e-3, q.uses


@pytest.mark.parametrize("name", sorted(TERMS))
def test_costs_and_jacobians_take_one_path(name):
    """The residuals of the solver's cost path (through the spans) equal the linearisation's
    and the public forward's."""
    from torch_dq.fitting import _linearize
    traj = curve("cumulative")
    term = TERMS[name](traj)
    ctrl = traj.control_points.detach()
    problem = Problem(traj, [term], ctrl.shape[:-2])
    values = _starts("test", problem, ctrl)
    r_cost = _linearize.residuals(problem, 0, ctrl, values)
    r_lin = problem.linearization._chained(0, term, ctrl, values, problem.width(values))[0]
    torch.testing.assert_close(r_cost, r_lin, atol=0, rtol=0)
    torch.testing.assert_close(r_cost, term(traj).detach(), atol=1e-10, rtol=1e-10)


# ----------------------------------------------------------------------------- the charts

def _samples(chart, seed):
    g = torch.Generator().manual_seed(seed)
    if isinstance(chart, Pose):
        return generic_dq(seed, 0.7)
    if isinstance(chart, Direction):
        return torch.tensor([0.2, -0.4, -9.7], dtype=F64) + torch.randn(3, generator=g,
                                                                        dtype=F64)
    if isinstance(chart, Scalar):
        return torch.tensor(0.01 * seed, dtype=F64)
    return torch.randn(chart.shape, generator=g, dtype=F64)


@pytest.mark.parametrize("chart", [Vector(3), Vector(8), Scalar(), Pose(), Direction()],
                         ids=lambda c: c.describe())
def test_chart_laws(chart):
    """``local(v, retract(v, d)) = d`` for small steps, ``retract(v, 0) = v``, the step's
    first-order effect against a formula written here."""
    assert type(chart).name in CHARTS and CHARTS[type(chart).name] is type(chart)
    v = _samples(chart, 3)
    g = torch.Generator().manual_seed(9)
    d = 0.1 * torch.randn(chart.dim, generator=g, dtype=F64)
    torch.testing.assert_close(chart.retract(v, torch.zeros_like(d)), v, atol=1e-15, rtol=0)
    torch.testing.assert_close(chart.local(v, chart.retract(v, d)), d, atol=1e-12, rtol=0)
    moved = chart.retract(v, d).numpy()
    if isinstance(chart, Pose):  # x exp(d): scipy's rotation of the body-frame twist
        R0 = Rotation.from_quat(np.roll(v[:4].numpy(), -1))
        R1 = Rotation.from_quat(np.roll(moved[:4], -1))
        np.testing.assert_allclose((R0.inv() * R1).as_rotvec(), d[:3].numpy(), atol=1e-12)
    elif isinstance(chart, Direction):  # the norm kept, moved orthogonally to g
        g0 = v.numpy()
        np.testing.assert_allclose(np.linalg.norm(moved), np.linalg.norm(g0), rtol=1e-13)
        angle = math.acos(np.dot(moved, g0) / np.dot(g0, g0))
        assert angle == pytest.approx(float(d.norm()), rel=1e-12)
    else:
        np.testing.assert_allclose(moved, v.numpy() + d.numpy().reshape(v.shape), atol=1e-15)


def test_direction_report_maps_the_chart_to_world_axes():
    """Gravity's reported coordinates: ``d Exp(B d) g / d d`` by central differences."""
    chart, g = Direction(), torch.tensor([0.3, -0.2, -9.8], dtype=F64)
    h = 1e-6
    fd = torch.stack([(chart.retract(g, h * e) - chart.retract(g, -h * e)) / (2 * h)
                      for e in torch.eye(2, dtype=F64)], -1)
    torch.testing.assert_close(chart.report(g), fd, atol=1e-7, rtol=0)


def test_scalar_bounds():
    c = Scalar(-0.1, 0.1)
    assert float(c.retract(torch.tensor(0.09, dtype=F64), torch.tensor([0.5], dtype=F64))) \
        == 0.1
    assert c.pinned(torch.tensor([0.1, -0.1, 0.05], dtype=F64)).tolist() == [True, True, False]
    assert not bool(Scalar(0.0, 1e-4).pinned(torch.tensor(0.0, dtype=F64)))
    assert c.bounded(-0.05, 0.2).low == -0.05 and c.bounded(-0.05, 0.2).high == 0.1


# ----------------------------------------------------------------------------- the toy term

def test_toy_term_with_a_time_moving_parameter_runs_through_estimate():
    """A clock drift of 0.02 (its own time rate ``t - t_0``) recovered with the trajectory
    from poses and drifting positions; the domain check widens by what the drift's bounds
    reach."""
    gen = torch.Generator().manual_seed(3)  # noise as the sigmas say
    tc = torch.linspace(0.0, 4.0, 161, dtype=F64)
    truth = dq.mul(motion(tc), dq.exp(1e-3 * torch.randn(161, 6, generator=gen, dtype=F64)))
    traj = BSpline.from_dualquats(truth, tc, n_ctrl=40, form="cumulative")
    tp = torch.linspace(0.5, 3.0, 126, dtype=F64)
    drifting = ClockDrift(tp, dq.to_rt(motion(tp + 0.02 * (tp - 0.5)))[1]
                          + 1e-3 * torch.randn(126, 3, generator=gen, dtype=F64), sigma=1e-3,
                          drift=Free(0.0))
    lo, hi = drifting.time_reach()
    assert float(lo.min()) == pytest.approx(-0.05 * 2.5) and float(hi.max()) == \
        pytest.approx(0.05 * 2.5)
    est = estimate(traj, [Poses(tc, truth, rot_sigma=1e-3, trans_sigma=1e-3), drifting],
                   verbose=False)
    assert bool(est.converged)
    assert est.parameters == [(drifting, "drift", 1)]
    std = float(est.std(drifting, "drift"))
    assert std < 1e-3 and abs(float(drifting._value("drift")) - 0.02) < 4 * std
    inside = torch.linspace(0.5, 1.95, 30, dtype=F64)  # inside [0, 1.975], not with the drift
    with pytest.raises(ValueError, match="ClockDrift times by drift leave"):
        estimate(BSpline.from_dualquats(truth[:80], tc[:80], n_ctrl=20),
                 [Poses(tc[:80], truth[:80], rot_sigma=1e-3, trans_sigma=1e-3),
                  ClockDrift(inside, dq.to_rt(motion(inside))[1], sigma=1e-3,
                             drift=Free(0.0))], verbose=False)


def test_a_time_moving_parameter_must_be_a_scalar():
    """A term whose time-moving parameter has another chart is told so, naming it."""
    t = torch.linspace(0.5, 1.5, 5, dtype=F64)
    term = ClockDrift(t, torch.zeros(5, 3, dtype=F64), sigma=0.01, drift=Free(0.0))
    term._slots["drift"] = Slot(term._fn, "drift", Vector(1), Free(torch.zeros(1, dtype=F64)))
    with pytest.raises(TypeError, match=r"test\.ClockDrift: drift moves the samples' times "
                                        r"\(time_rates\): its chart must be a Scalar"):
        term.time_reach()

"""The span vector-Jacobian products that skip the rows whose second-order cotangents are
known zero (``span_vjp(..., second=rows)``: a gyroscope's rows grouped with an
accelerometer's) and that read the curve's span tables computed once
(``span_vjp(..., tables=span_vjp_tables(ctrl))``) against reverse mode through the span's
public evaluation, and the system of poses and a grouped IMU against the reverse passes
they replace."""

from __future__ import annotations

import pytest
import torch
from test_perf9_cumulative_lie import _spline, span_samples  # one curve, its spans' samples

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Gyro, Poses, _linearize
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._linearize import _second
from torch_dq.fitting._problem import Problem
from torch_dq.nn import BSpline

F64 = torch.float64


def _reverse(spline: BSpline, pts, local, first, cot):
    """``(N, k, 4, 6)``: reverse mode through ``evaluate_span`` of the points moved by right
    steps ``c_i Exp(delta_i)`` at ``delta = 0``, one pass per row of ``cot (N, k, 3, 8)``."""
    rows = []
    for j in range(cot.shape[1]):
        delta = torch.zeros(*pts.shape[:-1], 6, dtype=F64, requires_grad=True)
        out = spline.evaluate_span(dq.mul(pts, dq.exp(delta)), local, first, 2)
        total = sum((x * cot[:, j, o]).sum() for o, x in enumerate(out))
        rows.append(torch.autograd.grad(total, delta)[0])
    return torch.stack(rows, 1)


@pytest.mark.parametrize("second", [slice(0, 2), slice(3, 5), slice(1, 4), slice(0, 5)])
def test_span_vjp_of_known_zero_second_order_rows_equals_reverse_mode(second):
    """Rows outside ``second`` with zero second-order cotangents (leading, trailing, both
    sides, none): the same products as reverse mode, and entries there are not read."""
    spline = _spline(seed=5)
    t, first, local, ctrl, pts = span_samples(spline, 11)
    cot = torch.randn(len(t), 5, 3, 8, generator=torch.Generator().manual_seed(6), dtype=F64)
    off = torch.ones(5, dtype=torch.bool)
    off[second] = False
    cot[:, off, 2] = 0.0
    with torch.no_grad():
        pose = spline.span_derivatives(ctrl, local, first, 0)[0]
    G = spline.span_vjp(pts, local, first, cot, pose, second)
    ref = _reverse(spline, pts, local, first, cot)
    assert G.shape == ref.shape == (len(t), 5, 4, 6)
    assert float((G - ref).abs().max()) < 1e-11 * float(ref.abs().max())
    junk = cot.clone()
    junk[:, off, 2] = float("nan")  # never read
    assert torch.equal(spline.span_vjp(pts, local, first, junk, pose, second), G)


@pytest.mark.parametrize("batch", [False, True])
def test_span_vjp_from_the_curves_tables_equals_reverse_mode(batch):
    """The tables of every span of the control points (a batch of two curves: each row its
    own spans), read by the samples' spans: the same products as reverse mode; tables of
    another batch shape are not read (the products from the points, still right)."""
    spline = _spline(seed=9)
    ctrl = spline.control_points.detach()
    if batch:
        ctrl = torch.stack((ctrl, dq.mul(ctrl, dq.exp(0.05 * torch.randn(
            9, 6, generator=torch.Generator().manual_seed(10), dtype=F64)))))
        spline = BSpline(ctrl, degree=3, knots=spline.knots, form="cumulative")
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo + 1e-3, hi - 1e-3, 13, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    pts = torch.stack([ctrl[..., f:f + 4, :] for f in first.tolist()], -3)
    lead = pts.shape[:-2]
    cot = torch.randn(*lead, 2, 3, 8, generator=torch.Generator().manual_seed(11), dtype=F64)
    with torch.no_grad():
        pose = spline.span_derivatives(ctrl, local, first, 0)[0]
    tables = spline.span_vjp_tables(ctrl)
    assert tables.shape == (80, 3, *ctrl.shape[:-2], 6)
    G = spline.span_vjp(pts, local, first, cot, pose, tables=tables)
    flat = _reverse(spline, pts.reshape(-1, 4, 8), local.expand(lead).reshape(-1),
                    first.expand(lead).reshape(-1), cot.reshape(-1, 2, 3, 8))
    ref = flat.reshape(*lead, 2, 4, 6)
    assert float((G - ref).abs().max()) < 1e-11 * float(ref.abs().max())
    other = spline.span_vjp(pts, local, first, cot, pose,
                            tables=tables[:, :, :1] if batch else tables[:, :, None])
    assert float((other - ref).abs().max()) < 1e-11 * float(ref.abs().max())


def test_second_rows_of_stacked_terms():
    """The rows of a group's stacked Jacobians whose second order may be nonzero: the terms
    that read it, when they are consecutive; else all (None)."""
    def rows(*spec):
        return [torch.zeros(4, k, o, 8) for k, o in spec]

    assert _second(rows((3, 2), (3, 3))) == slice(3, 6)
    assert _second(rows((3, 3), (2, 2))) == slice(0, 3)
    assert _second(rows((1, 2), (2, 3), (3, 3), (1, 1))) == slice(1, 6)
    assert _second(rows((2, 3), (1, 2), (2, 3))) is None
    assert _second(rows((3, 2), (3, 1))) is None


@pytest.mark.parametrize("cut", ["whole", "chunks", "parts"])
def test_grouped_imu_system_equals_the_reverse_passes(cut, monkeypatch):
    """Poses, and a gyroscope and an accelerometer read at the same times (one group, the
    gyroscope's rows first): the system through the closed form (one table of the spans for
    both groups, the gyroscope's second order skipped; also in chunks of 16 samples, and in
    parts of 25, which compute their own spans') equals the one by reverse passes through
    the spans (no closed form)."""
    if cut == "chunks":
        monkeypatch.setattr(_linearize, "_CHUNK", 16)
    elif cut == "parts":
        monkeypatch.setattr(_linearize, "PART", 25)
    spline = _spline(n=12, seed=7)
    lo, hi = (float(x) for x in spline.domain)
    ti = torch.linspace(lo + 1e-3, hi - 1e-3, 60, dtype=F64)
    g = torch.Generator().manual_seed(8)
    tc = torch.linspace(lo + 2e-3, hi - 2e-3, 23, dtype=F64)
    with torch.no_grad():
        poses = spline(tc)
    terms = [Poses(tc, poses, rot_sigma=0.01, trans_sigma=0.02),
             Gyro(ti, torch.randn(60, 3, generator=g, dtype=F64), sigma=0.01, bias=True),
             Accel(ti, torch.randn(60, 3, generator=g, dtype=F64), sigma=0.1, bias=True,
                   gravity=9.81)]
    ctrl = spline.control_points.detach()
    problem = Problem(spline, terms, ctrl.shape[:-2])
    values = _starts("test", problem, ctrl)
    assert sorted(len(x) for x in problem.groups(values)) == [1, 2]
    w = problem.width(values)
    closed = problem.system(ctrl, values, w)
    monkeypatch.setattr(BSpline, "span_vjp", lambda self, *a, **k: None)
    ref = problem.system(ctrl, values, w)
    for name in ("band", "cn", "nn", "gc", "gn"):
        a, b = getattr(closed, name), getattr(ref, name)
        assert float((a - b).abs().max()) <= 1e-9 * float(b.abs().max()), name

"""The span derivatives' Jacobians that the Gauss-Newton systems chain (issue 34): with
respect to the window's tangent steps ``c_j exp(delta_j)`` (one reverse pass per residual
row) and to the sample's time (the next time derivative times the local time's rate, no
time in the graph), against reverse mode through the layer's public ``derivatives`` written
here, per sample (the control points moved in the full curve, the time shifted): de Boor,
cumulative and Bezier curves, orders 0 to 2, generic and near-degenerate spans (identical
consecutive control points, a 180 degree increment), a batch of curves.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq._curve import span_points
from torch_dq.fitting._linearize import Linearization
from torch_dq.fitting._local import SpanEvaluator, tangent_step
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64


def _ctrl(n: int, degenerate: bool, batch: tuple[int, ...]) -> torch.Tensor:
    g = torch.Generator().manual_seed(7)
    c = dq.exp(0.4 * torch.randn(*batch, n, 6, generator=g, dtype=F64))
    if degenerate:  # c_2 == c_1, and a half turn about z from c_3 to c_4
        c = c.clone()
        c[..., 2, :] = c[..., 1, :]
        half = torch.tensor([0.0, 0.0, math.pi, 0.1, 0.0, 0.0], dtype=F64)
        c[..., 4, :] = dq.mul(c[..., 3, :], dq.exp(half))
    return c


def _curve(kind: str, degenerate: bool, batch: tuple[int, ...]):
    if kind == "bezier":
        return Bezier(_ctrl(5, degenerate, batch), domain=(0.0, 2.0))
    knots = torch.linspace(0.0, 2.0, 5, dtype=F64)
    knots = torch.cat((knots[:1].repeat(3), knots, knots[-1:].repeat(3)))
    return BSpline(_ctrl(7, degenerate, batch), degree=3, knots=knots, form=kind)


def _reference(curve, t: torch.Tensor, first: torch.Tensor, order: int):
    """Per sample, reverse mode through ``curve.derivatives`` of the whole curve: ``(..., N,
    O, w, 6)`` with respect to the span's steps and ``(..., N, O)`` to the time."""
    ctrl, w = curve.control_points.detach(), curve.span_size
    rows_c, rows_t = [], []
    for i in range(t.numel()):
        f = int(first[i])

        def fn(delta, dt, i=i, f=f):
            moved = torch.cat((ctrl[..., :f, :], tangent_step(ctrl[..., f:f + w, :], delta),
                               ctrl[..., f + w:, :]), -2)
            d = curve.derivatives(t[i:i + 1] + dt, order, ctrl=moved)
            return torch.stack(d, -2)[..., 0, :, :].flatten(-2)

        # vectorize: the rows' reverse passes as one backward under vmap (the same VJPs)
        Jc, Jt = torch.autograd.functional.jacobian(
            fn, (ctrl.new_zeros(w, 6), ctrl.new_zeros(())), vectorize=True)
        # Jc (..., O, w, 6) of the batch's rows together: each row moved by the same delta,
        # row b's outputs depend on row b's points only
        rows_c.append(Jc)
        rows_t.append(Jt)
    return torch.stack(rows_c, -4), torch.stack(rows_t, -2)


@pytest.mark.parametrize(("degenerate", "batch"), [(False, ()), (True, ()), (True, (2,))])
@pytest.mark.parametrize("order", [0, 1, 2])
@pytest.mark.parametrize("kind", ["de_boor", "cumulative", "bezier"])
def test_fast_span_jacobians_equal_reverse_mode(kind, order, degenerate, batch):
    curve = _curve(kind, degenerate, batch)
    spans = SpanEvaluator(curve)
    lin = Linearization(SimpleNamespace(spans=spans))
    t = torch.tensor([0.05, 0.5, 0.77, 1.0, 1.31, 1.9], dtype=F64)  # 0.5, 1.0: knots
    first = spans.first(t)
    w = curve.span_size
    f0 = first.clamp(max=spans.n - w)
    ctrl = curve.control_points.detach()
    gathered = span_points(ctrl, f0, w)  # (..., N, w, 8) of the sign-aligned chain
    off = (first - f0)[:, None] + torch.arange(spans.support)
    O = 8 * (order + 1)
    Jd = torch.eye(O, dtype=F64).reshape(O, order + 1, 8).expand(*batch, t.numel(), O,
                                                                    order + 1, 8)
    with torch.no_grad():
        pose = spans.shared(ctrl, t, first, 0)[0]
    Jc, none = lin._through_spans(gathered, [off], [t], [first], [Jd], order, False, [None],
                                  [pose])
    assert none is None
    with torch.no_grad():
        nxt = torch.stack(spans.shared(ctrl, t, first, order + 1), -2)[..., 1:, :]
    Jt = lin._time_columns([t], [first], [Jd], [nxt])
    ref_c, ref_t = _reference(curve, t, first, order)
    assert torch.isfinite(ref_c).all() and torch.isfinite(ref_t).all()
    scale = max(1.0, float(ref_c.abs().max()), float(ref_t.abs().max()))
    torch.testing.assert_close(Jc / scale, ref_c / scale, atol=1e-10, rtol=0)
    torch.testing.assert_close(Jt / scale, ref_t / scale, atol=1e-10, rtol=0)
    # the general path (the time in the graph, for orders above 2) agrees with both
    Jc2, Jt2 = lin._through_spans(gathered, [off], [t], [first], [Jd], order, True, [None],
                                  [pose])
    torch.testing.assert_close(Jc2 / scale, ref_c / scale, atol=1e-10, rtol=0)
    torch.testing.assert_close(Jt2 / scale, ref_t / scale, atol=1e-10, rtol=0)


def test_time_rate_is_zero_where_the_local_time_is_clamped():
    """Beyond the end (extrapolated samples are clamped into the last span) the time column
    vanishes, as reverse mode through the clamp gives."""
    curve = _curve("cumulative", False, ())
    spans = SpanEvaluator(curve)
    t = torch.tensor([0.3, 2.0 + 1e-3], dtype=F64)
    rate = spans.time_rate(t, spans.first(t))
    assert rate.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("batch", [(), (2,)])
@pytest.mark.parametrize("kind", ["de_boor", "cumulative", "split", "bezier"])
def test_shared_span_derivatives_equal_the_per_sample_spans(kind, batch):
    """``Curve.span_derivatives`` (the costs' and linearisation points' evaluation, a
    B-spline's span tables shared by the samples of a span) gives what ``evaluate_span``
    gives on each sample's copy of its span, at knots, inside spans and beyond both ends
    (local times clamped), on identical neighbours, a half turn and a control point of the
    other sign, orders 0 to 3."""
    curve = _curve(kind, True, batch)
    spans = SpanEvaluator(curve)
    t = torch.tensor([-0.2, 0.0, 0.05, 0.5, 0.77, 1.0, 1.31, 1.9, 2.0, 2.3], dtype=F64)
    first = spans.first(t)
    ctrl = curve.control_points.detach().clone()
    ctrl[..., 3, :] = -ctrl[..., 3, :]  # the same pose: the spans must agree on one sign
    for order in range(4):
        shared = spans.shared(ctrl, t, first, order)
        copies = spans.derivatives(span_points(ctrl, first, curve.span_size), t, first, order)
        assert len(shared) == order + 1
        for a, b in zip(shared, copies, strict=True):
            assert a.shape == (*batch, t.numel(), 8)
            scale = max(1.0, float(b.abs().max()))
            torch.testing.assert_close(a / scale, b / scale, atol=1e-12, rtol=0)


def test_shared_span_derivatives_with_a_row_of_knots_per_trajectory():
    """Batched knots: each row's spans from its own knots, as its per-sample copies."""
    ctrl = _ctrl(7, False, (2,))
    base = torch.linspace(0.0, 2.0, 5, dtype=F64)
    rows = torch.stack((base, base * 1.5 + 0.1))
    knots = torch.cat((rows[:, :1].repeat(1, 3), rows, rows[:, -1:].repeat(1, 3)), -1)
    curve = BSpline(ctrl, degree=3, knots=knots, form="cumulative")
    spans = SpanEvaluator(curve)
    t = torch.tensor([[0.1, 0.9, 1.7], [0.2, 1.6, 3.0]], dtype=F64)
    first = spans.first(t)
    shared = spans.shared(ctrl, t, first, 2)
    copies = spans.derivatives(span_points(ctrl, first, 4), t, first, 2)
    for a, b in zip(shared, copies, strict=True):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)


def _closed_form(curve, t, first, order, Jd, offsets=None, w=None):
    """``Linearization._through_spans`` without the times (the layer's closed form where it
    has one), one times list per row of ``t``/``first``/``Jd`` at its window ``offsets``."""
    spans = SpanEvaluator(curve)
    lin = Linearization(SimpleNamespace(spans=spans))
    ctrl = curve.control_points.detach()
    w = curve.span_size if w is None else w
    f0 = torch.stack(first).amin(0).clamp(max=spans.n - w)
    offsets = [(f - f0)[:, None] + torch.arange(spans.support) for f in first]
    with torch.no_grad():
        poses = [spans.shared(ctrl, ti, fi, 0)[0] for ti, fi in zip(t, first, strict=True)]
    Jc, _ = lin._through_spans(span_points(ctrl, f0, w), offsets, t, first, Jd, order, False,
                               [None] * len(t), poses)
    return Jc, offsets


@pytest.mark.parametrize("order", [0, 1, 2])
@pytest.mark.parametrize("degree", [1, 2, 4, 5])
def test_closed_form_span_jacobians_of_every_degree(degree, order):
    """The cumulative form's closed-form Jacobians (``torch_dq._cumulative_lie``: the
    recursions of Sommer et al. 2020 in SE(3)) against reverse mode through the public
    ``derivatives``, for degrees other than the cubic of the test above, on identical
    neighbours and a half turn, at knots and inside spans."""
    knots = torch.linspace(0.0, 2.0, 5, dtype=F64)
    knots = torch.cat((knots[:1].repeat(degree), knots, knots[-1:].repeat(degree)))
    curve = BSpline(_ctrl(degree + 4, True, ()), degree=degree, knots=knots,
                    form="cumulative")
    t = torch.tensor([0.05, 0.5, 0.77, 1.0, 1.31, 1.9], dtype=F64)
    first = SpanEvaluator(curve).first(t)
    O = 8 * (order + 1)
    Jd = torch.eye(O, dtype=F64).reshape(O, order + 1, 8).expand(t.numel(), O, order + 1, 8)
    Jc, _ = _closed_form(curve, [t], [first], order, [Jd])
    ref, _ = _reference(curve, t, first, order)
    scale = max(1.0, float(ref.abs().max()))
    torch.testing.assert_close(Jc / scale, ref / scale, atol=1e-10, rtol=0)


def test_closed_form_span_jacobians_of_two_times_lists_in_a_wider_window():
    """Samples with two times (an odometry pair) in a window wider than a span: each list's
    span columns land at its offsets, their sum the reference's (each list's Jacobian
    placed at its span), and the columns of no span stay zero."""
    curve = _curve("cumulative", True, ())
    spans = SpanEvaluator(curve)
    t0 = torch.tensor([0.05, 0.5, 0.77], dtype=F64)
    t1 = torch.tensor([0.9, 1.31, 1.9], dtype=F64)
    first = [spans.first(t0), spans.first(t1)]
    g = torch.Generator().manual_seed(3)
    Jd = [torch.randn(3, 2, 3, 8, generator=g, dtype=F64) for _ in range(2)]
    Jc, offsets = _closed_form(curve, [t0, t1], first, 2, Jd, w=7)
    want = torch.zeros_like(Jc)
    for t, f, J, off in zip((t0, t1), first, Jd, offsets, strict=True):
        ref, _ = _reference(curve, t, f, 2)  # (N, 24, w, 6): rows of X, dX, ddX
        rows = torch.einsum("nkc,ncwj->nkwj", J.flatten(-2), ref)
        for i in range(t.numel()):
            want[i, :, off[i]] += rows[i]
    torch.testing.assert_close(Jc, want, atol=1e-10, rtol=0)
    used = torch.zeros(3, 7, dtype=torch.bool)
    for off in offsets:
        used.scatter_(1, off, True)
    assert (~used).any() and (Jc.abs().sum((1, 3))[~used] == 0).all()


def test_closed_form_span_jacobians_in_float32():
    """float32 control points: the closed form within 1e-5 (relative to the largest entry)
    of the float64 reference (measured 2.1e-7)."""
    curve = _curve("cumulative", False, ())
    t = torch.tensor([0.05, 0.5, 0.77, 1.0, 1.31, 1.9], dtype=F64)
    first = SpanEvaluator(curve).first(t)
    Jd = torch.eye(24, dtype=F64).reshape(24, 3, 8).expand(t.numel(), 24, 3, 8)
    ref, _ = _reference(curve, t, first, 2)
    curve32 = BSpline(curve.control_points.detach().float(), degree=3,
                      knots=curve.knots.detach(), form="cumulative")
    Jc, _ = _closed_form(curve32, [t], [first], 2, [Jd.float()])
    assert Jc.dtype == torch.float32
    err = float((Jc.double() - ref).abs().max() / ref.abs().max())
    assert err < 1e-5, err


@pytest.mark.parametrize("kind", ["cumulative", "de_boor"])
def test_span_jacobians_of_samples_that_share_their_times(kind):
    """The corners of a frame share its time: the whole Jacobian once per distinct time (the
    cumulative form's closed form, the de Boor form's reverse passes), each sample's rows
    times it, as reverse mode through ``derivatives`` gives per sample."""
    from torch_dq.fitting._linearize import _distinct_times

    curve = _curve(kind, True, ())
    spans = SpanEvaluator(curve)
    lin = Linearization(SimpleNamespace(spans=spans))
    u = torch.tensor([0.05, 0.77, 1.0, 1.9], dtype=F64)
    t = u.repeat_interleave(20)  # 20 corners per frame
    first = spans.first(t)
    shared = _distinct_times(t, first, 2)
    assert shared is not None
    ctrl = curve.control_points.detach()
    off = torch.arange(spans.support).expand(t.numel(), spans.support)
    g = torch.Generator().manual_seed(5)
    Jd = torch.randn(t.numel(), 2, 1, 8, generator=g, dtype=F64)
    with torch.no_grad():
        pose = spans.shared(ctrl, t, first, 0)[0]
    Jc, none = lin._through_spans(span_points(ctrl, first, spans.support), [off], [t], [first],
                                  [Jd], 0, False, [shared], [pose])
    assert none is None
    ref, _ = _reference(curve, u, spans.first(u), 0)  # (U, 8, w, 6)
    want = torch.einsum("nkc,ncwj->nkwj", Jd.flatten(-2), ref.repeat_interleave(20, 0))
    torch.testing.assert_close(Jc, want, atol=1e-10, rtol=0)

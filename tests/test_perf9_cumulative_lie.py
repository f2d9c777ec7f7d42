"""The cumulative form's evaluation by its Lie-algebra recursions (``torch_dq._cumulative_lie``
``derivatives``: float64, nothing differentiated) against an independent mpmath reference,
against the span tables (what reverse mode runs), and ``_numerics.even_slopes`` / ``evens``
against ``even_slope`` / ``even``."""

from __future__ import annotations

import math

import mpmath as mp
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import _cumulative_lie, _numerics
from torch_dq._core import align_chain
from torch_dq.nn import BSpline

F64 = torch.float64


def _spline(n: int = 9, seed: int = 0, far: float = 20.0) -> BSpline:
    """A cumulative cubic B-spline whose control points wander (0.3 rad, 0.5 m per step)
    around a point ``far`` metres from the origin."""
    g = torch.Generator().manual_seed(seed)
    steps = dq.exp(torch.randn(n, 6, generator=g, dtype=F64) * torch.tensor(
        [0.3] * 3 + [0.5] * 3, dtype=F64))
    c = [dq.exp(torch.tensor([0.2, -0.1, 0.3, far, -far / 2, far / 3], dtype=F64))]
    for s in steps[1:]:
        c.append(dq.mul(c[-1], s))
    knots = torch.arange(-3, n + 1, dtype=F64) * 0.05 + torch.linspace(0, 0.01, n + 4,
                                                                        dtype=F64) ** 2
    return BSpline(torch.stack(c), degree=3, knots=knots, form="cumulative")


def span_samples(spline: BSpline, count: int):
    """``count`` times inside the domain, their spans ``first``, local times, the control
    points and each time's span points ``(count, 4, 8)``."""
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo + 1e-3, hi - 1e-3, count, dtype=F64)
    first = spline.support(t)[0]
    ctrl = spline.control_points.detach()
    pts = torch.stack([ctrl[f:f + 4] for f in first.tolist()])
    return t, first, spline.local_times(t, first), ctrl, pts


# ---------------------------------------------------------------- mpmath reference (readable)

def _qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw]


def _dqmul(a, b):
    real = _qmul(a[:4], b[:4])
    dual = [x + y for x, y in zip(_qmul(a[:4], b[4:]), _qmul(a[4:], b[:4]), strict=True)]
    return real + dual


def _cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _exp(xi):
    """SE(3) exponential of a twist (omega, v) as a unit dual quaternion (closed form)."""
    w, v = xi[:3], xi[3:]
    th = mp.sqrt(sum(x * x for x in w))
    if th == 0:
        r, t = [mp.mpf(1), *[0 * x for x in w]], list(v)
    else:
        r = [mp.cos(th / 2), *[mp.sin(th / 2) / th * x for x in w]]
        wxv = _cross(w, v)
        wwv = _cross(w, wxv)
        c1, c2 = (1 - mp.cos(th)) / th**2, (th - mp.sin(th)) / th**3
        t = [v[i] + c1 * wxv[i] + c2 * wwv[i] for i in range(3)]
    return r + [x / 2 for x in _qmul([0, *t], r)]


def _log(x):
    """Twist of a unit dual quaternion with a non-negative real part (closed form)."""
    r, d = x[:4], x[4:]
    s = mp.sqrt(sum(c * c for c in r[1:]))
    th = 2 * mp.atan2(s, r[0])
    w = [th / s * c for c in r[1:]] if s != 0 else [0 * c for c in r[1:]]
    t = [2 * c for c in _qmul(d, [r[0], -r[1], -r[2], -r[3]])[1:]]
    c3 = (1 - (th / 2) * mp.cot(th / 2)) / th**2 if th != 0 else mp.mpf(1) / 12
    wxt = _cross(w, t)
    wwt = _cross(w, wxt)
    return w + [t[i] - wxt[i] / 2 + c3 * wwt[i] for i in range(3)]


def _reference(points, lam, lam1, lam2):
    """``[X, X', X'']`` at one time: ``X(h) = c_0 prod_j Exp(l_j(h) d_j)`` with the basis
    ``l(h) = l + l' h + l'' h^2 / 2`` (its Taylor polynomial: the derivatives at ``h = 0``
    to order 2 are those of the spline), differentiated by mpmath at 40 digits."""
    pts = [[mp.mpf(float(x)) for x in p] for p in points]
    conj = [1, -1, -1, -1] * 2
    d = [_log(_dqmul([a * s for a, s in zip(pts[j], conj, strict=True)], pts[j + 1]))
         for j in range(len(pts) - 1)]
    lam, lam1, lam2 = ([mp.mpf(float(x)) for x in v] for v in (lam, lam1, lam2))

    def pose(h):
        x = pts[0]
        for j, dj in enumerate(d):
            lj = lam[j] + lam1[j] * h + lam2[j] * h * h / 2
            x = _dqmul(x, _exp([lj * c for c in dj]))
        return x

    return [[float(mp.diff(lambda h, c=c: pose(h)[c], 0, k)) for c in range(8)]
            for k in range(3)]


def test_lie_derivatives_against_mpmath():
    """Poses, velocities and accelerations of the recursions (no graph: the Lie path) at
    generic times of a spline 20 m from the origin, against mpmath; the span tables (reverse
    mode's path) against the same reference, for the record of both errors."""
    mp.mp.dps = 40
    spline = _spline()
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo + 1e-3, hi - 1e-3, 10, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    ctrl = spline.control_points.detach()
    assert _cumulative_lie.applies(ctrl, [local])
    with torch.no_grad():
        lie = spline.span_derivatives(ctrl, local, first, 2)
    with torch.enable_grad():
        tables = [x.detach() for x in spline.span_derivatives(ctrl.clone().requires_grad_(),
                                                               local, first, 2)]
    aligned = align_chain(ctrl)
    w = spline.time_model.bases(spline.time_model.span_bounds(first + 3)[0] + local, first + 3, 2,
                                cumulative=True)
    ref = torch.tensor([_reference(aligned[f:f + 4], w[0][i], w[1][i], w[2][i])
                        for i, f in enumerate(first.tolist())], dtype=F64).transpose(0, 1)
    for k in range(3):
        scale = ref[k].abs().max()
        err_lie = float((lie[k] - ref[k]).abs().max() / scale)
        err_tables = float((tables[k] - ref[k]).abs().max() / scale)
        assert err_lie < 1e-14, (k, err_lie, err_tables)  # measured 3e-16 to 8e-16
        assert err_tables < 1e-14, (k, err_lie, err_tables)  # 6e-16 to 1.4e-15


@pytest.mark.parametrize("order", [0, 1, 2])
@pytest.mark.parametrize("shape", [(), (1,), (5,), (2, 5), (3, 1, 5)])
def test_lie_path_matches_tables(order, shape):
    """The evaluation without a graph (the recursions) and with one (the span tables, what
    reverse mode differentiates) give the same numbers at every batch shape."""
    spline = _spline(seed=1)
    lo, hi = (float(x) for x in spline.domain)
    g = torch.Generator().manual_seed(2)
    t = lo + (hi - lo) * torch.rand(shape, generator=g, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    ctrl = spline.control_points.detach()
    with torch.no_grad():
        lie = spline.span_derivatives(ctrl, local, first, order)
    tables = spline.span_derivatives(ctrl.clone().requires_grad_(), local, first, order)
    assert len(lie) == order + 1
    for a, b in zip(lie, tables, strict=True):
        assert a.shape == b.shape
        scale = b.detach().abs().max().clamp_min(1.0)
        assert float((a - b.detach()).abs().max() / scale) < 1e-12


def test_lie_path_static_and_slow_spans():
    """Equal neighbours (a static segment) and nearly equal ones: finite, zero velocity
    where the spline stands still, the tables' values elsewhere."""
    c = dq.exp(torch.tensor([0.1, 0.2, -0.3, 5.0, 6.0, -7.0], dtype=F64)).expand(7, 8).clone()
    c[5:] = dq.mul(c[5:], dq.exp(torch.full((6,), 1e-9, dtype=F64)))
    spline = BSpline(c, degree=3, form="cumulative")
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo, hi, 40, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    with torch.no_grad():
        lie = spline.span_derivatives(c, local, first, 2)
    tables = spline.span_derivatives(c.clone().requires_grad_(), local, first, 2)
    for a, b in zip(lie, tables, strict=True):
        assert torch.isfinite(a).all()
        b = b.detach()
        assert float((a - b).abs().max()) < 1e-12 * max(1.0, float(b.abs().max()))
    still = first == 0
    assert still.any() and float(lie[1][still].abs().max()) < 1e-13


def test_lie_path_is_not_taken_with_a_graph_or_float32():
    ctrl = _spline().control_points.detach()
    w = [torch.rand(3, 4, dtype=F64)]
    assert _cumulative_lie.applies(ctrl, w)
    assert not _cumulative_lie.applies(ctrl.float(), [x.float() for x in w])
    assert not _cumulative_lie.applies(ctrl.clone().requires_grad_(), w)
    with torch.no_grad():
        assert _cumulative_lie.applies(ctrl.clone().requires_grad_(), w)
    assert not _cumulative_lie.applies(ctrl.float().double(), w)  # rounded: not unit to 1e-14


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_even_slopes_are_even_slope(dtype):
    """Several functions in one pass give ``even_slope``'s and ``even``'s numbers, bit for
    bit, below, around and above the switch points, and for an all-series input (the
    closed forms skipped)."""
    x2 = torch.cat((torch.logspace(-12, 1, 200, dtype=F64), torch.tensor([0.0, 9.0]))).to(dtype)
    names = ("sinc", "se3_c1", "se3_c2", "se3_c3")
    for x in (x2, x2[:50]):
        for name, (f, s) in zip(names, _numerics.even_slopes(names, x), strict=True):
            f0, s0 = _numerics.even_slope(name, x)
            assert torch.equal(f, f0) and torch.equal(s, s0), name
        for name, f in zip(("cos", "sinc"), _numerics.evens(("cos", "sinc"), x), strict=True):
            assert torch.equal(f, _numerics.even(name, x)), name
    assert math.isclose(float(_numerics.evens(("cos",), x2[-1:].double())[0]), math.cos(3.0),
                        rel_tol=1e-15)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_span_vjp_against_central_differences(order):
    """``BSpline.span_vjp`` (the fused closed form) against central differences of the span
    tables' evaluation (a graph forces them) along random right steps ``c_i Exp(h e)`` of
    each control point, at generic times of a spline 20 m from the origin."""
    spline = _spline(seed=3)
    _, first, local, ctrl, pts = span_samples(spline, 7)
    assert_vjp_matches_differences(spline, first, local, ctrl, pts, order, 4)


def assert_vjp_matches_differences(spline, first, local, ctrl, pts, order: int, seed: int):
    """``spline.span_vjp`` of random cotangents against central differences (``h = 1e-5``)
    of ``evaluate_span`` along random right steps of each of the span points ``pts (N, w,
    8)`` (rows 2, orders up to ``order``), to 1e-7 of the largest."""
    g = torch.Generator().manual_seed(seed)
    N, w = pts.shape[:2]
    cot = torch.randn(N, 2, order + 1, 8, generator=g, dtype=F64)
    with torch.no_grad():
        pose = spline.span_derivatives(ctrl, local, first, 0)[0]
    G = spline.span_vjp(pts, local, first, cot, pose)
    assert G.shape == (N, 2, w, 6)
    h = 1e-5
    for i in range(w):
        e = torch.randn(6, generator=g, dtype=F64)

        def moved(s, i=i, e=e):
            p = pts.clone()
            p[:, i] = dq.mul(p[:, i], dq.exp(s * e))
            out = spline.evaluate_span(p.requires_grad_(), local, first, order)
            return torch.stack([x.detach() for x in out], -2)  # (N, O, 8)

        fd = (moved(h) - moved(-h)) / (2 * h)
        ref = (fd[:, None] * cot).sum((-1, -2))
        got = (G[:, :, i] * e).sum(-1)
        assert float((got - ref).abs().max()) < 1e-7 * float(ref.abs().max()), i

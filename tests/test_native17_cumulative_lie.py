"""The compiled cumulative form (``torch_dq/_kernels/csrc/cumulative_lie.c`` behind
``_cumulative_lie.vjp`` and ``derivatives``) against the PyTorch code (``TORCH_DQ_NATIVE=0``)
on random and degenerate spans, and against independent references: central differences of
the span tables' evaluation (the vjp) and a numpy formula of the even functions."""

from __future__ import annotations

import math

import mpmath as mp
import pytest
import torch
from test_perf9_cumulative_lie import assert_vjp_matches_differences

import torch_dq.dualquat as dq
from torch_dq import _cumulative_lie, _numerics
from torch_dq._kernels import lie_native, native
from torch_dq.nn import BSpline

F64 = torch.float64

pytestmark = pytest.mark.skipif(native.library() is None,
                                reason="the compiled library is not built (setup.py build_ext)")


def _torch_path(monkeypatch, fn, *args):
    with monkeypatch.context() as m:
        m.setenv("TORCH_DQ_NATIVE", "0")
        assert not lie_native.applies(1, torch.zeros(1, dtype=F64))
        return fn(*args)


def _points(U: int, p: int, g: torch.Generator, kind: str) -> torch.Tensor:
    """``(U, p + 1, 8)`` chains of unit dual quaternions whose steps are random twists of
    ``kind``: generic, zero rotation, rotations of 1e-9 or 1e-4 rad, identical points,
    large rotations (near pi)."""
    xi = torch.randn(U, p, 6, generator=g, dtype=F64)
    scale = {"generic": 0.5, "pure": 0.0, "tiny": 1e-9, "small": 1e-4, "same": 0.0,
             "large": 1.2}[kind]
    xi[..., :3] *= scale
    if kind == "same":
        xi[..., 3:] = 0.0
    start = dq.exp(torch.randn(U, 6, generator=g, dtype=F64))
    pts = [start]
    for j in range(p):
        pts.append(dq.mul(pts[-1], dq.exp(xi[:, j])))
    return torch.stack(pts, 1)


def _close(a: torch.Tensor, b: torch.Tensor, tol: float = 1e-12, floor: float = 1e-300,
           ) -> None:
    """``a`` equals ``b`` to ``tol`` relative to the largest entry of ``b`` (at least
    ``floor``)."""
    assert a.shape == b.shape
    scale = float(b.abs().max().clamp_min(floor))
    err = float((a - b).abs().max()) / scale
    assert err < tol, err


@pytest.mark.parametrize("p", [1, 2, 3, 4, 5])
@pytest.mark.parametrize("kind", ["generic", "pure", "tiny", "small", "same", "large"])
def test_vjp_matches_torch(monkeypatch, p, kind):
    """Every order, ``k`` rows, ``second`` of several kinds, against the PyTorch vjp."""
    g = torch.Generator().manual_seed(p * 10 + len(kind))
    U, S = 7, 40
    span = _cumulative_lie.span_parts(_points(U, p, g, kind))
    inverse = torch.randint(0, U, (S,), generator=g)
    for O in (1, 2, 3):
        weights = [torch.rand(S, p, generator=g, dtype=F64) * (5.0 if o else 1.0)
                   for o in range(O)]
        for k, second in ((1, None), (3, slice(1, 3)), (4, slice(0, 4, 2)), (2, slice(2, 2))):
            cot = torch.randn(S, k, O, 8, generator=g, dtype=F64)
            pose = dq.exp(torch.randn(S, 6, generator=g, dtype=F64))
            got = _cumulative_lie.vjp(span, inverse, weights, cot, pose, second)
            ref = _torch_path(monkeypatch, _cumulative_lie.vjp, span, inverse, weights, cot,
                              pose, second)
            assert got.shape == (S, k, p + 1, 6)
            _close(got, ref)


def test_vjp_matches_torch_in_several_chunks(monkeypatch):
    """More samples than the PyTorch code's part (``VJP_CHUNK``), cotangents as the callers
    pass them (a component-major array's permuted view, read in place) and broadcast (a
    zero stride): the same numbers."""
    g = torch.Generator().manual_seed(5)
    U, S, p = 30, 2 * _cumulative_lie.VJP_CHUNK + 17, 3
    span = _cumulative_lie.span_parts(_points(U, p, g, "generic"))
    inverse = torch.randint(0, U, (S,), generator=g)
    weights = [torch.rand(S, p, generator=g, dtype=F64) for _ in range(3)]
    pose = dq.exp(torch.randn(S, 6, generator=g, dtype=F64))
    for cot in (torch.randn(2, 3, 8, S, generator=g, dtype=F64).permute(3, 0, 1, 2),
                torch.randn(S, 1, 3, 8, generator=g, dtype=F64).expand(S, 2, 3, 8)):
        got = _cumulative_lie.vjp(span, inverse, weights, cot, pose, slice(1, 2))
        ref = _torch_path(monkeypatch, _cumulative_lie.vjp, span, inverse, weights,
                          cot.contiguous(), pose, slice(1, 2))
        _close(got, ref)


def _spline(degree: int, seed: int, kind: str = "generic") -> BSpline:
    g = torch.Generator().manual_seed(seed)
    n = degree + 6
    c = _points(1, n - 1, g, kind)[0]
    knots = torch.arange(-degree, n + 1, dtype=F64) * 0.1
    return BSpline(c, degree=degree, knots=knots[:n + degree + 1], form="cumulative")


@pytest.mark.parametrize("degree", [2, 3, 4, 5, 6])
@pytest.mark.parametrize("kind", ["generic", "pure", "tiny", "same"])
def test_derivatives_match_torch(monkeypatch, degree, kind):
    """The compiled evaluation against the PyTorch recursions, orders 0 to 2."""
    spline = _spline(degree, degree, kind)
    ctrl = spline.control_points.detach()
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo, hi, 50, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    r = first + degree
    for order in (0, 1, 2):
        weights = [w.T.contiguous() for w in spline.time_model.bases(
            spline.time_model.span_bounds(r)[0] + local, r, order, cumulative=True)]
        assert _cumulative_lie.applies(ctrl, weights)
        got = _cumulative_lie.derivatives(ctrl, first, weights)
        ref = _torch_path(monkeypatch, _cumulative_lie.derivatives, ctrl, first, weights)
        assert len(got) == order + 1
        for a, b in zip(got, ref, strict=True):  # poses: unit; a static span's rates: 0
            _close(a, b, floor=1.0)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_vjp_against_central_differences(order):
    """``BSpline.span_vjp`` (compiled) against central differences of the span tables'
    evaluation along random right steps of each control point (degree 4)."""
    spline = _spline(4, 11)
    lo, hi = (float(x) for x in spline.domain)
    t = torch.linspace(lo + 1e-3, hi - 1e-3, 9, dtype=F64)
    first = spline.support(t)[0]
    local = spline.local_times(t, first)
    ctrl = spline.control_points.detach()
    pts = torch.stack([ctrl[f:f + 5] for f in first.tolist()])
    assert_vjp_matches_differences(spline, first, local, ctrl, pts, order, 12)


def _mp_exp(xi: list) -> list:
    """SE(3) exponential of a twist (omega, v) as a unit dual quaternion, closed form in
    mpmath at 40 digits: r = (cos(th/2), sin(th/2)/th omega), t = v + c1 w x v + c2 w x (w x v),
    dual part (0, t) r / 2."""
    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    w, v = xi[:3], xi[3:]
    th = mp.sqrt(sum(x * x for x in w))
    if th == 0:
        return [mp.mpf(1), 0, 0, 0, 0, *[x / 2 for x in v]]
    r = [mp.cos(th / 2), *[mp.sin(th / 2) / th * x for x in w]]
    wxv = cross(w, v)
    wwv = cross(w, wxv)
    t = [v[i] + (1 - mp.cos(th)) / th**2 * wxv[i] + (th - mp.sin(th)) / th**3 * wwv[i]
         for i in range(3)]
    # (0, t) r: scalar -t . r_v, vector r_0 t + t x r_v
    txr = cross(t, r[1:])
    return [*r, -sum(t[i] * r[1 + i] for i in range(3)) / 2,
            *[(r[0] * t[i] + txr[i]) / 2 for i in range(3)]]


@pytest.mark.parametrize("w", [0.0, 1e-9, 1e-4, 1e-2, 1.0, 3.0])
def test_even_functions_at_small_and_large_angles(monkeypatch, w):
    """One step of rotation ``w`` about a generic axis (the even functions' series branches
    near 0, their closed forms above): the compiled pose ``Exp(lambda d)`` against mpmath,
    and the compiled vjp against the PyTorch one (slopes of sinc, se3_c1, se3_c2)."""
    mp.mp.dps = 40
    axis = torch.tensor([0.48, -0.6, 0.64], dtype=F64)
    xi = torch.cat((w * axis, torch.tensor([0.3, -0.2, 0.1], dtype=F64)))[None]
    pts = torch.stack((dq.exp(torch.zeros(1, 6, dtype=F64)), dq.exp(xi)), 1)
    lam = [torch.tensor([[0.7]], dtype=F64), torch.tensor([[1.3]], dtype=F64),
           torch.tensor([[-0.4]], dtype=F64)]
    d = _cumulative_lie.span_parts(pts)[:6, 0, 0]  # the twist the C reads
    (X,) = _cumulative_lie.derivatives(pts[0], torch.zeros(1, dtype=torch.int64), lam[:1])
    ref = _mp_exp([mp.mpf(0.7) * mp.mpf(float(x)) for x in d])
    assert float((X[0] - torch.tensor([float(x) for x in ref], dtype=F64)).abs().max()) < 4e-16
    g = torch.Generator().manual_seed(3)
    cot = torch.randn(1, 2, 3, 8, generator=g, dtype=F64)
    args = (_cumulative_lie.span_parts(pts), torch.zeros(1, dtype=torch.int64), lam, cot,
            dq.exp(xi * 0.7), None)
    got = _cumulative_lie.vjp(*args)
    _close(got, _torch_path(monkeypatch, _cumulative_lie.vjp, *args), 1e-13)


@pytest.mark.parametrize("name", ["cos", "sinc", "se3_c1", "se3_c2"])
@pytest.mark.parametrize("side", [1 - 1e-9, 1 + 1e-9])
def test_switch_points_as_torch(monkeypatch, name, side):
    """Twists whose squared angle lies just below and above an even function's switch point
    (``_numerics.threshold("even_series", ...)``, 1e-9 relative either side): the compiled
    evaluation and vjp give the PyTorch numbers, and the pose mpmath's."""
    mp.mp.dps = 40
    coeffs = _numerics._EVEN[name][0]
    x2 = _numerics.threshold("even_series", F64, coeffs[-1]) * side
    lam = 0.7
    theta = math.sqrt(x2 * (4.0 if name == "cos" else 1.0)) / lam  # cos is read at theta / 2
    axis = torch.tensor([0.48, -0.6, 0.64], dtype=F64)
    xi = torch.cat((theta * axis, torch.tensor([0.3, -0.2, 0.1], dtype=F64)))[None]
    pts = torch.stack((dq.exp(torch.zeros(1, 6, dtype=F64)), dq.exp(xi)), 1)
    w = [torch.tensor([[lam]], dtype=F64), torch.tensor([[1.3]], dtype=F64),
         torch.tensor([[-0.4]], dtype=F64)]
    first = torch.zeros(1, dtype=torch.int64)
    got = _cumulative_lie.derivatives(pts[0], first, w)
    ref = _torch_path(monkeypatch, _cumulative_lie.derivatives, pts[0], first, w)
    for a, b in zip(got, ref, strict=True):
        _close(a, b, 1e-14, floor=1.0)
    d = _cumulative_lie.span_parts(pts)[:6, 0, 0]
    exact = _mp_exp([mp.mpf(lam) * mp.mpf(float(x)) for x in d])
    assert float((got[0][0] - torch.tensor([float(x) for x in exact], dtype=F64)).abs().max()) \
        < 4e-16
    cot = torch.randn(1, 2, 3, 8, generator=torch.Generator().manual_seed(1), dtype=F64)
    args = (_cumulative_lie.span_parts(pts), first, [x.T for x in w], cot, dq.exp(xi * lam),
            None)
    _close(_cumulative_lie.vjp(*args), _torch_path(monkeypatch, _cumulative_lie.vjp, *args),
           1e-13)

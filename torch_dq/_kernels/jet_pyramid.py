r"""The triangular scheme of De Casteljau and De Boor on jets, with its backward written out
(private).

The readable scheme is :func:`.jet_sclerp.pyramid` (eq. 11 on jets,
:func:`.jet_sclerp.sclerp`, level after level). :class:`_JetPyramid` runs it as it is
and differentiates it by hand instead of through autograd's record of the Taylor
recurrences (thousands of small ops per chunk, and a zero-filled gradient for every slice
of a level). With ``*`` the Cauchy product over the time coefficients, a level computes
from ``a = (P, Q)`` and ``b = (R, S)`` (``b`` sign-aligned to ``a``)

.. math::
    c = P * R,\quad \delta = P * S + Q * R,\quad (F, G) = w(c, s),\quad
    q = F_0 * a + F_1 * b - \epsilon\, \delta * D,\quad D = G_0 * P + G_1 * R.

All of it is bilinear but the weights :math:`w`, whose jets depend on those of
:math:`y = 1 - c` through the jets of :math:`\partial_y F = G` and :math:`\partial_y G = H`
along the path (:func:`torch_dq._taylor.weights_vjp`). The adjoint of a Cauchy product
:math:`z = x * y` is the correlation :math:`\bar x_i = \sum_{k \ge i} \bar z_k\, y_{k - i}`
(:func:`torch_dq._taylor.corr`): a level's backward is a few of them, and its cotangent
reaches the level below as ``a``'s (positions ``0 .. L - 1``) plus ``b``'s (``1 .. L``).

It runs in eager reverse mode on the control points; the gradient of the local parameters
(``t``, knots), a differentiated or batched backward and every other mode take the plain
jets.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple, cast

import torch
from torch import Tensor

from .. import _taylor
from .._autograd import reference_vjp, save, saved
from .._dispatch import batched, written_backward
from .._taylor import Jet, corr
from . import jet_sclerp
from .jet_sclerp import SclerpParts


def pyramid(points: Tensor, levels: list[Jet], order: int) -> Jet:
    """The jets ``(8, n)`` of the last level of the scheme (:func:`jet_sclerp.pyramid`)
    from level 0 ``points (8, m, n)`` (constant in time) and the levels' jets ``alpha
    (m - j, n)``: :class:`_JetPyramid` where reverse mode differentiates ``points`` alone,
    eagerly (:func:`torch_dq._dispatch.written_backward`), the plain jets elsewhere."""
    if written_backward([points], [x for level in levels for x in level]):
        return list(_JetPyramid.apply(points, levels, order))
    return jet_sclerp.pyramid([points, *[None] * order], levels)


class _Level(NamedTuple):
    """What the backward of a level keeps (jets; :func:`jet_sclerp.sclerp_parts`):
    its input ``q (8, L + 1, n)``, ``b``'s sign change and the weights' and correction's
    jets."""

    q: Jet
    sign: Tensor
    F: Jet
    G: Jet
    H: Jet
    delta: Jet
    D: Jet


class _JetPyramid(torch.autograd.Function):
    """:func:`jet_sclerp.pyramid` from constant ``points (8, m, n)`` with the
    backward of the module docstring (:func:`_level_vjp`, level after level). Its
    intermediates go through ``save_for_backward`` (:func:`torch_dq._autograd.save`)."""

    @staticmethod
    def forward(ctx, points: Tensor, levels: list[Jet], order: int):
        kept: list[SclerpParts] = []
        out = jet_sclerp.pyramid([points, *[None] * order], levels, kept)
        ctx.set_materialize_grads(False)
        items = [points, *(x for level in levels for x in level)]
        for j, p in enumerate(kept):  # the input of level j + 1 is level j's output
            q = kept[j - 1].q if j else [None] * (order + 1)
            items += [*q, p.sign, *p.F, *p.G, *p.H, *p.delta, *p.D]
        save(ctx, items)
        ctx.sizes = len(levels), order + 1
        return tuple(out)

    @staticmethod
    def backward(ctx, *grads):
        count, n = ctx.sizes
        items = saved(ctx)
        points = cast(Tensor, items[0])
        levels = [items[1 + j * n:1 + (j + 1) * n] for j in range(count)]
        if batched(*grads) or torch.is_grad_enabled():
            return _plain_vjp(points, levels, n - 1, grads), None, None
        per = 6 * n + 1  # q, sign, F, G, H, delta, D
        qb: Jet = [None if g is None else g.unsqueeze(1) for g in grads]
        for j in range(count - 1, -1, -1):
            x = items[1 + count * n + j * per:1 + count * n + (j + 1) * per]
            q = [points, *[None] * (n - 1)] if j == 0 else x[:n]
            F, G, H, delta, D = (x[n + 1 + k * n:n + 1 + (k + 1) * n] for k in range(5))
            qb = _level_vjp(_Level(q, cast(Tensor, x[n]), F, G, H, delta, D), qb)
        return qb[0], None, None


def _plain_vjp(points: Tensor, levels: list[Jet], order: int, grads) -> Tensor:
    """:class:`_JetPyramid`'s cotangent of ``points`` through the plain jets (differentiable
    again; batched under ``vmap``)."""

    def reference(p: Tensor) -> tuple[Tensor, ...]:
        out = jet_sclerp.pyramid([p, *[None] * order], levels)
        return tuple(torch.zeros_like(p[:, 0]) if x is None else x for x in out)

    cot = tuple(torch.zeros_like(points[:, 0]) if g is None else g for g in grads)
    return reference_vjp(reference, (points,), cot)[0]


def _dots(terms: Iterable[tuple[Jet, Jet]], i: int, value: float = 1.0) -> Tensor | None:
    """:func:`torch_dq._taylor.corr` of row-wise products, summed over the component rows."""
    out = corr(terms, i, value)
    return None if out is None else out.sum(0)


def _rows(jet: Jet, index) -> Jet:
    return [None if x is None else x[index] for x in jet]


def _halves(top: Tensor | None, bottom: Tensor | None) -> Tensor | None:
    """Rows ``0 .. 3`` and ``4 .. 7`` of a cotangent (``None``: zero)."""
    if top is None:
        return None if bottom is None else torch.cat((torch.zeros_like(bottom), bottom))
    return torch.cat((top, torch.zeros_like(top) if bottom is None else bottom))


def _shifted(ab: Tensor | None, bb: Tensor | None) -> Tensor | None:
    """A level's input cotangent ``(8, L + 1, n)`` from those of its ``a = q[:, :-1]`` and
    ``b = q[:, 1:]`` (``(8, L, n)``; ``None``: zero)."""
    if bb is None:
        return None if ab is None else torch.cat((ab, torch.zeros_like(ab[:, :1])), 1)
    if ab is None:
        return torch.cat((torch.zeros_like(bb[:, :1]), bb), 1)
    return torch.cat((ab[:, :1], ab[:, 1:] + bb[:, :-1], bb[:, -1:]), 1)


def _level_vjp(p: _Level, qb: Jet) -> Jet:
    """The cotangents of a level's input jets ``p.q (8, L + 1, n)`` from those of its output
    ``qb (8, L, n)`` (module docstring)."""
    n = len(qb)
    A = [None if x is None else x[:, :-1] for x in p.q]
    B = [None if x is None else x[:, 1:] * p.sign for x in p.q]  # sign-aligned to a
    P, Q = _rows(A, slice(4)), _rows(A, slice(4, 8))
    R, S = _rows(B, slice(4)), _rows(B, slice(4, 8))
    qd = _rows(qb, slice(4, 8))
    # the dual rows' correction, q -= eps delta * D
    db = [_dots([(qd, p.D)], i, -1.0) for i in range(n)]
    Db = [corr([(qd, p.delta)], i, -1.0) for i in range(n)]
    # the weights (q = F_0 * a + F_1 * b, D = G_0 * P + G_1 * R) back to c = 1 - y
    cb: Jet = [None] * n
    for r, X, X4 in ((0, A, P), (1, B, R)):
        Fb = [_dots([(qb, X)], i) for i in range(n)]
        Gb = [_dots([(Db, X4)], i) for i in range(n)]
        yb = _taylor.weights_vjp(Fb, Gb, _rows(p.G, (r, 0)), _rows(p.H, r), [True] * n)
        cb = [_taylor._lin(c, 1.0, y, -1.0) for c, y in zip(cb, yb, strict=True)]
    # a and b through F, D and the dots c = P * R, delta = P * S + Q * R
    F0, F1, G0, G1 = _rows(p.F, 0), _rows(p.F, 1), _rows(p.G, 0), _rows(p.G, 1)
    out: Jet = []
    for i in range(n):
        if A[i] is None:  # a coefficient known to be zero (level 0 is constant)
            out.append(None)
            continue
        ab = _halves(corr([(Db, G0), (cb, R), (db, S)], i), corr([(db, R)], i))
        bb = _halves(corr([(Db, G1), (cb, P), (db, Q)], i), corr([(db, P)], i))
        ab = _taylor._lin(corr([(qb, F0)], i), 1.0, ab)
        bb = _taylor._lin(corr([(qb, F1)], i), 1.0, bb)
        out.append(_shifted(ab, None if bb is None else bb * p.sign))
    return out

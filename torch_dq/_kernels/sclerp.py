r"""Fused screw interpolation (eq. 11) as a custom autograd op (private).

The readable eq. 11 is :func:`torch_dq.dualquat.sclerp`; this is the same formula on
component rows with the sign folded into the weights, chunked, with an analytic backward.
Notation and weights: :mod:`torch_dq._kernels.weights`. The pieces (:func:`frame`,
:func:`combine`, :func:`vjp_rows`) take rows ``(..., 8, N)`` of any strides: the fused curve
scheme (:mod:`torch_dq._kernels.pyramid`) gathers contiguous rows, :class:`_Sclerp` works in
the caller's ``(N, 8)`` memory seen as rows (``a.T``; no layout copies: its dot products are
sums of products of the strided components, :func:`dot`, and it writes the output and the
gradients in place).

There is no forward-mode rule: under ``torch.func`` transforms and forward AD the public
functions run their readable references (:func:`torch_dq._dispatch.fused_path`), so a
forward-mode call that reaches this op anyway raises instead of returning zeros. The backward
also runs under a vmap started after the forward (``torch.autograd.functional.jacobian(...,
vectorize=True)``, ``is_grads_batched=True``): a batched cotangent's chunks are concatenated
instead of written into the gradients.
"""

from __future__ import annotations

from typing import NamedTuple, cast

import torch
from torch import Tensor

from .._autograd import InputsSaved
from .._dispatch import batched
from .layout import chunks, coef
from .weights import Angle, Weights, WeightSlopes, screw_weights


class Frame(NamedTuple):
    """Dual scalar product (eq. 1) of a pair ``a = P + eps Q``, ``b = R + eps S`` after the
    sign choice; each ``(..., N)``. ``b`` itself is *not* sign-aligned: ``sigma`` is folded
    into the N-sized coefficients instead, saving a pass over ``b``."""

    c: Tensor  # sigma P.R = cos(theta)
    delta: Tensor  # sigma (P.S + R.Q)
    sigma: Tensor  # -1 where shortest and P.R < 0, else 1


class Cotangents(NamedTuple):
    """Vector-Jacobian product of :func:`combine` (see :func:`vjp_rows`)."""

    a: Tensor  # (..., 8, N) rows
    b: Tensor  # (..., 8, N) rows
    c: Tensor  # (..., N) sensitivity to the frame's c, already times sigma
    delta: Tensor  # (..., N) sensitivity to the frame's delta, already times sigma
    t: Tensor | None  # (..., N), None when the time derivatives were not asked for


def dot(x: Tensor, y: Tensor) -> Tensor:
    """``(x * y).sum(-2)`` over the components of ``(..., k, N)`` rows of any strides, the
    rounded products added in order: on the caller's ``(N, k)`` memory seen as ``(k, N)``
    (strided components) several times faster than a reduction over a trailing dim of 4 or 8.
    Not fused multiply-adds: at a tie of the shortest path (orthogonal real parts) their
    rounding could give the cosine the sign the rounded products do not (the readable
    reference's, ``sum``)."""
    xs, ys = x.unbind(-2), y.unbind(-2)
    acc = xs[0] * ys[0]
    for u, v in zip(xs[1:], ys[1:], strict=True):
        acc = acc + u * v
    return acc


def frame(A: Tensor, B: Tensor, shortest: bool) -> Frame:
    """:class:`Frame` of pairs of ``(..., 8, N)`` rows (any strides)."""
    P, Q, R, S = A[..., :4, :], A[..., 4:, :], B[..., :4, :], B[..., 4:, :]
    c = dot(P, R)
    # sigma = where(c < 0, -1, 1) (-0.0 counts as positive), in arithmetic: torch.where is
    # several times slower than a multiply on CPU.
    sigma = 1.0 - 2.0 * (c < 0).to(c.dtype) if shortest else torch.ones_like(c)
    delta = sigma * (dot(P, S) + dot(R, Q))
    return Frame(sigma * c, delta, sigma)


def weights(fr: Frame, t: Tensor, derivatives: bool = False, time_slopes: bool = True,
            ang: Angle | None = None, y: Tensor | None = None,
            h_slope: bool = False) -> Weights | WeightSlopes:
    """:func:`screw_weights` of a frame (``ang``: its :func:`angle`, ``y``: ``1 - c``, if
    already known; ``h_slope``: as there), evaluating only the branches in use in eager mode
    on CPU (where a host read is free)."""
    host = fr.c.device.type == "cpu" and not torch.compiler.is_compiling()
    return screw_weights(fr.c, t, derivatives, time_slopes=time_slopes, ang=ang,
                         host_branch=host, y=y, h_slope=h_slope)


def combine(A: Tensor, B: Tensor, fr: Frame, w: Weights | WeightSlopes,
            out: Tensor | None = None) -> Tensor:
    r"""Eq. 11 on rows: :math:`F_0 a + F_1 \sigma b - \epsilon\delta(G_0 P + G_1 \sigma R)`
    (into ``out``, rows of any strides, if given)."""
    F0, F1 = w.F
    G0, G1 = w.G
    s1 = fr.sigma * F1
    out = torch.mul(coef(F0), A, out=out).addcmul_(coef(s1), B)
    dual = out[..., 4:, :]
    dual.addcmul_(coef(fr.delta * G0), A[..., :4, :], value=-1.0)
    dual.addcmul_(coef(fr.delta * fr.sigma * G1), B[..., :4, :], value=-1.0)
    return out


def vjp_rows(A: Tensor, B: Tensor, fr: Frame, w: WeightSlopes, grad: Tensor,
             frame_terms: bool = True,
             out: tuple[Tensor, Tensor] | None = None) -> Cotangents:
    r"""Vector-Jacobian product of :func:`combine` at the output cotangent ``grad`` (the
    cotangents of ``a`` and ``b`` written into ``out``, rows of any strides, if given).

    Written for the sign-aligned :math:`b' = \sigma b`, with the sign folded into the
    coefficients.
    Without ``frame_terms`` the gradients leave out :math:`L_c\,\partial c + L_\delta\,
    \partial\delta` (the pyramid adds those once per pair of control points, from the
    returned sensitivities).
    """
    P, R = A[..., :4, :], B[..., :4, :]
    sigma, delta = fr.sigma, fr.delta
    (F0, F1), (G0, G1), (H0, H1) = w.F, w.G, w.H
    gd = grad[..., 4:, :]
    pa, pb = dot(grad, A), sigma * dot(grad, B)
    gP, gR = dot(gd, P), sigma * dot(gd, R)
    # Sensitivities to c = P.R', delta = P.S' + R'.Q and t (module docstring of weights).
    L_c = delta * (H0 * gP + H1 * gR) - G0 * pa - G1 * pb
    L_d = -(G0 * gP + G1 * gR)
    L_t = None
    if w.Fs is not None and w.Gs is not None:  # both or neither (time_slopes)
        (Fs0, Fs1), (Gs0, Gs1) = w.Fs, w.Gs
        L_t = Fs1 * pb - Fs0 * pa + delta * (Gs0 * gP - Gs1 * gR)
    s1 = sigma * F1
    grad_a = torch.mul(coef(F0), grad, out=None if out is None else out[0])
    grad_b = torch.mul(coef(s1), grad, out=None if out is None else out[1])
    grad_a[..., :4, :].addcmul_(coef(delta * G0), gd, value=-1.0)
    grad_b[..., :4, :].addcmul_(coef(sigma * delta * G1), gd, value=-1.0)
    sL_c, sL_d = sigma * L_c, sigma * L_d
    if frame_terms:
        add_frame_terms(grad_a, grad_b, A, B, sL_c, sL_d)
    return Cotangents(grad_a, grad_b, sL_c, sL_d, L_t)


def add_frame_terms(grad_a: Tensor, grad_b: Tensor, A: Tensor, B: Tensor, sL_c: Tensor,
                    sL_d: Tensor) -> None:
    r"""Add :math:`L_c\,\partial c/\partial(a, b) + L_\delta\,\partial\delta/\partial(a, b)`
    in place (``sL_c``, ``sL_d``: the sensitivities times ``sigma``, broadcast over
    ``(..., N)``)."""
    P, Q, R, S = A[..., :4, :], A[..., 4:, :], B[..., :4, :], B[..., 4:, :]
    sL_c, sL_d = coef(sL_c), coef(sL_d)
    grad_a[..., :4, :].addcmul_(sL_c, R).addcmul_(sL_d, S)
    grad_a[..., 4:, :].addcmul_(sL_d, R)
    grad_b[..., :4, :].addcmul_(sL_c, P).addcmul_(sL_d, Q)
    grad_b[..., 4:, :].addcmul_(sL_d, P)


class _Sclerp(InputsSaved):
    """Screw linear interpolation (eq. 11) with an analytic backward.

    Inputs are already broadcast: ``a, b (..., 8)``, ``t (...)``. Saves only the inputs;
    the backward recomputes the weights (cheaper in memory than keeping intermediates).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
        a2, b2, t1 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1)
        if torch.compiler.is_compiling():  # one graph, no writes into buffers (Dynamo)
            return _forward(a2.T, b2.T, t1, shortest).T.reshape(a.shape)
        out = a.new_empty(a.shape)  # the output itself, not a view (a caller may modify it)
        flat = out.view(-1, 8)
        for i in chunks(t1.shape[0], device=t1.device):  # the caller's layout, seen as rows
            _forward(a2[i].T, b2[i].T, t1[i], shortest, flat[i].T)
        return out

    @staticmethod
    def backward(ctx, grad):
        a, b, t = ctx.saved_tensors
        (shortest,) = ctx.constants
        need_t = ctx.needs_input_grad[2]
        a2, b2, t1, g2 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1), grad.reshape(-1, 8)
        parts = chunks(t1.shape[0], device=t1.device)
        if not (batched(grad) or torch.compiler.is_compiling() or torch.is_grad_enabled()):
            ga, gb = torch.empty_like(a2), torch.empty_like(b2)
            gt = t1.new_empty(t1.shape) if need_t else None
            for i in parts:
                ct = _chunk_vjp(a2[i], b2[i], t1[i], g2[i], shortest, need_t,
                                (ga[i].T, gb[i].T))
                if gt is not None:  # need_t
                    gt[i] = cast(Tensor, ct.t)  # not None with time_slopes=need_t
        else:  # a vmap over this backward, Dynamo or a double backward: no writes in place
            done = [_chunk_vjp(a2[i], b2[i], t1[i], g2[i], shortest, need_t)
                    for i in parts]
            ga = torch.cat([ct.a.T for ct in done])
            gb = torch.cat([ct.b.T for ct in done])
            gt = torch.cat([cast(Tensor, ct.t) for ct in done]) if need_t else None
        grad_t = gt.view(t.shape) if gt is not None else None
        return ga.view(a.shape), gb.view(b.shape), grad_t, None


def _forward(A: Tensor, B: Tensor, t: Tensor, shortest: bool,
             out: Tensor | None = None) -> Tensor:
    """Eq. 11 on rows ``(8, n)`` of any strides (into ``out`` if given)."""
    fr = frame(A, B, shortest)
    return combine(A, B, fr, weights(fr, t), out=out)


def _chunk_vjp(a: Tensor, b: Tensor, t: Tensor, grad: Tensor, shortest: bool,
               need_t: bool, out: tuple[Tensor, Tensor] | None = None) -> Cotangents:
    """:func:`vjp_rows` of one chunk of ``(n, 8)`` pairs, ``(n,)`` parameters and ``(n, 8)``
    output cotangents, in their layout seen as rows (the cotangent of ``t`` only with
    ``need_t``; those of ``a``, ``b`` into ``out`` if given)."""
    A, B = a.T, b.T
    fr = frame(A, B, shortest)
    w = cast(WeightSlopes, weights(fr, t, derivatives=True, time_slopes=need_t))
    return vjp_rows(A, B, fr, w, grad.T, out=out)


def sclerp(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Unchecked eq. 11 on broadcast inputs ``a, b (..., 8)``, ``t (...)``."""
    return _Sclerp.apply(a, b, t, shortest)

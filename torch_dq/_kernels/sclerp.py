r"""Fused screw interpolation (eq. 11) as a custom autograd op (private).

The readable eq. 11 is :func:`torch_dq.dualquat.sclerp`; this is the same formula on
component rows with the sign folded into the weights, chunked, with analytic backward
and forward-mode rules. Notation and weights: :mod:`torch_dq._kernels.weights`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .layout import chunks, coef, from_rows, to_rows
from .weights import screw_weights


def _frame(A: Tensor, B: Tensor, shortest: bool):
    """Halves, cosine ``c``, dual dot ``delta`` and sign of pairs of ``(..., 8, N)`` rows.

    ``B`` is *not* sign-aligned: the sign ``sigma`` (all ones when not ``shortest``) is folded
    into the N-sized coefficients instead, saving a pass over ``B``; ``c`` and ``delta`` are
    those of the sign-aligned pair.
    """
    P, Q, R, S = A[..., :4, :], A[..., 4:, :], B[..., :4, :], B[..., 4:, :]
    c = (P * R).sum(-2)
    sigma = torch.where(c < 0, -1.0, 1.0).to(c.dtype) if shortest else torch.ones_like(c)
    delta = sigma * ((P * S).sum(-2) + (R * Q).sum(-2))
    return P, Q, R, S, sigma * c, delta, sigma


def forward_rows(A: Tensor, B: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Eq. 11 on ``(..., 8, N)`` rows and ``(..., N)`` parameters."""
    P, _, R, _, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1) = screw_weights(c, t, derivatives=False)
    out = torch.addcmul(coef(F0) * A, coef(sigma * F1), B)
    out[..., 4:, :] -= torch.addcmul(coef(delta * G0) * P, coef(delta * sigma * G1), R)
    return out


def backward_rows(A: Tensor, B: Tensor, t: Tensor, grad: Tensor, shortest: bool):
    """Vector-Jacobian product of :func:`forward_rows`: rows of ``a`` and ``b``, and ``t``.

    Written for the sign-aligned ``b' = sigma b`` (``R, S`` below), then mapped back.
    """
    P, Q, R, S, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = screw_weights(c, t, True)
    R, S = coef(sigma) * R, coef(sigma) * S
    gr, gd = grad[..., :4, :], grad[..., 4:, :]
    pa, pb = (grad * A).sum(-2), sigma * (grad * B).sum(-2)
    gP, gR = (gd * P).sum(-2), (gd * R).sum(-2)
    # Sensitivities to c = P.R, delta = P.S + R.Q and t (module docstring).
    L_c = delta * (H0 * gP + H1 * gR) - G0 * pa - G1 * pb
    L_d = -(G0 * gP + G1 * gR)
    L_t = Fs1 * pb - Fs0 * pa + delta * (Gs0 * gP - Gs1 * gR)
    F0, F1, L_c, L_d = coef(F0), coef(F1), coef(L_c), coef(L_d)
    grad_a = torch.cat((F0 * gr - coef(delta * G0) * gd + L_c * R + L_d * S, F0 * gd + L_d * R), -2)
    grad_b = torch.cat((F1 * gr - coef(delta * G1) * gd + L_c * P + L_d * Q, F1 * gd + L_d * P), -2)
    return grad_a, coef(sigma) * grad_b, L_t


def jvp_rows(A, B, t, TA, TB, tt, shortest: bool) -> Tensor:
    """Jacobian-vector product of :func:`forward_rows` (tangents of the same shapes)."""
    P, Q, R, S, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = screw_weights(c, t, True)
    B, R, S, TB = coef(sigma) * B, coef(sigma) * R, coef(sigma) * S, coef(sigma) * TB
    tP, tQ, tR, tS = TA[..., :4, :], TA[..., 4:, :], TB[..., :4, :], TB[..., 4:, :]
    dc = (tP * R + P * tR).sum(-2)
    dd = (tP * S + P * tS + tR * Q + R * tQ).sum(-2)
    dF0, dF1 = -G0 * dc - Fs0 * tt, Fs1 * tt - G1 * dc
    dG0, dG1 = -H0 * dc - Gs0 * tt, Gs1 * tt - H1 * dc
    out = coef(F0) * TA + coef(F1) * TB + coef(dF0) * A + coef(dF1) * B
    out[..., 4:, :] -= (coef(delta) * (coef(G0) * tP + coef(G1) * tR + coef(dG0) * P
                                       + coef(dG1) * R)
                        + coef(dd) * (coef(G0) * P + coef(G1) * R))
    return out


class _SclerpVJP(torch.autograd.Function):
    """Screw linear interpolation (eq. 11) with an analytic backward.

    Inputs are already broadcast: ``a, b (..., 8)``, ``t (...)``. Saves only the inputs;
    the backward recomputes the weights (cheaper in memory than keeping intermediates).
    TorchDynamo cannot trace a Function that defines ``jvp``, so compiled code uses this
    class and eager code the subclass :class:`_Sclerp` that adds forward mode.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
        a2, b2, t1 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1)
        parts = [from_rows(forward_rows(to_rows(a2[i]), to_rows(b2[i]), t1[i], shortest))
                 for i in chunks(len(t1))]
        return torch.cat(parts).view(a.shape)

    @staticmethod
    def setup_context(ctx, inputs, output):
        a, b, t, shortest = inputs
        ctx.save_for_backward(a, b, t)
        ctx.save_for_forward(a, b, t)
        ctx.shortest = shortest

    @staticmethod
    def backward(ctx, grad):
        a, b, t = ctx.saved_tensors
        a2, b2, t1, g2 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1), grad.reshape(-1, 8)
        parts = [backward_rows(to_rows(a2[i]), to_rows(b2[i]), t1[i], to_rows(g2[i]), ctx.shortest)
                 for i in chunks(len(t1))]
        ga, gb, gt = (torch.cat(p, dim=-1) for p in zip(*parts, strict=True))
        return from_rows(ga).view(a.shape), from_rows(gb).view(b.shape), gt.view(t.shape), None


class _Sclerp(_SclerpVJP):
    """:class:`_SclerpVJP` with the forward-mode rule (``torch.func.jvp``, forward AD)."""

    @staticmethod
    def jvp(ctx, ta, tb, tt, _):
        a, b, t = ctx.saved_tensors
        ta = torch.zeros_like(a) if ta is None else ta
        tb = torch.zeros_like(b) if tb is None else tb
        tt = torch.zeros_like(t) if tt is None else tt
        A, B, TA, TB = (to_rows(x.reshape(-1, 8)) for x in (a, b, ta, tb))
        out = jvp_rows(A, B, t.reshape(-1), TA, TB, tt.reshape(-1), ctx.shortest)
        return from_rows(out).view(a.shape)


def sclerp(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Unchecked eq. 11 on broadcast inputs ``a, b (..., 8)``, ``t (...)``."""
    op = _SclerpVJP if torch.compiler.is_compiling() else _Sclerp
    return op.apply(a, b, t, shortest)

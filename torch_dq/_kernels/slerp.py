r"""Quaternion slerp on the shortest path, with an analytic backward (private).

The real part of eq. 11 (:mod:`torch_dq._kernels.weights`): for unit quaternions
:math:`q_0, q_1` with :math:`\sigma = \pm 1` the sign of :math:`q_0 \cdot q_1` and
:math:`c = \sigma\, q_0 \cdot q_1 = \cos\theta \ge 0`,

.. math::
    \mathrm{slerp}(q_0, q_1, t) = F_0\, q_0 + F_1\, \sigma q_1, \qquad
    F_i = \frac{\sin(s_i \theta)}{\sin\theta},\ s_0 = 1 - t,\ s_1 = t,

with the weights :math:`F` one power series in :math:`y = 1 - c` near :math:`c = 1` (equal
or opposite quaternions: exactly :math:`(1 - t, t)`, every derivative exact) and closed
forms elsewhere (:func:`torch_dq._kernels.weights.slerp_weights`). The weights depend on
:math:`c` alone, with bounded slope :math:`\partial F / \partial c`, so no angle is formed
from a difference of nearly equal quaternions. :func:`plain` is this formula in plain torch
ops on ``(..., 4)`` tensors (differentiable to any order in any mode, what
:func:`torch_dq.quat.slerp` runs under ``torch.func`` transforms); :func:`slerp` is the same
forward, to the bit, chunked, with the vector-Jacobian product written out:
with the output cotangent :math:`g`, :math:`p_0 = g \cdot q_0`,
:math:`p_1 = \sigma\, g \cdot q_1` and :math:`G = \partial F / \partial y`,

.. math::
    L_c = -(G_0 p_0 + G_1 p_1),\quad
    \bar q_0 = F_0 g + \sigma L_c q_1,\quad
    \bar q_1 = \sigma F_1 g + \sigma L_c q_0,\quad
    \bar t = F_{s,1} p_1 - F_{s,0} p_0.

The backward is itself plain torch ops, so a double backward differentiates it.
Everything stays in the caller's ``(N, 4)`` layout: no component-row copies (for 4
components they cost as much as the arithmetic they would speed up).
"""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor

from .._autograd import reference_vjp
from .._dispatch import batched
from .layout import CHUNK, chunks
from .weights import slerp_weights


def _dot(a: Tensor, b: Tensor) -> Tensor:
    """``(a * b).sum(-1)`` over 4 components as three fused multiply-adds of columns (2-3x
    faster on CPU than a reduction over a trailing dim of 4)."""
    a0, a1, a2, a3 = a.unbind(-1)
    b0, b1, b2, b3 = b.unbind(-1)
    return torch.addcmul(torch.addcmul(torch.addcmul(a0 * b0, a1, b1), a2, b2), a3, b3)


def _frame(q0: Tensor, q1: Tensor) -> tuple[Tensor, Tensor]:
    """``(c, sigma)``: :math:`\\sigma = -1` where :math:`q_0 \\cdot q_1 < 0`, else 1, and
    :math:`c = \\sigma\\, q_0 \\cdot q_1` (arithmetic, not ``torch.where``: several times
    faster on CPU)."""
    d = _dot(q0, q1)
    sigma = 1.0 - 2.0 * (d < 0).to(d.dtype)
    return sigma * d, sigma


def _host_branch(x: Tensor) -> bool:
    """Whether the weights may read a count on the host to skip unused branches (eager CPU)."""
    return x.device.type == "cpu" and not torch.compiler.is_compiling()


def plain(q0: Tensor, q1: Tensor, t: Tensor, host_branch: bool = False,
          out: Tensor | None = None) -> Tensor:
    """Slerp on the shortest path in plain torch ops (module docstring).

    Args:
        q0: ``(..., 4)`` unit quaternions.
        q1: ``(..., 4)`` unit quaternions, same shape as ``q0``.
        t: parameters broadcasting against the batch shape ``(...)``.
        host_branch: evaluate only the weights' branches in use (eager CPU; same bits).
        out: ``(..., 4)`` tensor to write the result into (not differentiable; the fused
            op's chunks of its result), or None.

    Returns:
        ``(..., 4)``.
    """
    c, sigma = _frame(q0, q1)
    F0, F1 = slerp_weights(c, t, host_branch=host_branch).F
    return torch.addcmul(F0[..., None] * q0, (sigma * F1)[..., None], q1, out=out)


class _Slerp(torch.autograd.Function):
    """:func:`plain` over cache-sized chunks, with the analytic backward of the module
    docstring.

    Inputs: ``q0, q1 (N, 4)`` and ``t`` either ``(N,)`` or ``(1,)`` (one ``t`` for all
    pairs). Saves only the inputs; the backward recomputes the weights.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
        out = torch.empty_like(q0)
        host = _host_branch(q0)
        for i in chunks(q0.shape[0], device=q0.device):
            plain(q0[i], q1[i], t if t.shape[0] == 1 else t[i], host, out=out[i])
        return out

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        q0, q1, t = ctx.saved_tensors
        if batched(grad):
            return reference_vjp(plain, (q0, q1, t), grad)
        need_t = ctx.needs_input_grad[2]
        common = t.shape[0] == 1
        g0, g1 = torch.empty_like(q0), torch.empty_like(q1)
        gts = []
        for i in chunks(q0.shape[0], device=q0.device):
            ti = t if common else t[i]
            gt = _vjp(q0[i], q1[i], ti, grad[i], g0[i], g1[i], need_t)
            if gt is not None:
                gts.append(gt.sum(0, keepdim=True) if common else gt)
        grad_t = (sum(gts[1:], gts[0]) if common else torch.cat(gts)) if need_t else None
        return g0, g1, grad_t


def _vjp(q0: Tensor, q1: Tensor, t: Tensor, grad: Tensor, out0: Tensor, out1: Tensor,
         need_t: bool) -> Tensor | None:
    """The VJP of one chunk (module docstring): writes the cotangents of ``q0, q1`` into
    ``out0, out1`` and returns that of ``t`` per pair (``None`` unless ``need_t``)."""
    c, sigma = _frame(q0, q1)
    w = slerp_weights(c, t, derivatives=True, time_slopes=need_t, host_branch=_host_branch(q0))
    (F0, F1), (G0, G1) = w.F, cast(Tensor, w.G)  # not None with derivatives
    p0, p1 = _dot(grad, q0), sigma * _dot(grad, q1)
    sL_c = (-sigma * (G0 * p0 + G1 * p1))[..., None]
    for dst, args in ((out0, (F0[..., None] * grad, sL_c, q1)),
                      (out1, ((sigma * F1)[..., None] * grad, sL_c, q0))):
        if torch.is_grad_enabled():  # a double backward records this: out= would not
            dst.copy_(torch.addcmul(*args))
        else:
            torch.addcmul(*args, out=dst)
    if w.Fs is None:
        return None
    Fs0, Fs1 = w.Fs
    return Fs1 * p1 - Fs0 * p0


def slerp(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    """Unchecked shortest-path slerp of ``q0, q1 (..., 4)`` (same shape) at ``t``
    broadcasting against their batch shape, through :class:`_Slerp`."""
    batch = q0.shape[:-1]
    tt = t.reshape(1) if t.numel() == 1 else t.expand(batch).reshape(-1)
    a, b = q0.reshape(-1, 4), q1.reshape(-1, 4)
    if a.shape[0] <= CHUNK and not (torch.is_grad_enabled()
                                    and (q0.requires_grad or q1.requires_grad or t.requires_grad)):
        # One chunk and nothing to differentiate: the Function's forward, to the bit, without
        # its per-call cost (which dominates a small batch).
        return plain(a, b, tt, _host_branch(a)).view(*batch, 4)
    return _Slerp.apply(a, b, tt).view(*batch, 4)

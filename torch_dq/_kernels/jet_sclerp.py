r"""Eq. 11 on Taylor jets (:func:`sclerp`, the triangular scheme :func:`pyramid`) and the
custom op of its weights (:class:`_WeightJets`, backward written out) (private).

The jet arithmetic and the weights in plain ops are :mod:`torch_dq._taylor` (the formulas and
sources: its docstring); this module adds the one autograd ``Function`` of that scheme. The
backward of the whole scheme, written out: :mod:`.jet_pyramid`.
"""

from __future__ import annotations

from typing import NamedTuple, cast

import torch
from torch import Tensor

from .. import _taylor
from .._autograd import reference_vjp, save, saved
from .._dispatch import batched, written_backward
from .._taylor import Jet, mul, weight_parts, weights_vjp

__all__ = ["SclerpParts", "pyramid", "sclerp", "sclerp_parts", "weights"]


def weights(c: Jet, s: Jet) -> tuple[Jet, Jet]:
    """Jets of the weights ``F, G`` of eq. 11 at ``cos(theta) = c`` ``(...)`` for
    ``s (2, ...)`` (rows ``1 - t`` and ``t``), ``c >= 0``:
    :func:`torch_dq._taylor.weight_parts`. Order 0 is what the fused kernels compute
    (:func:`torch_dq._kernels.weights.screw_weights`). Where reverse mode will differentiate
    jets of ``c`` alone (eager, :func:`torch_dq._dispatch.fused_path`), one op whose
    backward is written out (:class:`_WeightJets`)."""
    if _WeightJets.applies(c, s):
        out = _WeightJets.apply(s, *c)
        return list(out[:len(c)]), list(out[len(c):])
    F, G, _ = weight_parts(c, s, with_H=False)
    return F, G


class _WeightJets(torch.autograd.Function):
    r""":func:`weights` on jets ``c`` (``order >= 1``) for jets ``s`` that are not
    differentiated, with the backward written out: the jets of :math:`F(y(t), s(t))` depend
    on the coefficients of :math:`y = 1 - c` through the jets of its partial derivative along
    the path,
    :math:`\partial F_k / \partial y_i = (\partial_y F)_{k - i} = G_{k - i}` (perturb
    :math:`y(t)` by :math:`\varepsilon t^i`), and likewise :math:`\partial G_k / \partial y_i
    = H_{k - i}`; so

    .. math::
        \bar c_i = -\sum_{k \ge i} \big(\bar F_k\, G_{k - i} + \bar G_k\, H_{k - i}\big)

    summed over the two rows of ``s``: the forward's ``G`` and the jets of ``H``
    (:func:`weight_parts`), instead of autograd through the Taylor recurrences (about 5x
    the forward). Where the backward is itself differentiated or batched (``vmap``), the
    plain ops' VJP (:func:`torch_dq._autograd.reference_vjp`)."""

    @staticmethod
    def applies(c: Jet, s: Jet) -> bool:
        """Whether :func:`weights` takes this op: order >= 1, eager, reverse mode on ``c``
        alone (the plain ops give ``s``'s gradient and every other mode)."""
        return len(c) > 1 and written_backward(c, s)

    @staticmethod
    def forward(ctx, s: Jet, *c: Tensor | None):
        F, G, H = weight_parts(list(c), s, with_H=True)
        ctx.set_materialize_grads(False)
        save(ctx, [*c, *G, *H, *s])
        return (*F, *G)

    @staticmethod
    def backward(ctx, *grads):
        n, items = len(grads) // 2, saved(ctx)
        c, G, H, s = (items[k * n:(k + 1) * n] for k in range(4))
        if batched(*grads) or torch.is_grad_enabled():
            return (None, *_plain_weights_vjp(c, s, grads))
        yb = weights_vjp(list(grads[:n]), list(grads[n:]), G, H, [x is not None for x in c])
        return (None, *(None if ci is None or g is None else (-g).sum_to_size(ci.shape)
                        for ci, g in zip(c, yb, strict=True)))


def _plain_weights_vjp(c: Jet, s: Jet, grads) -> list[Tensor | None]:
    """:class:`_WeightJets`' cotangents of ``c`` through the plain ops (differentiable again;
    batched under ``vmap``)."""
    at = [i for i, x in enumerate(c) if x is not None]

    def reference(*known: Tensor) -> tuple[Tensor, ...]:
        jet: Jet = [None] * len(c)
        for i, x in zip(at, known, strict=True):
            jet[i] = x
        F, G, _ = weight_parts(jet, s, with_H=False)
        return tuple(torch.zeros_like(cast(Tensor, F[0])) if x is None else x for x in F + G)

    zero = torch.zeros_like
    outs = reference(*(cast(Tensor, c[i]) for i in at))
    cot = tuple(zero(o) if g is None else g for o, g in zip(outs, grads, strict=True))
    got = reference_vjp(reference, tuple(cast(Tensor, c[i]) for i in at), cot)
    out: list[Tensor | None] = [None] * len(c)
    for i, g in zip(at, got, strict=True):
        out[i] = g
    return out


class SclerpParts(NamedTuple):
    """:func:`sclerp_parts`: the interpolated jets and the intermediates of the written-out
    backward (:mod:`torch_dq._kernels.jet_pyramid`)."""

    q: Jet  # (8, ...)
    sign: Tensor  # (...): +-1, b's sign change
    F: Jet  # (2, 1, ...)
    G: Jet  # (2, 1, ...)
    H: Jet  # (2, ...), [] without with_H
    delta: Jet  # (...)
    D: Jet  # (4, ...): G_0 P + G_1 R


def sclerp(A: Jet, B: Jet, alpha: Jet) -> Jet:
    r"""Eq. 11 (shortest path) on jets of component rows: ``A, B (8, ...)``, ``alpha (...)``
    per coefficient (:mod:`torch_dq._taylor`'s docstring). The sign choice is the one of the
    current value (constant nearby). Components first: every product runs over contiguous
    rows and every dot product is a sum over the leading dim (fast on CPU, unlike a trailing
    dim of 4 or 8).
    """
    return sclerp_parts(A, B, alpha).q


def sclerp_parts(A: Jet, B: Jet, alpha: Jet, with_H: bool = False) -> SclerpParts:
    r""":func:`sclerp` and its intermediates (:class:`SclerpParts`; ``with_H``: also the jets
    of :math:`H = \partial_y G`, for a written-out backward)."""
    A0, B0 = cast(Tensor, A[0]), cast(Tensor, B[0])
    sign = 1.0 - 2.0 * ((A0[:4] * B0[:4]).sum(0) < 0).to(B0.dtype)
    B = _taylor._scale(B, sign)  # b's representative nearest to a
    # c = P.R and delta = P.S + Q.R in one product: a against b and against b's halves swapped
    dots = mul(A, [None if b is None else torch.stack((b, b.roll(4, 0))) for b in B])
    c = [None if d is None else d[0, :4].sum(0) for d in dots]
    delta = [None if d is None else d[1].sum(0) for d in dots]
    # s = 1 - t for a, t for b
    s = _taylor._stack(zip(_taylor._rsub(1.0, alpha), alpha, strict=True))
    F, G, H = weight_parts(c, s, with_H=True) if with_H else (*weights(c, s), [])
    F, G = ([None if w is None else w[:, None] for w in jet] for jet in (F, G))
    X = _taylor._stack(zip(A, B, strict=True))
    q = [None if x is None else x.sum(0) for x in mul(F, X)]  # F_0 a + F_1 b
    D = [None if x is None else x.sum(0) for x in mul(G, [None if x is None else x[:, :4]
                                                          for x in X])]
    correction = mul(delta, D)
    q = [None if x is None else _dual_minus(x, corr) for x, corr in zip(q, correction,
                                                                       strict=True)]
    return SclerpParts(q, sign, F, G, H, delta, D)


def _dual_minus(x: Tensor, corr: Tensor | None) -> Tensor:
    """Rows ``x (8, ...)`` with ``corr (4, ...)`` subtracted from the dual half."""
    real, dual = x.split(4)
    return torch.cat((real, cast(Tensor, _taylor._lin(dual, 1.0, corr, -1.0))))


def pyramid(q: Jet, levels: list[Jet], kept: list[SclerpParts] | None = None) -> Jet:
    """The triangular scheme of De Casteljau / De Boor on jets (readable; its written-out
    backward: :mod:`torch_dq._kernels.jet_pyramid`): level 0 ``q (8, m, n)``, then per
    level the jets ``alpha (m - j, n)`` of its local parameters; returns the jets of the
    last level, ``(8, n)``. ``kept``: a list to which each level's :func:`sclerp_parts`
    (with ``H``) is appended."""
    for alpha in levels:
        a, b = ([None if x is None else x[:, sl] for x in q]
                for sl in (slice(None, -1), slice(1, None)))
        if kept is None:
            q = sclerp(a, b, alpha)
        else:
            kept.append(sclerp_parts(a, b, alpha, with_H=True))
            q = kept[-1].q
    return [None if x is None else x[:, 0] for x in q]

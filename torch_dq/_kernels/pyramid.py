r"""Fused triangular scheme of De Casteljau and De Boor (paper section 4) (private).

The readable level loops are in :mod:`torch_dq.curves`; this runs all levels of the
scheme in component-row layout over cache-sized chunks, as one autograd op.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import layout
from .layout import chunks, from_rows, to_rows
from .sclerp import backward_rows, forward_rows, jvp_rows


def _gather(rows: Tensor, idx: Tensor) -> Tensor:
    """Control-point rows ``(8, M)`` gathered straight into level 0, ``(m, 8, n)``."""
    m, n = idx.shape
    return rows.index_select(1, idx.reshape(-1)).view(8, m, n).transpose(0, 1)


def _pyramid_levels(rows: Tensor, idx: Tensor, alphas: tuple[Tensor, ...]) -> list[Tensor]:
    """All levels of the triangular scheme for one chunk, each ``(m - j, 8, n)``."""
    levels = [_gather(rows, idx)]
    for alpha in alphas:
        D = levels[-1]
        levels.append(forward_rows(D[:-1], D[1:], alpha, True))
    return levels


class _PyramidVJP(torch.autograd.Function):
    r"""The triangular scheme of De Casteljau and De Boor, fused (paper section 4).

    Level 0 holds ``m`` control points per output, ``ctrl[idx[i, k]]``; level ``j`` holds
    :math:`d^{(j)}_i = \mathrm{sclerp}(d^{(j-1)}_i, d^{(j-1)}_{i+1}, \alpha_j[i])`
    (shortest path), and the output is the single point of level ``m - 1``.

    Inputs: ``ctrl (M, 8)``, ``idx (m, N)`` int64, and ``m - 1`` tensors
    ``alpha_j (m - j, N)``. Output ``(N, 8)``. All levels run in component-row layout over
    cache-sized chunks of ``N``; the backward recomputes them chunk by chunk, so nothing but
    the (small) inputs is saved: fused memory is O(output) instead of O(m^2 output).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(ctrl: Tensor, idx: Tensor, *alphas: Tensor) -> Tensor:
        rows = to_rows(ctrl)
        parts = [from_rows(_pyramid_levels(rows, idx[:, i], tuple(a[:, i] for a in alphas))[-1][0])
                 for i in chunks(idx.shape[1], layout.PYRAMID_CHUNK)]
        return torch.cat(parts)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)
        ctx.save_for_forward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        ctrl, idx, *alphas = ctx.saved_tensors
        rows = to_rows(ctrl)
        grad_rows = torch.zeros_like(rows)
        grad_alphas = [[] for _ in alphas]
        for i in chunks(idx.shape[1], layout.PYRAMID_CHUNK):
            chunk_alphas = tuple(a[:, i] for a in alphas)
            levels = _pyramid_levels(rows, idx[:, i], chunk_alphas)
            G = to_rows(grad[i]).unsqueeze(0)
            for j in range(len(alphas), 0, -1):
                D = levels[j - 1]
                gA, gB, g_alpha = backward_rows(D[:-1], D[1:], chunk_alphas[j - 1], G, True)
                grad_alphas[j - 1].append(g_alpha)
                # d_i^(j-1) feeds d_(i-1)^(j) as b and d_i^(j) as a
                zero = torch.zeros_like(gA[:1])
                G = torch.cat((gA, zero)) + torch.cat((zero, gB))
            grad_rows = grad_rows.index_add(1, idx[:, i].reshape(-1),
                                            G.transpose(0, 1).reshape(8, -1))
        return (from_rows(grad_rows), None, *(torch.cat(g, dim=-1) for g in grad_alphas))


class _Pyramid(_PyramidVJP):
    """:class:`_PyramidVJP` with the forward-mode rule."""

    @staticmethod
    def jvp(ctx, t_ctrl, _, *t_alphas):
        ctrl, idx, *alphas = ctx.saved_tensors
        t_ctrl = torch.zeros_like(ctrl) if t_ctrl is None else t_ctrl
        D, TD = _gather(to_rows(ctrl), idx), _gather(to_rows(t_ctrl), idx)
        for alpha, t_alpha in zip(alphas, t_alphas, strict=True):
            t_alpha = torch.zeros_like(alpha) if t_alpha is None else t_alpha
            D, TD = (forward_rows(D[:-1], D[1:], alpha, True),
                     jvp_rows(D[:-1], D[1:], alpha, TD[:-1], TD[1:], t_alpha, True))
        return from_rows(TD[0])


def pyramid(ctrl: Tensor, idx: Tensor, alphas: list[Tensor]) -> Tensor:
    """Unchecked fused De Casteljau / De Boor scheme (:class:`_PyramidVJP`), ``(N, 8)``."""
    op = _PyramidVJP if torch.compiler.is_compiling() else _Pyramid
    return op.apply(ctrl, idx, *alphas)

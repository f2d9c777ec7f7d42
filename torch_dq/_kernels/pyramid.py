r"""Fused triangular scheme of De Casteljau and De Boor (paper section 4) (private).

The readable level loops are in :mod:`torch_dq.curves`; this runs all levels of the
scheme in component-row layout over cache-sized chunks, as one autograd op.

Level 0 of both algorithms reads consecutive control points, so the pairs it interpolates
are the same for every time of a span (De Boor) or of a curve (De Casteljau): their frames
(cosine, dual dot, sign) and angles are computed once per pair of control points and
gathered, and in the backward the frame's part of the gradient is summed per pair before
it is expanded into control-point rows.
"""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor

from .._autograd import InputsSaved, index_add
from . import layout
from .layout import chunks, from_rows, to_rows
from .sclerp import Frame, add_frame_terms, combine, frame, vjp_rows, weights
from .weights import Angle, angle


def _pair_table(rows: Tensor) -> Tensor:
    """``(6, M - 1)``: :class:`Frame` and :class:`Angle` of control points ``(i, i + 1)``."""
    fr = frame(rows[:, :-1], rows[:, 1:], True)
    return torch.stack((*fr, *angle(fr.c)))


def _alpha(alphas: Tensor, m: int, j: int) -> Tensor:
    """Level ``j``'s ``m - j`` rows of the triangular stack (after the rows of levels
    ``1 .. j - 1``), or the shared ``(1, n)`` row."""
    if alphas.shape[0] == 1:
        return alphas
    start = (j - 1) * m - (j - 1) * j // 2  # sum of m - i for i = 1 .. j - 1
    return alphas[start:start + m - j]


def _levels(rows: Tensor, table: Tensor, first: Tensor, alphas: Tensor, m: int,
            derivatives: bool = False, time_slopes: bool = False):
    """All levels of the scheme for one chunk: the points ``(m - j, 8, n)`` of levels
    ``0 .. m - 1``, and the frames and weights of levels ``1 .. m - 1``."""
    n = first.shape[0]
    k = torch.arange(m, device=first.device)[:, None]
    D = rows.index_select(1, (first + k).reshape(-1)).view(8, m, n).transpose(0, 1)
    pairs = table.index_select(1, (first + k[:-1]).reshape(-1)).view(6, m - 1, n)
    fr = Frame(*pairs[:3])
    ang: Angle | None = Angle(*pairs[3:])
    points, frames, ws = [D], [], []
    for j in range(1, m):
        A, B = D[:-1], D[1:]
        if j > 1:
            fr, ang = frame(A, B, True), None
        w = weights(fr, _alpha(alphas, m, j), derivatives, time_slopes, ang)
        D = combine(A, B, fr, w)
        points.append(D)
        frames.append(fr)
        ws.append(w)
    return points, frames, ws


class _Pyramid(InputsSaved):
    r"""The triangular scheme of De Casteljau and De Boor, fused (paper section 4).

    Level 0 holds ``m`` consecutive control points per output, ``ctrl[first + k]``,
    ``k = 0 .. m - 1``; level ``j`` holds
    :math:`d^{(j)}_i = \mathrm{sclerp}(d^{(j-1)}_i, d^{(j-1)}_{i+1}, \alpha_j[i])`
    (shortest path), and the output is the single point of level ``m - 1``.

    Inputs: ``ctrl (M, 8)``, ``first (N,)`` int64, ``alphas``: the levels' parameters
    stacked, ``(m (m - 1) / 2, N)`` (level ``j`` has ``m - j`` rows), or ``(1, N)`` shared
    by every level and position (De Casteljau), and ``m``. Output ``(N, 8)``. All levels run
    in component-row layout over cache-sized chunks of ``N``; the backward recomputes them
    chunk by chunk, so nothing but the (small) inputs is saved: memory O(output) instead
    of O(m^2 output).

    Under ``torch.compile`` float32 runs in float64 (:func:`pyramid`): inductor's CPU code
    for the float32 backward gave gradients a quarter off (torch 2.13; float64, eager and
    ``aot_eager`` exact; ``tests/test_compile_float32_pyramid.py``).
    Under ``torch.compile`` the batch is one graph and AOTAutograd's partitioner chooses
    what the backward keeps: the points of levels ``0 .. m - 2`` and a few scalars per time
    (cubic, float32: 424 bytes per time, 13x the output's 32), recomputing the weights.
    Keeping the weights as well (returned by the forward) measured slower on CPU.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(ctrl: Tensor, first: Tensor, alphas: Tensor, m: int) -> Tensor:
        rows = to_rows(ctrl)
        table = _pair_table(rows)
        parts = [from_rows(_levels(rows, table, first[i], alphas[:, i], m)[0][-1][0])
                 for i in chunks(first.shape[0], layout.PYRAMID_CHUNK, first.device)]
        return torch.cat(parts)

    @staticmethod
    def backward(ctx, grad):
        ctrl, first, alphas = ctx.saved_tensors
        (m,), need_alpha = ctx.constants, ctx.needs_input_grad[2]
        rows = to_rows(ctrl)
        table = _pair_table(rows)
        grad_rows = torch.zeros_like(rows)
        pair_c = rows.new_zeros(rows.shape[1] - 1)  # level-1 frame sensitivities per pair
        pair_d = torch.zeros_like(pair_c)
        used = torch.zeros_like(pair_c, dtype=torch.bool)  # pairs inside one curve's span
        grad_alphas: list[Tensor] = []
        for i in chunks(first.shape[0], layout.PYRAMID_CHUNK, first.device):
            points, frames, ws = _levels(rows, table, first[i], alphas[:, i], m, True, need_alpha)
            G = to_rows(grad[i]).unsqueeze(0)
            g_alpha: list[Tensor] = []
            for j in range(m - 1, 0, -1):
                D = points[j - 1]
                ct = vjp_rows(D[:-1], D[1:], frames[j - 1], ws[j - 1], G, frame_terms=j > 1)
                g_alpha.append(cast(Tensor, ct.t))  # None only when not need_alpha (unused)
                if j == 1:
                    pair = (first[i] + torch.arange(m - 1, device=first.device)[:, None])
                    pair_c = index_add(pair_c, 0, pair.reshape(-1), ct.c.reshape(-1))
                    pair_d = index_add(pair_d, 0, pair.reshape(-1), ct.delta.reshape(-1))
                    used = used.index_fill(0, pair.reshape(-1), True)
                # d_i^(j-1) feeds d_(i-1)^(j) as b and d_i^(j) as a
                G = torch.cat((ct.a[:1], ct.a[1:] + ct.b[:-1], ct.b[-1:]))
            level0 = first[i] + torch.arange(m, device=first.device)[:, None]
            grad_rows = index_add(grad_rows, 1, level0.reshape(-1),
                                  G.transpose(0, 1).reshape(8, -1))
            if need_alpha:
                g_alpha.reverse()  # level order
                grad_alphas.append(cast(Tensor, sum(g.sum(0, keepdim=True) for g in g_alpha))
                                   if alphas.shape[0] == 1 else torch.cat(g_alpha))
        # Level 1's frame terms, once per pair of control points (i, i + 1). Pairs that no
        # output reads (e.g. the last point of one curve and the first of the next) are
        # zeroed, not multiplied by a zero sensitivity: a NaN in one curve stays there.
        A, B = (torch.where(used, x, 0.0) for x in (rows[:, :-1], rows[:, 1:]))
        # zeros like the gradient rows, which are batched where the backward runs under vmap
        # (the frame terms are added in place)
        grad_a, grad_b = (torch.zeros_like(grad_rows[:, 1:]) for _ in range(2))
        add_frame_terms(grad_a, grad_b, A, B, pair_c, pair_d)
        zero = torch.zeros_like(grad_a[:, :1])
        grad_rows = grad_rows + torch.cat((grad_a, zero), 1) + torch.cat((zero, grad_b), 1)
        grad_alpha = torch.cat(grad_alphas, -1) if need_alpha else None
        return from_rows(grad_rows), None, grad_alpha, None


def pyramid(ctrl: Tensor, idx: Tensor, alphas: list[Tensor] | Tensor) -> Tensor:
    """Unchecked fused De Casteljau / De Boor scheme (:class:`_Pyramid`), ``(N, 8)``.

    Args:
        ctrl: ``(M, 8)`` control points (flattened over curves).
        idx: ``(m, N)`` int64 indices into ``ctrl`` of level 0 of each output; consecutive
            (``idx[k] = idx[0] + k``), as both algorithms read them.
        alphas: the ``m - 1`` levels' parameters, ``(m - j, N)`` for level ``j``; or one
            ``(1, N)`` tensor used at every level and position (De Casteljau's ``t``).
    """
    m = idx.shape[0]
    stacked = alphas if isinstance(alphas, Tensor) else torch.cat(alphas)
    if torch.compiler.is_compiling() and ctrl.dtype == torch.float32:
        wide = _Pyramid.apply(ctrl.double(), idx[0], stacked.double(), m)
        return wide.to(torch.float32)
    return _Pyramid.apply(ctrl, idx[0], stacked, m)

r"""The curve schemes through their fused ops (private; the readable schemes and the public
functions are in :mod:`torch_dq.curves`, which chooses between them with
:func:`torch_dq._dispatch.fused_path`).

Each function flattens the batch of curves into one index of control points and calls one
kernel: De Casteljau and De Boor through :func:`torch_dq._kernels.pyramid.pyramid`, the
cumulative form through :func:`torch_dq._cumulative.derivatives`, the time derivatives of
every scheme on jets through :func:`torch_dq._kernels.jet_pyramid.pyramid`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _cumulative, _taylor
from ._kernels import jet_pyramid
from ._kernels.layout import chunks
from ._kernels.pyramid import pyramid

__all__ = ["fused_bezier", "fused_bspline", "fused_cumulative", "jet_scheme", "span_points"]


def span_points(ctrl: Tensor, r: Tensor, degree: int, batch: torch.Size) -> Tensor:
    """The ``degree + 1`` control points of each time's span, ``(*batch, T, p + 1, C)``
    (``ctrl (..., n, C)``), gathered through one flat index (the backward accumulates into
    ``(B n, C)``)."""
    n, T, C = ctrl.shape[-2], r.shape[-1], ctrl.shape[-1]
    flat = ctrl.expand(*batch, n, C).reshape(-1, C)
    offsets = (torch.arange(batch.numel(), device=r.device) * n).reshape(*batch, 1, 1)
    idx = r[..., None] + torch.arange(-degree, 1, device=r.device) + offsets
    idx = idx.expand(*batch, T, degree + 1)
    return flat.index_select(0, idx.reshape(-1)).view(*batch, T, degree + 1, C)


def fused_bezier(ctrl: Tensor, s: Tensor, batch: torch.Size) -> Tensor:
    """De Casteljau through the fused op: every curve's ``m`` control points are level 0,
    with ``alpha = s`` at every level."""
    T, m, B = s.shape[-1], ctrl.shape[-2], batch.numel()
    flat = ctrl.expand(*batch, m, 8).reshape(B * m, 8)
    # idx[i, b T + k] = b m + i: the i-th control point of curve b, for each of its T times
    idx = (torch.arange(B, device=s.device)[:, None] * m + torch.arange(m, device=s.device))
    idx = idx.T[:, :, None].expand(m, B, T).reshape(m, B * T)
    ss = s.expand(*batch, T).reshape(1, B * T)
    out = pyramid(flat, idx, ss)  # one (1, B T) parameter row shared by every level
    return out.view(*batch, T, 8)


def fused_bspline(ctrl: Tensor, r: Tensor, alphas: list[Tensor], degree: int,
                   batch: torch.Size) -> Tensor:
    """De Boor through the fused op, which gathers the ``degree + 1`` points of each time
    itself and recomputes the levels in its backward (memory O(output))."""
    p, n, T, B = degree, ctrl.shape[-2], r.shape[-1], batch.numel()
    flat = ctrl.expand(*batch, n, 8).reshape(B * n, 8)
    offsets = (torch.arange(B, device=r.device) * n).reshape(*batch, 1, 1)
    idx = r[..., None] + torch.arange(-p, 1, device=r.device) + offsets  # (*batch, T, p + 1)
    rows = [a.expand(*batch, T, p + 1 - j).reshape(B * T, p + 1 - j).T
            for j, a in enumerate(alphas, start=1)]
    out = pyramid(flat, idx.expand(*batch, T, p + 1).reshape(B * T, p + 1).T, rows)
    return out.view(*batch, T, 8)


def fused_cumulative(ctrl: Tensor, r: Tensor, weights: list[Tensor], degree: int,
                      batch: torch.Size, kernel=_cumulative.derivatives) -> list[Tensor]:
    """The cumulative form and its time derivatives to ``len(weights) - 1`` through its fused
    ops (``kernel``: :func:`torch_dq._cumulative.derivatives`, or
    :func:`torch_dq._cumulative_lie.derivatives` where it applies), which read the ``degree +
    1`` points from ``c_{r-p}`` on and each pair's relative motion once; ``weights``: the
    basis and its derivatives, ``(..., T, p)`` each."""
    n, T, B = ctrl.shape[-2], r.shape[-1], batch.numel()
    flat = ctrl.expand(*batch, n, 8).reshape(B * n, 8)
    offsets = (torch.arange(B, device=r.device) * n).reshape(*batch, 1)
    first = (r - degree + offsets).expand(*batch, T).reshape(B * T)
    w = [x.expand(*batch, T, degree).reshape(B * T, degree).T for x in weights]
    return [x.view(*batch, T, 8) for x in kernel(flat, first, w)]


JET_CHUNK = 16384  # times per eager chunk of the jet scheme (its temporaries stay in cache)


def jet_scheme(points: Tensor, levels, order: int, batch: torch.Size) -> list[Tensor]:
    r"""The triangular scheme of :func:`torch_dq.curves._de_casteljau` /
    :func:`torch_dq.curves._de_boor` on jets: the time derivatives ``0..order`` of every
    level, propagated through eq. 11 in truncated Taylor arithmetic (:mod:`torch_dq._taylor`).

    ``points (*batch, T, m, 8)``: level 0 (constant in time), evaluated as component rows
    ``(8, m, n)`` over chunks of times; ``levels``: per level ``j``
    the local parameters and their slopes ``d alpha / dt``, ``(..., T, m - j)`` (affine in
    ``t``: no higher Taylor coefficients). Returns ``[x, dx/dt, ..., d^order x/dt^order]``.
    """
    T, m = points.shape[-3:-1]
    n = batch.numel() * T
    # Component rows (8, m, n): every op runs over contiguous rows of times.
    points = points.reshape(n, m * 8).T.reshape(m, 8, n).transpose(0, 1)
    flat = [tuple(x.expand(*batch, T, m - j).reshape(n, m - j).T for x in level)
            for j, level in enumerate(levels, start=1)]
    outs = []
    parts = chunks(n, JET_CHUNK, points.device)  # temporaries stay in cache
    # split, not sliced: one backward node for all chunks, not a zero-filled copy of the
    # whole gradient per chunk
    pieces = points.split(JET_CHUNK, -1) if len(parts) > 1 else (points,)
    for part, piece in zip(parts, pieces, strict=True):
        # Zero Taylor coefficients are None (skipped): level 0 is constant, alpha affine.
        jets = [[alpha[:, part].contiguous(), slope[:, part].contiguous(),
                 *[None] * (order - 1)][:order + 1] for alpha, slope in flat]
        q = jet_pyramid.pyramid(piece.contiguous(), jets, order)
        outs.append([x.T for x in _taylor.derivatives(q)])
    # contiguous: compiled, the one chunk's transpose would keep its column-major strides
    return [torch.cat(xs).contiguous().view(*batch, T, 8) for xs in zip(*outs, strict=True)]

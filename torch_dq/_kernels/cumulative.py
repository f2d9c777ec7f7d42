r"""The cumulative form's poses as one fused autograd op (private; reference:
:func:`torch_dq._cumulative.jets`, front door :func:`torch_dq._cumulative.poses`).

Each power from the identity is :math:`\beta + \alpha x` with dual numbers
:math:`\alpha, \beta` (eq. 11's weights), so the product of powers expands into a sum of
per-span products of control points (:func:`_span_tables`, computed once per span start)
with per-time dual weights (:mod:`.subsets`), one weighted sum of table rows per time
(:mod:`.cumulative_rows`); the backward is written out (:class:`_Poses`).
"""

from __future__ import annotations

from typing import cast

import torch
from torch import Tensor

from .._autograd import index_add, reference_vjp
from .._dispatch import batched
from . import products
from .cumulative_rows import (
    Runs,
    chunk_parts,
    gathered_rows,
    row_dots,
    run_cotangents,
    run_rows,
    run_sums,
    segment_outer,
    sorted_runs,
    weighted_rows,
)
from .layout import to_rows
from .sclerp import Frame
from .sclerp import weights as screw_weights
from .subsets import subset_jets, subset_levels, subset_vjp
from .weights import Angle, Weights, WeightSlopes, angle

__all__ = ["chunk_weights", "full_pairs", "poses", "signs", "tables"]


def _span_tables(ctrl: Tensor, starts: Tensor, p: int,
                 used: Tensor | None = None) -> tuple[Tensor, Tensor]:
    r"""Per span start ``f`` in ``starts (U,)`` (indices into ``ctrl (M, 8)``, at most
    ``M - p``), the products of the expanded form and the relative motions' frames, as plain
    (differentiable) torch ops on ``U``-sized rows.

    With :math:`R_j = c_{f+j-1}^{-1} c_{f+j}` and its power
    :math:`R_j^{w} = \beta_j + \alpha_j R_j` (eq. 11 from the identity; the dual numbers
    :math:`\beta = F_0 - \epsilon\delta G_0`, :math:`\alpha = \sigma (F_1 - \epsilon\delta
    G_1)` commute with everything), the pose expands into
    :math:`c_f \prod_j (\beta_j + \alpha_j R_j) = \sum_S w_S\, T_S`,
    :math:`T_S = c_f \prod_{j \in S} R_j` (ascending ``j``) over the subsets ``S`` of
    ``1..p``, :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S} \beta_j`.

    Returns ``table (U * 2K, 8)``, ``K = 2^p``: rows ``u 2K + m`` the :math:`T_S` of
    ``starts[u]`` (bit ``j - 1`` of ``m`` set where ``j`` is in ``S``) and rows
    ``u 2K + K + m`` their real parts moved to the dual half (what a dual weight
    multiplies); and ``pairs (3, p, U)``: the frames ``c, delta, sigma`` of the
    :math:`R_j` from the identity. Where ``used (U,)`` (bool) is given, the starts it marks
    false (which no time reads) are computed from zeros: a NaN control point of one curve
    cannot reach the gradients of another through a span that straddles both.
    """
    idx = starts[:, None] + torch.arange(p + 1, device=ctrl.device)
    P = ctrl[idx]  # (U, p + 1, 8)
    if used is not None:
        P = torch.where(used[:, None, None], P, 0.0)
    conj = P.new_tensor([1.0, -1.0, -1.0, -1.0] * 2)
    rel = (products.right_matrix(P[:, 1:]) @ (P[:, :-1] * conj)[..., None]).squeeze(-1)
    right = products.right_matrix(rel).transpose(-1, -2)  # x R_j = x @ right[:, j]
    T = P[:, :1]
    for j in range(p):
        T = torch.cat((T, T @ right[:, j]), 1)  # (F, 2^(j+1), 8)
    shifted = torch.cat((torch.zeros_like(T[..., :4]), T[..., :4]), -1)
    table = torch.cat((T, shifted), 1).reshape(-1, 8)
    sigma = 1.0 - 2.0 * (rel[..., 0] < 0).to(rel.dtype)
    return table, torch.stack((sigma * rel[..., 0], sigma * rel[..., 4], sigma)).transpose(1, 2)


def chunk_weights(full: Tensor, f: Tensor, w: Tensor, derivatives: bool = False,
                   need_w: bool = False,
                   h_slope: bool = False) -> tuple[Frame, Weights | WeightSlopes, Tensor]:
    """The powers' frames (gathered per time), weights and the real parts ``b_r (2, p, n)``
    of their dual factors of one chunk (``full (6 p, F)``: the pairs' frames and angles, or
    ``(7 p, F)`` with :math:`y = 1 - c` last, computed in a wider dtype; ``h_slope``: as in
    :func:`screw_weights`)."""
    p, n = w.shape
    g = full.index_select(1, f).view(-1, p, n)
    fr = Frame(*g[:3])
    ws = screw_weights(fr, w, derivatives, need_w, Angle(*g[3:6]),
                       g[6] if g.shape[0] == 7 else None, h_slope)
    return fr, ws, ws.F * signs(fr.sigma)


def _dual_parts(sigma: Tensor, delta: Tensor, G: Tensor) -> Tensor:
    r"""The dual parts ``b_d (2, p, n)`` of :math:`\beta, \alpha`: :math:`-\delta (G_0,
    \sigma G_1)`."""
    return -delta * (G * signs(sigma))


def signs(sigma: Tensor, first: float = 1.0) -> Tensor:
    """``(first, sigma)`` stacked, to weigh the two rows of eq. 11's weights (products, not
    selected rows: their gradients are not zero-filled copies)."""
    return torch.stack((torch.full_like(sigma, first), sigma))


def _kept(kept: Tensor, part: slice, shape: torch.Size) -> Tensor:
    """The chunk ``part`` of the forward's saved weights, a contiguous ``(3, 2, p, n)`` block
    of the flat buffer ``kept`` (chunks one after the other)."""
    p, N = shape
    start, stop, _ = part.indices(N)
    return kept[6 * p * start:6 * p * stop].view(3, 2, p, stop - start)


class _Poses(torch.autograd.Function):
    r"""The cumulative form's poses from the span tables (:func:`_span_tables`):
    :math:`\sum_S w_S(t)\, T_S[f]`, one weighted bag of table rows per time
    (:func:`.weighted_rows`, or per run of sorted times :func:`.run_rows`), the weights from
    eq. 11's dual weights of each power.

    Inputs: ``table (F * 2K, 8)``, ``pairs (3, p, F)`` of ``F`` span starts, ``first (N,)``
    int64 (each time's start ``f``, an index into them), ``w (p, N)``, ``save``, ``runs``
    (:func:`.sorted_runs`, or ``None``). Outputs: the poses ``(N, 8)``, in the caller's layout,
    and with ``save`` what the backward reads (not differentiable): the bags' weights
    ``(N, 2K)`` (``(0, 2K)`` with ``runs``, whose backward recomputes them from the last
    subset level, and under ``torch.compile``, whose backward recomputes them in fused
    elementwise code) and ``(b_r, G, H) (3, 2, p, N)``, memory about 2x (4x without
    ``runs``) the poses'. The weights run over cache-sized chunks of component rows. The
    backward returns the cotangents of the table and of the frames' ``c`` and ``delta``;
    autograd carries them to the control points through the (small) tables.
    Where the backward is itself differentiated, or the gradient of ``w`` is asked for, it
    recomputes the weights from the inputs instead (plain torch ops: twice differentiable).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(table: Tensor, pairs: Tensor, first: Tensor, w: Tensor, save: bool,
                runs: Runs | None) -> tuple[Tensor, Tensor, Tensor]:
        full = full_pairs(pairs)
        N, width = first.shape[0], table.shape[0] // pairs.shape[-1]
        out = table.new_empty(N, 8)
        # with runs or under torch.compile the backward recomputes the bags' weights
        keep = save and runs is None and not torch.compiler.is_compiling()
        bags = table.new_empty(N if keep else 0, width)
        kept = table.new_empty(6 * w.shape[0] * N if save else 0)
        for i, run in chunk_parts(N, runs, table.device):
            fr, ws, b_r = chunk_weights(full, first[i], w[:, i], save, False)
            W = subset_jets(b_r[None], _dual_parts(fr.sigma, fr.delta, ws.G)[None])[0]
            if save:
                torch.stack((b_r, ws.G, cast(WeightSlopes, ws).H),
                            out=_kept(kept, i, w.shape))
            if run is not None:
                run_rows(table.view(-1, width, 8), W, i, run, out)
                continue
            if bags.shape[0]:
                bags[i] = W.T
            out[i] = weighted_rows(table, first[i], bags[i] if bags.shape[0] else W.T)
        return out, bags, kept

    @staticmethod
    def setup_context(ctx, inputs, output):
        table, pairs, first, w, _, ctx.runs = inputs
        ctx.mark_non_differentiable(*output[1:])
        ctx.set_materialize_grads(False)
        ctx.save_for_backward(table, pairs, first, w, *output[1:])

    @staticmethod
    def backward(ctx, grad, *_):
        if grad is None:  # only the (non-differentiable) saved weights were reached
            return None, None, None, None, None, None
        table, pairs, first, w, bags, kept = ctx.saved_tensors
        if batched(grad):  # under vmap (jacobian / hessian with vectorize=True)
            g_table, g_pairs, g_w = reference_vjp(
                lambda *x: _reference_poses(x[0], x[1], first, x[2]), (table, pairs, w), grad)
            return g_table, g_pairs, None, g_w, None, None
        need_w, plain = ctx.needs_input_grad[3], not torch.is_grad_enabled()
        reuse = kept.shape[0] > 0 and not need_w and plain
        runs = ctx.runs if plain else None  # the runs' products are not differentiable
        full = full_pairs(pairs)
        p, F = pairs.shape[1:]
        width = table.shape[0] // F
        grad = grad.contiguous()
        g_pairs = torch.zeros_like(pairs[:2])
        g_table, grad_w = table.new_zeros(F, width, 8), []
        for i, run in chunk_parts(first.shape[0], runs, table.device):
            f, G = first[i], grad[i]
            if reuse:
                sd = full.view(6, -1, F)[1:3].flatten(0, 1).index_select(1, f)
                (delta, sigma), (b_r, wG, wH) = sd.view(2, p, -1), _kept(kept, i, w.shape)
            else:
                fr, slopes, b_r = chunk_weights(full, f, w[:, i], True, need_w)
                ws = cast(WeightSlopes, slopes)
                sigma, delta, wG, wH = fr.sigma, fr.delta, ws.G, ws.H
            b_d = _dual_parts(sigma, delta, wG)
            levels = subset_levels(b_r[None], b_d[None])
            last = torch.cat(levels[-1], 1)[0]
            if run is not None:
                gW = run_cotangents(table.view(F, width, 8), last, to_rows(G), i, run, g_table)
            else:
                W = bags[i] if reuse and bags.shape[0] else last.T
                g_table = g_table + segment_outer(W, G, f, F)
                gW = row_dots(table, f, G, F)
            g_r, g_d = (x[0] for x in subset_vjp(levels, b_r[None], b_d[None], gW[None]))
            # b_r = (F0, sigma F1), b_d = -delta (G0, sigma G1): sensitivities to F and G
            sig = signs(sigma)
            gF, gG = sig * g_r, -delta * sig * g_d
            g_delta = -(sig * wG * g_d).sum(0)
            g_c = -(wG * gF + wH * gG).sum(0)  # dF/dc = -G, dG/dc = -H
            g_cd = torch.stack((g_c, g_delta))
            g_pairs = (run_sums(g_cd, run, g_pairs) if run is not None
                       else index_add(g_pairs, 2, f, g_cd))
            if need_w:  # s = (1 - w, w)
                Fs, Gs = cast(Tensor, ws.Fs), cast(Tensor, ws.Gs)
                grad_w.append((Fs[1] * gF[1] + Gs[1] * gG[1]) - (Fs[0] * gF[0] + Gs[0] * gG[0]))
        g_pairs = torch.cat((g_pairs, torch.zeros_like(pairs[2:])))
        return (g_table.view(-1, 8), g_pairs, None,
                torch.cat(grad_w, -1) if need_w else None, None, None)


def _reference_poses(table: Tensor, pairs: Tensor, first: Tensor, w: Tensor) -> Tensor:
    """:class:`_Poses`' poses ``(N, 8)`` in plain torch ops, unchunked (its backward's
    reference under ``vmap``)."""
    fr, ws, b_r = chunk_weights(full_pairs(pairs), first, w)
    W = subset_jets(b_r[None], _dual_parts(fr.sigma, fr.delta, ws.G)[None])[0]
    return gathered_rows(table, first, W.T)


def full_pairs(pairs: Tensor) -> Tensor:
    """``(6 p, F)``: the frames ``(3, p, F)`` and their :class:`Angle` rows."""
    return torch.cat((pairs, torch.stack(angle(pairs[0])))).flatten(0, 1)


def poses(ctrl: Tensor, first: Tensor, weights: Tensor) -> Tensor:
    r"""The cumulative form's poses through the fused op (eager reverse mode and
    ``torch.compile``; :func:`torch_dq._cumulative.poses` chooses it).

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened
            into one ``M``).
        first: ``(N,)``, ``N >= 1``, int64 index into ``ctrl`` of each time's
            :math:`c_{r-p}`; the time reads ``ctrl[first .. first + p]``.
        weights: ``(p, N)`` the cumulative basis :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``
            (:meth:`torch_dq._time.KnotDomain.bases`, cumulative, transposed), in ``ctrl``'s dtype.

    Returns:
        ``(N, 8)``: :math:`c_{r-p} \prod_j (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}`. Differentiable
        twice (reverse mode) with respect to ``ctrl`` and ``weights``. In eager mode the
        tables (:func:`_span_tables`, ``2^(p+1) x 8`` values each) are built for the span
        starts in use only (at most ``N``); under ``torch.compile`` (no data-dependent
        sizes) for every span start.
    """
    p = weights.shape[0]
    table, pairs, first = tables(ctrl, first, p)
    save = torch.is_grad_enabled() and (ctrl.requires_grad or weights.requires_grad)
    return _Poses.apply(table, pairs, first, weights, save, sorted_runs(first))[0]


def tables(ctrl: Tensor, first: Tensor, p: int) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`_span_tables` of the span starts that ``first`` reads, and ``first`` as
    indices into them. Eager: the starts in use only (one host read); under
    ``torch.compile`` (no data-dependent sizes) a table per start, unused ones from zeros."""
    F = ctrl.shape[0] - p
    used = torch.zeros(F, dtype=torch.bool, device=ctrl.device).index_fill(0, first, True)
    if torch.compiler.is_compiling():
        table, pairs = _span_tables(ctrl, torch.arange(F, device=ctrl.device), p, used)
        return table, pairs, first
    starts = used.nonzero()[:, 0]  # one host read
    if starts.shape[0] < F:  # index the tables of the starts in use
        first = (used.cumsum(0) - 1)[first]
    table, pairs = _span_tables(ctrl, starts, p)
    return table, pairs, first

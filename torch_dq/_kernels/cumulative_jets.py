r"""The cumulative form's time derivatives through the span tables (private; reference:
:func:`torch_dq._cumulative.jets`, front door :func:`torch_dq._cumulative.derivatives`).

The tables are constant on a span, so the time derivatives fall on the scalar dual weights
alone: jets of ``(L, 2, p, n)`` rows (:func:`_weight_jets`, backward written out in
:class:`_BagJets`), each order one weighted sum of table rows
(:class:`.Rows`).
"""

from __future__ import annotations

import math
from typing import NamedTuple, cast

import torch
from torch import Tensor

from .. import _taylor
from .._autograd import reference_vjp, save, saved
from .._dispatch import batched, written_backward
from .._numerics import even
from .cumulative import chunk_weights, full_pairs, signs, tables
from .cumulative_rows import POSES_CHUNK, Rows, sorted_runs
from .layout import chunks
from .subsets import SubsetJets, subset_levels, subset_vjp
from .weights import WeightSlopes, angle_square

__all__ = ["derivatives"]


def _compose(D: list[Tensor], h: _taylor.Jet) -> list[Tensor]:
    r"""Taylor coefficients of :math:`f(s(t))` from the derivatives ``D[m]`` :math:`=
    f^{(m)}(s_0)` and the normalised Taylor coefficients ``h = [None, s_1, s_2, ...]`` of
    :math:`s` (Faà di Bruno): :math:`\sum_m D_m (s - s_0)^m / m!`, truncated."""
    order = len(h) - 1
    terms: list[list[Tensor]] = [[] for _ in range(order + 1)]
    power = h
    for m in range(1, order + 1):
        scaled = D[m] / math.factorial(m) if m > 1 else D[m]
        for k in range(m, order + 1):
            terms[k].append(cast(Tensor, power[k]) * scaled)
        if m < order:
            power = _taylor.mul(power, h)
    return [D[0], *(sum(x[1:], x[0]) for x in terms[1:])]


def _s_derivatives(F: Tensor, Fs: Tensor, G: Tensor, Gs: Tensor, th2: Tensor, kappa: Tensor,
                   count: int) -> tuple[list[Tensor], list[Tensor]]:
    r"""The derivatives :math:`\partial_s^m F`, :math:`\partial_s^m G`, ``m < count`` (at
    least 2), of eq. 11's weights (or of sums of them) from their values and slopes by
    :math:`\partial_s^2 F = -\theta^2 F`, :math:`\partial_s^2 G = -\kappa F - \theta^2 G`
    (:func:`angle_square`)."""
    DF, DG = [F, Fs], [G, Gs]
    for m in range(2, count):
        DF.append(-th2 * DF[m - 2])
        DG.append(-(kappa * DF[m - 2] + th2 * DG[m - 2]))
    return DF, DG


def _h_derivatives(DF: list[Tensor], DG: list[Tensor], H: Tensor, Hs: Tensor, th2: Tensor,
                   kappa: Tensor, kappa_y: Tensor) -> list[Tensor]:
    r""":math:`\partial_s^m H = \partial_y \partial_s^m G` (as :func:`_s_derivatives`, for
    ``m < len(DF)``) by :math:`\partial_s^2 H = -\kappa' F - 2 \kappa G - \theta^2 H`: the
    derivative in :math:`y` of the second equation, as ``DG`` is that of ``DF``."""
    DH = [H, Hs]
    for m in range(2, len(DF)):
        DH.append(-(kappa_y * DF[m - 2] + 2.0 * kappa * DG[m - 2] + th2 * DH[m - 2]))
    return DH


class _BagParts(NamedTuple):
    r"""What :class:`_BagJets`' backward keeps: the real parts of the factors of the subsets
    (``b_r (L, 2, p, n)``) and of the total weight (``t_r (L, 1, p, n)``); the jets of
    their derivatives in :math:`y`, ``CG`` (of ``b_r``; also the dual parts per unit
    :math:`-\delta`), ``CH`` (of ``CG``), ``TG``, ``TH`` (the same for ``t``); ``delta (p,
    n)``; and the levels of both products (:func:`.subset_levels`)."""

    b_r: Tensor
    CG: Tensor
    CH: Tensor
    t_r: Tensor
    TG: Tensor
    TH: Tensor
    delta: Tensor
    levels_b: list[tuple[Tensor, Tensor]]
    levels_t: list[tuple[Tensor, Tensor]]

    def tensors(self) -> list[Tensor]:
        """Every tensor, flat (:meth:`rebuild` inverts it)."""
        return [*self[:7], *(x for lv in (self.levels_b, self.levels_t) for pair in lv
                             for x in pair)]

    @staticmethod
    def rebuild(items: list[Tensor]) -> _BagParts:
        """The parts from :meth:`tensors`."""
        b_r, CG, CH, t_r, TG, TH, delta = items[:7]
        pairs = list(zip(items[7::2], items[8::2], strict=True))
        half = len(pairs) // 2
        return _BagParts(b_r, CG, CH, t_r, TG, TH, delta, pairs[:half], pairs[half:])


def _weight_jets(full: Tensor, squares: Tensor, f: Tensor, w: list[Tensor]) -> Tensor:
    r"""The bags' weights of :func:`._span_tables`' expansion and their time derivatives,
    ``(L, 2K, n)`` (order first, real parts above dual parts; the empty subset's rows hold
    the total weight, :func:`_difference_table`), at times reading the span starts ``f
    (n,)``, from the ``L`` normalised Taylor coefficients ``w``, ``(p, n)`` each, of the
    cumulative basis (any ``L``); ``full``: :func:`.full_pairs`, ``squares (3, p, F)``:
    :func:`angle_square` of the pairs.

    The span's frames are constant in time, so only the powers' dual weights
    :math:`\beta_j = F(1 - w_j) - \epsilon\delta_j G(1 - w_j)`,
    :math:`\alpha_j = \sigma_j (F(w_j) - \epsilon\delta_j G(w_j))` move. Their derivatives
    in ``s`` follow from eq. 11's weights and slopes (:func:`screw_weights`) by
    :math:`\partial_s^2 F = -\theta^2 F`, :math:`\partial_s^2 G = -\kappa F - \theta^2 G`
    (:func:`angle_square`), their jets in time by composition with :math:`w_j(t)`
    (:func:`_compose`), and :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S}
    \beta_j` is a Cauchy product of dual-number jets (:class:`.SubsetJets`). Torch ops on
    ``(L, 2, p, n)`` rows; where reverse mode differentiates the pairs alone, eagerly, one op
    whose backward is written out (:class:`_BagJets`).
    """
    if _BagJets.applies(full, squares, w):
        return _BagJets.apply(full, squares, f, *w)
    return _bag_jets(full, squares, f, w)[0]


def _bag_jets(full: Tensor, squares: Tensor, f: Tensor, w: list[Tensor],
              keep: bool = False) -> tuple[Tensor, _BagParts | None]:
    """:func:`_weight_jets` and, with ``keep``, :class:`_BagParts`."""
    fr, slopes, _ = chunk_weights(full, f, w[0], True, True, keep)
    ws = cast(WeightSlopes, slopes)
    th2, kappa, kappa_y = squares.flatten(0, 1).index_select(1, f).view(3, -1, f.shape[0])
    Fs, Gs = cast(Tensor, ws.Fs), cast(Tensor, ws.Gs)
    DF, DG = _s_derivatives(ws.F, Fs, ws.G, Gs, th2, kappa, len(w))
    h: _taylor.Jet = [None, *(torch.stack((-x, x)) for x in w[1:])]  # s = (1 - w, w)
    sig = signs(fr.sigma)
    b_r, CG = (torch.stack(_compose(D, h)) * sig for D in (DF, DG))
    b_d = CG * -fr.delta
    levels: list[list[tuple[Tensor, Tensor]]] | None = [] if keep else None
    W = _products(b_r, b_d, levels)
    # The empty subset's rows 0 and K weigh c_f by the total sum_S w_S = prod_j (beta_j +
    # alpha_j), each factor F(1 - w) + sigma F(w) - eps delta (G(1 - w) + sigma G(w)) as a
    # function of w. Its slope -F_s(1 - w) + F_s(w) cancels on a slow span: for sigma = 1 it
    # is theta sin((1/2 - w) theta) / cos(theta / 2) (the sum is cos((1/2 - w) theta) /
    # cos(theta / 2)), from theta^2 and sinc((1/2 - w) theta), exact to the last bits.
    u = 0.5 - w[0]
    slope = th2 * u * even("sinc", u * u * th2) / torch.sqrt(0.5 * (1.0 + fr.c))
    neg = signs(fr.sigma, -1.0)
    TF, TG = _s_derivatives((ws.F * sig).sum(0),
                            torch.where(fr.sigma > 0, slope, (Fs * neg).sum(0)),
                            (ws.G * sig).sum(0), (Gs * neg).sum(0), th2, kappa, len(w))
    hw: _taylor.Jet = [None, *w[1:]]
    t_r, t_G = (torch.stack(_compose(D, hw))[:, None] for D in (TF, TG))
    t_d = t_G * -fr.delta
    total = _products(t_r, t_d, levels)
    K = W.shape[1] // 2
    W = W.index_copy(1, torch.tensor([0, K], device=W.device), total)
    W = W * _factorials(W, len(w))
    if not keep:
        return W, None
    H, Hs = ws.H, cast(Tensor, ws.Hs)
    DH = _h_derivatives(DF, DG, H, Hs, th2, kappa, kappa_y)
    TH = _h_derivatives(TF, TG, (H * sig).sum(0), (Hs * neg).sum(0), th2, kappa, kappa_y)
    kept = cast(list, levels)
    return W, _BagParts(b_r, CG, torch.stack(_compose(DH, h)) * sig, t_r, t_G,
                        torch.stack(_compose(TH, hw))[:, None], fr.delta, *kept)


def _products(b_r: Tensor, b_d: Tensor, kept: list | None) -> Tensor:
    """:class:`.SubsetJets` of the factors; with ``kept`` (in :class:`_BagJets`' forward,
    where autograd records nothing), its levels appended there for the backward."""
    if kept is None:
        return SubsetJets.apply(b_r, b_d)
    kept.append(subset_levels(b_r, b_d))
    return torch.cat(kept[-1][-1], 1)


def _factorials(W: Tensor, count: int) -> Tensor:
    """``(count, 1, 1)``: ``k!``, the derivatives' scale of the normalised coefficients."""
    return W.new_tensor([float(math.factorial(k)) for k in range(count)])[:, None, None]


class _BagJets(torch.autograd.Function):
    r""":func:`_weight_jets` with its backward written out, for cotangents of the pairs alone
    (``full``: :math:`\delta` and :math:`y = 1 - c`).

    Every quantity of a factor is a function of its pair's :math:`y` (the weights, their
    slopes, :math:`\theta^2`, :math:`\kappa`) and, linearly, :math:`\delta`; and
    :math:`\partial_y \partial_s^m F = \partial_s^m G`, :math:`\partial_y \partial_s^m G =
    \partial_s^m H` (:func:`_h_derivatives`), so the derivative in :math:`y` of a factor's
    jets is the composition of the next weight's (``CG``, ``CH``). The subsets' cotangents
    come from :func:`.subset_vjp`; the total derivatives in :math:`y` go to the row of ``y``
    (the angle rows and ``squares`` get none: their part is in it). Where the backward is
    itself differentiated or batched, the plain ops' VJP."""

    @staticmethod
    def applies(full: Tensor, squares: Tensor, w: list[Tensor]) -> bool:
        """Whether :func:`_weight_jets` takes this op: eager reverse mode on the pairs alone
        (the basis' gradient, for ``t`` and the knots, through the plain ops), with ``y`` in
        ``full`` (``7 p`` rows: it carries the total derivative in ``y``, ``squares`` none)."""
        return full.shape[0] == 7 * w[0].shape[0] and written_backward([full], list(w))

    @staticmethod
    def forward(ctx, full: Tensor, squares: Tensor, f: Tensor, *w: Tensor) -> Tensor:
        W, parts = _bag_jets(full, squares, f, list(w), keep=True)
        save(ctx, [full, squares, f, *w, *cast(_BagParts, parts).tensors()])
        ctx.count = len(w)
        return W

    @staticmethod
    def backward(ctx, gW):
        items = cast(list[Tensor], saved(ctx))
        full, squares, f, w = items[0], items[1], items[2], items[3:3 + ctx.count]
        none = (None,) * (1 + len(w))  # f, w
        if batched(gW) or torch.is_grad_enabled():
            return (*reference_vjp(lambda a, b: _bag_jets(a, b, f, w)[0], (full, squares), gW),
                    *none)
        p = _BagParts.rebuild(items[3 + ctx.count:])
        gW = gW * _factorials(gW, len(w))
        at = torch.tensor([0, gW.shape[1] // 2], device=gW.device)
        gb_r, gb_d = subset_vjp(p.levels_b, p.b_r, p.CG * -p.delta,
                                 gW.index_fill(1, at, 0.0))
        gt_r, gt_d = subset_vjp(p.levels_t, p.t_r, p.TG * -p.delta, gW.index_select(1, at))
        gy = ((gb_r * p.CG - p.delta * gb_d * p.CH).sum((0, 1))
              + (gt_r * p.TG - p.delta * gt_d * p.TH).sum((0, 1)))
        gdelta = -((gb_d * p.CG).sum((0, 1)) + (gt_d * p.TG).sum((0, 1)))
        n_p = gy.shape[0]
        rows = full.new_zeros(2 * n_p, full.shape[1]).index_add(
            1, f, torch.cat((gdelta, gy)))
        grad = full.new_zeros(7, n_p, full.shape[1])
        grad[1], grad[6] = rows[:n_p], rows[n_p:]
        return grad.view(full.shape), None, *none


def _difference_table(table: Tensor, width: int) -> Tensor:
    r""":func:`._span_tables`' rows with the empty subset's :math:`T_\emptyset = c_f` kept and
    subtracted from the others (real and shifted rows alike): :math:`\sum_S w_S T_S =
    (\sum_S w_S)\, c_f + \sum_{S \ne \emptyset} w_S (T_S - c_f)`. For the time
    derivatives, whose weights sum to nearly nothing on a slow span: summed as they are, the
    rounding of the large weights times :math:`|c_f|` (a translation far from the origin)
    swamps the result (float32: 6e-3 m/s^2 for a robot standing still 17 m away)."""
    blocks = table.view(-1, 2, width // 2, 8)
    base = blocks[:, :, :1]
    return torch.cat((base, blocks[:, :, 1:] - base), 2).view(-1, 8)


def derivatives(ctrl: Tensor, first: Tensor, weights: list[Tensor]) -> list[Tensor]:
    r"""The cumulative form and its time derivatives, order 1 or more, through the span
    tables (eager reverse mode and ``torch.compile``; :func:`torch_dq._cumulative.derivatives`
    chooses it).

    With the expansion of :func:`._span_tables`,
    :math:`X^{(k)}(t) = \sum_S w_S^{(k)}(t)\, T_S`: the tables are constant on a span, so
    the time derivatives fall on the scalar dual weights alone (:func:`_weight_jets`: jets
    of ``(L, 2, p, n)`` rows, not dual-quaternion jets as in
    :func:`~torch_dq._cumulative.jets`; their backward written out, :class:`_BagJets`, or
    where the basis is differentiated too, the subset products' alone,
    :class:`.SubsetJets`), and each order is one weighted sum of
    table rows (:class:`.Rows`, analytic backward). The
    tables, the pairs' angles and ``y = 1 - c`` are computed in float64
    (:func:`_difference_table`). Differentiable twice (reverse mode) with respect to
    ``ctrl`` and ``weights``.

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened).
        first: ``(N,)``, ``N >= 1``, int64 index into ``ctrl`` of each time's
            :math:`c_{r-p}`.
        weights: ``order + 1 >= 2`` tensors ``(p, N)``, the cumulative basis and its time
            derivatives (:meth:`torch_dq._time.KnotDomain.bases`, cumulative,
            transposed), in ``ctrl``'s dtype.

    Returns:
        ``order + 1`` tensors ``(N, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`.
    """
    p, N = weights[0].shape
    # the tables' products and differences in float64: exact for nearly equal neighbours
    # and the pairs' angles with y = 1 - c (the series' variable: a small angle's y is below
    # float32's resolution at 1, and with it the weights' theta^2 terms)
    table, pairs, first = tables(ctrl.to(torch.float64), first, p)
    table = _difference_table(table, 2 ** (p + 1)).to(ctrl.dtype)
    full = torch.cat((full_pairs(pairs), 1.0 - pairs[0])).to(ctrl.dtype)
    squares = torch.stack(angle_square(pairs[0])).to(ctrl.dtype)
    coefs = [w / math.factorial(k) for k, w in enumerate(weights)]
    W = torch.cat([_weight_jets(full, squares, first[i], [w[:, i] for w in coefs])
                   for i in chunks(N, POSES_CHUNK, first.device)], -1)
    return list(Rows.apply(table, first, W, sorted_runs(first)))

r"""Linearisation of the problem of :func:`~torch_dq.fitting.estimate`: the terms' whitened
residuals through the curve's spans, their exact Jacobians and the Gauss-Newton system.

One evaluation serves the costs and the linearisation points: a sample's time ``t' = t +
shift`` (the term's :meth:`~torch_dq.fitting.Term.time_shift`) selects its span
(``spans.first``), the curve evaluates every sample's span from the shared control points
(:meth:`~torch_dq.fitting._local.SpanEvaluator.shared`, the layer's own evaluation: a
B-spline's span tables once per span), the term maps the derivatives to residuals
(:meth:`~torch_dq.fitting.Term.residuals`). :func:`group_residuals` stops there (trial
costs); :class:`Linearization` also differentiates, on per-sample copies of the spans' points
(``torch_dq._curve.span_points``: the same sign-aligned chain, so the signs agree): the
residuals with respect to the span derivatives and the nuisance steps (one reverse pass over
``k`` copies), chained through the spans to the control points' steps (the layer's closed
form, :meth:`~torch_dq.nn.Curve.span_vjp`, where it has one: a cumulative B-spline's; else
``k`` reverse passes over per-sample span copies; the whole Jacobian once per distinct time
where samples share their times) and the samples' times (the next time derivative of the span:
no time in that graph), the times to the time-moving parameters by their declared rates
(:meth:`~torch_dq.fitting.Term.time_rates`). Terms read at identical times that no estimated
parameter moves (``Problem.groups``: an IMU's gyroscope and accelerometer) share the
evaluation and the chain: the spans' derivatives evaluated once, to the highest order a term
reads, each term's residual Jacobians stacked and chained through the spans together (one
closed-form product), then split back per term (each keeps its rows, weights and nuisance
columns).

The Gauss-Newton system has three blocks: the control-point band ``A_cc (..., n, w, 6, 6)``
(a sample touches ``w`` consecutive control points), the coupling ``A_cn (..., n, 6, m)``
and ``A_nn (..., m, m)``; the gradient ``g = J^T W r`` (``W`` the robust weights).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .._core import distinct
from .._curve import span_points
from .._kernels import native
from . import _robust
from ._local import sample_jacobians, tangent_step
from ._normal import System, _Normal, _window_normal

__all__ = ["Linearization", "Memo", "System", "group_residuals", "residuals"]

#: Samples of a term linearised at once (Term.parts): bounds the memory, and keeps a part's
#: per-sample arrays (a few MB each) out of fresh mappings: 65,536 took 12-21 % more CPU on
#: 600-1200 s records (a 60 s record's 12,000 IMU samples are one part either way)
PART = 1 << 14
_CHUNK = 1 << 15  # samples per chunk of reverse passes through the spans (order 0)
_ROWS = 1 << 14  # samples per chunk of the normal equations' rows (bounds their copies)


MEMO_BYTES = 1 << 25  # span derivatives a point keeps for its system (Memo)
TABLES_BYTES = 1 << 25  # the largest span table a system's parts share (_share_tables)


class Memo:
    """The span derivatives of a point, by (group, part), and the group's members' whitened
    residuals there: what :func:`group_residuals` evaluated for a trial's cost and
    :meth:`Linearization.system` takes (and drops) when the trial is accepted, instead of
    evaluating them again (a group, ``Problem.groups``, by its first term: its members'
    derivatives are kept once). At most ``MEMO_BYTES`` of them: a long record's would raise
    the peak memory by as much (235 MB for an hour of 200 Hz IMU), and its parts are
    evaluated again instead."""

    def __init__(self) -> None:
        self.entries: dict[tuple[int, int], list[tuple[Tensor, ...]]] = {}
        self.residuals: dict[tuple[int, int], list[Tensor]] = {}
        self.left = MEMO_BYTES
        #: ``(..., N)`` bool by term index: the observations with a prediction at the point,
        #: for the terms that can lose some (:meth:`~torch_dq.fitting.Term.seen`), kept
        #: whatever the budget
        self.seen: dict[int, Tensor] = {}

    def put(self, key: tuple[int, int], derivs: list[tuple[Tensor, ...]],
            residuals: list[Tensor]) -> None:
        """Keep ``derivs`` and the members' ``residuals`` (group, part ``key``) within the
        budget."""
        size = sum(d.numel() * d.element_size() for d in (*(d for ds in derivs for d in ds),
                                                          *residuals))
        if size <= self.left:
            self.entries[key], self.residuals[key] = derivs, residuals
            self.left -= size

    def take(self, key: tuple[int, int],
             ) -> tuple[list[tuple[Tensor, ...]], list[Tensor]] | None:
        """The derivatives and residuals kept for ``key`` (dropped from the memo), or
        None."""
        if key not in self.entries:
            return None
        return self.entries.pop(key), self.residuals.pop(key)


def residuals(problem, i: int, ctrl: Tensor, values: list[Tensor]) -> Tensor:
    """Whitened residuals ``(..., N, k)`` of term ``i`` alone (a group of its own:
    :func:`group_residuals`)."""
    return group_residuals(problem, (i,), ctrl, values)[0]


def group_residuals(problem, group: tuple[int, ...], ctrl: Tensor, values: list[Tensor],
                    memo: Memo | None = None) -> list[Tensor]:
    """Whitened residuals ``(..., N, k)`` of each term of ``group`` (``Problem.groups``:
    terms read at the same times) at ``(ctrl, values)`` through the spans, a part of at most
    ``PART`` samples at a time, the span derivatives evaluated once per part to the highest
    order a member reads (no domain check: :func:`~torch_dq.fitting.estimate` checked the
    times once); kept in ``memo`` where given, with the observations each term predicts
    (``Memo.seen``)."""
    vals = [problem.term_values(i, values) for i in group]
    order = _order(problem, group, vals)  # as the linearisation's
    out: list[list[Tensor]] = [[] for _ in group]
    seen: list[list[Tensor]] = [[] for _ in group]
    for k, parts in enumerate(_group_parts(problem, group)):
        ps = [term.per_sample(v) for term, v in zip(parts, vals, strict=True)]
        derivs = _part_derivatives(problem.spans, parts[0], ctrl, parts[0].time_shift(ps[0]),
                                   order)
        evs = [[d[:term.order + 1] for d in derivs] for term in parts]
        part = [term.residuals(ev, p) for term, ev, p in zip(parts, evs, ps, strict=True)]
        for rows, r in zip(out, part, strict=True):
            rows.append(r)
        if memo is not None:
            memo.put((group[0], k), derivs, part)
            for sees, term, ev, p in zip(seen, parts, evs, ps, strict=True):
                if (s := term.seen(ev, p)) is not None:
                    sees.append(s)
    if memo is not None:
        memo.seen.update({i: torch.cat(s, -1) for i, s in zip(group, seen, strict=True) if s})
    return [torch.cat(rows, -2) for rows in out]


def _group_parts(problem, group: tuple[int, ...]) -> list[tuple]:
    """The parts of at most ``PART`` samples (:meth:`~torch_dq.fitting.Term.parts`) of the
    terms of ``group``, one tuple of its members' per part (a group's members are cut
    alike)."""
    return list(zip(*(problem.terms[i].parts(PART) for i in group), strict=True))


def _order(problem, group: tuple[int, ...], vals: list[dict[str, Tensor]]) -> int:
    """The highest span derivative the terms of ``group`` read (with their values ``vals``),
    :func:`_rated`'s next one included."""
    return max(problem.terms[i].order + _rated(problem, i, v)
               for i, v in zip(group, vals, strict=True))


def _part_derivatives(spans, term, ctrl: Tensor, shift: Tensor, order: int,
                      ) -> list[tuple[Tensor, ...]]:
    """Span derivatives ``0 .. order`` at each times list of ``term`` (a part), its times
    moved by ``shift``."""
    derivs = []
    for t in term.times_list():
        t = spans.since_origin(t, shift)
        first = spans.first(t)
        with torch.no_grad():
            derivs.append(_point_derivatives(spans, ctrl, t, first,
                                             _distinct_times(t, first, 2), order))
    return derivs


def _rated(problem, i: int, vals: dict[str, Tensor]) -> bool:
    """Whether term ``i``'s spans are evaluated to one derivative more than it reads: its
    times move with an estimated parameter and it reads orders 0 to 2, so the linearisation
    takes its time columns from the next derivative (:meth:`Linearization._time_columns`);
    the cost path evaluates the same, so costs and linearisation agree to the bit."""
    rates = problem.terms[i].time_rates()
    return problem.terms[i].order < 3 and any(
        (i, name) in problem.index and name in rates for name in vals)


def width(problem, values: list[Tensor]) -> int:
    """Control points a sample's residual may touch (the band width ``w``)."""
    spans = problem.spans
    w = spans.support
    for i, term in enumerate(problem.terms):
        ts = term.times_list()
        if len(ts) > 1:
            dt = term.time_shift(term.per_sample(problem.term_values(i, values)))
            f = [spans.first(spans.since_origin(t, dt)) for t in ts]
            w = max(w, int((f[1] - f[0]).abs().max()) + spans.support)
    return min(w, spans.n)


class Linearization:
    """The Gauss-Newton system of a problem at a point (module docstring).

    Args:
        problem: the :class:`~torch_dq.fitting._problem.Problem` (its terms, spans, batch
            and estimated parameters).
    """

    def __init__(self, problem) -> None:
        self.p = problem
        self.spans = problem.spans

    def system(self, ctrl: Tensor, values: list[Tensor], w: int, memo: Memo | None = None,
               robust: bool = True) -> System:
        """Gauss-Newton system at ``(ctrl, values)`` with the robust weights there (unit
        weights where not ``robust``: the data's information whatever their residuals; the span
        derivatives and the residuals taken, and dropped, from ``memo`` where
        :func:`group_residuals` kept them at this point), a group of terms read at the same
        times (``Problem.groups``) and a part of its samples at a time.

        Each term's rows carry only the nuisance columns its samples' windows touch
        (:meth:`_columns`: a camera term its extrinsic and clock, one bias segment of a
        random walk its own), so a window's normal matrix stays small however many
        nuisance parameters the problem has; :class:`_Normal` scatters them into place.
        Where there are several groups, the closed-form span products of all groups read
        one table of the spans (:meth:`~torch_dq.fitting._local.SpanEvaluator.tables`)
        where it is small (:meth:`_share_tables`; a longer record's parts compute their own
        spans', whose memory is a part's). The terms' own blocks
        (``System.own``, the per-term degrees of freedom) only where ``robust``: a unit-weight
        system judges the data's information and is never the one the uncertainties read."""
        p = self.p
        Bf = max(p.batch.numel(), 1)
        acc = _Normal(ctrl, Bf, self.spans.n, w, p.m, len(p.terms) if robust else 1)
        rs: list[list[Tensor]] = [[] for _ in p.terms]
        weights: list[list[Tensor]] = [[] for _ in p.terms]
        groups = [(g, _group_parts(p, g)) for g in p.groups(values)]
        tables = self.spans.tables(ctrl) if self._share_tables(groups) else None
        for group, cut in groups:
            for k, parts in enumerate(cut):  # memory: a part
                added = self._add_part(acc, group, parts, ctrl, values, w,
                                       None if memo is None else memo.take((group[0], k)),
                                       tables, robust)
                for i, (r, wt) in zip(group, added, strict=True):
                    rs[i].append(r)
                    weights[i].append(wt)
        return acc.system([torch.cat(r, -2) for r in rs], [torch.cat(x, -1) for x in weights])

    def _share_tables(self, groups: list[tuple[tuple[int, ...], list]]) -> bool:
        """Whether the groups' parts read one table of every span
        (:meth:`~torch_dq.fitting._local.SpanEvaluator.tables`): where several groups read
        the spans (each part would compute its spans' again: twice the work for an IMU and a
        pose term) and the table (80 ``p`` float64 per span, 23 MB for 600 s of 20 Hz
        knots) is no larger than ``TABLES_BYTES`` or every group is one part (a part's own
        spans are then all of them)."""
        if len(groups) < 2:
            return False
        size = 80 * (self.spans.support - 1) * max(self.p.batch.numel(), 1) * self.spans.n * 8
        return size <= TABLES_BYTES or all(len(x) == 1 for _, x in groups)

    def _add_part(self, acc: _Normal, group: tuple[int, ...], terms: tuple, ctrl: Tensor,
                  values: list[Tensor], w: int,
                  known: tuple[list[tuple[Tensor, ...]], list[Tensor]] | None,
                  tables: Tensor | None = None, robust: bool = True,
                  ) -> list[tuple[Tensor, Tensor]]:
        """Add the normal equations of ``terms`` (the terms ``group`` or a part of their
        samples, :meth:`~torch_dq.fitting.Term.parts`; their span derivatives and residuals
        ``known`` where known, :class:`Memo`; the spans' ``tables`` where shared) to
        ``acc``, a term after the other; their residuals and robust weights."""
        derivs, rs = known or (None, None)
        out = []
        for i, term, (r, f0, Jc, Jn) in zip(group, terms, self._group_chained(
                group, terms, ctrl, values, w, derivs, rs, tables), strict=True):
            wt = _weights(term, r, robust)
            keys = self._windows(f0, w)
            # the windows from the part's first on (a part of a long record: not all n)
            lo, hi = torch.stack(torch.aminmax(keys)).tolist() if keys.numel() else (0, 0)
            rel = keys - lo
            local, gcols, valid = self._columns(i, Jn, rel, hi - lo + 1)
            if native.enabled(r, wt, Jc, acc.band, *Jn.values()):  # one pass, no rows kept
                acc.add_samples(rel.reshape(-1), lo, *self._flat(r, wt, Jc, Jn), local,
                                gcols.masked_fill(~valid, -1), i)
                out.append((r, wt))
                continue
            # every sample's window takes all the term's columns, in order: none selected
            plain = (local.shape[-1] == sum(J.shape[-1] for J in Jn.values())
                     and bool(valid[rel].all()))
            for a in range(0, r.shape[-2], _ROWS):  # the rows a chunk at a time
                k = rel[:, a:a + _ROWS]
                Y = self._rows(slice(a, a + _ROWS), r, wt, Jc, Jn, w,
                               None if plain else (local[k], valid[k]))
                win, block = _window_normal(k.reshape(-1), Y.flatten(0, 1))
                acc.add(win + lo, block, gcols[win], i)
            out.append((r, wt))
        return out

    def _columns(self, i: int, Jn: dict[str, Tensor], keys: Tensor, G: int,
                 ) -> tuple[Tensor, Tensor, Tensor]:
        """Per window ``(G, M)`` (``keys``: the samples' windows, below ``G``): the term's
        nuisance columns its samples touch (a nonzero Jacobian entry), as the term's own
        (``local``) and the problem's (``gcols``) indices, and ``valid`` (False on padding;
        ``M`` the most any window touches)."""
        p, Bf = self.p, keys.shape[0]
        N = keys.shape[-1]
        act, glob = [], []
        for name, J in Jn.items():
            q = p.index[(i, name)]
            act.append((J != 0).any(-2).expand(*p.batch, N, q.dim).reshape(Bf, N, q.dim))
            glob.append(torch.arange(q.offset, q.offset + q.dim, device=keys.device))
        if not act:
            empty = keys.new_zeros(G, 0)
            return empty, empty, empty.bool()
        per = torch.cat(act, -1).flatten(0, 1).to(torch.int32)
        touched = per.new_zeros(G, per.shape[-1]).index_add_(0, keys.reshape(-1), per) > 0
        M = int(touched.sum(-1).max())
        local = torch.sort(touched.to(torch.int32), dim=-1, descending=True, stable=True)[1][:, :M]
        return local, torch.cat(glob)[local], touched.gather(-1, local)

    def _rows(self, c: slice, r: Tensor, wt: Tensor, Jc: Tensor,
              Jn: dict[str, Tensor], w: int, cols: tuple[Tensor, Tensor] | None) -> Tensor:
        """``(Bf, S, k, 6 w + M + 1)``: the whitened rows ``[J_c | J_n | r]`` of the term's
        samples ``c`` weighted by the square roots of their robust weights ``wt``,
        ``J_n`` in their windows' columns ``cols = (local, valid)``: ``local (Bf, S, M)``,
        zero where not ``valid`` (None: all the term's columns, in order)."""
        p = self.p
        Bf, k = max(p.batch.numel(), 1), r.shape[-1]
        r, wt, Jc = r[..., c, :], wt[..., c], Jc[..., c, :, :, :]
        own = [J[..., c, :, :].expand(*p.batch, r.shape[-2], k, J.shape[-1]).reshape(
            Bf, -1, k, J.shape[-1]) for J in Jn.values()]
        S, M = r.shape[-2], sum(J.shape[-1] for J in own) if cols is None else cols[0].shape[-1]
        sw = wt.expand(*p.batch, S).reshape(Bf, S, 1, 1).sqrt()
        out = r.new_empty(Bf, S, k, 6 * w + M + 1)  # each block weighted into its columns
        torch.mul(Jc.expand(*p.batch, S, k, w, 6).reshape(Bf, S, k, w, 6), sw[..., None],
                  out=out[..., :6 * w].unflatten(-1, (w, 6)))
        if cols is None:
            a = 6 * w
            for J in own:
                torch.mul(J, sw, out=out[..., a:a + J.shape[-1]])
                a += J.shape[-1]
        elif M:
            local, valid = cols
            torch.mul(torch.cat(own, -1).gather(-1, local[:, :, None, :].expand(Bf, S, k, M)),
                      valid[:, :, None, :], out=out[..., 6 * w:-1]).mul_(sw)
        torch.mul(r.expand(*p.batch, S, k).reshape(Bf, S, k), sw[..., 0], out=out[..., -1])
        return out

    def _flat(self, r: Tensor, wt: Tensor, Jc: Tensor, Jn: dict[str, Tensor],
              ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``Jc (Bf N, k, w, 6)``, the nuisance columns ``(Bf N, k, Mt)`` (the term's, in
        order), ``r (Bf N, k)`` and ``wt (Bf N,)``: the batch's samples in a row, views
        where they can be (``_Normal.add_samples`` reads them by their strides)."""
        batch, (N, k) = self.p.batch, r.shape[-2:]
        S = max(batch.numel(), 1) * N
        own = [J.expand(*batch, N, k, J.shape[-1]) for J in Jn.values()]
        Jnc = own[0] if len(own) == 1 else (torch.cat(own, -1) if own
                                             else r.new_zeros(*batch, N, k, 0))
        return (Jc.expand(*batch, *Jc.shape[-4:]).reshape(S, *Jc.shape[-3:]),
                Jnc.reshape(S, k, Jnc.shape[-1]), r.expand(*batch, N, k).reshape(S, k),
                wt.expand(*batch, N).reshape(S))

    def _windows(self, f0: Tensor, w: int) -> Tensor:
        """``(Bf, N)`` window ids ``b (n + w) + f0`` of the samples' window starts ``f0``."""
        batch = self.p.batch
        Bf, N = max(batch.numel(), 1), f0.shape[-1]
        return (f0.expand(*batch, N).reshape(Bf, N)
                + (torch.arange(Bf, device=f0.device) * (self.spans.n + w))[:, None])

    def _chained(self, i: int, term, ctrl: Tensor, values: list[Tensor], w: int,
                 known: list[tuple[Tensor, ...]] | None = None):
        """:meth:`_group_chained` of ``term`` (term ``i`` or a part of it) alone."""
        return self._group_chained((i,), (term,), ctrl, values, w, known)[0]

    def _group_chained(self, group: tuple[int, ...], terms: tuple, ctrl: Tensor,
                       values: list[Tensor], w: int,
                       known: list[tuple[Tensor, ...]] | None = None,
                       residuals: list[Tensor] | None = None, tables: Tensor | None = None,
                       ) -> list[tuple]:
        """Per term of ``terms`` (the terms ``group``, or a part of each, read at the same
        times): per-sample whitened residuals ``(..., N, k)`` (``residuals`` where known:
        the trial cost's at this point), the window start and their Jacobians. The span
        derivatives at the current point (``known``, or evaluated once to the highest order
        a term reads), each term's residual Jacobians with respect to
        them and to its nuisance steps, chained through the spans together
        (``_through_spans``: the terms' rows stacked, a lower order's padded with zeros), the
        times' to the time-moving parameters by their rates (a term of its own: a group's
        times move with no estimated parameter)."""
        p, lead = self.p, terms[0]
        vals = [p.term_values(i, values) for i in group]
        shift = lead.time_shift(lead.per_sample(vals[0]))
        times = [self.spans.since_origin(t, shift) for t in lead.times_list()]
        firsts = [self.spans.first(t) for t in times]
        f0, gathered, offs = self._window(ctrl, firsts, w)
        shared = [_distinct_times(t, f, 2) for t, f in zip(times, firsts, strict=True)]
        top = max(term.order for term in terms)
        rated = _order(p, group, vals) > top  # time columns: the next derivative
        if known is None:  # the span derivatives at the current point (and the next)
            with torch.no_grad():
                known = [_point_derivatives(self.spans, ctrl, t, f, s, top + rated)
                         for t, f, s in zip(times, firsts, shared, strict=True)]
        derivs = [torch.stack(d, -2) for d in known]
        ests = [[name for name in v if (i, name) in p.index] for i, v in zip(group, vals,
                                                                            strict=True)]
        rates = [term.time_rates() for term in terms]
        timed = [[name for name in est if name in rt] for est, rt in zip(ests, rates,
                                                                         strict=True)]
        L = len(derivs)
        rows, parts = _row_buffer(terms, top + 1, derivs)  # the closed forms write there
        jac = [self._residual_jacobians(i, term, v, [x for x in est if x not in tm],
                                        [d[..., :term.order + 1, :] for d in derivs],
                                        gathered.shape[:-2], r, o)
               for i, term, v, est, tm, r, o in zip(group, terms, vals, ests, timed,
                                                    _or_none(residuals, len(terms)), parts,
                                                    strict=True)]
        Jd = [_stacked([J[l] for _, J in jac], top + 1, rows) for l in range(L)]
        Jc, Jt = self._through_spans(gathered, offs, times, firsts, Jd, top,
                                     bool(timed[0]) and not rated, shared,
                                     [d[..., 0, :] for d in derivs],
                                     _second([J[0] for _, J in jac]), tables)
        if rated:
            Jt = self._time_columns(times, firsts, Jd, [d[..., 1:, :] for d in derivs])
        N = times[0].shape[-1]
        f0 = f0.expand(*gathered.shape[:-3], N)
        out = []
        for (r, J), est, tm, Jcol, rt in zip(jac, ests, timed, Jc.split(
                [r.shape[-1] for r, _ in jac], -3), rates, strict=True):
            Jn = dict(zip([x for x in est if x not in tm], J[L:], strict=True))
            if Jt is not None:
                for name in tm:  # dr/dt dt/dtheta (a Scalar chart: dtheta/ddelta = 1)
                    rate = torch.as_tensor(rt[name], dtype=Jt.dtype, device=Jt.device)
                    Jn[name] = (Jt * rate.expand(Jt.shape[:-1])[..., None])[..., None]
            out.append((r, f0, Jcol, Jn))
        return out

    def _window(self, ctrl: Tensor, firsts: list[Tensor], w: int,
                ) -> tuple[Tensor, Tensor, list[Tensor]]:
        """The samples' window start ``f0 (..., N)`` (the first of their spans ``firsts``,
        within the curve), the window's points ``(..., N, w, 8)`` (``span_points``) and each
        span's offsets in it ``(..., N, support)``."""
        n, sup = self.spans.n, self.spans.support
        f0 = firsts[0] if len(firsts) == 1 else torch.stack(firsts).amin(0)  # (no copy)
        f0 = torch.minimum(f0, torch.full_like(f0, n - w))
        offs = [(f - f0)[..., None] + torch.arange(sup, device=f.device) for f in firsts]
        return f0, span_points(ctrl, f0, w), offs

    def _residual_jacobians(self, i: int, term, vals: dict[str, Tensor], nuisance: list[str],
                            derivs: list[Tensor], shape: torch.Size, r: Tensor | None = None,
                            out: Tensor | None = None) -> tuple[Tensor, list[Tensor]]:
        """Residuals of ``term`` (term ``i`` or a part) and their Jacobians with respect to
        the span derivatives ``derivs (..., N, order + 1, 8)`` and to the chart steps of its
        ``nuisance`` parameters (the term's closed form, which takes the residuals ``r``
        where known, and writes its rows into ``out`` where given: ``Term._rows_into``; else
        ``sample_jacobians``: one reverse pass over ``k`` copies)."""
        L, kw = len(derivs), {} if out is None else {"out": out}
        closed = term.residual_jacobians([d.unbind(-2) for d in derivs], term.per_sample(vals),
                                         nuisance, r, **kw)
        if closed is not None:
            return closed
        slots = term.slots()

        def residual(lv):
            ps = term.per_sample(vals)
            for name, d in zip(nuisance, lv[L:], strict=True):
                ps[name] = slots[name].chart.retract(ps[name], d)
            return term.residuals([d.unbind(-2) for d in lv[:L]], ps)

        steps = [derivs[0].new_zeros(*shape, self.p.index[(i, name)].dim) for name in nuisance]
        return sample_jacobians(residual, derivs + steps, term.dim)

    def _time_columns(self, times: list[Tensor], firsts: list[Tensor], Jd: list[Tensor],
                      nxt: list[Tensor]) -> Tensor:
        r"""``(..., N, k)``: the residuals' Jacobian with respect to the samples' time shift,
        exactly: span derivative ``o`` moves with ``t`` as derivative ``o + 1`` times the
        local times' rate (:meth:`~torch_dq.fitting._local.SpanEvaluator.time_rate`), so
        :math:`\sum_l \sum_o J_{d,l,o} \cdot d_{l,o+1}\, \dot s_l` over the times lists
        ``l`` (``Jd (..., N, k, order + 1, 8)``, ``nxt (..., N, order + 1, 8)`` the
        derivatives ``1 .. order + 1``)."""
        cols = [torch.einsum("...koc,...oc->...k", J, d) * self.spans.time_rate(t, f)[..., None]
                for t, f, J, d in zip(times, firsts, Jd, nxt, strict=True)]
        return sum(cols[1:], cols[0])

    def _span_derivatives(self, pts: Tensor, off: Tensor, t: Tensor, first: Tensor,
                          order: int) -> tuple[Tensor, ...]:
        """Derivatives at ``t`` of the spans ``first``, whose points are the window points
        ``pts (..., N, w, 8)`` at offsets ``off (..., N, support)``."""
        return self.spans.derivatives(self._select(pts, off), t, first, order)

    def _select(self, pts: Tensor, off: Tensor) -> Tensor:
        """``(..., N, support, 8)``: the span points at offsets ``off (..., N, support)`` of
        the window points ``pts (..., N, w, 8)``."""
        lead = pts.shape[:-3]
        return torch.take_along_dim(pts, off.expand(*lead, *off.shape[-2:])[..., None], dim=-2)

    def _through_spans(self, gathered: Tensor, offs: list[Tensor], times: list[Tensor],
                       firsts: list[Tensor], Jd: list[Tensor], order: int, timed: bool,
                       shared: list, poses: list[Tensor], second: slice | None = None,
                       tables: Tensor | None = None) -> tuple[Tensor, Tensor | None]:
        r"""Chain the residuals' Jacobians ``Jd (..., N, k, order + 1, 8)`` with respect to
        the span derivatives (one per times list) through the spans: ``(..., N, k, w, 6)``
        with respect to the window's steps and, when ``timed``, ``(..., N, k)`` with respect
        to the times (None otherwise: times without gradient take the cheaper path; the
        time columns of orders 0 to 2 come from :meth:`_time_columns`). ``shared``: each
        list's :func:`_distinct_times`; ``poses``: each list's poses ``(..., N, 8)``;
        ``second``: the rows whose second order may be nonzero (:func:`_second`);
        ``tables``: the spans' tables of the closed form, where shared.

        Without the times: the layer's closed form where it has one (:meth:`_closed_form`).
        Else by reverse passes:

        Chunks of ``_CHUNK >> order`` samples, each with its own window points (moved by
        their own steps: the samples are independent), one forward and ``k`` reverse passes
        (row ``j`` of ``Jd`` as the cotangent of pass ``j``): memory bounded by the chunk
        whatever ``N``.
        """
        k, O = Jd[0].shape[-3], 8 * (order + 1)
        one = shared[0] if len(times) == 1 else None
        if one is not None and times[0].numel() >= 2 * O / k * one[0].numel():
            # the whole Jacobian once per distinct time
            return self._through_distinct(gathered, offs[0], firsts[0], Jd[0], order, timed,
                                          poses[0], *one)
        if not timed:
            closed = self._closed_form(gathered, offs, times, firsts, Jd, poses, second,
                                       tables)
            if closed is not None:
                return closed, None
        *shape, N, w, _ = gathered.shape
        Jc = gathered.new_zeros(*shape, N, k, w, 6)
        Jt = gathered.new_zeros(*shape, N, k) if timed else None
        size = max(1, _CHUNK >> order)
        for a in range(0, N, size):
            c = slice(a, a + size)
            with torch.enable_grad():
                dc = gathered.new_zeros(*shape, min(size, N - a), w, 6).requires_grad_()
                dt = gathered.new_zeros(*shape, min(size, N - a)).requires_grad_(timed)
                pts = tangent_step(gathered[..., c, :, :], dc)
                D = [self._span_derivatives(pts, off[..., c, :], t[..., c] + dt, f[..., c],
                                            order)
                     for off, t, f in zip(offs, times, firsts, strict=True)]
                for j in range(k):
                    total = torch.stack([(d * J[..., c, j, o, :]).sum() for Dl, J in
                                         zip(D, Jd, strict=True) for o, d in enumerate(Dl)])
                    grads = torch.autograd.grad(total.sum(), [dc, dt] if timed else [dc],
                                                retain_graph=j < k - 1)
                    Jc[..., c, j, :, :] = grads[0]
                    if Jt is not None:
                        Jt[..., c, j] = grads[1]
        return Jc, Jt

    def _closed_form(self, gathered: Tensor, offs: list[Tensor], times: list[Tensor],
                     firsts: list[Tensor], Jd: list[Tensor], poses: list[Tensor],
                     second: slice | None = None, tables: Tensor | None = None,
                     ) -> Tensor | None:
        """:meth:`_through_spans` by the layer's closed-form vector-Jacobian products
        (:meth:`~torch_dq.fitting._local.SpanEvaluator.vjp`), ``_CHUNK`` samples at a time,
        each times list's span columns added at its offsets in the window; None where the
        layer has none."""
        *shape, N, w, _ = gathered.shape
        k, sup = Jd[0].shape[-3], self.spans.support
        whole = w == sup and len(times) == 1  # the window is the span (offsets 0 .. w - 1)
        if whole and N <= _CHUNK:  # one chunk: the layer's rows as they are (no copy)
            G = self.spans.vjp(gathered, times[0], firsts[0], Jd[0], poses[0], second,
                               tables)
            return None if G is None else G.expand(*shape, N, k, w, 6)
        Jc = gathered.new_zeros(*shape, N, k, w, 6)
        for a in range(0, N, _CHUNK):
            c = slice(a, a + _CHUNK)
            for off, t, f, J, x in zip(offs, times, firsts, Jd, poses, strict=True):
                o = off[..., c, :]
                pts = gathered[..., c, :, :] if whole else self._select(gathered[..., c, :, :], o)
                G = self.spans.vjp(pts, t[..., c], f[..., c], J[..., c, :, :, :],
                                   x[..., c, :], second, tables)
                if G is None:
                    return None
                if whole:
                    Jc[..., c, :, :, :] = G
                else:
                    at = o[..., None, :, None].expand(*G.shape[:-3], k, sup, 6)
                    Jc[..., c, :, :, :].scatter_add_(-2, at, G)
        return Jc

    def _through_distinct(self, gathered: Tensor, off: Tensor, first: Tensor, Jd: Tensor,
                          order: int, timed: bool, pose: Tensor, t: Tensor, inverse: Tensor,
                          pick: Tensor) -> tuple[Tensor, Tensor | None]:
        r""":meth:`_through_spans` for samples that share their times (the corners of one
        frame): the span derivatives' whole Jacobian ``(..., U, order + 1, 8, w, 6)`` at
        the ``U`` distinct times ``t`` (sample ``pick[u]`` at ``t[u]``, sample ``i`` at
        ``t[inverse[i]]``; a time fixes its span), one reverse pass per output component,
        then each sample's rows ``Jd (..., N, k, order + 1, 8)`` times its time's
        Jacobian. Exact, as the per-sample passes; cheaper when ``U (order + 1) 8`` is well
        below ``N k``. Without the times, the whole Jacobian is the layer's closed form
        (:meth:`_closed_form` of the identity's rows) where it has one.
        """
        *shape, N, w, _ = gathered.shape
        k, O = Jd.shape[-3], 8 * (order + 1)
        Dc = None if timed else self._closed_form(
            gathered.index_select(-3, pick), [off[pick]], [t], [first[pick]],
            [torch.eye(O, dtype=Jd.dtype, device=Jd.device).reshape(O, order + 1, 8).expand(
                t.numel(), O, order + 1, 8)],
            [pose.index_select(-2, pick)])
        Dt: Tensor | None = None
        if Dc is None:
            Dc, Dt = self._distinct_passes(gathered, off, first, order, timed, t, pick)
        else:
            Dc = Dc.flatten(-2)
        Jd = Jd.flatten(-2)  # (..., N, k, O)
        Jc = gathered.new_empty(*shape, N, k, w, 6)
        Jt = gathered.new_empty(*shape, N, k) if timed else None
        for a in range(0, N, _CHUNK):
            i, c = inverse[a:a + _CHUNK], slice(a, a + _CHUNK)
            Jc[..., c, :, :, :] = (Jd[..., c, :, :] @ Dc.index_select(-3, i)).unflatten(
                -1, (w, 6))
            if Jt is not None and Dt is not None:
                Jt[..., c, :] = (Jd[..., c, :, :] @ Dt.index_select(-2, i)[..., None])[..., 0]
        return Jc, Jt

    def _distinct_passes(self, gathered: Tensor, off: Tensor, first: Tensor, order: int,
                         timed: bool, t: Tensor, pick: Tensor) -> tuple[Tensor, Tensor]:
        """:meth:`_through_distinct`'s whole Jacobians ``(..., U, O, w 6)`` and ``(..., U,
        O)`` by one reverse pass per output component over copies of the distinct times'
        spans."""
        *shape, _, w, _ = gathered.shape
        O, U = 8 * (order + 1), t.numel()
        size = max(1, _CHUNK >> order)
        Dc = gathered.new_zeros(*shape, U, O, w * 6)
        Dt = gathered.new_zeros(*shape, U, O)
        for a in range(0, U, size):
            s = pick[a:a + size]
            with torch.enable_grad():
                dc = gathered.new_zeros(*shape, s.numel(), w, 6).requires_grad_()
                dt = gathered.new_zeros(*shape, s.numel()).requires_grad_(timed)
                pts = tangent_step(gathered.index_select(-3, s), dc)
                D = torch.stack(self._span_derivatives(pts, off[s], t[a:a + size] + dt,
                                                       first[s], order), -2).flatten(-2)
                for o in range(O):
                    grads = torch.autograd.grad(D[..., o].sum(), [dc, dt] if timed else [dc],
                                                retain_graph=o < O - 1)
                    Dc[..., a:a + size, o, :] = grads[0].flatten(-2)
                    if timed:
                        Dt[..., a:a + size, o] = grads[1]
        return Dc, Dt


def _or_none(xs: list[Tensor] | None, n: int) -> list[Tensor | None]:
    """``xs``, or ``n`` times None."""
    return [None] * n if xs is None else list(xs)


def _weights(term, r: Tensor, robust: bool = True) -> Tensor:
    """Robust weights ``(..., N)`` of ``term``'s residuals ``r (..., N, k)`` (ones where not
    ``robust``), masked samples' zero."""
    wt = _robust.weight(term.robust if robust else None, r.norm(dim=-1), term.robust_k)
    return wt * term.mask.to(wt.dtype)


def _row_buffer(terms: tuple, O: int, derivs: list[Tensor],
                ) -> tuple[Tensor | None, list[Tensor | None]]:
    """An empty ``(..., N, sum k_j, O, 8)`` for :func:`_stacked` (component-major, the
    samples' shape that of ``derivs[0] (..., N, o, 8)``) and per term its rows there, where
    several terms read one times list and one writes its rows into it (``Term._rows_into``:
    no copy); else None and Nones."""
    if len(derivs) > 1 or len(terms) == 1 or not any(term._rows_into for term in terms):
        return None, [None] * len(terms)
    rows = derivs[0].new_empty(sum(term.dim for term in terms), O, 8,
                               *derivs[0].shape[:-2]).movedim((0, 1, 2), (-3, -2, -1))
    at = rows.split([term.dim for term in terms], -3)
    return rows, [x if term._rows_into else None for x, term in zip(at, terms, strict=True)]


def _stacked(Js: list[Tensor], O: int, rows: Tensor | None = None) -> Tensor:
    """The rows ``Js`` (each ``(..., N, k_j, o_j, 8)``, ``o_j <= O``) of a group's terms as one
    ``(..., N, sum k_j, O, 8)``, the orders a term does not read zero; component-major in
    memory (``(sum k_j, O, 8, ..., N)`` permuted: the layout the span's vector-Jacobian
    products read, and the closed-form rows' own, so each copy here is a row copy). In
    ``rows`` (:func:`_row_buffer`) where given: the rows a term wrote there are not copied."""
    if len(Js) == 1 and Js[0].shape[-2] == O:
        return Js[0]
    lead = torch.broadcast_shapes(*(J.shape[:-3] for J in Js))
    out = rows if rows is not None and rows.shape[:-3] == lead else Js[0].new_empty(
        sum(J.shape[-3] for J in Js), O, 8, *lead).movedim((0, 1, 2), (-3, -2, -1))
    a = 0
    for J in Js:
        at = out[..., a:a + J.shape[-3], :J.shape[-2], :]
        if (J.data_ptr(), J.shape, J.stride()) != (at.data_ptr(), at.shape, at.stride()):
            at.copy_(J)  # not written in place by the term
        out[..., a:a + J.shape[-3], J.shape[-2]:, :] = 0.0
        a += J.shape[-3]
    return out


def _second(Js: list[Tensor]) -> slice | None:
    """The rows of :func:`_stacked` ``Js`` whose second order may be nonzero: those of the
    terms that read it (``o_j > 2``), when consecutive (else None: all)."""
    reads = [J.shape[-2] > 2 for J in Js for _ in range(J.shape[-3])]
    if True not in reads:
        return None
    a, b = reads.index(True), len(reads) - reads[::-1].index(True)
    return slice(a, b) if all(reads[a:b]) else None


def _point_derivatives(spans, ctrl: Tensor, t: Tensor, first: Tensor, shared, order: int,
                       ) -> tuple[Tensor, ...]:
    """Span derivatives ``order + 1`` x ``(..., N, 8)`` at the samples' times ``t``, spans
    ``first (..., N)``, from the shared control points ``ctrl``
    (:meth:`~torch_dq.fitting._local.SpanEvaluator.shared`): once per distinct time,
    gathered, where ``shared`` (:func:`_distinct_times`) holds them; else at every sample.
    The one evaluation of the costs and of the linearisation points."""
    if shared is None:
        return spans.shared(ctrl, t, first, order)
    u, inverse, pick = shared
    return tuple(d.index_select(-2, inverse) for d in spans.shared(ctrl, u, first[pick], order))


def _distinct_times(t: Tensor, first: Tensor, ratio: float,
                    ) -> tuple[Tensor, Tensor, Tensor] | None:
    """The distinct times ``u (U,)`` of samples ``t (N,)`` (their spans ``first (N,)``),
    ``inverse (N,)`` (``t = u[inverse]``) and one sample ``pick (U,)`` at each, when the
    batch shares the times and ``N >= ratio U`` (evaluating per distinct time pays); else
    None."""
    if t.dim() != 1 or first.dim() != 1:
        return None
    u, inverse, pick = distinct(t)
    return None if t.numel() < ratio * u.numel() else (u, inverse, pick)

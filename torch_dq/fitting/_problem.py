r"""The least-squares problem of :func:`~torch_dq.fitting.estimate`: parameters, costs, and
the Gauss-Newton system in block form.

Unknowns: a body-frame step ``delta_k`` (6) per control point, ``c_k <- c_k exp(delta_k)``,
and the chart steps of the ``m`` estimated nuisance parameters.
With ``J`` the whitened Jacobian and ``W`` the robust
weights, the Gauss-Newton matrix has three blocks: the control-point band
``A_cc (..., n, w, 6, 6)`` (a sample touches ``w`` consecutive control points), the coupling
``A_cn (..., n, 6, m)`` and ``A_nn (..., m, m)``; the gradient ``g = J^T W r``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import dualquat
from . import _robust
from ._local import SpanEvaluator, sample_jacobians, tangent_step
from ._nuisance import Free, chart_distance, retract
from ._terms import Term

__all__ = ["Param", "Problem", "System"]

_CHUNK = 1 << 15  # samples per chunk of reverse passes through the spans (order 0)


@dataclass
class Param:
    """One estimated nuisance parameter: its :class:`Free`, kind, chart columns, start."""

    free: Free
    kind: str
    dim: int
    offset: int  # first column in the nuisance vector
    start: Tensor
    bound: float  # |value| bound (time offsets), inf otherwise
    low: float = -math.inf  # lower bound of a scalar parameter (-bound for time offsets)


@dataclass
class System:
    """Gauss-Newton system (flattened batch ``Bf``): ``band (Bf, n, w, 6, 6)``, ``cn (Bf,
    n, 6, m)``, ``nn (Bf, m, m)``, gradients ``gc (Bf, n, 6)``, ``gn (Bf, m)``; per term
    whitened residuals and robust weights."""

    band: Tensor
    cn: Tensor
    nn: Tensor
    gc: Tensor
    gn: Tensor
    residuals: list[Tensor]
    weights: list[Tensor]


class Problem:
    """Terms, their estimated parameters and the trajectory's span structure.

    Args:
        trajectory: the curve layer.
        terms: the measurement terms.
        batch: the control points' batch shape.
    """

    def __init__(self, trajectory, terms: list[Term], batch: torch.Size) -> None:
        self.trajectory, self.terms, self.batch = trajectory, terms, batch
        self.spans = SpanEvaluator(trajectory)
        self.params: list[Param] = []
        self.index: dict[tuple[int, str], Param] = {}
        self.m = 0

    def add(self, term_i: int, name: str, free: Free, kind: str, dim: int, start: Tensor,
            bound: float, low: float | None = None) -> None:
        """Register the estimated parameter ``name`` of term ``term_i`` (shared frees once),
        a scalar one within ``[low, bound]`` (``low`` default ``-bound``)."""
        low = -bound if low is None else low
        for p in self.params:
            if p.free is free:
                p.bound, p.low = min(p.bound, bound), max(p.low, low)
                self.index[(term_i, name)] = p
                return
        p = Param(free, kind, dim, self.m, start, bound, low)
        self.params.append(p)
        self.index[(term_i, name)] = p
        self.m += dim

    # -- values
    def term_values(self, i: int, values: list[Tensor]) -> dict[str, Tensor]:
        """Nuisance values of term ``i`` (estimated ones from ``values``, by param)."""
        term = self.terms[i]
        like = torch.empty((), dtype=torch.float64, device=self.spans.device)
        out = {}
        for name, slot in term.slots().items():
            p = self.index.get((i, name))
            out[name] = values[self.params.index(p)] if p is not None else slot.value(like)
        return out

    def retract(self, ctrl: Tensor, values: list[Tensor], dc: Tensor, dn: Tensor,
                ) -> tuple[Tensor, list[Tensor]]:
        """Control points and values moved by ``dc (..., n, 6)`` and ``dn (..., m)``."""
        new = dualquat.mul(ctrl, dualquat.exp(dc))
        moved = []
        for p, v in zip(self.params, values, strict=True):
            x = retract(p.kind, v, dn[..., p.offset:p.offset + p.dim])
            moved.append(x.clamp(p.low, p.bound) if p.kind == "offset" else x)
        return new, moved

    # -- costs
    def data_cost(self, ctrl: Tensor, values: list[Tensor]) -> list[Tensor]:
        """Robust cost ``(...)`` of each term (the layer's public path)."""
        out = []
        for i, term in enumerate(self.terms):
            r = term.evaluate(self.trajectory, ctrl, self.term_values(i, values))
            out.append(_robust.rho(term.robust, r.norm(dim=-1), term.robust_k).sum(-1)
                       .expand(self.batch))
        return out

    def prior_cost(self, values: list[Tensor]) -> Tensor:
        """Gaussian priors of the :class:`Free` parameters that have ``prior_std``."""
        total = torch.zeros(self.batch, dtype=torch.float64, device=self.spans.device)
        for p, v in zip(self.params, values, strict=True):
            if p.free.prior_std is not None:
                std = torch.as_tensor(p.free.prior_std, dtype=v.dtype, device=v.device)
                d = chart_distance(p.kind, p.start, v) / std
                total = total + (d * d).sum(-1).expand(self.batch)
        return total

    def prior_information(self) -> Tensor:
        """``(m,)`` diagonal Gauss-Newton information of the Free priors (0 where none)."""
        info = torch.zeros(self.m, dtype=torch.float64, device=self.spans.device)
        for p in self.params:
            if p.free.prior_std is not None:
                std = torch.as_tensor(p.free.prior_std, dtype=torch.float64)
                info[p.offset:p.offset + p.dim] = (1.0 / std**2).expand(p.dim)
        return info

    # -- linearization
    def width(self, values: list[Tensor]) -> int:
        """Control points a sample's residual may touch (the band width ``w``)."""
        w = self.spans.support
        for i, term in enumerate(self.terms):
            ts = term.times_list()
            if len(ts) > 1:
                vals = self.term_values(i, values)
                dt = term.time_shift(term.per_sample(vals, {k: s.kind for k, s in
                                                            term.slots().items()}))
                f = [self.spans.first(t + dt) for t in ts]
                w = max(w, int((f[1] - f[0]).abs().max()) + self.spans.support)
        return min(w, self.spans.n)

    def system(self, ctrl: Tensor, values: list[Tensor], w: int) -> System:
        """Gauss-Newton system at ``(ctrl, values)`` with the robust weights there."""
        Bf = max(self.batch.numel(), 1)
        n, m, c = self.spans.n, self.m, 6 * w
        G = Bf * (n + w)  # windows: batch row b, first control point f at b (n + w) + f
        normal = ctrl.new_zeros(G, c + m + 1, c + m + 1)
        residuals, weights = [], []
        for i in range(len(self.terms)):
            r, wt, f0, Jc, Jn = self._term_jacobians(i, ctrl, values, w)
            residuals.append(r)
            weights.append(wt)
            N, k = r.shape[-2:]
            sw = wt.expand(*self.batch, N).reshape(Bf, N, 1, 1).sqrt()
            cols = [Jc.expand(*self.batch, N, k, w, 6).reshape(Bf, N, k, c)]
            Jn_all = ctrl.new_zeros(Bf, N, k, m)
            for name, J in Jn.items():
                p = self.index[(i, name)]
                Jn_all[..., p.offset:p.offset + p.dim] += J.expand(
                    *self.batch, N, k, p.dim).reshape(Bf, N, k, p.dim)
            cols += [Jn_all, r.expand(*self.batch, N, k).reshape(Bf, N, k, 1)]
            Y = torch.cat(cols, dim=-1) * sw  # whitened, weighted rows [J_c | J_n | r]
            normal += _window_normal(self._windows(f0, w).reshape(-1), Y.reshape(Bf * N, k, -1),
                                     G)
        normal = normal.reshape(Bf, n + w, c + m + 1, c + m + 1)
        band = ctrl.new_zeros(Bf, n + w, w, 6, 6)
        for a in range(w):  # window f's block (a, a + d) is the band's (f + a, d)
            for d in range(w - a):
                band[:, a:, d] += normal[:, :n + w - a, 6 * a:6 * a + 6,
                                         6 * (a + d):6 * (a + d) + 6]
        gc = ctrl.new_zeros(Bf, n + w, 6)
        cn = ctrl.new_zeros(Bf, n + w, 6, m)
        for a in range(w):  # window f's rows a go to control point f + a
            gc[:, a:] += normal[:, :n + w - a, 6 * a:6 * a + 6, -1]
            cn[:, a:] += normal[:, :n + w - a, 6 * a:6 * a + 6, c:c + m]
        nn = normal[:, :, c:c + m, c:c + m].sum(1)
        gn = normal[:, :, c:c + m, -1].sum(1)
        return System(band[:, :n], cn[:, :n], nn, gc[:, :n], gn, residuals, weights)

    def _windows(self, f0: Tensor, w: int) -> Tensor:
        """``(Bf, N)`` window ids ``b (n + w) + f0`` of the samples' window starts ``f0``."""
        Bf, N = max(self.batch.numel(), 1), f0.shape[-1]
        return (f0.expand(*self.batch, N).reshape(Bf, N)
                + (torch.arange(Bf, device=f0.device) * (self.spans.n + w))[:, None])

    def _term_jacobians(self, i: int, ctrl: Tensor, values: list[Tensor], w: int):
        """Whitened residuals, robust weights, window start and Jacobians of term ``i``."""
        term = self.terms[i]
        r, f0, Jc, Jn = self._chained(i, ctrl, values, w)
        wt = _robust.weight(term.robust, r.norm(dim=-1), term.robust_k)
        wt = wt * term.mask.to(wt.dtype)
        return r, wt, f0, Jc, Jn

    def _chained(self, i: int, ctrl: Tensor, values: list[Tensor], w: int):
        """Per-sample outputs of term ``i``, its window start and the outputs' Jacobians:
        the span derivatives at the current point, the outputs' Jacobians with respect to
        them and to the nuisance steps, chained through the spans (``_through_spans``).
        The outputs are the whitened residuals ``(..., N, k)``."""
        term = self.terms[i]
        vals = self.term_values(i, values)
        kinds = {k: s.kind for k, s in term.slots().items()}
        shift = term.time_shift(term.per_sample(vals, kinds))
        times = [t + shift for t in term.times_list()]
        firsts = [self.spans.first(t) for t in times]
        f0 = torch.stack(firsts).amin(0)
        n, sup = self.spans.n, self.spans.support
        f0 = torch.minimum(f0, torch.full_like(f0, n - w))
        window = (f0[..., None] + torch.arange(w, device=f0.device)).clamp(max=n - 1)
        N = times[0].shape[-1]
        shape = torch.broadcast_shapes(self.batch, f0.shape[:-1])
        gathered = ctrl.expand(*shape, n, 8).gather(
            -2, window.expand(*shape, N, w).reshape(*shape, N * w, 1).expand(
                *shape, N * w, 8)).reshape(*shape, N, w, 8)
        est = [name for name in vals if (i, name) in self.index]
        timed = [name for name in est if name in term.time_params]  # move the times
        nuisance = [name for name in est if name not in timed]  # read by the residual
        offs = [(f - f0)[..., None] + torch.arange(sup, device=f.device) for f in firsts]
        with torch.no_grad():  # the span derivatives at the current point
            derivs = [torch.stack(self._span_derivatives(gathered, off, t + shift, f,
                                                         term.order), -2)
                      for off, t, f in zip(offs, term.times_list(), firsts, strict=True)]
        L = len(derivs)

        def residual(lv):
            p = term.per_sample(vals, kinds)
            for name, d in zip(nuisance, lv[L:], strict=True):
                p[name] = retract(kinds[name], p[name], d)
            return term.residuals([d.unbind(-2) for d in lv[:L]], p)

        r, J = sample_jacobians(residual, derivs + [
            ctrl.new_zeros(*shape, N, self.index[(i, name)].dim) for name in nuisance],
            term.dim)
        Jn = dict(zip(nuisance, J[L:], strict=True))
        Jc, Jt = self._through_spans(gathered, offs, [t + shift for t in term.times_list()],
                                     firsts, J[:L], term.order, bool(timed))
        if Jt is not None:
            for name, ds in self._time_jacobians(i, vals, kinds, timed, (*shape, N)).items():
                Jn[name] = Jt[..., None] * ds[..., None, :]  # dr/dt dt/dtheta
        return r, f0.expand(*shape, N), Jc, Jn

    def _time_jacobians(self, i: int, vals: dict[str, Tensor], kinds: dict[str, str],
                        names: list[str], shape: tuple[int, ...]) -> dict[str, Tensor]:
        """``d t'_i / d delta`` ``(..., N, dim)`` of term ``i``'s time-moving parameters
        ``names`` (their chart steps), by autograd of :meth:`Term.time_shift` (each sample's
        shift depends on its own copy of the steps)."""
        term = self.terms[i]
        with torch.enable_grad():
            steps = [vals[k].new_zeros(*shape, self.index[(i, k)].dim).requires_grad_()
                     for k in names]
            p = term.per_sample(vals, kinds)
            for k, d in zip(names, steps, strict=True):
                p[k] = retract(kinds[k], p[k], d)
            grads = torch.autograd.grad(term.time_shift(p).expand(shape).sum(), steps,
                                        allow_unused=True)
        return {k: torch.zeros_like(d) if g is None else g
                for k, d, g in zip(names, steps, grads, strict=True)}

    def _span_derivatives(self, pts: Tensor, off: Tensor, t: Tensor, first: Tensor,
                          order: int) -> tuple[Tensor, ...]:
        """Derivatives at ``t`` of the spans ``first``, whose points are the window points
        ``pts (..., N, w, 8)`` at offsets ``off (..., N, support)``."""
        sup = self.spans.support
        lead = pts.shape[:-3]
        sel = torch.take_along_dim(pts, off.expand(*lead, off.shape[-2], sup)[..., None], dim=-2)
        return self.spans.derivatives(sel, t, first, order)

    def _through_spans(self, gathered: Tensor, offs: list[Tensor], times: list[Tensor],
                       firsts: list[Tensor], Jd: list[Tensor], order: int, timed: bool,
                       ) -> tuple[Tensor, Tensor | None]:
        r"""Chain the residuals' Jacobians ``Jd (..., N, k, order + 1, 8)`` with respect to
        the span derivatives (one per times list) through the spans: ``(..., N, k, w, 6)``
        with respect to the window's steps and, when ``timed``, ``(..., N, k)`` with respect
        to the times (None otherwise: times without gradient take the cheaper path).

        Chunks of ``_CHUNK >> order`` samples, each with its own window points (moved by
        their own steps: the samples are independent), one forward and ``k`` reverse passes
        (row ``j`` of ``Jd`` as the cotangent of pass ``j``): memory bounded by the chunk
        whatever ``N``.
        """
        *shape, N, w, _ = gathered.shape
        k = Jd[0].shape[-3]
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


def _window_normal(keys: Tensor, Y: Tensor, G: int) -> Tensor:
    r"""Per window :math:`\sum_i Y_i^T Y_i` ``(G, q, q)`` of the samples' rows ``Y (S, k,
    q)`` with window ``keys (S,)`` (in ``0 .. G - 1``), by batched matrix products.

    The samples of a window are laid out on pages of ``P`` samples (``P`` the mean count
    per used window: at most about twice as many pages as used windows, the padding at
    most ``S``), one product per page, the pages summed into their windows.
    """
    S, k, q = Y.shape
    if S == 0:
        return Y.new_zeros(G, q, q)
    order = torch.argsort(keys, stable=True)
    keys = keys[order]
    counts = torch.bincount(keys, minlength=G)
    P = -(-S // int((counts > 0).sum()))
    pos = torch.arange(S, device=keys.device) - (torch.cumsum(counts, 0) - counts)[keys]
    pages = -(-counts // P)
    first_page = torch.cumsum(pages, 0) - pages
    X = Y.new_zeros(int(pages.sum()) * P, k, q)
    X[first_page[keys] * P + pos] = Y[order]  # page first_page + pos // P, slot pos % P
    X = X.reshape(-1, P * k, q)
    owner = torch.repeat_interleave(torch.arange(G, device=keys.device), pages)
    return Y.new_zeros(G, q, q).index_add_(0, owner, X.mT @ X)

r"""The objective of :func:`~torch_dq.fitting.estimate`: the terms, their estimated
parameters, the robust costs and the Gaussian priors.

Unknowns: a body-frame step ``delta_k`` (6) per control point, ``c_k <- c_k exp(delta_k)``,
and the chart steps of the ``m`` estimated nuisance parameters (their charts:
:mod:`torch_dq.fitting._charts`). The costs and the Gauss-Newton system
(:mod:`torch_dq.fitting._linearize`) evaluate the terms by one path, through the curve's
spans, once per group of terms read at the same times (:meth:`Problem.groups`: an IMU's
gyroscope and accelerometer). :class:`Summary` is what an
:class:`~torch_dq.fitting.Estimate` reads of a solved problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .. import dualquat
from . import _linearize, _robust
from ._charts import Chart, Scalar
from ._linearize import Linearization, Memo, System
from ._local import SpanEvaluator
from ._nuisance import Free
from ._terms import Term

__all__ = ["Param", "Problem", "Summary"]


@dataclass(eq=False)
class Param:
    """One estimated nuisance parameter: its :class:`Free`, chart (a shared time parameter's
    bounds the intersection of its terms'), first column in the nuisance vector, start, and
    the ``(term, name)`` pairs that use it."""

    free: Free
    chart: Chart
    offset: int
    start: Tensor
    uses: list[tuple[Term, str]]

    @property
    def dim(self) -> int:
        return self.chart.dim


@dataclass(frozen=True)
class Summary:
    """A solved problem as :class:`~torch_dq.fitting.Estimate` reads it.

    Attributes:
        terms: the terms.
        batch: the control points' batch shape.
        n, m: control points, nuisance chart coordinates.
        params: the estimated parameters (:class:`Param`), in column order.
        prior_information: ``(m,)`` diagonal information of the Free priors.
        spans: the curve's span evaluation (``first``, ``derivatives``, ``support``).
        trajectory: the curve layer (its domain check).
        system: the data-only Gauss-Newton system at the solution.
        problem: the ``Problem`` itself (its systems at nearby points: the exact
            Hessian's products of ``torch_dq.fitting._observed``).
        counted: per term ``(..., N)`` bool, the samples that ``chi2`` and ``dof`` count
            (``Term.solved``: the unmasked ones, a reprojection's with an image).
    """

    terms: list[Term]
    batch: torch.Size
    n: int
    m: int
    params: list[Param]
    prior_information: Tensor
    spans: SpanEvaluator
    trajectory: object
    system: System
    problem: Problem
    counted: list[Tensor]


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
        self.linearization = Linearization(self)
        self.params: list[Param] = []
        self.index: dict[tuple[int, str], Param] = {}
        self.m = 0
        self._groups: list[tuple[int, ...]] | None = None

    def add(self, term_i: int, name: str, free: Free, chart: Chart, start: Tensor) -> None:
        """Register the estimated parameter ``name`` of term ``term_i`` (shared frees once,
        a :class:`~torch_dq.fitting._charts.Scalar` within every term's bounds)."""
        use = (self.terms[term_i], name)
        for p in self.params:
            if p.free is free:
                if isinstance(p.chart, Scalar) and isinstance(chart, Scalar):
                    p.chart = p.chart.bounded(chart.low, chart.high)
                p.uses.append(use)
                self.index[(term_i, name)] = p
                return
        p = Param(free, chart, self.m, start, [use])
        self.params.append(p)
        self.index[(term_i, name)] = p
        self.m += chart.dim

    def summary(self, system: System, counted: list[Tensor]) -> Summary:
        """The solved problem for :class:`~torch_dq.fitting.Estimate` (``counted``: per term,
        the samples its ``chi2`` counts)."""
        return Summary(self.terms, self.batch, self.spans.n, self.m, list(self.params),
                       self.prior_information(), self.spans, self.trajectory, system, self,
                       counted)

    def groups(self, values: list[Tensor]) -> list[tuple[int, ...]]:
        """The terms by their span evaluation, in order of their first term: terms read at
        identical times (equal moved times ``t + shift``, ``_timing``) that no estimated
        parameter moves (:meth:`~torch_dq.fitting.Term.time_rates`) and that are cut into
        parts alike share one evaluation of the spans' derivatives and one chain through
        them (:mod:`torch_dq.fitting._linearize`); any other term is a group of its own.
        Decided at the first call, once the estimated parameters are registered (the shifts
        of such terms do not depend on ``values``)."""
        if self._groups is None:
            out: list[tuple[list[int], tuple[list[Tensor], bool] | None]] = []
            for i in range(len(self.terms)):
                key = self._timing(i, values)
                g = next((g for g, k in out if key is not None and k is not None
                          and _same_timing(k, key)), None)
                if g is None:
                    out.append(([i], key))
                else:
                    g.append(i)
            self._groups = [tuple(g) for g, _ in out]
        return self._groups

    def _timing(self, i: int, values: list[Tensor]) -> tuple[list[Tensor], bool] | None:
        """Term ``i``'s moved times and whether it can be cut into parts, or None where an
        estimated parameter moves its times (its span evaluation is its own)."""
        term = self.terms[i]
        if any((i, name) in self.index for name in term.time_rates()):
            return None
        shift = term.time_shift(term.per_sample(self.term_values(i, values)))
        return [t + shift for t in term.times_list()], term.N < 2 or len(
            term.parts(term.N - 1)) > 1

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
        return dualquat.mul(ctrl, dualquat.exp(dc)), self.moved(values, dn)

    def moved(self, values: list[Tensor], dn: Tensor) -> list[Tensor]:
        """The nuisance ``values`` moved by ``dn (..., m)`` in their charts."""
        return [p.chart.retract(v, dn[..., p.offset:p.offset + p.dim])
                for p, v in zip(self.params, values, strict=True)]

    # -- costs
    def data_cost(self, ctrl: Tensor, values: list[Tensor], memo: Memo | None = None,
                  ) -> list[Tensor]:
        """Robust cost ``(...)`` of each term (through the spans, as the Jacobians: a group's
        span derivatives once, :meth:`groups`; kept in ``memo`` for :meth:`system` where
        given)."""
        out: list[Tensor] = [torch.empty(0)] * len(self.terms)
        for group in self.groups(values):
            for i, r in zip(group, _linearize.group_residuals(self, group, ctrl, values, memo),
                            strict=True):
                term = self.terms[i]
                out[i] = _robust.rho(term.robust, r.norm(dim=-1), term.robust_k).sum(-1).expand(
                    self.batch)
        return out

    def prior_cost(self, values: list[Tensor]) -> Tensor:
        """Gaussian priors of the :class:`Free` parameters that have ``prior_std``."""
        total = torch.zeros(self.batch, dtype=torch.float64, device=self.spans.device)
        for p, v in zip(self.params, values, strict=True):
            if p.free.prior_std is not None:
                std = torch.as_tensor(p.free.prior_std, dtype=v.dtype, device=v.device)
                d = p.chart.local(p.start, v) / std
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

    # -- linearisation (torch_dq.fitting._linearize)
    def width(self, values: list[Tensor]) -> int:
        """Control points a sample's residual may touch (the band width ``w``)."""
        return _linearize.width(self, values)

    def system(self, ctrl: Tensor, values: list[Tensor], w: int, memo: Memo | None = None,
               robust: bool = True) -> System:
        """Gauss-Newton system at ``(ctrl, values)`` with the robust weights there (unit
        weights where not ``robust``; the span derivatives from ``memo`` where
        :meth:`data_cost` kept them at this point)."""
        return self.linearization.system(ctrl, values, w, memo, robust)


def _same_timing(a: tuple[list[Tensor], bool], b: tuple[list[Tensor], bool]) -> bool:
    """Whether two terms' ``Problem._timing`` are identical: as many moved times lists, each
    of equal shape, dtype, device and values, and the same splitting."""
    return a[1] == b[1] and len(a[0]) == len(b[0]) and all(
        x.shape == y.shape and x.dtype == y.dtype and x.device == y.device and torch.equal(x, y)
        for x, y in zip(a[0], b[0], strict=True))

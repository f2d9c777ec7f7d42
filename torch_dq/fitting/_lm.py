r"""The Levenberg-Marquardt loop of :func:`~torch_dq.fitting.estimate`.

Each iteration linearises every term exactly (:mod:`torch_dq.fitting._linearize`), weights
the samples by the robust kernels at the current residuals (iteratively reweighted least
squares), and tries damped steps (:mod:`torch_dq.fitting._solver`) until each batch element
accepts one that lowers its objective (data cost, the pulls of ``torch_dq.fitting._prior``
and the Free priors) or gives up. Convergence: the scaled gradient test of
:func:`~torch_dq.fitting.estimate`'s ``tol``. The loop knows the problem through
:class:`~torch_dq.fitting._problem.Problem`'s objective (``data_cost``, ``prior_cost``,
``retract``, ``system``) and the step through :class:`~torch_dq.fitting._solver.DampedStep`.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import torch
from torch import Tensor

from .. import _cumulative_lie, dualquat
from . import _prior
from ._banded import BandedCholesky
from ._charts import Scalar
from ._linearize import Memo, System
from ._problem import Problem
from ._solver import DampedStep, Marquardt, SchurSolver

__all__ = ["History", "LevenbergMarquardt", "Point"]

_MAX_REJECTIONS = 13  # damping increases before a batch element stops: back towards the
# last accepted damping, then x10 each from Marquardt.START at least, to 1e4-1e8 (8 from
# 1e-12 ended at 1e-3, short of the damping that lowered TUM fr1_xyz's objective: "no damped
# step lowers" 46 std off)
_NONFINITE = "non-finite cost at the start"
_EXACT = 1e-20  # per residual component: a cost below this is exact data (the test's floor)
_ROUNDOFF = 1e-14  # per residual component: a cost at float64 roundoff (whitened residuals of
# sigma 1e-3 round to ~1e-13 on unit-scale data): converged where no damped step lowers it
# or where its decrease is no longer the quadratic model's (LevenbergMarquardt.iteration)
_LEFT_OUT = 1e6  # the pulls' stiffening in the scaled gradient test when they are re-anchored
_BOUND_SLOW = 1e-3  # a step lowering the objective by at most this much relatively, a clock
# offset held on its bound (descent outwards): two in a row stop it, the data put it further
# (a truth 0.05 s past the bound crept 50 steps at 1e-3 to 1e-5 a step, unconverged)
_LOOSE = 100.0  # the second regularisation of the scaled gradient test (times REGULARISE)


@dataclass
class Point:
    """A point of the iteration: control points ``(..., n, 8)``, nuisance values, the
    objective and the data cost ``(...)`` there, and the span derivatives its cost evaluated
    (``memo``, for its Gauss-Newton system; empty once that is built) with the observations
    predicted there (``memo.seen``, kept)."""

    ctrl: Tensor
    values: list[Tensor]
    objective: Tensor
    data: Tensor
    memo: Memo = field(default_factory=Memo, repr=False)

    def where(self, sel: Tensor, other: Point) -> Point:
        """``other`` where ``sel (...)`` holds (``other`` itself, its memo kept, where it
        holds everywhere), this point elsewhere."""
        if bool(sel.all()):
            return other

        def pick(a: Tensor, b: Tensor) -> Tensor:
            event = (1,) * (a.dim() - sel.dim())
            return torch.where(sel.reshape(torch.Size((*sel.shape, *event))), a, b)

        memo = Memo()
        memo.seen = {i: pick(s, self.memo.seen[i]) for i, s in other.memo.seen.items()}
        return Point(pick(other.ctrl, self.ctrl),
                     [pick(a, b) for a, b in zip(other.values, self.values, strict=True)],
                     pick(other.objective, self.objective), pick(other.data, self.data), memo)

    def keeps(self, other: Point, batch: torch.Size) -> Tensor:
        """``(Bf,)`` bool: whether every observation predicted here is predicted at
        ``other`` (``Memo.seen``): a step that hid some (a reprojection turned behind the
        camera has a zero residual) would lower the cost by the residuals it hid."""
        kept = torch.ones(batch, dtype=torch.bool, device=self.objective.device)
        for i, s in self.memo.seen.items():
            kept = kept & ~(s & ~other.memo.seen[i]).any(-1)
        return kept.reshape(-1)


@dataclass
class History:
    """What the loop did: ``loss`` and ``objective`` ``(steps + 1, ...)``, ``steps`` run,
    ``reason`` (joined per batch element), ``converged (...)``, the data ``system`` at the
    last point, its band ``width``, whether every direction of that system carries
    information (``informed``: its band plus the
    pulls certified positive definite with room, nothing pulled) and the last Newton
    decrement ``(Bf,)`` (inf where none was taken)."""

    loss: Tensor
    objective: Tensor
    steps: int
    reason: str
    converged: Tensor
    system: System
    width: int
    informed: bool
    decrement: Tensor


class LevenbergMarquardt:
    """The iteration state: current point, damping, per-element stopping.

    Args:
        problem: the objective.
        ctrl, values: the start.
        prior: the numerical prior's weight (:mod:`torch_dq.fitting._prior`).
        solver: the linear solver (:class:`~torch_dq.fitting._solver.SchurSolver`).
    """

    def __init__(self, problem: Problem, ctrl: Tensor, values: list[Tensor], prior: float,
                 solver: SchurSolver | None = None) -> None:
        self.p, self.start, self.solver = problem, ctrl, solver
        self.anchor, self.prior = values, prior
        self.batch, self.Bf, self.n = problem.batch, max(problem.batch.numel(), 1), problem.spans.n
        self.w = problem.width(values)
        memo = Memo()
        data = torch.stack(problem.data_cost(ctrl, values, memo)).sum(0)
        self.system = problem.system(ctrl, values, self.w, memo)
        self._null_of: System | None = None  # the system the null space was found for
        self._gradient: tuple = (None, None)  # ((point, system), gradient) at the last call
        self._pull_at: tuple = (None, None)  # (point, its _step_pull)
        self._factor: BandedCholesky | None = None  # the undamped band's, for _decrement
        self._pulls(prior)
        self.count = torch.stack([(t.mask.sum(-1) * t.dim).expand(self.batch).to(torch.float64)
                                  for t in problem.terms]).sum(0).reshape(self.Bf)
        self.point = Point(ctrl, values, data + self._pull(ctrl, values), data, memo)
        self.damping = Marquardt(self.Bf, ctrl)
        self.timed, self.span = _time_columns(problem)
        like = self.damping.lam
        self.stalled = torch.zeros_like(like, dtype=torch.bool)
        self.slow = torch.zeros_like(like, dtype=torch.bool)  # last step below _BOUND_SLOW
        self.on_bound = torch.zeros_like(like, dtype=torch.long)  # slow steps held there
        self.decrement = torch.full_like(like, torch.inf)
        flat = self.point.objective.reshape(self.Bf)
        self.active = torch.isfinite(flat) & (flat > 0)
        self.converged = flat == 0
        self.reasons = ["" if a else "the cost is zero" if float(o) == 0 else _NONFINITE
                        for o, a in zip(flat, self.active.tolist(), strict=True)]

    def _pulls(self, prior: float) -> None:
        """The pulls at the start and the combinations no sample determines. Which control
        point combinations the data determine is judged without the robust weights: from a
        far start a robust kernel weighs every sample of its term down (Cauchy: 2e-4 at 230
        sigmas), and where that term alone sees the control points (poses at the ends of an
        IMU record) they fell below the floor and were pulled, held at the start for good
        (their residuals, and weights, never recovered)."""
        s, p = self.system, self.p
        weighed = prior > 0 and any(bool((w < t.mask).any()) for t, w in zip(
            p.terms, s.weights, strict=True))  # some robust weight below 1
        data = p.system(self.start, self.anchor, self.w, robust=False) if weighed else s
        # relative thresholds where an IMU term reads the curve's derivatives, nuisance or
        # not: its information sets the typical level, and the poses that alone see the ends
        # of its record were judged against it (pulled to a far start: 190 sigmas off)
        relative = bool(p.params) or any(t.order >= 1 for t in p.terms)
        cpull = _prior.control_pull(data.band, prior, relative)
        del data  # (memory: a second band while the pulls are found)
        info = torch.diag(p.prior_information().to(s.nn))
        reg = _prior.Regularised(s.band, cpull)
        self.pulls = (cpull, _prior.nuisance_pull(reg, s.cn, s.nn + info, prior))
        self._control_null(reg)

    def _relinearize(self) -> None:
        """The data system at the current point (and the pulls re-anchored there, with
        estimated nuisance parameters: :meth:`_reanchor`)."""
        del self.system, self._null_of  # the old system freed before the new is built
        self._gradient, self._factor = (None, None), None
        x = self.point
        self.system = self.p.system(x.ctrl, x.values, self.w, x.memo)
        self._null_of, self.informed = None, False  # until the new system's null is found
        if self.p.params:
            self._reanchor()

    def _reanchor(self) -> None:
        """With estimated nuisance parameters: the pulls recomputed at the current point and
        anchored there (their cost zero at it): a damping along the directions without
        information, never a spring back to the start. An extrinsic turning by a radian
        turns every control point of the body's trajectory with it; a pull anchored at the
        start held the ends' control points (and their weak directions, found in the
        start's charts) in the old frame, against the extrinsic: TUM fr1_xyz with an
        identity extrinsic start stalled 46 standard deviations off."""
        self.start, self.anchor = self.point.ctrl, self.point.values
        del self.pulls, self.null  # the old ones freed before the new are made (memory)
        self._pulls(self.prior)
        x = self.point
        self.point = Point(x.ctrl, x.values, x.data + self._pull(x.ctrl, x.values), x.data,
                           x.memo)

    def _pull(self, c: Tensor, v: list[Tensor]) -> Tensor:
        """The pulls (``torch_dq.fitting._prior``, from the anchor) and the Free priors
        (from their starts), ``(...)``."""
        d = dualquat.log(dualquat.mul(dualquat.conj(self.start), c))
        Pd = _prior.band_apply(self.pulls[0], d.reshape(self.Bf, self.n, 6, 1))
        u = _prior.nuisance_chart(self.p, self.anchor, v)
        Pn = self.pulls[1].reshape(*self.batch, self.p.m, self.p.m)
        return ((d * Pd.reshape(d.shape)).sum((-1, -2))
                + (u[..., None, :] @ Pn @ u[..., :, None])[..., 0, 0] + self.p.prior_cost(v))

    def objective(self, c: Tensor, v: list[Tensor], memo: Memo | None = None,
                  ) -> tuple[Tensor, Tensor]:
        """Data cost and objective (data plus the pulls and the Free priors), ``(...)``;
        the span derivatives kept in ``memo`` where given."""
        data = torch.stack(self.p.data_cost(c, v, memo)).sum(0)
        return data, data + self._pull(c, v)

    def _prior_gradient(self) -> tuple[Tensor, Tensor]:
        """Half the gradient of the pulls and the Free priors in the step charts. At the
        pulls' anchor (the start, or where :meth:`_reanchor` put it) they are a quadratic at
        its minimum: the Free priors' alone there."""
        x = self.point
        if x.ctrl is self.start and all(a is b for a, b in zip(x.values, self.anchor,
                                                               strict=True)):
            return x.ctrl.new_zeros(self.Bf, self.n, 6), self._free_gradient(x.values)
        with torch.enable_grad():
            dc = x.ctrl.new_zeros(*self.batch, self.n, 6).requires_grad_()
            dn = x.ctrl.new_zeros(*self.batch, self.p.m).requires_grad_()
            extra = self._pull(*self.p.retract(x.ctrl, x.values, dc, dn))
            gc, gn = torch.autograd.grad(0.5 * extra.sum(), (dc, dn), allow_unused=True)
        gc = torch.zeros_like(dc) if gc is None else gc
        gn = torch.zeros_like(dn) if gn is None else gn
        return gc.reshape(self.Bf, self.n, 6), gn.reshape(self.Bf, self.p.m)

    def _free_gradient(self, values: list[Tensor]) -> Tensor:
        """Half the gradient ``(Bf, m)`` of the Free priors in the nuisance charts."""
        with torch.enable_grad():
            dn = self.point.ctrl.new_zeros(*self.batch, self.p.m).requires_grad_()
            cost = self.p.prior_cost(self.p.moved(values, dn))
            if not cost.requires_grad:  # no Free prior
                return dn.detach().reshape(self.Bf, self.p.m)
            (gn,) = torch.autograd.grad(0.5 * cost.sum(), dn)
        return gn.reshape(self.Bf, self.p.m)

    def gradient(self) -> tuple[Tensor, Tensor]:
        """Half the gradient of the objective at the current point (system plus pulls),
        once per point and system."""
        at, grad = self._gradient
        if at is None or at[0] is not self.point or at[1] is not self.system:
            pc, pn = self._prior_gradient()
            grad = (self.system.gc + pc, self.system.gn + pn)
            self._gradient = ((self.point, self.system), grad)
        return grad

    def _outward(self, gn: Tensor) -> Tensor:
        """``(Bf, m)`` bool: the bounded scalars on their bound whose descent (``-gn``)
        points outwards."""
        out = torch.zeros_like(gn, dtype=torch.bool)
        for q, v in zip(self.p.params, self.point.values, strict=True):
            if isinstance(q.chart, Scalar):
                out[:, q.offset] = q.chart.outward(v.reshape(self.Bf), gn[:, q.offset])
        return out

    def _bounded(self, gn: Tensor) -> Tensor:
        """``gn`` without the components of bounded scalars on their bound whose descent
        points outwards (a constrained optimum there: the projected gradient)."""
        return torch.where(self._outward(gn), 0.0, gn)

    def _held_names(self, b: int) -> str:
        """The bounded scalars of element ``b`` held on their bound (descent outwards)."""
        out = self._outward(self.gradient()[1])[b]
        return ", ".join(f"{type(q.uses[0][0]).__name__}.{q.uses[0][1]} on its bound "
                         f"{float(self.point.values[i].reshape(self.Bf)[b]):g}"
                         for i, q in enumerate(self.p.params)
                         if isinstance(q.chart, Scalar) and bool(out[q.offset]))

    def _ends(self) -> Tensor | None:
        """``(Bf, m)`` bool: the scalars at their natural end 0 (a line delay) at the current
        point, which the steps that would go below hold there (``DampedStep``); None where
        none is."""
        ends = torch.zeros(self.Bf, self.p.m, dtype=torch.bool, device=self.start.device)
        for q, v in zip(self.p.params, self.point.values, strict=True):
            if isinstance(q.chart, Scalar):
                ends[:, q.offset] = q.chart.at_end(v.reshape(self.Bf))
        return ends if bool(ends.any()) else None

    def _step_pull(self) -> Tensor:
        r"""The control points' pull information in the current point's step charts,
        :math:`J^T P J` (``(Bf, n, w, 6, 6)``): the pulls' cost is :math:`d^T P d` with
        :math:`d = \mathrm{Log}(s^{-1} c)` from the anchor ``s``, and a step ``c
        \mathrm{Exp}(\delta)`` moves ``d`` by :math:`J_r^{-1}(d)\, \delta`
        (``_log_jacobians``), off the identity by about half the angle. Taken as
        ``P`` (the anchor's chart), a far start's pull was misjudged along the weakly
        determined directions it holds, where it weighs as much as the data: a camera's
        trajectory from a 0.35 rad start crept at a rate of 0.46 per step and stopped
        unconverged. ``P`` itself at the anchor; once per point."""
        x, pull = self.point, self.pulls[0]
        if x.ctrl is self.start or not bool(pull.any()):
            return pull
        at, out = self._pull_at
        if at is not x or out is None:
            J = _log_jacobians(self.start, x.ctrl).reshape(self.Bf, self.n, 6, 6)
            out = torch.empty_like(pull)
            for d in range(pull.shape[2]):
                out[:, :self.n - d, d] = J[:, :self.n - d].mT @ pull[:, :self.n - d, d] @ J[:, d:]
                out[:, self.n - d:, d] = pull[:, self.n - d:, d]  # past the end: zero
            self._pull_at = (x, out)
        return out

    def _step(self, stiff: float = 1.0, factor: BandedCholesky | None = None) -> DampedStep:
        """The damped step, the pulls ``stiff`` times stiffer (``factor``: the undamped
        band's factorisation, or None)."""
        cpull = self._step_pull()
        pulls = (cpull, self.pulls[1]) if stiff == 1.0 else (stiff * cpull,
                                                               stiff * self.pulls[1])
        return DampedStep(self.system, pulls, self.null, self.p.prior_information(),
                          self.solver, self._ends(), factor)

    def _decrement(self) -> tuple[Tensor, Tensor]:
        r"""The Newton decrement :math:`g^T H^{-1} g` ``(Bf,)`` at the current point and
        whether its solves succeeded. Where every direction carries information (the
        factorisation of :math:`A - \mathrm{NULL}\, D` certified no control-point
        combination without it, ``torch_dq.fitting._prior.Regularised.certified``, and
        nothing is pulled: ``informed``), one undamped solve where it succeeds, on the
        factorisation of the band that :meth:`_control_null` kept. Else, on
        directions without information it is no distance, so it is the limit of
        :math:`g^T (H + \epsilon D)^{-1} g` as :math:`\epsilon \to 0` without its
        :math:`1/\epsilon` part (``D`` the diagonal), extrapolated from ``epsilon =
        REGULARISE`` and ``100 REGULARISE``."""
        gc, gn = self.gradient()
        gn = self._bounded(gn)
        if self._null_of is not self.system:  # factored once per system
            self._control_null(_prior.Regularised(self.system.band, self._step_pull()))
        if self.informed:
            factor, self._factor = self._factor, None  # held no longer (memory)
            dc, dn, ok = self._step(factor=factor).step(torch.zeros_like(self.damping.lam),
                                                        gc, gn)
            if bool(ok.all()):
                return -((gc * dc).sum((-1, -2)) + (gn * dn).sum(-1)), ok
        # re-anchored pulls (nuisance estimated) hold their directions where they are: those
        # are left out like the directions without information (a stiffer pull)
        step = self._step(_LEFT_OUT if self.p.params else 1.0)
        decs, ok = [], torch.ones_like(self.active)
        for eps in (_prior.REGULARISE, _LOOSE * _prior.REGULARISE):
            dc, dn, good = step.step(torch.full_like(self.damping.lam, eps), gc, gn)
            decs.append(-((gc * dc).sum((-1, -2)) + (gn * dn).sum(-1)))
            ok &= good
        # g^T (H + eps D)^-1 g = d + c / eps: d extrapolated
        return (decs[1] * _LOOSE - decs[0]) / (_LOOSE - 1.0), ok

    def _control_null(self, reg: _prior.Regularised) -> None:
        """The combinations of control points without information of the current system
        (``reg``: its band plus the pulls) and whether it is :attr:`informed`; if so, the
        band's factorisation as it is (``reg.exact``, often factored already by
        ``torch_dq.fitting._prior.nuisance_pull``), kept for :meth:`_decrement`'s undamped
        solve: nothing pulled, that band is the damped step's bit for bit."""
        self.null, self._null_of = _prior.control_null(reg), self.system
        self.informed = (reg.certified and not bool(self.pulls[0].any())
                         and not bool(self.pulls[1].any()))
        self._factor = reg.exact if self.informed else None

    def check(self, tol: float, final: bool = False) -> None:
        r"""The scaled gradient test at the current point (its system built): an element
        whose Newton decrement (:meth:`_decrement`) is at most ``tol * max(objective,
        1e-20 * residual count)`` converged: the step left is at most ``sqrt(tol * chi2)``
        standard deviations of any quantity, ``sqrt(tol * dof)`` scaled ones. An element
        that stalled (its last accepted step lowered the objective by at most ``tol``
        relatively) or, with ``final``, ran out of steps, stops unconverged."""
        dec, ok = self._decrement()
        self.decrement = torch.where(self.active, dec, self.decrement)
        thr = tol * torch.maximum(self.point.objective.reshape(self.Bf), _EXACT * self.count)
        good = self.active & ok & torch.isfinite(dec) & (dec <= thr)
        held = self.active & self.slow & self._outward(self.gradient()[1]).any(-1)
        self.on_bound = torch.where(held, self.on_bound + 1, 0)
        bound = ~good & (self.on_bound >= 2)
        stop = self.active & ~good & (self.stalled | final | bound)
        for b in range(self.Bf):
            what = f"g^T H^-1 g = {float(dec[b]):.3g}, tol * max(cost, 1e-20 residuals) = " \
                   f"{float(thr[b]):.3g}"
            if bool(good[b]):
                self.reasons[b] = f"the scaled gradient test passed ({what})"
            elif bool(stop[b]) and bool(bound[b]):
                self.reasons[b] = (f"a bound holds {self._held_names(b)}, the data put it "
                                   f"further (raise max_time_offset): two steps lowered the "
                                   f"objective by at most {_BOUND_SLOW:g} relatively ({what}); "
                                   f"not converged")
            elif bool(stop[b]) and bool(self.stalled[b]):
                self.reasons[b] = (f"no progress: a step lowered the objective by at most "
                                   f"tol={tol!r} relatively, the gradient is not negligible "
                                   f"({what}); not converged")
            elif bool(stop[b]):
                self.reasons[b] = f"steps reached before convergence ({what})"
        self.converged |= good
        self.active &= ~(good | stop)

    def _trials(self, pending: Tensor) -> tuple[Point, Tensor, Tensor]:
        """Damped steps from the current point until each ``pending`` element accepts one
        that lowers its objective or ``_MAX_REJECTIONS`` rises of its damping; the accepted
        points (the current one elsewhere), the elements still pending and the accepted
        steps' gain ratios (actual over predicted decrease, ``(Bf,)``)."""
        x, batch, Bf = self.point, self.batch, self.Bf
        gc, gn = self.gradient()
        step = self._step()
        new, gain = x, torch.zeros_like(self.damping.lam)
        for _ in range(_MAX_REJECTIONS):
            dc, dn, ok = step.step(self.damping.lam, gc, gn)
            ok = ok & torch.isfinite(dc).all(-1).all(-1) & torch.isfinite(dn).all(-1)
            dc, dn = self._in_time_trust(dc, dn)
            tc, tv = self.p.retract(x.ctrl, x.values, dc.reshape(*batch, self.n, 6),
                                    dn.reshape(*batch, self.p.m))
            memo = Memo()
            td, to = self.objective(tc, tv, memo)
            trial = Point(tc, tv, to, td, memo)
            acc = pending & ok & torch.isfinite(to.reshape(Bf)) & (
                to.reshape(Bf) < x.objective.reshape(Bf)) & x.keeps(trial, batch)
            if bool(acc.any()):
                new = new.where(acc.reshape(batch), trial)
                drop = x.objective.reshape(Bf) - to.reshape(Bf)
                gain = torch.where(acc, drop / step.predicted(gc, gn, dc, dn), gain)
            pending = pending & ~acc
            self.damping.reject(pending)
            if not bool(pending.any()):
                break
        return new, pending, gain

    def _in_time_trust(self, dc: Tensor, dn: Tensor) -> tuple[Tensor, Tensor]:
        """The step ``(dc, dn)`` shortened, its direction kept, where it would move the
        samples' times by more than one knot span (``_time_columns``): a time's
        linearisation holds within a fraction of a span. Far from the data (a 1 rad
        extrinsic's start on knots that interpolate noise-free poses) a step that lowered
        the cost through the other parameters also moved the clock offsets by several
        spans, out to their bounds, and the estimate stopped there unconverged."""
        if self.timed is None:
            return dc, dn
        cols, rates = self.timed
        move = (dn[:, cols].abs() * rates).amax(-1)
        f = torch.where(move > self.span, self.span / move, torch.ones_like(move))
        return dc * f[:, None, None], dn * f[:, None]

    def iteration(self, tol: float) -> None:
        """One Gauss-Newton system, damped trials until each element accepts or gives up.
        A cost at float64 roundoff is converged (exact data) when no damped step lowers it
        or when the quadratic model no longer predicts the decrease (gain at most 1/4)."""
        new, pending, gain = self._trials(self.active.clone())
        Bf, old = self.Bf, self.point.objective.reshape(self.Bf)
        self.slow = self.active & ~pending & ((old - new.objective.reshape(Bf))
                                              <= _BOUND_SLOW * new.objective.reshape(Bf))
        self.stalled = self.active & ~pending & ((old - new.objective.reshape(Bf))
                                                 <= tol * new.objective.reshape(Bf))
        exact = self.active & (pending | (gain <= 0.25)) & (old <= _ROUNDOFF * self.count)
        for b in (pending | exact).nonzero()[:, 0].tolist():
            self.reasons[b] = (f"no damped step lowers the objective while the scaled gradient "
                               f"test fails (g^T H^-1 g = {float(self.decrement[b]):.3g}): a "
                               f"numerical minimum; not converged") if not bool(exact[b]) else (
                f"a cost at float64 roundoff that no damped step lowers as the quadratic model "
                f"predicts (exact data: {float(old[b]):.3g})")
        self.converged |= exact
        self.active &= ~(pending | exact)
        self.damping.accept(pending, gain)
        self.point = new

    def run(self, steps: int, tol: float, bar) -> History:
        """Iterate up to ``steps`` times (progress on ``bar``, tqdm's methods, or None)."""
        p = self.p
        losses, objectives = [self.point.data.clone()], [self.point.objective.clone()]
        done = 0
        for k in range(steps):
            if k:
                self._relinearize()
            self.check(tol)
            if not bool(self.active.any()):
                break
            done = k + 1
            self.iteration(tol)
            losses.append(self.point.data.clone())
            objectives.append(self.point.objective.clone())
            if bar is not None:
                bar.update(1)
                bar.set_postfix(cost=f"{float(self.point.data.sum()):.6e}",
                                damping=f"{float(self.damping.lam.max()):.1e}")
        if bool(self.active.any()):
            if done:
                self._relinearize()
            self.check(tol, final=True)
        return History(torch.stack(losses), torch.stack(objectives), done, self._reason(steps),
                       self.converged.reshape(p.batch), self.system, self.w, self.informed,
                       self.decrement)

    def _reason(self, steps: int) -> str:
        """The stop reasons joined (with a warning when ``steps`` ran out or the steps
        stalled before the test passed)."""
        reasons = self.reasons
        if steps and any(r.startswith("steps reached") for r in reasons):
            warnings.warn(f"fitting.estimate: steps={steps} reached before the scaled gradient "
                          f"test passed; raise steps (the estimate may be far from the "
                          f"optimum)", RuntimeWarning, stacklevel=4)
        stalled = [r for r in reasons if r.startswith("no progress")]
        if stalled:
            warnings.warn(f"fitting.estimate: stopped before the scaled gradient test passed "
                          f"({stalled[0]}); the estimate may be off the optimum: check the "
                          f"sensors' units and sigmas, the start, or loosen tol",
                          RuntimeWarning, stacklevel=4)
        return reasons[0] if len(reasons) == 1 else "; ".join(
            f"{r} ({reasons.count(r)}x)" for r in dict.fromkeys(reasons))


def _log_jacobians(start: Tensor, ctrl: Tensor) -> Tensor:
    r"""``(..., n, 6, 6)``: the derivatives :math:`J_r^{-1}(d)` of :math:`d =
    \mathrm{Log}(s^{-1} c\, \mathrm{Exp}(\delta))` at :math:`\delta = 0` for control points
    ``ctrl`` and anchors ``start`` ``(..., n, 8)``."""
    return _cumulative_lie.right_jacobian_inverse(
        dualquat.log(dualquat.mul(dualquat.conj(start), ctrl)))


def _time_columns(problem: Problem) -> tuple[tuple[Tensor, Tensor] | None, float]:
    """The nuisance columns that move the samples' times (a clock offset, a line delay:
    :meth:`~torch_dq.fitting.Term.time_rates`) with their largest rates, or None; and the
    trajectory's shortest knot span."""
    cols, rates = [], []
    for q in problem.params:
        r = [float(torch.as_tensor(t.time_rates()[name]).abs().max()) for t, name in q.uses
             if name in t.time_rates()]
        if r and q.dim == 1:
            cols.append(q.offset)
            rates.append(max(r))
    knots = problem.spans.trajectory.time_model.knots.detach().to(torch.float64)
    gaps = knots.diff(dim=-1)
    span = float(gaps[gaps > 0].min()) if bool((gaps > 0).any()) else math.inf
    if not cols:
        return None, span
    like = problem.spans.trajectory.control_points
    return (torch.tensor(cols, device=like.device),
            torch.tensor(rates, dtype=like.dtype, device=like.device)), span

r""":func:`estimate`: Levenberg-Marquardt over a trajectory and the terms' nuisance parameters.

Each iteration linearizes every term exactly, weights the
samples by the robust kernels at the current residuals (iteratively reweighted least
squares), and solves the damped Gauss-Newton system: the banded control-point block is
factored (``BandedCholesky``), the ``m`` nuisance steps come
from their ``m x m`` Schur complement and the control-point steps by back-substitution,
:math:`O((N + n) m + m^3)`. A step is accepted where it lowers the robust cost plus priors
(per batch element), the damping grows tenfold otherwise; its diagonal is Marquardt's,
floored at a tenth of the typical information. Convergence: the scaled gradient test of
:func:`estimate`'s ``tol``.
"""

from __future__ import annotations

import math
import numbers
import sys
import warnings
from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor

from .. import _checks, dualquat
from .._progress import progress
from . import _prior
from . import _structure as structure
from ._banded import BandedCholesky
from ._problem import Problem
from ._terms import Accel, Term
from ._uncertainty import Estimate

__all__ = ["estimate"]

_MAX_REJECTIONS = 8  # damping increases (x10 each) before a batch element stops
_NONFINITE = "non-finite cost at the start"
_EXACT = 1e-20  # per residual component: a cost below this is exact data (the test's floor)
_ROUNDOFF = 1e-14  # per residual component: a cost at float64 roundoff (whitened residuals of
# sigma 1e-3 round to ~1e-13 on unit-scale data): no damped step lowering it is converged
_LOOSE = 100.0  # the second regularisation of the scaled gradient test (times REGULARISE)


def _check_args(fn: str, trajectory, terms, steps, tol, prior, verbose) -> list[Term]:
    from .._curve import Curve
    if not isinstance(trajectory, Curve):
        _checks.fail(fn, f"expected a torch_dq.nn curve layer (BSpline or Bezier) for "
                         f"trajectory, got {type(trajectory).__name__}", TypeError)
    if isinstance(terms, Term):
        terms = [terms]
    if not isinstance(terms, Sequence) or not terms or not all(
            isinstance(t, Term) for t in terms):
        _checks.fail(fn, "terms must be a non-empty list of fitting terms (Poses, Positions, "
                         "RelativePoses, Gyro, Accel)", TypeError)
    if len({id(t) for t in terms}) != len(terms):
        _checks.fail(fn, "a term appears twice in terms")
    if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 0:
        _checks.fail(fn, f"steps must be an int >= 0, got {steps!r}")
    for name, v in (("tol", tol), ("prior", prior)):
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not (
                math.isfinite(v) and float(v) >= 0):
            _checks.fail(fn, f"{name} must be a finite real number >= 0, got {v!r}")
    _checks.flag(fn, "verbose", verbose)
    return list(terms)


def _check_domains(fn: str, trajectory, terms: list[Term], batch: torch.Size) -> None:
    """Times (widened by an estimated offset's bound) inside the trajectory's domain (per
    trajectory for per-trajectory knots)."""
    lo, hi = (torch.as_tensor(e, dtype=torch.float64) for e in trajectory.domain)
    eps = torch.finfo(trajectory.control_points.dtype).eps
    tol = (1e-9 + 4 * eps) * (hi - lo)  # the layer's relative knots round in its dtype
    for term in terms:
        name = type(term).__name__
        slot = term.slots()["time_offset"]
        if slot.estimated:
            what = f"widened by max_time_offset={term.max_time_offset!r}"
        else:
            fixed = slot.fixed
            dt = float(fixed) if fixed is not None and fixed.numel() == 1 else 0.0
            what = f"shifted by time_offset={dt!r}" if dt else ""
        a, b = term.time_reach()  # what the parameters moving the times can reach
        moved = [k for k in term.time_params if k != "time_offset" and k in term.slots()
                 and term.slots()[k].present]
        what += f" and by {', '.join(moved)}" if moved else ""
        for t in term.times_list():
            if t.dim() == 2 and (len(batch) != 1 or t.shape[0] != batch[0]):
                _checks.fail(fn, f"{name} times {_checks.shape_str(t.shape)} do not match the "
                                 f"trajectory's batch {_checks.shape_str(batch)}")
            first, last = (x.to(torch.float64).cpu() for x in ((t + a).amin(-1),
                                                                (t + b).amax(-1)))
            bad = ((first < lo - tol) | (last > hi + tol)).reshape(-1)
            if bool(bad.any()):
                i = int(bad.nonzero()[0, 0])
                pick = lambda x: float(x.reshape(-1)[i] if x.numel() > 1 else x)  # noqa: E731
                row = f" (trajectory {i})" if lo.dim() or t.dim() == 2 else ""
                fix = ("extend the trajectory or lower max_time_offset" if slot.estimated
                       else "extend the trajectory or drop those samples")
                if pick(last) - pick(first) < 1e-3 * (pick(hi) - pick(lo)) or (
                        pick(first) > pick(hi) or pick(last) < pick(lo)):
                    fix += " (are the times in the trajectory's units and origin?)"
                _checks.fail(fn, f"{name} times{' ' + what if what else ''} leave the "
                                 f"trajectory's domain{row} [{pick(lo)!r}, {pick(hi)!r}]: got "
                                 f"[{pick(first)!r}, {pick(last)!r}]; {fix}")


def _warn_c1(trajectory, terms: list[Term]) -> None:
    """Warn when an Accel term reads the accelerations of a curve that is not C2
    (:meth:`torch_dq.nn.Curve.acceleration_jumps`: a de Boor B-spline of degree >= 2, a
    cumulative one of degree < 3): its accelerations jump at the knots."""
    note = (trajectory.acceleration_jumps() if any(isinstance(t, Accel) for t in terms)
            else None)
    if note is not None:
        warnings.warn(f"fitting.estimate: an Accel term with {note}", UserWarning,
                      stacklevel=3)


def _warn_pinned(problem: Problem, values: list[Tensor]) -> None:
    """Warn for a time offset that ended on its ``max_time_offset`` bound."""
    for q, v in zip(problem.params, values, strict=True):
        if q.kind == "offset" and bool((v.abs() >= q.bound * (1.0 - 1e-9)).any()):
            warnings.warn(f"fitting.estimate: a time offset ended on its bound "
                          f"max_time_offset={q.bound!r}: the data put it further (raise "
                          f"max_time_offset); its standard deviation is inf",
                          RuntimeWarning, stacklevel=3)


class _Lines:
    """Progress without a terminal: one plain line per step on stderr (tqdm's methods)."""

    def __init__(self) -> None:
        self.k = 0

    def update(self, n: int) -> None:
        self.k += n

    def set_postfix(self, loss: str, damping: str) -> None:
        print(f"torch_dq.estimate: step {self.k}: cost {loss}, damping {damping}",
              file=sys.stderr, flush=True)

    def close(self) -> None:
        pass


def _starts(fn: str, problem: Problem, ctrl: Tensor) -> list[Tensor]:
    """Register the estimated parameters and their start values (batch expanded)."""
    batch = problem.batch
    for i, term in enumerate(problem.terms):
        vals = term.values(problem.trajectory, ctrl)
        for name, slot in term.slots().items():
            if slot.free is None:
                continue
            v = vals[name].to(torch.float64)
            event = v.shape[v.dim() - (0 if slot.kind == "offset" else 1):]
            v = v.expand(torch.Size((*batch, *event)))
            low, bound = term.bounds(name)
            if name == "time_offset" and bool((v.abs() > bound).any()):
                _checks.fail(fn, f"{type(term).__name__}'s time_offset starts "
                             f"at {float(v.abs().max()):g} s, outside its max_time_offset="
                             f"{bound!r}: start it inside [-{bound!r}, {bound!r}] or raise "
                             f"max_time_offset")
            if bool(((v < low) | (v > bound)).any()):
                _checks.fail(fn, f"{type(term).__name__}'s {name} starts outside its range "
                                 f"[{low!r}, {bound!r}]")
            problem.add(i, name, slot.free, slot.kind, slot.dim, v.clone(), bound, low)
            if slot.free.value is None:
                slot.free.value = v.clone()
    return [q.start.clone() for q in problem.params]


class _Solver:
    """The damped Gauss-Newton step of one iteration (Schur complement on the nuisance):
    the data system plus the pulls (``torch_dq.fitting._prior``) and the Free priors,
    damped by ``lam`` times its diagonal (Marquardt's scaling)."""

    def __init__(self, problem: Problem, system, pulls: tuple[Tensor, Tensor],
                 null: tuple[Tensor, Tensor]) -> None:
        self.p, self.s, self.null = problem, system, null
        self.band = system.band + pulls[0]
        self.diag = self.band[:, :, 0].diagonal(dim1=-2, dim2=-1).maximum(
            _prior.damping_floor(system.band))
        self.floor = 1e-12 * self.diag.mean((-1, -2)).clamp_min(1e-300)
        info = problem.prior_information().to(system.band)
        self.nn = system.nn + torch.diag(info) + pulls[1]
        self.ndiag = self.nn.diagonal(dim1=-2, dim2=-1)

    def step(self, lam: Tensor, gc: Tensor, gn: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Steps ``dc (Bf, n, 6)``, ``dn (Bf, m)`` and ``ok (Bf,)`` at damping ``lam``."""
        s, m = self.s, self.p.m
        band = self.band.clone()
        band[:, :, 0] += torch.diag_embed(lam[:, None, None] * (self.diag
                                                                + self.floor[:, None, None]))
        chol = BandedCholesky(band)
        ok = chol.ok
        if not m:
            return self._project(-chol.solve(gc[..., None])[..., 0]), gc.new_zeros(
                gc.shape[0], 0), ok
        X = chol.solve(torch.cat((gc[..., None], s.cn), dim=-1))
        y, Z = X[..., 0], X[..., 1:]
        S = self.nn + torch.diag_embed(lam[:, None] * (self.ndiag + self.floor[:, None]))
        S = S - torch.einsum("bnim,bniq->bmq", s.cn, Z)
        rhs = -gn + torch.einsum("bnim,bni->bm", s.cn, y)
        L, info = torch.linalg.cholesky_ex(0.5 * (S + S.mT))
        ok = ok & (info == 0)
        eye = torch.eye(m, dtype=S.dtype, device=S.device)
        L = torch.where((info == 0)[:, None, None], L, eye)
        dn = torch.cholesky_solve(rhs[..., None], L)[..., 0]
        dc = -y - torch.einsum("bnim,bm->bni", Z, dn)
        return self._project(dc), dn, ok

    def _project(self, dc: Tensor) -> Tensor:
        """``dc`` without the combinations of control points that no sample determines (no
        drift along them: ``torch_dq.fitting._prior.control_null``)."""
        U, DU = self.null
        if not U.shape[-1]:
            return dc
        return dc - torch.einsum("bnik,bk->bni", U, torch.einsum("bnik,bni->bk", DU, dc))


def estimate(trajectory, terms, steps: int = 50, tol: float = 1e-9, prior: float = 1e-3,
             verbose: bool = True) -> Estimate:
    r"""Estimate a trajectory and the terms' nuisance parameters from their measurements.

    Minimises :math:`\sum_{terms} \sum_i \rho(|r_i|)` (whitened residuals, robust kernels)
    plus the Gaussian priors of :class:`~torch_dq.fitting.Free` parameters, plus the
    numerical ``prior``, which only keeps what the data do not determine where the start
    put it (``torch_dq.fitting._prior``): combinations of neighbouring control points
    carrying less than ``1e-6`` times the typical information (time gaps, ends without
    samples; ``prior`` times it, their weakly determined edges included, when no nuisance
    parameter is estimated) are pulled to the start with weight ``prior``, nuisance directions
    without information (below ``1e-9``, scaled) likewise, and combinations of control
    points that no sample resolves (knots closer than the samples) are never stepped along.
    Nothing else is pulled: a determined parameter (an extrinsic, a time offset, the
    trajectory's placement) ends where the data put it, whatever its start.
    Levenberg-Marquardt in local charts (``c_k exp(delta_k)`` and the nuisance charts of
    :mod:`torch_dq.fitting`), exact Jacobians, steps accepted on the robust cost (module
    docstring). The trajectory's
    control points are updated in place (rounded once to its dtype; the solve runs in
    float64), the nuisance values are read on the terms afterwards (``term.bias``, ...).

    A trajectory with control points ``(B, n, 8)`` and terms with times ``(B, N)`` (or
    shared ``(N,)``) and data ``(B, N, ...)`` are ``B`` independent problems, solved
    together (per-element damping and stopping).

    Args:
        trajectory: a :class:`~torch_dq.nn.BSpline` or :class:`~torch_dq.nn.Bezier`
            (its control points are the start).
        terms: a list of terms (:class:`~torch_dq.fitting.Poses`, ...).
        steps: maximum number of iterations (0: only the uncertainties at the start).
        tol: converged when the Newton decrement :math:`g^T H^{-1} g` of the objective
            (``g`` half its gradient, ``H`` its Gauss-Newton matrix, directions without
            information left out) is at most ``tol * max(objective, 1e-20 N)`` (``N`` the
            residual components): the step left is below :math:`\sqrt{tol\,\chi^2}`
            standard deviations of any quantity. An accepted step that lowers the objective
            by at most ``tol`` relatively while that test fails stops the iteration as not
            converged (``reason`` starts with "no progress"); so does ``steps`` (with a
            ``RuntimeWarning``) or no damped step lowering the objective.
        prior: relative weight and threshold of the pull on what the data do not
            determine (see above), ``>= 0``.
        verbose: progress on stderr: a tqdm bar when stderr is a terminal and tqdm is
            installed, otherwise one line per step (step, cost, damping).

    Returns:
        :class:`~torch_dq.fitting.Estimate`.

    Raises:
        ValueError: bad arguments, terms times outside the domain (widened by an estimated
            time offset's ``max_time_offset``), parameters the terms cannot determine, batch
            shapes that do not match.

    Warns:
        UserWarning: an :class:`~torch_dq.fitting.Accel` term with a B-spline that is not
            C2 (``form="de_boor"`` of degree >= 2, ``form="cumulative"`` of degree < 3):
            its accelerations jump at the knots.
        RuntimeWarning: ``steps`` reached before convergence; a time offset that ended on
            its ``max_time_offset``.
        TypeError: a trajectory that is not a curve layer, terms that are not terms.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> from torch_dq.fitting import Poses
        >>> from torch_dq.nn import BSpline
        >>> t = torch.linspace(0.0, 2.0, 41, dtype=torch.float64)
        >>> truth = dq.exp(t[:, None] * torch.tensor([0.0, 0, 1.0, 0.5, 0, 0],
        ...                                          dtype=torch.float64))
        >>> spline = BSpline.from_dualquats(truth, t, n_ctrl=8)  # from_poses on (8,) poses
        >>> est = estimate(spline, [Poses(t, truth, rot_sigma=0.01, trans_sigma=0.01)],
        ...                verbose=False)
        >>> bool(est.final_loss < 1e-6)
        True
    """
    fn = "fitting.estimate"
    terms = _check_args(fn, trajectory, terms, steps, tol, prior, verbose)
    structure.check(fn, terms)
    ctrl = trajectory.control_points.detach().to(torch.float64)
    batch = ctrl.shape[:-2]
    _check_domains(fn, trajectory, terms, batch)
    _warn_c1(trajectory, terms)
    problem = Problem(trajectory, terms, batch)
    values = _starts(fn, problem, ctrl)
    bar = progress(int(steps), verbose and sys.stderr.isatty(), "torch_dq.estimate")
    if verbose and bar is None:
        bar = _Lines()
    try:
        ctrl, values, history = _iterate(problem, ctrl, values, int(steps), float(tol),
                                         float(prior), bar)
    finally:
        if bar is not None:
            bar.close()
    with torch.no_grad():
        trajectory.control_points = ctrl.to(trajectory.control_points.dtype)
    for q, v in zip(problem.params, values, strict=True):
        q.free.value = v.detach().clone()
    for term in terms:
        term.solved(trajectory)
    _warn_pinned(problem, values)
    return Estimate(problem, ctrl, values, history)


class _LevenbergMarquardt:
    """The iteration state: current point, objective, damping, per-element stopping."""

    def __init__(self, problem: Problem, ctrl: Tensor, values: list[Tensor], prior: float,
                 ) -> None:
        self.p, self.start = problem, ctrl
        self.batch, self.Bf, self.n = problem.batch, max(problem.batch.numel(), 1), problem.spans.n
        self.w = problem.width(values)
        self.system = s = problem.system(ctrl, values, self.w)
        cpull = _prior.control_pull(s.band, prior, bool(problem.params))
        info = torch.diag(problem.prior_information().to(s.nn))
        self.pulls = (cpull, _prior.nuisance_pull(s.band, s.cn, s.nn + info, cpull, prior))
        self.null = _prior.control_null(s.band, cpull)
        self.pulled = (int(_prior.undetermined(s.band).sum())
                       + int((self.null[0] != 0).any(-2).any(-2).sum())) // self.Bf
        self.count = torch.stack([(t.mask.sum(-1) * t.dim).expand(self.batch).to(torch.float64)
                                  for t in problem.terms]).sum(0).reshape(self.Bf)
        self.ctrl, self.values = ctrl, values
        self.data, self.obj = self.objective(ctrl, values)
        self.lam = torch.full((self.Bf,), 1e-4, dtype=torch.float64, device=ctrl.device)
        self.stalled = torch.zeros(self.Bf, dtype=torch.bool, device=ctrl.device)
        self.decrement = torch.full((self.Bf,), torch.inf, dtype=torch.float64,
                                    device=ctrl.device)
        self.converged = torch.zeros(self.Bf, dtype=torch.bool, device=ctrl.device)
        flat = self.obj.reshape(self.Bf)
        self.active = torch.isfinite(flat) & (flat > 0)
        self.converged |= flat == 0
        self.reasons = ["" if a else "the cost is zero" if float(o) == 0 else _NONFINITE
                        for o, a in zip(flat, self.active.tolist(), strict=True)]

    def _pull(self, c: Tensor, v: list[Tensor]) -> Tensor:
        """The pulls (``torch_dq.fitting._prior``) and the Free priors, ``(...)``."""
        d = dualquat.log(dualquat.mul(dualquat.conj(self.start), c))
        Pd = _prior.band_apply(self.pulls[0], d.reshape(self.Bf, self.n, 6, 1))
        u = _prior.nuisance_chart(self.p, v)
        Pn = self.pulls[1].reshape(*self.batch, self.p.m, self.p.m)
        return ((d * Pd.reshape(d.shape)).sum((-1, -2))
                + (u[..., None, :] @ Pn @ u[..., :, None])[..., 0, 0] + self.p.prior_cost(v))

    def objective(self, c: Tensor, v: list[Tensor]) -> tuple[Tensor, Tensor]:
        """Data cost and objective (data plus the pulls and the Free priors), ``(...)``."""
        data = torch.stack(self.p.data_cost(c, v)).sum(0)
        return data, data + self._pull(c, v)

    def _prior_gradient(self) -> tuple[Tensor, Tensor]:
        """Half the gradient of the pulls and the Free priors in the step charts."""
        with torch.enable_grad():
            dc = self.ctrl.new_zeros(*self.batch, self.n, 6).requires_grad_()
            dn = self.ctrl.new_zeros(*self.batch, self.p.m).requires_grad_()
            extra = self._pull(*self.p.retract(self.ctrl, self.values, dc, dn))
            gc, gn = torch.autograd.grad(0.5 * extra.sum(), (dc, dn), allow_unused=True)
        gc = torch.zeros_like(dc) if gc is None else gc
        gn = torch.zeros_like(dn) if gn is None else gn
        return gc.reshape(self.Bf, self.n, 6), gn.reshape(self.Bf, self.p.m)

    def gradient(self) -> tuple[Tensor, Tensor]:
        """Half the gradient of the objective at the current point (system plus pulls)."""
        pc, pn = self._prior_gradient()
        return self.system.gc + pc, self.system.gn + pn

    def _bounded(self, gn: Tensor) -> Tensor:
        """``gn`` without the components of time offsets on their bound whose descent
        points outwards (a constrained optimum there: the projected gradient)."""
        gn = gn.clone()
        for q, v in zip(self.p.params, self.values, strict=True):
            if q.kind == "offset":
                v = v.reshape(self.Bf)
                out = (v.abs() >= q.bound * (1.0 - 1e-9)) & (v * gn[:, q.offset] < 0)
                gn[:, q.offset] = torch.where(out, 0.0, gn[:, q.offset])
        return gn

    def check(self, tol: float, final: bool = False) -> None:
        r"""The scaled gradient test at the current point (its system built): an element
        whose Newton decrement :math:`g^T H^{-1} g` (``g`` half the gradient of the
        objective, ``H`` its undamped Gauss-Newton matrix; on directions without information
        the decrement is no distance: it is the limit of :math:`g^T (H + \epsilon D)^{-1} g`
        as :math:`\epsilon \to 0` without its :math:`1/\epsilon` part, ``D`` the diagonal,
        extrapolated from ``epsilon = 1e-10`` and ``1e-8``) is at most ``tol * max(objective,
        1e-20 * residual count)`` converged: the step left is at most ``sqrt(tol * chi2)``
        standard deviations of any quantity, ``sqrt(tol * dof)`` scaled ones. An element
        that stalled (its last accepted step lowered
        the objective by at most ``tol`` relatively) or, with ``final``, ran out of steps,
        stops unconverged."""
        gc, gn = self.gradient()
        gn = self._bounded(gn)
        self.null = _prior.control_null(self.system.band, self.pulls[0])
        solver = _Solver(self.p, self.system, self.pulls, self.null)
        decs, ok = [], torch.ones_like(self.active)
        for eps in (_prior.REGULARISE, _LOOSE * _prior.REGULARISE):
            dc, dn, good = solver.step(torch.full_like(self.lam, eps), gc, gn)
            decs.append(-((gc * dc).sum((-1, -2)) + (gn * dn).sum(-1)))
            ok &= good
        # g^T (H + eps D)^-1 g = d + c / eps, c from the directions without information
        # (their contribution is no distance in standard deviations): d extrapolated
        dec = (decs[1] * _LOOSE - decs[0]) / (_LOOSE - 1.0)
        self.decrement = torch.where(self.active, dec, self.decrement)
        thr = tol * torch.maximum(self.obj.reshape(self.Bf), _EXACT * self.count)
        good = self.active & ok & torch.isfinite(dec) & (dec <= thr)
        stop = self.active & ~good & (self.stalled | final)
        for b in range(self.Bf):
            what = f"g^T H^-1 g = {float(dec[b]):.3g}, tol * max(cost, 1e-20 residuals) = " \
                   f"{float(thr[b]):.3g}"
            if bool(good[b]):
                self.reasons[b] = f"the scaled gradient test passed ({what})"
            elif bool(stop[b]) and bool(self.stalled[b]):
                self.reasons[b] = (f"no progress: a step lowered the objective by at most "
                                   f"tol={tol!r} relatively, the gradient is not negligible "
                                   f"({what}); not converged")
            elif bool(stop[b]):
                self.reasons[b] = f"steps reached before convergence ({what})"
        self.converged |= good
        self.active &= ~(good | stop)

    def iteration(self, tol: float) -> None:
        """One Gauss-Newton system, damped trials until each element accepts or gives up."""
        gc, gn = self.gradient()
        solver = _Solver(self.p, self.system, self.pulls, self.null)
        pending = self.active.clone()
        batch, Bf = self.batch, self.Bf
        new: list[Any] = [self.ctrl, self.values, self.obj, self.data]
        for _ in range(_MAX_REJECTIONS):
            dc, dn, ok = solver.step(self.lam, gc, gn)
            ok = ok & torch.isfinite(dc).all(-1).all(-1) & torch.isfinite(dn).all(-1)
            tc, tv = self.p.retract(self.ctrl, self.values, dc.reshape(*batch, self.n, 6),
                                    dn.reshape(*batch, self.p.m))
            td, to = self.objective(tc, tv)
            acc = pending & ok & torch.isfinite(to.reshape(Bf)) & (to.reshape(Bf) <
                                                                  self.obj.reshape(Bf))
            sel = acc.reshape(batch)
            new[0] = torch.where(sel[..., None, None], tc, new[0])
            new[1] = [torch.where(sel.reshape(torch.Size((*batch, *(1,) * (v.dim() - len(batch)
                                                                         )))), a, v)
                      for a, v in zip(tv, new[1], strict=True)]
            new[2], new[3] = torch.where(sel, to, new[2]), torch.where(sel, td, new[3])
            pending &= ~acc
            self.lam = torch.where(pending, self.lam * 10.0, self.lam)
            if not bool(pending.any()):
                break
        self.stalled = self.active & ~pending & ((self.obj - new[2]).reshape(Bf)
                                                 <= tol * new[2].reshape(Bf))
        exact = pending & (self.obj.reshape(Bf) <= _ROUNDOFF * self.count)
        for b in pending.nonzero()[:, 0].tolist():
            self.reasons[b] = (f"no damped step lowers the objective while the scaled gradient "
                               f"test fails (g^T H^-1 g = {float(self.decrement[b]):.3g}): a "
                               f"numerical minimum; not converged") if not bool(exact[b]) else (
                f"no damped step lowers a cost at float64 roundoff (exact data: "
                f"{float(self.obj.reshape(Bf)[b]):.3g})")
        self.converged |= exact
        self.active &= ~pending
        self.lam = torch.where(pending, self.lam, (self.lam / 10.0).clamp_min(1e-12))
        self.ctrl, self.values, self.obj, self.data = new


def _iterate(problem: Problem, ctrl: Tensor, values: list[Tensor], steps: int, tol: float,
             prior: float, bar):
    """The Levenberg-Marquardt loop; returns the final point and its history."""
    lm = _LevenbergMarquardt(problem, ctrl, values, prior)
    losses, objectives = [lm.data.clone()], [lm.obj.clone()]
    done = 0
    for k in range(steps):
        if k:
            lm.system = problem.system(lm.ctrl, lm.values, lm.w)
        lm.check(tol)
        if not bool(lm.active.any()):
            break
        done = k + 1
        lm.iteration(tol)
        losses.append(lm.data.clone())
        objectives.append(lm.obj.clone())
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{float(lm.data.sum()):.6e}",
                            damping=f"{float(lm.lam.max()):.1e}")
    if bool(lm.active.any()):
        if done:
            lm.system = problem.system(lm.ctrl, lm.values, lm.w)
        lm.check(tol, final=True)
    reasons = lm.reasons
    if steps and any(r.startswith("steps reached") for r in reasons):
        warnings.warn(f"fitting.estimate: steps={steps} reached before the scaled gradient test "
                      f"passed; raise steps (the estimate may be far from the optimum)",
                      RuntimeWarning, stacklevel=3)
    reason = reasons[0] if len(reasons) == 1 else "; ".join(
        f"{r} ({reasons.count(r)}x)" for r in dict.fromkeys(reasons))
    history = {"loss": torch.stack(losses), "objective": torch.stack(objectives),
               "steps": done, "reason": reason, "system": lm.system, "width": lm.w,
               "pulled": lm.pulled, "converged": lm.converged.reshape(problem.batch)}
    return lm.ctrl, lm.values, history

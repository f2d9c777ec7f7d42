r""":func:`estimate`: Levenberg-Marquardt over a trajectory and the terms' nuisance parameters.

Each iteration linearizes every term exactly, weights the
samples by the robust kernels at the current residuals (iteratively reweighted least
squares), and solves the damped Gauss-Newton system: the banded control-point block is
factored (``BandedCholesky``), the ``m`` nuisance steps come
from their ``m x m`` Schur complement and the control-point steps by back-substitution,
:math:`O((N + n) m + m^3)`. A step is accepted where it lowers the robust cost plus priors
(per batch element), the damping grows tenfold otherwise.
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
from . import _structure as structure
from ._banded import BandedCholesky
from ._problem import Problem
from ._terms import Accel, Term
from ._uncertainty import Estimate

__all__ = ["estimate"]

_MAX_REJECTIONS = 8  # damping increases (x10 each) before a batch element stops
_NONFINITE = "non-finite cost at the start"
_SETTLING = 1e-2  # relative decrease of a step below which the next one is predicted first


def progress(total: int, enabled: bool, desc: str):
    """A tqdm bar when enabled and tqdm is installed, else None."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=total, desc=desc, leave=False)


def _check_args(fn: str, trajectory, terms, steps, tol, prior, verbose) -> list[Term]:
    from ..nn import Curve
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
            a, b = -term.max_time_offset, term.max_time_offset
            what = f"widened by max_time_offset={term.max_time_offset!r}"
        else:
            fixed = slot.fixed
            dt = float(fixed) if fixed is not None and fixed.numel() == 1 else 0.0
            a = b = dt
            what = f"shifted by time_offset={dt!r}" if dt else ""
        for t in term.times_list():
            if t.dim() == 2 and (len(batch) != 1 or t.shape[0] != batch[0]):
                _checks.fail(fn, f"{name} times {_checks.shape_str(t.shape)} do not match the "
                                 f"trajectory's batch {_checks.shape_str(batch)}")
            first, last = (x.to(torch.float64).cpu() for x in (t.amin(-1) + a, t.amax(-1) + b))
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
    """Warn when an Accel term reads the accelerations of a C1 (de Boor) B-spline."""
    from ..nn import BSpline
    if (isinstance(trajectory, BSpline) and trajectory.form == "de_boor"
            and trajectory.degree >= 2 and any(isinstance(t, Accel) for t in terms)):
        warnings.warn(f"fitting.estimate: an Accel term with a degree-{trajectory.degree} "
                      f"B-spline of form='de_boor', which is only C1 (its accelerations jump "
                      f"at the knots); build it with form='cumulative' for IMU work",
                      UserWarning, stacklevel=3)


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
            bound = term.max_time_offset if slot.kind == "offset" else math.inf
            if bool((v.abs() > bound).any()):
                _checks.fail(fn, f"{type(term).__name__}'s time_offset starts "
                             f"at {float(v.abs().max()):g} s, outside its max_time_offset="
                             f"{bound!r}: start it inside [-{bound!r}, {bound!r}] or raise "
                             f"max_time_offset")
            problem.add(i, name, slot.free, slot.kind, slot.dim, v.clone(), bound)
            if slot.free.value is None:
                slot.free.value = v.clone()
    return [q.start.clone() for q in problem.params]


class _Solver:
    """The damped Gauss-Newton step of one iteration (Schur complement on the nuisance)."""

    def __init__(self, problem: Problem, system, mu: Tensor) -> None:
        self.p, self.s, self.mu = problem, system, mu
        band = system.band
        self.diag = band[:, :, 0].diagonal(dim1=-2, dim2=-1) + mu[:, None, None]
        self.floor = 1e-12 * self.diag.mean((-1, -2)).clamp_min(1e-300)
        info = problem.prior_information().to(band)
        self.nn = system.nn + torch.diag(info)
        self.ndiag = self.nn.diagonal(dim1=-2, dim2=-1)

    def step(self, lam: Tensor, gc: Tensor, gn: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Steps ``dc (Bf, n, 6)``, ``dn (Bf, m)`` and ``ok (Bf,)`` at damping ``lam``."""
        s, m = self.s, self.p.m
        band = s.band.clone()
        add = self.mu[:, None, None] + lam[:, None, None] * (self.diag + self.floor[:, None,
                                                                                    None])
        band[:, :, 0] += torch.diag_embed(add)
        chol = BandedCholesky(band)
        ok = chol.ok
        if not m:
            return -chol.solve(gc[..., None])[..., 0], gc.new_zeros(gc.shape[0], 0), ok
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
        return dc, dn, ok


def estimate(trajectory, terms, steps: int = 50, tol: float = 1e-9, prior: float = 1e-3,
             verbose: bool = True) -> Estimate:
    r"""Estimate a trajectory and the terms' nuisance parameters from their measurements.

    Minimises :math:`\sum_{terms} \sum_i \rho(|r_i|)` (whitened residuals, robust kernels)
    plus the Gaussian priors of :class:`~torch_dq.fitting.Free` parameters, plus the
    numerical ``prior``: ``prior`` times the mean data curvature per control point times
    :math:`\sum_k |\log(c_k^{0\,-1} c_k)|^2`, a pull towards the start that keeps control
    points without data (time gaps) where the start put them and changes a well-determined
    fit by about ``prior`` times its distance from the start. Levenberg-Marquardt in local
    charts (``c_k exp(delta_k)`` and the nuisance charts of :mod:`torch_dq.fitting`),
    exact Jacobians, steps accepted on the robust cost (module docstring). The trajectory's
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
        tol: stop when an accepted step lowers the objective by at most ``tol`` relatively.
        prior: weight of the pull towards the start (see above), ``>= 0``.
        verbose: progress on stderr: a tqdm bar when stderr is a terminal and tqdm is
            installed, otherwise one line per step (step, cost, damping).

    Returns:
        :class:`~torch_dq.fitting.Estimate`.

    Raises:
        ValueError: bad arguments, terms times outside the domain (widened by an estimated
            time offset's ``max_time_offset``), parameters the terms cannot determine, batch
            shapes that do not match.

    Warns:
        UserWarning: an :class:`~torch_dq.fitting.Accel` term with a B-spline of
            ``form="de_boor"`` and degree >= 2 (only C1: its accelerations jump at the
            knots); ``form="cumulative"`` is smooth there.
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
    return Estimate(problem, ctrl, values, history)


class _LevenbergMarquardt:
    """The iteration state: current point, objective, damping, per-element stopping."""

    def __init__(self, problem: Problem, ctrl: Tensor, values: list[Tensor], prior: float,
                 ) -> None:
        self.p, self.start = problem, ctrl
        self.batch, self.Bf, self.n = problem.batch, max(problem.batch.numel(), 1), problem.spans.n
        self.w = problem.width(values)
        self.system = problem.system(ctrl, values, self.w)
        self.fresh = True  # self.system is at the current point
        diag0 = self.system.band[:, :, 0].diagonal(dim1=-2, dim2=-1).mean((-1, -2))
        self.mu = prior * diag0
        self.solver = _Solver(problem, self.system, self.mu)
        self.settling = torch.zeros(self.Bf, dtype=torch.bool, device=ctrl.device)
        self.ctrl, self.values = ctrl, values
        self.data, self.obj = self.objective(ctrl, values)
        self.lam = torch.full((self.Bf,), 1e-4, dtype=torch.float64, device=ctrl.device)
        flat = self.obj.reshape(self.Bf)
        self.active = torch.isfinite(flat) & (flat > 0)
        self.reasons = ["" if a else "the cost is zero" if float(o) == 0 else _NONFINITE
                        for o, a in zip(flat, self.active.tolist(), strict=True)]

    def _pull(self, c: Tensor, v: list[Tensor]) -> Tensor:
        pull = dualquat.log(dualquat.mul(dualquat.conj(self.start), c))
        return self.mu.reshape(self.batch) * (pull * pull).sum((-1, -2)) + self.p.prior_cost(v)

    def objective(self, c: Tensor, v: list[Tensor]) -> tuple[Tensor, Tensor]:
        """Data cost and objective (data plus the pull and the Free priors), ``(...)``."""
        data = torch.stack(self.p.data_cost(c, v)).sum(0)
        return data, data + self._pull(c, v)

    def _prior_gradient(self) -> tuple[Tensor, Tensor]:
        """Half the gradient of the pull and the Free priors in the step charts."""
        with torch.enable_grad():
            dc = self.ctrl.new_zeros(*self.batch, self.n, 6).requires_grad_()
            dn = self.ctrl.new_zeros(*self.batch, self.p.m).requires_grad_()
            extra = self._pull(*self.p.retract(self.ctrl, self.values, dc, dn))
            gc, gn = torch.autograd.grad(0.5 * extra.sum(), (dc, dn), allow_unused=True)
        gn = torch.zeros_like(dn) if gn is None else gn
        return gc.reshape(self.Bf, self.n, 6), gn.reshape(self.Bf, self.p.m)

    def predicted_stop(self, tol: float) -> None:
        """Stop the elements whose next step, as the last system predicts it (its damped
        Gauss-Newton matrix, the exact gradient here), lowers the objective by at most
        ``tol`` relatively: the model decrease of the step ``dx`` is at most ``-2 g^T dx``
        (``g`` the half gradient). Only after a step that lowered the objective by at most
        ``_SETTLING`` relatively (after larger ones the prediction would rarely stop). The
        gradient ``J^T W r`` comes from the Gauss-Newton system at the current point, which
        is kept: the next iteration needs it, or the uncertainties after a stop (where it
        replaces a chained pass of the costs, the uncertainties save a whole system)."""
        if not bool((self.active & self.settling).any()):
            return
        self.system, self.fresh = self.p.system(self.ctrl, self.values, self.w), True
        gc, gn = self.system.gc, self.system.gn
        pc, pn = self._prior_gradient()
        gc, gn = gc + pc, gn + pn
        dc, dn, ok = self.solver.step(self.lam, gc, gn)
        pred = -2.0 * ((gc * dc).sum((-1, -2)) + (gn * dn).sum(-1))
        obj = self.obj.reshape(self.Bf)
        small = self.active & self.settling & ok & torch.isfinite(pred) & (pred <= tol * obj)
        for b in small.nonzero()[:, 0].tolist():
            self.reasons[b] = (f"the relative decrease fell below tol={tol!r} (the next "
                               f"step's, predicted)")
        self.active &= ~small

    def iteration(self, tol: float) -> None:
        """One Gauss-Newton system, damped trials until each element accepts or gives up."""
        pc, pn = self._prior_gradient()
        gc, gn = self.system.gc + pc, self.system.gn + pn
        self.solver = solver = _Solver(self.p, self.system, self.mu)
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
        small = self.active & ~pending & ((self.obj - new[2]).reshape(Bf)
                                          <= tol * new[2].reshape(Bf))
        for b in range(Bf):
            if bool(pending[b]):
                self.reasons[b] = "no damped step lowers the cost (a numerical minimum)"
            elif bool(small[b]):
                self.reasons[b] = f"the relative decrease fell below tol={tol!r}"
        self.fresh = not bool((self.active & ~pending).any())  # no element moved
        self.active &= ~(pending | small)
        self.lam = torch.where(pending, self.lam, (self.lam / 10.0).clamp_min(1e-12))
        self.settling = (self.obj - new[2]).reshape(Bf) <= _SETTLING * new[2].reshape(Bf)
        self.ctrl, self.values, self.obj, self.data = new


def _iterate(problem: Problem, ctrl: Tensor, values: list[Tensor], steps: int, tol: float,
             prior: float, bar):
    """The Levenberg-Marquardt loop; returns the final point and its history (with the
    Gauss-Newton system at the final point where one was built there, for the
    uncertainties)."""
    lm = _LevenbergMarquardt(problem, ctrl, values, prior)
    losses, objectives = [lm.data.clone()], [lm.obj.clone()]
    done = 0
    for k in range(steps):
        if not bool(lm.active.any()):
            break
        if k:
            lm.predicted_stop(tol)
            if not bool(lm.active.any()):
                break
            if not lm.fresh:
                lm.system, lm.fresh = problem.system(lm.ctrl, lm.values, lm.w), True
        done = k + 1
        lm.iteration(tol)
        losses.append(lm.data.clone())
        objectives.append(lm.obj.clone())
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{float(lm.data.sum()):.6e}",
                            damping=f"{float(lm.lam.max()):.1e}")
    converged = torch.tensor([r not in ("", _NONFINITE) for r in lm.reasons],
                             device=lm.active.device) & ~lm.active
    reasons = [r or f"steps={steps} reached" for r in lm.reasons]
    reason = reasons[0] if len(reasons) == 1 else "; ".join(
        f"{r} ({reasons.count(r)}x)" for r in dict.fromkeys(reasons))
    history = {"loss": torch.stack(losses), "objective": torch.stack(objectives),
               "steps": done, "reason": reason, "converged": converged.reshape(problem.batch),
               "system": lm.system if lm.fresh and problem.width(lm.values) == lm.w
               else None}
    return lm.ctrl, lm.values, history

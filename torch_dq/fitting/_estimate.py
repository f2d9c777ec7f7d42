r""":func:`estimate`: the entry point of the estimation engine.

It checks the arguments and the terms' times against the curve's domain once, registers the
estimated parameters with their starts (:class:`~torch_dq.fitting._problem.Problem`, the
objective), runs the loop (:class:`~torch_dq.fitting._lm.LevenbergMarquardt`, with the
damped step and the linear solver of :mod:`torch_dq.fitting._solver` and the linearisation
of :mod:`torch_dq.fitting._linearize`), writes the solution back and returns an
:class:`~torch_dq.fitting.Estimate` built from the problem's
:class:`~torch_dq.fitting._problem.Summary`.
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from .. import _checks
from .._progress import reporter
from . import _structure as structure
from ._align import imu_aligned
from ._charts import Scalar
from ._imu import Accel, Gyro
from ._knots import round_up
from ._lm import LevenbergMarquardt
from ._problem import Problem
from ._terms import Term
from ._uncertainty import Estimate

__all__ = ["estimate"]


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
                         "RelativePoses, Gyro, Accel, Reprojections)", TypeError)
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
    dom = trajectory.time_model  # its tolerance: the layer's own (KnotDomain.outside)
    for term in terms:
        name = type(term).__name__
        slot = term.slots()["time_offset"]
        parts = []
        if slot.estimated:
            parts.append(f"widened by max_time_offset={term.max_time_offset!r}")
        else:
            fixed = slot.fixed
            dt = float(fixed) if fixed is not None and fixed.numel() == 1 else 0.0
            parts += [f"shifted by time_offset={dt!r}"] if dt else []
        a, b = term.time_reach()  # what the parameters moving the times can reach
        moved = [k for k in term.time_rates() if k != "time_offset"]
        parts += [f"by {', '.join(moved)}"] if moved else []
        what = " and ".join(parts)
        for t in term.times_list():
            if t.dim() == 2 and (len(batch) != 1 or t.shape[0] != batch[0]):
                _checks.fail(fn, f"{name} times {_checks.shape_str(t.shape)} do not match the "
                                 f"trajectory's batch {_checks.shape_str(batch)}")
            first, last = (x.to(torch.float64) for x in ((t + a).amin(-1), (t + b).amax(-1)))
            out = dom.outside(torch.stack((first, last), -1)).cpu()
            bad = out.any(-1).reshape(-1)
            first, last = first.cpu(), last.cpu()
            if bool(bad.any()):
                i = int(bad.nonzero()[0, 0])
                def pick(x: Tensor, i: int = i) -> float:
                    return float(x.reshape(-1)[i] if x.numel() > 1 else x)

                row = f" (trajectory {i})" if lo.dim() or t.dim() == 2 else ""
                short = [pick(lo) - pick(first), pick(last) - pick(hi)]
                ends = out.reshape(-1, 2)[i if out.numel() > 2 else 0].tolist()
                slack = 0.5 * pick(dom.tolerance(torch.float64).cpu())  # within the rounding
                extend = _extend_hint(trajectory, [s - slack if e else 0.0 for s, e in
                                                   zip(short, ends, strict=True)],
                                      (pick(first) + slack, pick(last) - slack), pick)
                fix = (f"{extend} or lower max_time_offset" if slot.estimated
                       else f"{extend} or drop those samples")
                if pick(last) - pick(first) < 1e-3 * (pick(hi) - pick(lo)) or (
                        pick(first) > pick(hi) or pick(last) < pick(lo)):
                    fix += " (are the times in the trajectory's units and origin?)"
                _checks.fail(fn, f"{name} times{' ' + what if what else ''} leave the "
                                 f"trajectory's domain{row} [{pick(lo)!r}, {pick(hi)!r}]: got "
                                 f"[{pick(first)!r}, {pick(last)!r}]; {fix}")


def _extend_hint(trajectory, short: list[float], reach: tuple[float, float],
                 pick: Callable[[Tensor], float]) -> str:
    """The advice on times reaching ``reach`` (first, last) beyond the trajectory's domain
    by ``short`` (at its start, at its end; 0 where inside), both less half the domain's
    tolerance: for a curve built from poses (``Curve._poses_span``), the ``margin=`` that
    covers them, counted like ``from_poses``' from the poses' first and last times; else how
    far to extend the domain. Every number rounded up (followed literally, it works)."""
    def up(x: float) -> str:
        return f"{round_up(x):g}"

    span = trajectory._poses_span
    if span is not None:
        reach_out = max(pick(span[0]) - reach[0], reach[1] - pick(span[1]))
        return (f"extend the trajectory: build it with nn.BSpline.from_poses / from_dualquats"
                f"(..., margin={up(reach_out)}) (the margin counts from the poses' first and "
                f"last times; this curve's falls {up(max(short))} short)")
    where = " and ".join(f"{up(s)} at its {end}" for s, end in zip(short, ("start", "end"),
                                                                  strict=True) if s > 0)
    return (f"extend the trajectory's domain by {where} (this curve was not built by "
            f"nn.BSpline.from_poses / from_dualquats, whose margin= counts from the poses' "
            f"first and last times)")


def _check_batches(fn: str, terms: list[Term], batch: torch.Size) -> None:
    """Each term's data and nuisance values (fixed, or a Free's start or value) with
    leading dims that broadcast to the trajectory's batch (and no more of them)."""
    def fits(lead: torch.Size) -> bool:
        try:
            return torch.broadcast_shapes(lead, batch) == batch
        except RuntimeError:
            return False

    for term in terms:
        name = type(term).__name__
        if not fits(term.mask.shape[:-1]):
            _checks.fail(fn, f"{name} data of batch {_checks.shape_str(term.mask.shape[:-1])} "
                             f"do not match the trajectory's batch {_checks.shape_str(batch)}")
        for key, slot in term.slots().items():
            free = slot.free
            v = slot.fixed if free is None else (free.value if free.value is not None
                                                 else free.start)
            if isinstance(v, Tensor) and not fits(v.shape[:v.dim() - len(slot.shape)]):
                what = "" if free is None else (" start" if free.value is None else " value")
                each = (f" or one per trajectory {_checks.shape_str(batch + slot.shape)}"
                        if batch else "")
                _checks.fail(fn, f"{name}'s {key}{what} {_checks.shape_str(v.shape)} does "
                                 f"not match the trajectory's batch {_checks.shape_str(batch)}: "
                                 f"expected {_checks.shape_str(slot.shape)}{each}")


def _warn_c1(trajectory, terms: list[Term]) -> None:
    """Warn when an Accel term reads the accelerations of a curve that is not C2
    (:meth:`torch_dq.nn.Curve.acceleration_jumps`: a de Boor B-spline of degree >= 2, a
    cumulative one of degree < 3): its accelerations jump at the knots."""
    note = (trajectory.acceleration_jumps() if any(isinstance(t, Accel) for t in terms)
            else None)
    if note is not None:
        warnings.warn(f"fitting.estimate: an Accel term with {note}", UserWarning,
                      stacklevel=3)


def _warn_offset_kinks(trajectory, terms: list[Term]) -> None:
    """Warn for a term reading accelerations (``order >= 2``: :class:`Accel`) whose samples'
    times an estimated parameter moves, on a curve whose accelerations are not C1 in time:
    its cost kinks in that parameter as samples cross knots, and Gauss-Newton stalls short of
    the optimum (Kalibr and basalt fit time offsets on splines of order 5-6, degree 4-5;
    :meth:`torch_dq.nn.Curve.acceleration_kinks`)."""
    curve = trajectory.acceleration_kinks()
    if curve is None:
        return
    for term in terms:
        moving = [n for n in term.time_rates() if term.slots()[n].estimated]
        if term.order >= 2 and moving:
            name = f"{type(term).__name__}.{moving[0]}"
            warnings.warn(f"fitting.estimate: {name} is estimated on {curve}, whose "
                          f"accelerations are not C1 in time: the {type(term).__name__} cost "
                          f"kinks in {name} as samples cross knots and the solve may stop "
                          f"short of the optimum; use a B-spline of degree >= 4 "
                          f"(form='cumulative' or 'split', e.g. BSpline.from_poses(..., "
                          f"degree=4, form='cumulative'))", RuntimeWarning, stacklevel=3)
            return


def _warn_pinned(problem: Problem, values: list[Tensor]) -> None:
    """Warn for a time offset that ended on its ``max_time_offset`` bound."""
    for q, v in zip(problem.params, values, strict=True):
        if isinstance(q.chart, Scalar) and bool(q.chart.pinned(v).any()):
            warnings.warn(f"fitting.estimate: a time offset ended on its bound "
                          f"max_time_offset={q.chart.high!r}: the data put it further (raise "
                          f"max_time_offset); its standard deviation is inf",
                          RuntimeWarning, stacklevel=3)


def _starts(fn: str, problem: Problem, ctrl: Tensor) -> list[Tensor]:
    """Register the estimated parameters and their start values (batch expanded)."""
    batch = problem.batch
    for i, term in enumerate(problem.terms):
        vals = term.values(problem.trajectory, ctrl)
        for name, slot in term.slots().items():
            if slot.free is None:
                continue
            v = vals[name].to(torch.float64)
            event = v.shape[v.dim() - len(slot.shape):]
            v = v.expand(torch.Size((*batch, *event)))
            _check_start(fn, term, name, slot.chart, v)
            problem.add(i, name, slot.free, slot.chart, v.clone())
            if slot.free.value is None:
                slot.free.value = v.clone()
    return [q.start.clone() for q in problem.params]


def _check_start(fn: str, term: Term, name: str, chart, v: Tensor) -> None:
    """Fail for a start outside a bounded scalar's range."""
    if not isinstance(chart, Scalar):
        return
    low, high = chart.low, chart.high
    if name == "time_offset" and bool((v.abs() > high).any()):
        _checks.fail(fn, f"{type(term).__name__}'s time_offset starts "
                     f"at {float(v.abs().max()):g} s, outside its max_time_offset="
                     f"{high!r}: start it inside [-{high!r}, {high!r}] or raise "
                     f"max_time_offset")
    if bool(((v < low) | (v > high)).any()):
        _checks.fail(fn, f"{type(term).__name__}'s {name} starts outside its range "
                         f"[{low!r}, {high!r}]")


def estimate(trajectory, terms, steps: int = 50, tol: float = 1e-9, prior: float = 1e-3,
             verbose: bool = True) -> Estimate:
    r"""Estimate a trajectory and the terms' nuisance parameters from their measurements.

    Minimises :math:`\sum_{terms} \sum_i \rho(|r_i|)` (whitened residuals, robust kernels)
    plus the Gaussian priors of :class:`~torch_dq.fitting.Free` parameters, plus the
    numerical ``prior``, which only keeps what the data do not determine where the start
    put it (``torch_dq.fitting._prior``): combinations of neighbouring control points
    carrying less than ``1e-6`` times the typical information (time gaps, ends without
    samples; ``prior`` times it, their weakly determined edges included, when no nuisance
    parameter is estimated and no IMU term reads the curve's derivatives) are pulled to the
    start with weight ``prior``, nuisance directions
    without information (below ``1e-9``, scaled) likewise, and combinations of control
    points that no sample resolves (knots closer than the samples) are never stepped along.
    With estimated nuisance parameters the pulls are found again and anchored at every
    linearisation point (a damping along those directions, not a spring to the start: an
    extrinsic that turns turns every control point with it), a window's information is judged
    against its own best-determined direction (control points seen only by poses are not
    undetermined next to an accelerometer's), and the pulled directions are left out of the
    convergence test.
    Nothing else is pulled: a determined parameter (an extrinsic, a time offset, the
    trajectory's placement) ends where the data put it, whatever its start.
    Where only an IMU sees the rotations (one trajectory with :class:`~torch_dq.fitting.Positions`,
    :class:`~torch_dq.fitting.Gyro` and :class:`~torch_dq.fitting.Accel` terms alone), the
    start's rotations are replaced by the gyroscope's integrated rates aligned on the
    accelerometer (``torch_dq.fitting._align``) where that lowers the start's cost: a
    start with identity rotations (positions alone) would crawl along the heading.
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
            converged (``reason`` starts with "no progress"; a ``RuntimeWarning``); so does
            ``steps`` (warned too) or no damped step lowering the objective; so does a
            clock offset held on its ``max_time_offset`` bound (the descent pointing
            outwards) while two steps in a row lower the objective by at most ``1e-3``
            relatively (``reason`` starts with "a bound holds" and names it, e.g.
            ``Gyro.time_offset on its bound 0.1``; the bound is warned).
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
            its ``max_time_offset``; an :class:`~torch_dq.fitting.Accel` term's time offset
            estimated on a curve whose accelerations are not C1 in time (a B-spline of
            degree < 4, or of form ``"de_boor"``): its cost kinks in the offset as samples
            cross knots, and the solve may stall; use degree >= 4.
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
    _check_batches(fn, terms, batch)
    _check_domains(fn, trajectory, terms, batch)
    _warn_c1(trajectory, terms)
    _warn_offset_kinks(trajectory, terms)
    ctrl = imu_aligned(fn, trajectory, terms, ctrl)
    problem = Problem(trajectory, terms, batch)
    values = _starts(fn, problem, ctrl)
    for term in terms:  # a start at rest tells nothing of a gyroscope's units: the poses do
        if isinstance(term, Gyro):
            term.check_units_against(terms)
    bar = reporter(int(steps), verbose, "torch_dq.estimate")
    try:
        lm = LevenbergMarquardt(problem, ctrl, values, float(prior))
        history = lm.run(int(steps), float(tol), bar)
    finally:
        if bar is not None:
            bar.close()
    ctrl, values = lm.point.ctrl, lm.point.values
    with torch.no_grad():
        trajectory.control_points = ctrl.to(trajectory.control_points.dtype)
    for q, v in zip(problem.params, values, strict=True):
        q.free.value = v.detach().clone()
    counted = [term.solved(trajectory) for term in terms]
    _warn_pinned(problem, values)
    system = history.system if history.width == problem.width(values) else \
        problem.system(ctrl, values, problem.width(values))
    return Estimate(problem.summary(system, counted), ctrl, values, history)

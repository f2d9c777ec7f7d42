r""":func:`fit`: refine a curve module on timestamped poses (a thin case of
:func:`~torch_dq.fitting.estimate` for Levenberg-Marquardt, or any torch optimizer)."""

from __future__ import annotations

import functools
import itertools
import math
import numbers
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from .. import _checks, dualquat
from .._progress import progress
from .._start import check_determined
from .._start import check_sample_times as check_times
from ..losses import pose_loss
from ._estimate import estimate
from ._terms import Poses, _pose_data, check_pose_data

__all__ = ["FitHistory", "fit"]


# ----------------------------------------------------------------------------- history

@dataclass
class FitHistory:
    """What :func:`fit` did.

    Attributes:
        loss: the loss before each optimizer step (``len(loss) == steps``); for ``"lm"``
            the regularised objective it minimises (the loss plus its ``prior`` pull, see
            :func:`fit`; the loss itself at the start).
        steps: number of optimizer steps taken.
        final_loss: the loss of the returned parameters (the best iterate seen).
        converged: True when the stopping test held (the loop stopped there).
        seconds: wall-clock time of the loop.
        best_step: how many optimizer steps led to the returned parameters (0: the start
            was the best; ``steps``: the last iterate).
        optimizer: the optimizer used (``"lm"``, ``"adam"``, ... or its class name).
        reason: what stopped the loop (the stopping test, ``steps``, a non-finite loss, no
            progress of LBFGS, ...).
    """

    loss: list[float] = field(default_factory=list)
    steps: int = 0
    final_loss: float = math.nan
    converged: bool = False
    seconds: float = 0.0
    best_step: int = 0
    optimizer: str = ""
    reason: str = ""


# ----------------------------------------------------------------------------- optimizers

_DEFAULT_LR = {"adam": 1e-2, "sgd": 1e-2, "lbfgs": 1.0}
_NAMES = "'auto', 'lm', 'adam', 'sgd', 'lbfgs', a torch.optim optimizer or a callable(params)"


def _make_optimizer(fn: str, optimizer, params: list, lr: float | None):
    if isinstance(optimizer, str):
        name = optimizer.lower()
        lr = _DEFAULT_LR[name] if lr is None else lr
        if isinstance(lr, bool) or not isinstance(lr, numbers.Real) or not lr > 0:
            _checks.fail(fn, f"lr must be a real number > 0, got {lr!r}")
        if name == "adam":
            return torch.optim.Adam(params, lr=lr)
        if name == "sgd":
            return torch.optim.SGD(params, lr=lr, momentum=0.9)
        return torch.optim.LBFGS(params, lr=lr, line_search_fn="strong_wolfe")
    if lr is not None:
        _checks.fail(fn, "lr applies to named optimizers only; set it in the optimizer or "
                         "factory")
    if isinstance(optimizer, torch.optim.Optimizer):
        return optimizer
    if callable(optimizer):
        opt = optimizer(params)
        if not isinstance(opt, torch.optim.Optimizer):
            _checks.fail(fn, f"the optimizer factory must return a torch.optim.Optimizer, "
                             f"got {type(opt).__name__}", TypeError)
        return opt
    _checks.fail(fn, f"optimizer must be {_NAMES} -> optimizer, got "
                     f"{type(optimizer).__name__}")


def _pose_loss_weights(loss) -> tuple[float, float] | None:
    """``(rot_weight, trans_weight)`` when ``loss`` is :func:`pose_loss` (possibly a
    ``functools.partial`` of it with those keywords), else None."""
    if loss is pose_loss:
        return 1.0, 1.0
    if (isinstance(loss, functools.partial) and loss.func is pose_loss and not loss.args
            and set(loss.keywords) <= {"rot_weight", "trans_weight"}):
        wr = loss.keywords.get("rot_weight", 1.0)
        wt = loss.keywords.get("trans_weight", 1.0)
        if all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
               and float(v) >= 0 for v in (wr, wt)):
            return float(wr), float(wt)
    return None


# ----------------------------------------------------------------------------- problem

class FitProblem:
    r"""What :func:`fit` minimises, built once and shared by all its optimizers.

    It holds the module and its trainable parameters, the times as the module takes them
    (checked once against the curve's domain and, on their basis, for Schoenberg-Whitney),
    the normalised targets and the cost: :meth:`cost` is what every optimizer minimises and
    what :class:`FitHistory` reports. Its kind follows ``loss``:

    - *term* (:attr:`term` a :class:`~torch_dq.fitting.Poses`): a curve layer with
      :func:`~torch_dq.losses.pose_loss` or a ``functools.partial`` of it setting
      ``rot_weight`` / ``trans_weight``. The weights are the term's inverse variances
      (sigmas ``weight ** -0.5``), so :meth:`cost`, the term's cost over the number of
      poses, is ``pose_loss(module(times), targets)``. Levenberg-Marquardt runs
      :func:`~torch_dq.fitting.estimate` on this term (its whitened residuals and Jacobian
      blocks); the torch optimizers minimise the same ``term.cost``.
    - *callable* (:attr:`term` None): any other ``loss`` (a user callable has no residuals
      for Gauss-Newton), or a module that is not a curve layer: :meth:`cost` is
      ``loss(module(times), targets)``, for the torch optimizers only.

    Args:
        fn: the public name for messages.
        module: the module fitted.
        times: ``(N,)`` strictly increasing times in the module's time, or ``(..., N)``
            with a row per trajectory (for a curve layer, the control points' batch).
        poses: ``(..., N, 8)`` dual quaternions or ``(..., N, 4, 4)`` matrices (finite).
        loss: the loss (see above).
        exact: check the samples determine every control point (Schoenberg-Whitney) even
            when there are fewer control points than samples (unregularised least squares).

    Raises:
        ValueError: non-finite or badly shaped poses, bad times (also outside a curve
            layer's domain, or rows that are not the curve's trajectories), a module
            without trainable parameters, an underdetermined curve, targets whose batch does
            not broadcast with the curve's.
        TypeError: non-floating tensors.
    """

    def __init__(self, fn: str, module: torch.nn.Module, times: Tensor, poses: Tensor,
                 loss: Callable[[Tensor, Tensor], Tensor], exact: bool = False) -> None:
        from .._curve import Curve
        poses = _check_poses(fn, poses)
        check_times(fn, times, poses.shape[-2], batched=True)
        self.module, self.loss = module, loss
        self.params = [p for p in module.parameters() if p.requires_grad]
        if not self.params:
            _checks.fail(fn, "module has no parameters that require grad")
        weights = None
        if isinstance(module, Curve):
            like = module.control_points
            self.batch = like.shape[:-2]  # the control points' batch shape
            _check_rows(fn, module, times, self.batch)
            _check_basis(fn, module, times, exact)
            self.times = times.detach().to(like.device)
            weights = _pose_loss_weights(loss)
        else:
            like = self.params[0]
            self.times = times.detach().to(dtype=like.dtype, device=like.device)
        self.target = dualquat.normalize(poses.detach().to(dtype=like.dtype,
                                                           device=like.device))
        self.term = None if weights is None else self._term(fn, weights)

    def _term(self, fn: str, weights: tuple[float, float]) -> Poses:
        """The :class:`Poses` term of ``pose_loss`` with these weights; the targets take the
        batch shape they broadcast to with the control points'."""
        try:
            batch = _checks.broadcast_shapes(self.batch, self.target.shape[:-2])
        except RuntimeError:
            _checks.fail(fn, f"batch shapes do not broadcast: poses "
                             f"{_checks.shape_str(self.target.shape[:-2])}, the module's "
                             f"control points {_checks.shape_str(self.batch)}")
        self.target = self.target.expand(*batch, *self.target.shape[-2:])
        wr, wt = weights
        return Poses(self.times, self.target, rot_sigma=wr ** -0.5 if wr > 0 else math.inf,
                     trans_sigma=wt ** -0.5 if wt > 0 else math.inf)

    def cost(self) -> Tensor:
        """The 0-d cost of the module's current parameters (differentiable)."""
        if self.term is None:
            return self.loss(self.module(self.times), self.target)
        return self.term.cost(self.module).sum() / self.target.shape[:-1].numel()

    def levenberg_marquardt(self, fn: str, steps: int, tol: float, prior: float,
                            verbose: bool, history: FitHistory) -> None:
        """:func:`~torch_dq.fitting.estimate` on :attr:`term`; fills ``history``."""
        assert self.term is not None  # "lm" needs a curve and pose_loss (_resolve_optimizer)
        if self.target.shape[:-2] != self.batch:
            _checks.fail(fn, f"optimizer='lm' needs poses with the module's batch shape "
                             f"{_checks.shape_str(self.batch)}, got poses "
                             f"{_checks.shape_str(self.target.shape)}")
        with warnings.catch_warnings():  # history.converged and .reason say it instead
            warnings.filterwarnings("ignore", r"fitting\.estimate: steps=\d+ reached",
                                    RuntimeWarning)
            est = estimate(self.module, [self.term], steps=steps, tol=tol, prior=prior,
                           verbose=verbose and sys.stderr.isatty())  # a bar on a terminal only
        count = self.target.shape[:-1].numel()
        history.loss = [float(v.sum()) / count for v in est.objective[:-1]] or [
            float(est.objective[0].sum()) / count]
        history.steps = est.steps
        history.converged = bool(est.converged.all())
        history.reason = est.reason
        history.best_step = est.steps
        with torch.no_grad():
            history.final_loss = float(self.cost())


# ----------------------------------------------------------------------------- fit

def fit(module: torch.nn.Module, times: Tensor, poses: Tensor,
        optimizer: str | torch.optim.Optimizer
        | Callable[[list[Tensor]], torch.optim.Optimizer] = "auto",
        steps: int = 500, lr: float | None = None, tol: float = 1e-9, window: int = 10,
        loss: Callable[[Tensor, Tensor], Tensor] = pose_loss, prior: float = 1e-3,
        verbose: bool = True) -> FitHistory:
    r"""Fit a curve module to timestamped poses; the module ends at the best iterate seen.

    Minimises ``loss(module(times), poses)`` (``times`` in the module's own time, the
    caller's units, exactly as for ``module(times)``) over the module's parameters. Every
    optimizer works on one problem built once (the normalised targets, the times' basis,
    the cost), and the loss reported is the one minimised. For a curve layer with
    :func:`~torch_dq.losses.pose_loss` (or a ``functools.partial`` of it setting
    ``rot_weight`` / ``trans_weight``) that cost is a :class:`~torch_dq.fitting.Poses`
    term's, with sigmas ``weight ** -0.5`` (its value is ``pose_loss``'s); any other
    ``loss`` callable, or another module, is evaluated as ``loss(module(times), targets)``
    and needs a torch optimizer.

    - ``optimizer="lm"``: Levenberg-Marquardt on a :class:`~torch_dq.nn.BSpline` or
      :class:`~torch_dq.nn.Bezier`: :func:`~torch_dq.fitting.estimate` with that
      :class:`~torch_dq.fitting.Poses` term (steps in local charts ``ctrl_k exp(delta_k)``,
      body-frame twists, so the fit does not depend on where the world origin is; exact
      Jacobians of the rotation-vector and translation residuals, whose squared norm is
      ``pose_loss``'s term; a banded Gauss-Newton matrix factored in :math:`O(n)`); it only
      accepts steps that lower the objective. One step is one Gauss-Newton iteration;
      stops as :func:`~torch_dq.fitting.estimate` does (converged on its scaled gradient
      test). Regularised by its ``prior``: the combinations of control points that the
      samples barely or do not determine (a time gap longer than a knot span) are pulled
      to where the start put them (:meth:`~torch_dq.nn.BSpline.from_poses` bridges such
      gaps by screw motion); a well-determined fit is not changed. ``prior=0`` gives the
      plain least-squares fit and raises ``ValueError`` when it is underdetermined
      (Schoenberg-Whitney).
    - ``"adam"``, ``"sgd"`` (momentum 0.9), ``"lbfgs"`` (strong Wolfe line search), a
      ``torch.optim.Optimizer`` instance over the module's parameters, or a callable
      ``params -> Optimizer``: each step calls ``optimizer.step(closure)`` on the raw
      control points (they stay unit through the parametrization). Early stopping: after
      ``window`` steps, stop when :math:`|L_{k-w} - L_k| \le tol \cdot |L_{k-w}|` or the
      loss is exactly 0; a non-finite loss stops the loop. The parameters of the lowest
      loss evaluated (including inside LBFGS's line search) are restored at the end.
    - ``"auto"`` (default): ``"lm"`` for a curve layer with a ``pose_loss`` loss and no
      ``lr``, else ``"adam"``.

    Args:
        module: a :class:`~torch_dq.nn.Bezier` / :class:`~torch_dq.nn.BSpline` (or, with
            a torch optimizer, any module mapping ``(N,)`` times to ``(..., N, 8)`` poses).
        times: ``(N,)`` strictly increasing times in the module's time, shared by every
            trajectory; or ``(..., N)``, each row strictly increasing, the times of one
            trajectory: for a curve layer the batch must be its control points' ``(...,
            n, 8)`` batch (a :class:`~torch_dq.nn.BSpline` from
            :meth:`~torch_dq.nn.BSpline.from_poses` with ``(B, N)`` times, whose row ``b``
            of knots covers ``times[b]``; or batched control points on one knot vector,
            each row of times inside its domain), and the fit equals fitting each
            trajectory alone with ``"lm"``. A curve layer takes times as they are (float64
            UNIX seconds with a float32 module are fine); another module gets them cast
            to its parameters' dtype.
        poses: ``(..., N, 8)`` unit dual quaternions or ``(..., N, 4, 4)`` homogeneous
            matrices, cast to the module's dtype and device.
        optimizer: see above.
        steps: maximum number of optimizer steps (``>= 1``).
        lr: learning rate of a named torch optimizer (default 1e-2 for Adam and SGD, 1 for
            LBFGS); must be None with an instance or a factory, and with ``"lm"``.
        tol: relative loss change below which to stop (0: never, for torch optimizers).
        window: steps between the compared losses (``>= 1``; torch optimizers).
        loss: ``loss(pred, target) -> 0-d tensor``; default :func:`torch_dq.losses.pose_loss`
            (mean of rad² + length²; use ``functools.partial(pose_loss, trans_weight=...)``
            to balance the units).
        prior: ``"lm"``: relative weight and threshold of the pull on what the samples do
            not determine (see above and :func:`~torch_dq.fitting.estimate`), ``>= 0``.
        verbose: show a tqdm progress bar when stderr is a terminal and tqdm is installed.

    Returns:
        :class:`FitHistory` with the per-step losses; ``final_loss`` is the loss of the
        returned (best) parameters.

    Raises:
        ValueError: bad shapes, unknown optimizer name, bad ``steps``/``lr``/``tol``/
            ``window``, non-increasing times, times outside the module's domain,
            ``(..., N)`` times whose batch is not the control points' (a single curve
            takes ``(N,)`` times; build one curve per trajectory with
            :meth:`~torch_dq.nn.BSpline.from_poses` and ``(B, N)`` times),
            ``"lm"`` with another loss or module, more control points than samples (and,
            with ``prior=0``, a control point whose support holds no sample of its own).
        TypeError: non-module ``module``, non-floating tensors, a factory that does not
            return an optimizer.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> from torch_dq.nn import BSpline
        >>> t = torch.linspace(0.0, 2.0, 30)
        >>> target = dq.exp(t[:, None] * torch.tensor([0.0, 0.0, 1.0, 0.5, 0.0, 0.0]))
        >>> spline = BSpline(dq.identity((6,)), knots=torch.tensor(
        ...     [0.0, 0, 0, 0, 0.67, 1.33, 2, 2, 2, 2]))  # domain [0, 2] seconds
        >>> history = fit(spline, t, target, verbose=False)  # Levenberg-Marquardt
        >>> history.final_loss < 1e-6 * history.loss[0]
        True
    """
    fn = "nn.fit"
    if not isinstance(module, torch.nn.Module):
        _checks.fail(fn, f"expected a torch.nn.Module for module, got {type(module).__name__}",
                     TypeError)
    steps = _check_count(fn, "steps", steps)
    window = _check_count(fn, "window", window)
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not tol >= 0:
        _checks.fail(fn, f"tol must be a real number >= 0, got {tol!r}")
    if isinstance(prior, bool) or not isinstance(prior, numbers.Real) or not (
            math.isfinite(prior) and prior >= 0):
        _checks.fail(fn, f"prior must be a finite real number >= 0, got {prior!r}")
    if not callable(loss):
        _checks.fail(fn, f"expected a callable for loss, got {type(loss).__name__}", TypeError)
    from .._curve import Curve
    name = _resolve_optimizer(fn, optimizer, isinstance(module, Curve), loss, lr)
    problem = FitProblem(fn, module, times, poses, loss, exact=name == "lm" and prior == 0)
    history = FitHistory(optimizer=name or type(optimizer).__name__)
    start = time.perf_counter()
    if name == "lm":
        problem.levenberg_marquardt(fn, steps, tol, prior, verbose, history)
    else:
        bar = progress(steps, verbose and sys.stderr.isatty(), "torch_dq.fit")
        try:
            opt = _make_optimizer(fn, name if name is not None else optimizer,
                                  problem.params, lr)
            _torch_loop(problem, opt, steps, tol, window, history, bar)
        finally:
            if bar is not None:
                bar.close()
    history.seconds = time.perf_counter() - start
    return history


def _check_poses(fn: str, poses) -> Tensor:
    """``(..., N, 8)`` finite target poses (matrices converted; rigid ones, with non-zero
    rotations: the measurement terms' check)."""
    poses, matrices = _pose_data(fn, "poses", poses)  # detached, as fit's targets are
    bad = ~torch.isfinite(poses).all(-1)
    if bool(bad.any()):
        where = bad.nonzero()[0].tolist()
        _checks.fail(fn, f"poses must be finite: {int(bad.sum())} non-finite pose(s), the "
                         f"first at index {tuple(where)}; drop or mask them before fitting")
    valid = torch.ones(poses.shape[:-1], dtype=torch.bool, device=poses.device)
    check_pose_data(fn, "poses", poses, matrices, valid)
    return poses


def _check_rows(fn: str, module, times: Tensor, batch: torch.Size) -> None:
    """``(..., N)`` times: one row per trajectory, their batch the control points'."""
    if times.dim() == 1 or times.shape[:-1] == batch:
        return
    if batch == torch.Size():
        _checks.fail(fn, f"times {_checks.shape_str(times.shape)} give a row per trajectory "
                         f"but the module is one curve (control points "
                         f"{_checks.shape_str(module.control_points.shape)}): pass (N,) "
                         f"times, or build one curve per row with "
                         f"torch_dq.nn.BSpline.from_poses(..., times (B, N), ...)")
    rows = ", ".join(str(b) for b in batch)
    _checks.fail(fn, f"times {_checks.shape_str(times.shape)} must have a row per trajectory "
                     f"of the module: expected shape ({rows}, N) for "
                     f"control points {_checks.shape_str(module.control_points.shape)}")


def _check_basis(fn: str, module, times: Tensor, exact: bool) -> None:
    """Times inside the curve's domain; with more control points than samples, or for the
    unregularised least squares (``exact``), samples that determine every control point
    (Schoenberg-Whitney, on the times' basis), row by row for ``(..., N)`` times or a row
    of knots per trajectory."""
    t = times.detach()
    knots = getattr(module, "knots", None)
    rows = knots is not None and knots.dim() > 1  # the basis broadcasts times and knots
    try:
        first, values = module.basis(t if rows or t.dim() == 1 else t.reshape(-1))
    except ValueError as e:  # times outside the module's domain: say who was called
        raise ValueError(f"{fn}: {e}") from None
    first, values = first.cpu(), values.cpu()
    if not rows:  # one knot vector for every row of times
        first, values = first.view(t.shape), values.view(*t.shape, -1)
        knots = None if knots is None else knots.expand(*t.shape[:-1], -1)
    if module.n_ctrl <= values.shape[-2] and not exact:
        return
    for row in itertools.product(*map(range, first.shape[:-1])):  # () for one row
        try:
            check_determined(fn, first[row], values[row], module.n_ctrl,
                             None if knots is None else knots[row].cpu())
        except ValueError as e:  # name the trajectory
            raise ValueError(f"{e} (trajectory {row})" if row else str(e)) from None


def _resolve_optimizer(fn: str, optimizer, curve: bool, loss, lr) -> str | None:
    """The optimizer's name (None for an instance or a factory), ``"auto"`` resolved."""
    if not isinstance(optimizer, str):
        return None
    name = optimizer.lower()
    if name not in ("auto", "lm", *_DEFAULT_LR):
        _checks.fail(fn, f"optimizer must be {_NAMES} -> optimizer, got {optimizer!r}")
    weights = _pose_loss_weights(loss)
    if name == "auto":
        return "lm" if curve and weights is not None and lr is None else "adam"
    if name == "lm":
        if not curve:
            _checks.fail(fn, "optimizer='lm' fits a torch_dq.nn.BSpline or Bezier (a curve "
                             "layer); use optimizer='adam' for another module")
        if weights is None:
            _checks.fail(fn, "optimizer='lm' minimises pose_loss: pass loss=pose_loss or "
                             "functools.partial(pose_loss, rot_weight=..., trans_weight=...)")
        if lr is not None:
            _checks.fail(fn, "lr applies to the torch optimizers, not to optimizer='lm'")
    return name


def _check_count(fn: str, name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        _checks.fail(fn, f"{name} must be an int >= 1, got {value!r}")
    return int(value)


def _torch_loop(problem: FitProblem, opt, steps: int, tol: float, window: int,
                history: FitHistory, bar) -> None:
    """``optimizer.step(closure)`` loop on ``problem.cost()`` with early stopping; restores
    the best iterate (the start when no finite loss was seen), so the module never ends
    worse than it came in."""
    params = problem.params
    initial = [p.detach().clone() for p in params]
    best: dict[str, Any] = {"loss": math.inf, "params": None, "step": 0}

    def closure():
        opt.zero_grad(set_to_none=True)
        value = problem.cost()
        v = float(value.detach())
        if v < best["loss"]:  # the parameters that gave it, before the step changes them
            best.update(loss=v, params=[p.detach().clone() for p in params],
                        step=history.steps)
        value.backward()
        return value

    history.reason = f"steps={steps} reached"
    for k in range(steps):
        before = [p.detach().clone() for p in params]
        value = float(opt.step(closure).detach())
        history.loss.append(value)
        history.steps = k + 1
        if bar is not None:
            bar.update(1)
            if k % 10 == 0:
                bar.set_postfix(loss=f"{value:.3e}")
        if not math.isfinite(value):
            history.reason = "non-finite loss"
            break
        if all(torch.equal(a, b) for a, b in zip(before, params, strict=True)):
            history.reason = _stalled(opt)
            break
        if value == 0.0 or (k >= window and tol > 0 and
                            abs(history.loss[k - window] - value)
                            <= tol * abs(history.loss[k - window])):
            history.converged = True
            history.reason = "zero loss" if value == 0.0 else (
                f"relative change over window={window} steps below tol={tol!r}")
            break
    _restore(problem, initial, best, history)


def _stalled(opt) -> str:
    """Why a step left the parameters unchanged (LBFGS: its own tolerances)."""
    if isinstance(opt, torch.optim.LBFGS):
        group = opt.param_groups[0]
        return (f"LBFGS made no progress: its stopping tests (tolerance_grad="
                f"{group['tolerance_grad']!r}, tolerance_change={group['tolerance_change']!r})"
                f" held before any move; pass optimizer=lambda p: torch.optim.LBFGS(p, "
                f"tolerance_grad=...) or use optimizer='lm'")
    return f"{type(opt).__name__} step left the parameters unchanged"


def _restore(problem: FitProblem, initial: list[Tensor], best: dict[str, Any],
             history: FitHistory) -> None:
    """Put back the best parameters seen (or the start), set ``final_loss``."""
    with torch.no_grad():
        final = float(problem.cost())
        saved = best["params"] if best["params"] is not None else initial
        if not final <= best["loss"]:
            for p, value in zip(problem.params, saved, strict=True):
                p.copy_(value)
            final = float(problem.cost())
            history.best_step = best["step"]
        else:
            history.best_step = history.steps
    history.final_loss = final

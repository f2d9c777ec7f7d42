r"""Knots from the data: the B-spline knot spacing chosen by an inner hold-out.

:func:`choose_knot_spacing` (re-exported as ``torch_dq.fitting.choose_knot_spacing``) picks the
seconds between knots of a B-spline fitted to timestamped poses, so that nobody has to tune
it by hand (kontiki ships a helper with the same aim). It never looks at poses held out by
the caller: it splits the poses it is given once more,

1. *inner fit*: all but every :data:`CHECK_EVERY`-th pose (80 % of them, the first and the
   last included); *inner check*: the others, each between two fitted neighbours, as the
   caller's held-out poses are;
2. for candidate spacings of a geometric grid (from the finest the inner fit determines,
   ``n_ctrl <= N_inner``, upwards in steps of :data:`GRID_RATIO`; coarse to fine: every
   other one until an error has clearly risen past its lowest, then the ones between
   next to those near the lowest, where the choice lies), builds the least-squares
   start of :meth:`torch_dq.nn.BSpline.from_poses` on the inner fit (the same knots and
   :func:`torch_dq._start.least_squares_start`, evaluated by :func:`torch_dq.curves.bspline`,
   so that the layers can use this module: it imports no layer; no refinement: O(N) per
   candidate, so the search takes seconds on 10^4 poses) and measures the mean rotation
   angle and translation error at the inner-check poses;
3. keeps the *largest* spacing whose two errors are both within ``tolerance`` (2 %) of the
   best of their kind: the smoothest curve that fits as well as the best one, which does
   not chase noise;
4. for all the poses given: where that candidate is within :data:`DATA_LIMIT_STEPS` grid
   steps of the finest (*data-limited*: the errors still fall as the knots get as fine as
   the data allow, as on 10 Hz car-like data), the finest spacing all the poses determine
   (``n_ctrl = N``); elsewhere (*noise-limited*) the candidate scaled by the density ratio
   (about 0.8), never below that finest. The best spacing of a regression spline does not
   scale with the density where noise matters (theory: as ``N^(-1/(2p+3))``); halving it,
   as an even/odd split would ask, fits knots to the noise and makes the derivatives noisy.

The errors of the whole curve are then measured by the caller on its own held-out poses,
which the choice never saw. The spacing is in the time unit of ``times`` (seconds).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import _checks, _start, curves, dualquat, losses, quat
from .._curve import UnitDualQuaternion
from .._time import KnotDomain

__all__ = ["CHECK_EVERY", "DATA_LIMIT_STEPS", "FINEST_PER_POSE", "GRID_RATIO", "SpacingSearch",
           "check_fineness", "choose_knot_spacing", "errors_at", "finest_spacing", "inner_split",
           "knot_spacing_search", "n_ctrl", "round_down", "round_up"]

#: Ratio between consecutive candidate spacings.
GRID_RATIO = 2 ** 0.25

#: The inner check takes every ``CHECK_EVERY``-th pose: the inner fit keeps 80 % of the
#: density, so the spacing chosen there needs little scaling (the best spacing of a
#: regression spline does not scale with the density where noise matters).
CHECK_EVERY = 5

#: A candidate chosen within this many grid steps of the finest that the inner fit
#: determines means the data limit the spacing (the errors still fall, or are noisy, as the
#: knots get as fine as the data allow): then the finest that all the poses determine.
DATA_LIMIT_STEPS = 2

#: At most this many candidates (from the finest up: a factor 2^(24/4) = 64 in spacing).
MAX_CANDIDATES = 25


@dataclass(frozen=True)
class SpacingSearch:
    """What :func:`knot_spacing_search` tried and chose.

    Attributes:
        spacing: the chosen spacing for all the poses (the time unit of ``times``), rounded
            up to 4 digits: the finest they determine when ``data_limited``, else the chosen
            candidate scaled by ``scale`` (never below that finest).
        candidates: the spacings tried on the inner fit, increasing.
        rot_mean: mean rotation error (rad) of each candidate at the inner-check poses.
        trans_mean: mean translation error (the poses' unit) of each, likewise.
        chosen: index of the chosen candidate.
        best: index of the candidate with the lowest errors (the smallest worse of the two
            ratios to their minima).
        tolerance: the relative margin used.
        n_fit: poses of the inner fit; ``n_check``: poses of the inner check; ``n``: all.
        degree: the B-spline degree.
        n_ctrl_fit: control points of the chosen candidate on the inner fit.
        form: the B-spline form (``"de_boor"``, ``"cumulative"`` or ``"split"``).
        data_limited: the chosen candidate is within :data:`DATA_LIMIT_STEPS` grid steps
            of the finest the inner fit determines.
        scale: the inner fit's mean time step over that of all the poses (about 0.8).
    """

    spacing: float
    candidates: tuple[float, ...]
    rot_mean: tuple[float, ...]
    trans_mean: tuple[float, ...]
    chosen: int
    best: int
    tolerance: float
    n_fit: int
    n_check: int
    n: int
    degree: int
    n_ctrl_fit: int
    form: str
    data_limited: bool
    scale: float

    @property
    def near_limit(self) -> bool:
        """The chosen candidate has more control points than 80 % of the inner fit's poses
        (where a refinement may chase noise: the ``fit`` command checks it on the inner
        split)."""
        return self.n_ctrl_fit > 0.8 * self.n_fit

    def reason(self) -> str:
        """What was tried, what was chosen and why, in two sentences (the command line
        prints it; units: seconds, degrees, millimetres for metre poses)."""
        i, c = self.chosen, self.candidates
        tried = (f"tried {len(c)} spacings from {c[0]:.4g} s to {c[-1]:.4g} s (grid ratio "
                 f"2^(1/4), coarse to fine),"
                 f" each fitted to {self.n_fit} of the {self.n} poses and checked on the "
                 f"other {self.n_check}")
        within = (self.rot_mean[i] <= (1 + self.tolerance) * min(self.rot_mean) + 1e-15
                  and self.trans_mean[i] <= (1 + self.tolerance) * min(self.trans_mean) + 1e-15)
        how = (f"is the largest whose mean errors ({{}}) are within {100 * self.tolerance:g} % "
               f"of" if within else "has the best balance of mean errors ({}) against")
        chosen = (f"{c[i]:.4g} s " + how.format(f"{math.degrees(self.rot_mean[i]):.3g} deg, "
                                                f"{1e3 * self.trans_mean[i]:.3g} mm") +
                  f" the lowest "
                  f"({math.degrees(min(self.rot_mean)):.3g} deg, "
                  f"{1e3 * min(self.trans_mean):.3g} mm)")
        if self.data_limited:
            return (f"{tried}; {chosen}, within {DATA_LIMIT_STEPS} steps of the finest those "
                    f"{self.n_fit} poses determine: the data, not their noise, limit the "
                    f"spacing, so the finest all {self.n} poses determine: {self.spacing:.4g} s")
        return (f"{tried}; {chosen}: noise, not the data, limits it, so it is scaled only by "
                f"the density ratio {self.scale:.3g}: {self.spacing:.4g} s")


def n_ctrl(duration: float, spacing: float, degree: int) -> int:
    """Control points of clamped uniform knots at most ``spacing`` apart over ``duration``."""
    return math.ceil(duration / spacing - 1e-9) + degree


#: ``BSpline.from_poses(knot_spacing=)`` refuses a spacing more than this many times finer
#: than the poses' mean spacing (an IMU at 1 kHz with 5 samples per knot span under 1 Hz
#: poses asks for 200): finer is a unit mistake (nanosecond times with a spacing in
#: seconds asked for 3e10 control points, 960 GB).
FINEST_PER_POSE = 1000


def check_fineness(fn: str, t64: Tensor, knot_spacing: float, degree: int,
                   margin: float) -> None:
    """``BSpline.from_poses(knot_spacing=)``'s check: refuse a ``knot_spacing`` more than
    :data:`FINEST_PER_POSE` times finer than the mean spacing of the poses at float64 times
    ``t64 (..., N)`` (the longest row's), before anything of that size is allocated; the
    message gives the control points it needs (over the span widened by ``margin`` at each
    end), the spacing that works and, for times that look like UNIX nanoseconds (or micro-,
    milli-), the unit."""
    N = t64.shape[-1]
    duration = float((t64[..., -1] - t64[..., 0]).max())
    mean = duration / (N - 1)
    if knot_spacing * FINEST_PER_POSE >= mean:
        return
    spans = (duration + 2 * margin) / knot_spacing  # finite: knot_spacing is a normal float
    count = math.ceil(spans - 1e-9) + degree if spans < 1e15 else f"{spans + degree:.3g}"
    unit = _checks.unix_unit(float(t64.abs().max()))
    hint = (f" (the times look like UNIX {unit[0]}: pass seconds, times * {unit[1]:g})"
            if unit and float(t64.abs().max()) >= _checks.LATEST else "")
    _checks.fail(fn, f"knot_spacing={knot_spacing!r} is more than {FINEST_PER_POSE} times "
                     f"finer than the poses' mean spacing {mean:.6g} (the times' units): it "
                     f"needs {count} control points for N = {N} poses{hint}; pass "
                     f"knot_spacing={round_up(mean / FINEST_PER_POSE):g} or more, in the "
                     f"times' units")


def finest_spacing(duration: float, n_samples: int, degree: int) -> float:
    """The smallest spacing whose ``n_ctrl`` does not exceed ``n_samples``, rounded up to 4
    significant digits (so that the number, written as printed, still works)."""
    if n_samples <= degree:
        return math.inf
    return round_up(duration / (n_samples - degree))


def round_up(value: float, digits: int = 4) -> float:
    """``value`` rounded up to ``digits`` significant digits (a hint followed literally must
    work: rounding down could ask for one control point too many)."""
    if not (math.isfinite(value) and value > 0):
        return value
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(value)))
    up = math.ceil(value * scale - 1e-9) / scale
    return float(f"{up:.{digits}g}")


def round_down(value: float, digits: int = 4) -> float:
    """``value`` rounded down to ``digits`` significant digits (for an upper bound that a
    hint states: followed literally, it must work)."""
    if not (math.isfinite(value) and value > 0):
        return value
    scale = 10.0 ** (digits - 1 - math.floor(math.log10(value)))
    return float(f"{math.floor(value * scale + 1e-9) / scale:.{digits}g}")


def _unit64(poses: Tensor) -> Tensor:
    """``(N, 8)`` the poses as ``BSpline.from_poses`` takes them: rotations normalised,
    float64."""
    q, p = dualquat.to_rt(poses)
    return dualquat.from_rt(quat.normalize(q), p).to(torch.float64)


def _start_poses(times: Tensor, x64: Tensor, dtype: torch.dtype, spacing: float, degree: int,
                 form: str, at: Tensor) -> Tensor:
    """Poses at ``at`` of the least-squares start with knots at most ``spacing`` apart over
    ``times``, fitted to ``x64`` (:func:`_unit64` of poses of ``dtype``): what
    ``BSpline.from_poses(..., n_ctrl=n_ctrl(duration, spacing, degree))`` followed by a call
    at ``at`` gives (its knots, its start, in the poses' dtype)."""
    n = n_ctrl(float(times[-1] - times[0]), spacing, degree)
    t0, t1 = float(times[0]), float(times[-1])
    k64 = t0 + curves.clamped_uniform_knots(n, degree, dtype=torch.float64) * (t1 - t0)
    dom = KnotDomain((k64 - t0).to(dtype), degree, t0)  # as the layer holds them
    rel = dom.relative(times, torch.float64)
    first, values = dom.basis(rel)
    ctrl = _start.least_squares_start("fitting.choose_knot_spacing", x64, rel, first, values,
                                      n, dom.greville(), form == "split").to(dtype)
    unit = UnitDualQuaternion()  # the layer's control points: assigned, then read
    ctrl = unit(unit.right_inverse(ctrl))
    return curves.bspline(ctrl, dom.relative(at, torch.float64), degree, dom.knots,
                          check=False, extrapolate=True, form=form)


def errors_at(pred: Tensor, poses: Tensor) -> tuple[float, float]:
    """Mean rotation (rad) and translation errors of poses ``pred`` against ``poses``."""
    pred = pred.detach().to(poses.dtype)
    rot = losses.rotation_angle(pred, poses).double()
    trans = losses.translation_error(pred, poses).double()
    return float(rot.mean()), float(trans.mean())


def _scores(times: Tensor, x64: Tensor, at: Tensor, target: Tensor, spacing: float,
            degree: int, form: str) -> tuple[float, float]:
    """Mean rotation (rad) and translation errors at the times ``at`` against ``target`` of
    the start fitted to ``x64`` at ``times`` (the start's warnings about coarse knots are the
    search's business: silenced)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pred = _start_poses(times, x64, target.dtype, spacing, degree, form, at)
    return errors_at(pred, target)


def inner_split(n: int) -> tuple[Tensor, Tensor]:
    """Indices of the inner fit (all but every :data:`CHECK_EVERY`-th pose; the first and
    the last among them) and of the inner check (the others)."""
    check = torch.zeros(n, dtype=torch.bool)
    check[CHECK_EVERY // 2::CHECK_EVERY] = True
    check[0] = check[-1] = False
    return (~check).nonzero().squeeze(1), check.nonzero().squeeze(1)


def _check_args(fn: str, times: Tensor, poses: Tensor, degree: int, tolerance: float) -> None:
    _checks.tensor(fn, "poses", poses, 8)
    _checks.tensor(fn, "times", times, None)
    if times.dim() != 1 or poses.dim() != 2 or poses.shape[0] != times.shape[0]:
        _checks.fail(fn, f"expected times (N,) and poses (N, 8), got "
                         f"{_checks.shape_str(times.shape)} and "
                         f"{_checks.shape_str(poses.shape)}")
    _checks.integer(fn, "degree", degree, 1)
    _checks.real(fn, "tolerance", tolerance, "a number in [0, 1)", lambda v: 0 <= v < 1)
    t = times.detach()
    if not bool(torch.isfinite(t).all()) or not bool((t[1:] > t[:-1]).all()):
        _checks.fail(fn, "times must be finite and strictly increasing")
    if not bool(torch.isfinite(poses.detach()).all()):
        _checks.fail(fn, "poses must be finite")
    if times.shape[0] < 2 * (degree + 2):
        _checks.fail(fn, f"needs at least {2 * (degree + 2)} poses for degree {degree} (half "
                         f"of them fit, half check), got {times.shape[0]}")


def _grid(duration: float, n_fit: int, degree: int) -> list[float]:
    """The candidate spacings: from the finest the inner fit determines up, in steps of
    :data:`GRID_RATIO` (each rounded up to 4 digits), at most :data:`MAX_CANDIDATES`, while
    they leave more than ``degree`` control points."""
    grid = [finest_spacing(duration, n_fit, degree)]
    while len(grid) < MAX_CANDIDATES and n_ctrl(duration, grid[-1], degree) > degree:
        grid.append(round_up(grid[-1] * GRID_RATIO))
    return grid if n_ctrl(duration, grid[-1], degree) > degree else grid[:-1]


def _coarse_to_fine(score, size: int, tolerance: float) -> dict[int, tuple[float, float]]:
    r"""Scores ``{grid index: (rot, trans)}`` of the grid points :func:`knot_spacing_search`
    needs, ``score(i)`` computing one: every other point from the finest up until either
    error passes :math:`1 + 10\,tol` (at most 2) times its lowest so far (coarser knots
    only get worse, and the choice needs both errors within :math:`1 + tol` of their
    lowest), then the points between whose neighbour is *near* the best (both errors
    within :math:`1 + 8\,tol` of the lowest), until none is left. The choice (the lowest
    errors, the largest point within ``tol`` of them) lies among those."""
    stop, near = min(2.0, 1.0 + 10.0 * tolerance), 1.0 + 8.0 * tolerance
    scores: dict[int, tuple[float, float]] = {}
    for i in range(0, size, 2):
        scores[i] = score(i)
        lows = [min(v) for v in zip(*scores.values(), strict=True)]
        if any(e > stop * low + 1e-12 for e, low in zip(scores[i], lows, strict=True)):
            break
    top = max(scores)
    while True:
        lows = [min(v) for v in zip(*scores.values(), strict=True)]
        close = [i for i, e in scores.items()
                 if all(v <= near * low + 1e-15 for v, low in zip(e, lows, strict=True))]
        todo = sorted({j for i in close for j in (i - 1, i + 1)
                       if 0 <= j <= top and j not in scores})
        if not todo:
            return scores
        for j in todo:
            scores[j] = score(j)


def knot_spacing_search(times: Tensor, poses: Tensor, degree: int = 3, *,
                        tolerance: float = 0.02, form: str = "de_boor") -> SpacingSearch:
    r"""The knot spacing search of :func:`choose_knot_spacing`, with what it tried.

    Args and Raises: as :func:`choose_knot_spacing`.

    Returns:
        :class:`SpacingSearch` (``.spacing`` is the choice, ``.reason()`` says why).
    """
    fn = "choose_knot_spacing"
    _check_args(fn, times, poses, degree, tolerance)
    if form not in ("de_boor", "cumulative", "split"):
        _checks.fail(fn, f"form must be 'de_boor', 'cumulative' or 'split', got {form!r}")
    # on the CPU whatever the inputs' device: the search's results are host numbers, and its
    # many small least-squares starts would be launch-bound on an accelerator
    times = times.detach().to("cpu", torch.float64)
    poses = poses.detach().cpu()
    fit, check = inner_split(times.shape[0])
    duration = float(times[fit][-1] - times[fit][0])
    grid = _grid(duration, fit.shape[0], degree)
    inner = (times[fit], _unit64(poses[fit]), times[check], poses[check])
    scores = _coarse_to_fine(lambda i: _scores(*inner, grid[i], degree, form), len(grid),
                             tolerance)
    index = sorted(scores)
    candidates = [grid[i] for i in index]
    rot, trans = [scores[i][0] for i in index], [scores[i][1] for i in index]
    rot_best, trans_best = min(rot), min(trans)
    ratio = [max(r / max(rot_best, 1e-300), p / max(trans_best, 1e-300))
             for r, p in zip(rot, trans, strict=True)]
    best = min(range(len(ratio)), key=ratio.__getitem__)
    ok = [i for i, (r, p) in enumerate(zip(rot, trans, strict=True))
          if r <= (1 + tolerance) * rot_best + 1e-15 and p <= (1 + tolerance) * trans_best + 1e-15]
    chosen = max(ok) if ok else best
    whole = float(times[-1] - times[0])
    finest = finest_spacing(whole, times.shape[0], degree)
    scale = (whole / (times.shape[0] - 1)) / (duration / (fit.shape[0] - 1))
    limited = index[chosen] <= DATA_LIMIT_STEPS
    spacing = finest if limited else max(round_up(candidates[chosen] * scale), finest)
    return SpacingSearch(spacing, tuple(candidates), tuple(rot), tuple(trans), chosen, best,
                         float(tolerance), int(fit.shape[0]), int(check.shape[0]),
                         int(times.shape[0]), degree,
                         n_ctrl(duration, candidates[chosen], degree), form, limited, scale)


def choose_knot_spacing(times: Tensor, poses: Tensor, degree: int = 3, *,
                        tolerance: float = 0.02, form: str = "de_boor") -> float:
    r"""Seconds between knots for a B-spline fitted to these poses, chosen from the data.

    Splits the poses into an inner fit (all but every 5th) and an inner check (every 5th),
    fits the least-squares start (:meth:`torch_dq.nn.BSpline.from_poses`) on the inner fit
    for a geometric grid of spacings (ratio :math:`2^{1/4}`, from the finest that the inner
    fit determines), and takes the largest spacing whose mean rotation and translation
    errors at the inner check are both within ``tolerance`` of the best ones. Within two grid
    steps of the finest (the data limit the spacing) it returns the finest spacing all ``N``
    poses determine; otherwise (noise limits it) the spacing scaled by the density ratio
    (about 0.8), never below that finest (see :mod:`torch_dq.fitting._knots`). Pass only the poses
    you fit: poses held out to measure the fit must not be among them. Costs one O(N)
    least-squares start per candidate tried (about a second for 10^4 poses).

    Args:
        times: ``(N,)`` strictly increasing times (float64 UNIX seconds welcome).
        poses: ``(N, 8)`` unit dual quaternions at ``times``.
        degree: B-spline degree.
        tolerance: relative margin on the best errors (default 2 %).
        form: the B-spline form the curve will use (:class:`torch_dq.nn.BSpline`).

    Returns:
        The spacing in the unit of ``times``; with it, ``n_ctrl = ceil(duration / spacing) +
        degree`` never exceeds the ``N`` poses.

    Raises:
        ValueError: bad shapes, non-finite or unsorted times, non-finite poses, fewer than
            ``2 (degree + 2)`` poses, a bad ``degree``, ``tolerance`` or ``form``.
        TypeError: non-floating tensors.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> t = torch.linspace(0.0, 10.0, 201, dtype=torch.float64)
        >>> xi = torch.stack((torch.sin(t), 0 * t, 0 * t, t, torch.cos(t), 0 * t), -1)
        >>> h = choose_knot_spacing(t, dq.exp(xi))
        >>> 0.05 <= h <= 2.0
        True
    """
    return knot_spacing_search(times, poses, degree, tolerance=tolerance, form=form).spacing

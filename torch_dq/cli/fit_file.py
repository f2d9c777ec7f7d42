r"""The application behind ``python -m torch_dq fit FILE``: fit a B-spline to a trajectory file.

Reads a TUM, KITTI or EuRoC trajectory (:func:`torch_dq.io.read_trajectory`, float64 times
in the file's own seconds, UNIX seconds included; times that the reader finds to be
nanoseconds, microseconds or milliseconds are converted to seconds here, with a printed
note, where :func:`~torch_dq.io.read_trajectory` itself keeps them and warns), then

1. *split*: every ``holdout``-th pose (and the last) is fitted, the others are held out to
   measure the fit (``holdout=1``: fit all, report the fit residuals);
2. *fit*: chooses the knot spacing from the fitted poses alone
   (:func:`torch_dq.fitting.choose_knot_spacing`, ``knot_spacing="auto"``, the default) or
   takes the one given, builds the least-squares start
   :meth:`torch_dq.nn.BSpline.from_poses` and refines it with :func:`torch_dq.nn.fit`
   (progress bar on a terminal, tqdm optional) where that pays (``refine="auto"``: one
   Gauss-Newton step would lower the rotation or the translation part of the fitted poses'
   cost by more than :data:`REFINE_GAIN`, 1 %, of it; ``torch_dq.cli._refine``);
3. *report*: prints the spacing and why, the held-out errors (translation in mm, rotation
   in degrees: mean, median, max) and the fit time;
4. *write*: to the output folder ``trajectory.csv`` (the curve resampled at ``rate`` Hz with
   world-frame velocities and accelerations, :func:`torch_dq.io.write_csv`), ``spline.pt``
   (the module's ``state_dict``), ``summary.json`` and the figures of
   ``torch_dq.cli.fit_plots``.

The input is never written to; a folder holding the results of an earlier run is refused
unless ``overwrite=True``. Options the data cannot satisfy raise :class:`OptionError`, whose
message names a value that works (hints are rounded so that, used literally, they work).
Matplotlib is optional (``pip install 'torch_dq[plot]'``): without it the figures are
skipped with a one-line notice.

Reload the fitted curve (control points, degree, knots, form, time origin) with::

    spline = torch_dq.nn.BSpline.from_state_dict(torch.load("spline.pt"))

Example:
    >>> from torch_dq.cli.fit_file import run_fit
    >>> summary = run_fit("tests/data/tum_fr1_xyz_sub.txt", out="/tmp/fit",
    ...                   steps=5, plots=False, verbose=False)  # doctest: +SKIP
    >>> summary["heldout_errors"]["translation_mm"]["median"]  # doctest: +SKIP
"""

from __future__ import annotations

import errno
import functools
import inspect
import json
import math
import os
import time
import warnings
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from .. import _checks, dualquat, io
from .. import nn as dqnn
from .._report import evaluate, import_matplotlib, no_matplotlib, pose_errors, say_warnings
from ..fitting import _knots
from ._errors import OptionError
from ._fit_input import read_seconds
from ._refine import predicted_gain

__all__ = ["DEFAULTS", "FIGURES", "MAX_RESAMPLED", "OUTPUTS", "REFINE_GAIN", "REFINE_TOL",
           "FitResult", "OptionError", "run_fit"]

#: Figures written when matplotlib is available.
FIGURES = ("components.png", "kinematics.png", "residuals.png")

#: Files always written.
OUTPUTS = ("trajectory.csv", "spline.pt", "summary.json")

#: At most this many rows in ``trajectory.csv`` (``--rate`` is bounded by the duration).
MAX_RESAMPLED = 1_000_000

#: ``tol`` of the refinement (:func:`torch_dq.nn.fit`'s scaled gradient test): it stops
#: once the Newton decrement left is at most this fraction of the objective. After one
#: Gauss-Newton step from the least-squares start that is ~3e-8 on the TUM files (the
#: held-out errors equal to 5 digits those of ``tol=1e-9``, which takes a second step).
REFINE_TOL = 1e-7

#: ``refine="auto"``: the least-squares start is kept (no Levenberg-Marquardt) where one
#: Gauss-Newton step from it would lower neither the rotation nor the translation part of
#: the fitted poses' cost by more than this fraction of that part
#: (``torch_dq.cli._refine.predicted_gain``): the step would move the curve by at most
#: ~10 % of the residuals (0.4-0.9 % on TUM's 200 Hz motion capture, where the held-out
#: errors of the start and of the refined curve agree to within 1 % either way).
REFINE_GAIN = 0.01

#: The gap note adds that gaps limit the knot spacing where they take more than this
#: fraction of the span (uniform knots put control points there too, and ``n_ctrl`` is at
#: most the fitted poses' count: 10 s of gap in 16 s of 50 Hz poses coarsen the spacing
#: from 0.081 s to 0.108 s, held-out errors 23 % higher than without the gap).
GAP_SHARE = 0.25


@dataclass
class FitResult:
    """What the figures and the report need from one fit (times in seconds, float64).

    Attributes:
        traj: the file's poses (:class:`torch_dq.io.Trajectory`); ``poses`` their ``(N, 8)``
            unit dual quaternions.
        fit_idx, held_idx: indices of the fitted and held-out poses.
        spline: the fitted :class:`torch_dq.nn.BSpline`.
        pred: ``(N, 8)`` the curve at every pose's time (float64).
        rot_deg, trans_mm: ``(N,)`` the curve's error at every pose.
        grid: ``(M,)`` the resampling times; ``x`` the curve there, ``kin`` its world-frame
            kinematics (float64); ``in_gap`` ``(M,)`` bool: inside a gap between poses longer
            than 2 knot spacings (no data there).
    """

    traj: io.Trajectory
    poses: Tensor
    fit_idx: Tensor
    held_idx: Tensor
    spline: Any
    pred: Tensor
    rot_deg: Tensor
    trans_mm: Tensor
    grid: Tensor
    x: Tensor
    kin: Any
    in_gap: Tensor

    @property
    def t0(self) -> float:
        """The first pose's time (s)."""
        return float(self.traj.times[0])

    @property
    def report_idx(self) -> Tensor:
        """Indices of the poses whose errors are reported (the held-out ones; the fitted
        ones when none is held out)."""
        return self.held_idx if len(self.held_idx) else self.fit_idx


# ----------------------------------------------------------------------------- options

def _check_options(knot_spacing, degree, form, holdout, steps, rate) -> None:
    if form not in ("de_boor", "cumulative", "split"):
        raise ValueError(f"fit: form must be 'de_boor', 'cumulative' or 'split', got {form!r}")
    for name, value, low in (("degree", degree, 1), ("holdout", holdout, 1), ("steps", steps, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"fit: {name} must be an int >= {low}, got {value!r}")
    if knot_spacing != "auto" and not (
            isinstance(knot_spacing, (int, float)) and not isinstance(knot_spacing, bool)
            and math.isfinite(knot_spacing) and knot_spacing > 0):
        raise ValueError(f"fit: knot_spacing must be 'auto' or a finite number of seconds > 0, "
                         f"got {knot_spacing!r}")
    if rate is not None and not (isinstance(rate, (int, float)) and math.isfinite(rate)
                                 and rate > 0):
        raise ValueError(f"fit: rate must be a finite number of Hz > 0, got {rate!r}")


def _same_file(a: str, b: str) -> bool:
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.normcase(os.path.abspath(a)) == os.path.normcase(os.path.abspath(b))


def _check_out(out: str, inputs: list[str], overwrite: bool, plots: bool) -> None:
    """Never write over an input; refuse earlier results unless ``overwrite``; ``out`` must
    be a folder (or not exist yet)."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise OptionError(f"--out {out} is a file, not a folder: choose a folder (it is made "
                          f"if missing)")
    names = OUTPUTS + (FIGURES if plots else ())
    for name in names:
        for source in inputs:
            if _same_file(os.path.join(out, name), source):
                raise OptionError(f"--out {out} would overwrite the input {source} (the fit "
                                  f"writes {name} there): choose another --out")
    earlier = [name for name in OUTPUTS + FIGURES if os.path.exists(os.path.join(out, name))]
    if earlier and not overwrite:
        raise OptionError(f"{out} already holds results of an earlier run ({', '.join(earlier)})"
                          f": pass --overwrite to replace them, or choose another --out")


# ----------------------------------------------------------------------------- split

def _fitted_count(n: int, holdout: int) -> int:
    """How many poses :func:`_split` fits: every ``holdout``-th and the last."""
    return len(range(0, n, holdout)) + (1 if (n - 1) % holdout else 0)


def _split(n: int, holdout: int, degree: int) -> tuple[Tensor, Tensor]:
    """Indices of the fitted poses (every ``holdout``-th and the last) and of the others.

    Raises:
        OptionError: fewer fitted poses than a degree-``degree`` B-spline needs, naming a
            ``--holdout`` and a ``--degree`` that work.
    """
    n_fit = _fitted_count(n, holdout)
    if n_fit < degree + 1:
        ways = []
        ok = [k for k in range(min(holdout, n), 0, -1) if _fitted_count(n, k) >= degree + 1]
        if ok:
            ways.append(f"--holdout {ok[0]}" + (" (fit all)" if ok[0] == 1 else " or less"))
        if n_fit >= 2:
            ways.append(f"--degree {n_fit - 1}")
        raise OptionError(f"{n_fit} fitted poses (1 in {holdout} of {n}, and the last) are "
                          f"too few for a degree-{degree} B-spline, which needs "
                          f"{degree + 1}: pass {' or '.join(ways)}")
    fitted = torch.zeros(n, dtype=torch.bool)
    fitted[::holdout] = True
    fitted[-1] = True
    return fitted.nonzero().squeeze(1), (~fitted).nonzero().squeeze(1)


# ----------------------------------------------------------------------------- fit

def _refinement_check(times: Tensor, poses: Tensor, search: _knots.SpacingSearch,
                      steps: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """Does refining the start help? Near the data limit (``n_ctrl`` close to the number of
    poses) a least-squares fit can chase the noise between samples: the inner split of
    ``search`` fitted at its chosen candidate, once as the start and once refined by
    :func:`torch_dq.nn.fit` (``steps``): ``((rot, trans) before, (rot, trans) after)``, the
    mean errors (rad, the poses' unit) at the inner check."""
    times = times.detach().double()
    fit, check = _knots.inner_split(times.shape[0])
    duration = float(times[fit][-1] - times[fit][0])
    q, p = dualquat.to_rt(poses[fit])
    spline = dqnn.BSpline.from_poses(q, p, times[fit], degree=search.degree, form=search.form,
                                     n_ctrl=_knots.n_ctrl(duration, search.candidates[
                                         search.chosen], search.degree))
    with torch.no_grad():
        before = _knots.errors_at(spline(times[check]), poses[check])
    dqnn.fit(spline, times[fit], poses[fit].to(spline.control_points.dtype), steps=steps,
             tol=REFINE_TOL, verbose=False)
    with torch.no_grad():
        return before, _knots.errors_at(spline(times[check]), poses[check])


def _knot_spacing(times: Tensor, poses: Tensor, degree: int, form: str, knot_spacing,
                  steps: int) -> tuple[float, str, int]:
    """The knot spacing (s) for the fitted poses, why, and the refinement steps to take."""
    n, duration = times.shape[0], float(times[-1] - times[0])
    finest = _knots.finest_spacing(duration, n, degree)
    if knot_spacing == "auto":
        if n < 2 * (degree + 2):
            return finest, (f"the finest that {n} fitted poses determine (too few to choose "
                            f"by an inner hold-out)"), steps
        search = _knots.knot_spacing_search(times, poses, degree, form=form)
        if steps and search.data_limited:
            return search.spacing, (f"{search.reason()}; no refinement: with about as many "
                                    f"control points as poses, the least-squares start "
                                    f"already fits them, and refining chases their noise"), 0
        if steps and search.near_limit:  # close to interpolation: does refining help?
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                (r0, p0), (r1, p1) = _refinement_check(times, poses, search, steps)
            if r1 > r0 and p1 > p0:
                return search.spacing, (f"{search.reason()}; no refinement: on the inner "
                                        f"split it raised the errors from {math.degrees(r0):.3g}"
                                        f" deg, {1e3 * p0:.3g} mm to {math.degrees(r1):.3g} "
                                        f"deg, {1e3 * p1:.3g} mm"), 0
        return search.spacing, search.reason(), steps
    if knot_spacing > duration:
        raise OptionError(f"--knot-spacing {knot_spacing:g} s is longer than the "
                          f"{duration:.3f} s that the fitted poses span: pass --knot-spacing "
                          f"{_knots.round_down(duration):g} or less (a single knot span), "
                          f"or auto")
    n_ctrl = _knots.n_ctrl(duration, knot_spacing, degree)
    if n_ctrl > n:
        raise OptionError(f"a knot every {knot_spacing:g} s over {duration:.3f} s needs "
                          f"{n_ctrl} control points, more than the {n} fitted poses: pass "
                          f"--knot-spacing {finest:g} or more (or auto), or a lower --holdout")
    return float(knot_spacing), "as given (--knot-spacing)", steps


def _fit(train: io.Trajectory, poses: Tensor, spacing: float, degree: int, form: str,
         steps: int, dtype: torch.dtype, verbose: bool, gate: bool
         ) -> tuple[Any, Any, dict, tuple[float, float] | None]:
    """The least-squares start, then ``steps`` of :func:`torch_dq.nn.fit`; with ``gate``
    only where one Gauss-Newton step would gain more than :data:`REFINE_GAIN` of a part of
    the cost (``torch_dq.cli._refine.predicted_gain``). (spline, history or None,
    timings in seconds, the predicted gains or None where not tested)."""
    n_ctrl = _knots.n_ctrl(float(train.times[-1] - train.times[0]), spacing, degree)
    start = time.perf_counter()
    spline = dqnn.BSpline.from_poses(train.rotations.to(dtype), train.translations.to(dtype),
                                     train.times, n_ctrl=n_ctrl, degree=degree, form=form)
    init_s = time.perf_counter() - start
    history, gain = None, None
    if steps > 0 and gate:
        gain = predicted_gain(spline, train.times, poses.to(dtype))
    if steps > 0 and (gain is None or max(gain) > REFINE_GAIN):
        history = dqnn.fit(spline, train.times, poses.to(dtype), steps=steps, tol=REFINE_TOL,
                           verbose=verbose)
    return spline, history, {"least_squares_start": init_s,
                             "fit_total": time.perf_counter() - start}, gain


def _nominal_rate(rate: float) -> float:
    """``rate`` (Hz) with the fewest significant digits (1 to 6) within 0.1 % of it, so
    that the resampling grid steps by a round number (100.0000954 Hz -> 100 Hz)."""
    for digits in range(1, 7):
        nominal = float(f"{rate:.{digits}g}")
        if abs(nominal - rate) <= 1e-3 * rate:
            return nominal
    return rate


def _resampling(t0: float, t1: float, rate: float) -> Tensor:
    """``t0 + k / rate`` up to ``t1`` (float64 s); at most :data:`MAX_RESAMPLED` of them."""
    duration = t1 - t0
    if duration * rate >= MAX_RESAMPLED:
        top = _knots.round_down((MAX_RESAMPLED - 1) / duration)  # followed literally, works
        raise OptionError(f"--rate {rate:g} Hz over {duration:.3f} s gives more than "
                          f"{MAX_RESAMPLED} samples: pass --rate {top:g} or less")
    count = math.floor(duration * rate + 1e-9) + 1
    return (t0 + torch.arange(count, dtype=torch.float64) / rate).clamp(max=t1)


# ----------------------------------------------------------------------------- report

def _stats(values: Tensor) -> dict:
    v = values.detach().double().cpu()
    if v.numel() == 0:
        return {"mean": math.nan, "median": math.nan, "max": math.nan}
    return {"mean": float(v.mean()), "median": float(v.median()), "max": float(v.max())}


def _errors(pred: Tensor, truth: Tensor, idx: Tensor) -> dict:
    rot, trans = pose_errors(pred[idx], truth[idx])
    return {"translation_mm": _stats(1e3 * trans), "rotation_deg": _stats(rot)}


def _print_errors(say, result: FitResult, errors: dict, imu: bool) -> None:
    held = len(result.held_idx)
    what = "held-out" if held else "fit (nothing held out)"
    say(f"{what + f' errors ({len(result.report_idx)} poses)':<34}{'mean':>9}{'median':>9}"
        f"{'max':>9}" + ("   (the poses and IMU fit)" if imu else ""))
    for label, key in (("translation [mm]", "translation_mm"), ("rotation [deg]", "rotation_deg")):
        s = errors[key]
        say(f"  {label:<32}{s['mean']:9.3f}{s['median']:9.3f}{s['max']:9.3f}")


def _describe_input(say, path: str, traj: io.Trajectory) -> dict:
    n, t0 = len(traj), float(traj.times[0])
    duration = float(traj.times[-1]) - t0
    rate = 1.0 / float(torch.diff(traj.times).median())
    origin = f", from UNIX time {t0:.6f} s" if t0 > 1e8 else ""
    say(f"torch_dq fit: {path}: {n} poses over {duration:.3f} s ({rate:.4g} Hz){origin}")
    return {"file": path, "poses": n, "start_time_s": t0, "duration_s": duration,
            "median_rate_hz": rate}


def _gap_note(traj: io.Trajectory, spacing: float) -> tuple[int, str | None]:
    """How many gaps between poses are longer than 2 knot spacings, and a note saying so
    (``None`` when there is none)."""
    steps = torch.diff(traj.times)
    count = int((steps > 2 * spacing).sum())
    if not count:
        return 0, None
    worst = int(steps.argmax())
    share = float(steps[steps > 2 * spacing].sum() / (traj.times[-1] - traj.times[0]))
    costly = (f"; {'they take' if count != 1 else 'it takes'} {100 * share:.0f} % of the "
              f"span and, with uniform knots, of the control points, whose number the fitted "
              f"poses bound: this limits the knot spacing; for finer knots, fit the parts "
              f"between the gaps separately" if share > GAP_SHARE else "")
    return count, (f"{count} gap{'s' * (count != 1)} between poses longer than 2 knot "
                   f"spacings ({2 * spacing:.4g} s; the longest {float(steps[worst]):.3f} s, "
                   f"{float(traj.times[worst] - traj.times[0]):.3f} s after the first pose): "
                   f"the curve bridges {'them' if count != 1 else 'it'} smoothly, without "
                   f"data (trajectory.csv marks such rows in_gap = 1){costly}")


def _in_gap(grid: Tensor, times: Tensor, spacing: float) -> Tensor:
    """``(M,)`` bool: the grid times strictly inside a gap between consecutive poses longer
    than 2 knot spacings."""
    i = torch.searchsorted(times, grid, right=True).clamp(1, times.shape[0] - 1)
    lo, hi = times[i - 1], times[i]
    return (hi - lo > 2 * spacing) & (grid > lo) & (grid < hi)


def _reload_text(path: str) -> str:
    return f"spline = torch_dq.nn.BSpline.from_state_dict(torch.load({path!r}))"


# ----------------------------------------------------------------------------- write

def _write_csv(path: str, result: FitResult, spacing: float, about: str) -> None:
    """``trajectory.csv`` (:func:`torch_dq.io.write_csv`): the comment lines (the units with
    the ``in_gap`` note, then ``about``), the header row (:data:`torch_dq.io.CSV_COLUMNS`
    and ``in_gap``), then one row per grid time."""
    q, p = dualquat.to_rt(result.x)
    note = (f"in_gap 1 inside a gap between poses longer than 2 knot spacings "
            f"({2 * spacing:.4g} s: no data there, the curve bridges it), else 0")
    io.write_csv(path, io.Trajectory(result.grid, q, p), result.kin, [about],
                 extra_columns={"in_gap": (result.in_gap, note)}, comments_first=True)


def _write(out: str, path: str, result: FitResult, summary: dict, plots: bool) -> dict:
    """Write the resampled CSV, the state dict, the figures and ``summary.json``."""
    os.makedirs(out, exist_ok=True)
    paths = {name: os.path.join(out, name) for name in OUTPUTS}
    model = summary["model"]
    imu = f" and the IMU {summary['imu']['file']}" if summary["imu"] else ""
    _write_csv(paths["trajectory.csv"], result, model["knot_spacing_s"],
               f"torch_dq fit of {path}{imu}: B-spline of degree {model['degree']}, "
               f"{model['n_ctrl']} control points (a knot every {model['knot_spacing_s']:g} "
               f"s), resampled at {summary['resampled']['rate_hz']:.9g} Hz")
    torch.save(result.spline.state_dict(), paths["spline.pt"])
    if plots:
        try:
            Figure, Canvas = import_matplotlib()
        except ImportError:
            summary["warnings"].append(no_matplotlib("torch-dq fit"))
        else:
            from . import fit_plots

            for name, draw in zip(FIGURES, fit_plots.PLOTS, strict=True):
                paths[name] = draw(Figure, Canvas, os.path.join(out, name), result)
    summary["outputs"] = paths
    with open(paths["summary.json"], "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=2)
    return paths


# ----------------------------------------------------------------------------- driver

def _fit_and_measure(traj: io.Trajectory, fit_idx: Tensor, held_idx: Tensor, spacing: float,
                     degree: int, form: str, steps: int, rate: float, dtype: torch.dtype,
                     verbose: bool, joint=None, gate: bool = False, kept: str | None = None,
                     announce=None) -> tuple[FitResult, dict]:
    """Fit (``gate``: LM only where it pays, :func:`_fit`; ``kept``: why the least-squares
    start is kept, where the caller knows), tell ``announce(fit)`` of it,
    fit ``joint(spline, times, poses) -> (spline, summary entry)`` (e.g. with an IMU: the
    curve measured, resampled and written is then that joint fit's), then measure and
    resample the curve."""
    poses = traj.poses()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spline, history, seconds, gain = _fit(traj.select(fit_idx), poses[fit_idx], spacing,
                                              degree, form, steps, dtype, verbose, gate)
        fit = _pose_fit(history, seconds, gain, kept)
        if announce:
            announce(fit)
        extra = None
        if joint:  # may fit another curve (the IMU's knots)
            spline, extra = joint(spline, traj.times[fit_idx], poses[fit_idx])
    pred = evaluate(spline, traj.times)
    rot, trans = pose_errors(pred, poses)
    grid = _resampling(float(traj.times[0]), float(traj.times[-1]), rate)
    with torch.no_grad():
        kin = spline.kinematics(grid)
    kin = type(kin)(*(None if v is None else v.double() for v in kin))
    result = FitResult(traj, poses, fit_idx, held_idx, spline, pred, rot, 1e3 * trans, grid,
                       evaluate(spline, grid), kin, _in_gap(grid, traj.times, spacing))
    fit.update(warnings=say_warnings("torch-dq fit", caught), imu=extra)
    return result, fit


def _pose_fit(history, seconds: dict, gain: tuple[float, float] | None,
              kept: str | None) -> dict:
    """``summary.json``'s ``fit`` entry of the pose-only fit (its ``warnings`` and ``imu``
    come later); ``kept``: the reason given where the least-squares start was kept."""
    fit = {"steps": history.steps if history else 0,
           "refined": history is not None, "reason": history.reason if history else None,
           "loss_start": history.loss[0] if history and history.loss else None,
           "loss_final": history.final_loss if history else None, "seconds": seconds}
    if gain is not None:
        fit["predicted_gain"] = {"rotation": gain[0], "translation": gain[1]}
        if history is None:
            fit["reason"] = _kept(gain)
    if kept is not None:
        fit["reason"] = kept
    return fit


def _kept(gain: tuple[float, float]) -> str:
    """Why the least-squares start was kept (``refine="auto"``)."""
    return (f"one Gauss-Newton step would lower the fitted poses' rotation and translation "
            f"costs by {100 * gain[0]:.2g} % and {100 * gain[1]:.2g} %, at most "
            f"{100 * REFINE_GAIN:g} % each: the start is the optimum to within the noise; "
            f"--refine always refines it")


def run_fit(path: str | os.PathLike[str], *, format: str = "auto",
            times: str | os.PathLike[str] | Tensor | None = None, duplicates: str = "error",
            knot_spacing: float | str = "auto", degree: int | None = None,
            form: str | None = None,
            holdout: int = 2,
            steps: int = 50, rate: float | None = None, dtype: torch.dtype = torch.float64,
            out: str = "torch_dq_fit", overwrite: bool = False,
            imu: str | os.PathLike[str] | None = None, time_offset: str | None = None,
            refine: str = "auto", plots: bool = True, verbose: bool = True) -> dict:
    r"""Fit a B-spline to a trajectory file, measure it on held-out poses, write the results.

    Args:
        path: the trajectory file (TUM, KITTI or EuRoC; see :mod:`torch_dq.io`).
        format: ``"auto"``, ``"tum"``, ``"kitti"`` or ``"euroc"``.
        times: KITTI only: its times file.
        duplicates: ``"error"`` or ``"first"`` (keep the first pose of a repeated time).
        knot_spacing: seconds between knots (``n_ctrl = ceil(duration / knot_spacing) +
            degree``), or ``"auto"`` (default): chosen from the fitted poses alone by
            :func:`torch_dq.fitting.choose_knot_spacing`.
        degree: B-spline degree; ``None`` (default): 4 with ``imu`` and
            ``time_offset="estimate"`` (accelerations C1 in time, so the accelerometer's cost
            is smooth in the offset: ``torch_dq.cli.fit_imu.default_degree``), else 3.
        form: the B-spline form (:class:`torch_dq.nn.BSpline`): ``"de_boor"`` (the paper's
            De Boor pyramid of sclerps, C1 at knots), ``"cumulative"`` (Kim-Kim-Shin, C2
            for a cubic: continuous accelerations, for IMU work) or ``"split"`` (cumulative
            SO(3) rotation, Euclidean translation, C2); ``None`` (default):
            ``"cumulative"`` with ``imu``, else ``"de_boor"``.
        holdout: fit every ``holdout``-th pose (and the last), hold the others out
            (``1``: fit them all).
        steps: maximum steps of :func:`torch_dq.nn.fit` (``0``: keep the least-squares
            start).
        refine: ``"auto"`` (default): refine the least-squares start by
            :func:`torch_dq.nn.fit` only where it pays: where one Gauss-Newton step from
            it would lower the rotation or the translation part of the fitted poses' cost
            (:func:`torch_dq.losses.pose_loss`) by more than :data:`REFINE_GAIN` (1 %) of
            that part, predicted from the start's gradient and the basis' Gram matrix
            (``torch_dq.cli._refine``; ~0.04 s on 5,000 poses). Elsewhere the start is
            already the optimum to within the noise (one step would move the curve by at
            most ~10 % of the residuals) and is kept. ``"always"``: refine whenever
            ``steps > 0``. With ``imu`` the joint fit refines the curve either way.
        rate: resampling rate of ``trajectory.csv`` in Hz (default: the file's median
            rate); at most :data:`MAX_RESAMPLED` rows.
        dtype: dtype of the module (times stay float64).
        out: output folder (created).
        overwrite: replace the results of an earlier run in ``out`` (the input file is
            never written, whatever this says).
        imu: an IMU file (:func:`torch_dq.io.read_imu`) on the poses' clock: the curve is
            then refined on the fitted poses and the IMU together
            (``torch_dq.cli.fit_imu.fit_with_imu``; biases, gravity and their standard
            deviations printed and in the summary), on the cumulative form unless ``form``
            says otherwise (continuous accelerations). The pose-only fit's line is printed
            first, then the joint fit's; the errors, ``trajectory.csv``, ``spline.pt`` and
            the figures are of the joint fit's curve (``summary.json``: ``holdout.curve``;
            its ``fit`` entry is the pose-only fit's, its ``imu`` entry the joint fit's).
        time_offset: with ``imu``: ``None`` (the clocks agree) or ``"estimate"`` (one
            offset for the gyroscope and the accelerometer, at most 0.1 s).
        plots: write the figures (needs matplotlib).
        verbose: print the report and show the progress bar.

    Returns:
        The summary written to ``summary.json``: input, model (with the knot spacing and
        why it was chosen), fit and held-out errors (``{"translation_mm": {"mean",
        "median", "max"}, "rotation_deg": {...}}``), timings and the paths written.

    Raises:
        torch_dq.io.TrajectoryFileError: malformed file (names the file and the line).
        OptionError: options this data cannot satisfy (too few fitted poses, knots too
            close, a rate too high, an output folder holding the input or earlier results);
            the message names a value that works.
        ValueError: bad argument types or ranges.
        OSError: unreadable file, unwritable output folder.
    """
    if form is None:
        form = "cumulative" if imu is not None else "de_boor"
    if degree is None:
        from .fit_imu import default_degree

        degree = default_degree(imu, time_offset)
    _check_options(knot_spacing, degree, form, holdout, steps, rate)
    if refine not in ("auto", "always"):
        raise ValueError(f"fit: refine must be 'auto' or 'always', got {refine!r}")
    path, out = os.fspath(path), os.fspath(out)
    _check_inputs(path, out, times, imu, time_offset, overwrite, plots)
    say = print if verbose else (lambda *a, **k: None)
    traj, read_warnings, read_s, unit = read_seconds(path, format, times, duplicates)
    fit_idx, held_idx = _split(len(traj), holdout, degree)
    train = traj.select(fit_idx)
    spacing, why, fit_steps = _knot_spacing(train.times, train.poses(), degree, form,
                                            knot_spacing, steps)
    info = {**_describe_input(say, path, traj), "time_unit": unit or "seconds"}
    if unit:
        say(f"note: the file's times are {unit}: converted to seconds (divided by "
            f"{1 / dict(_checks.TIME_UNITS)[unit]:.0e}); every output is in seconds")
    info["gaps_over_2_knot_spacings"], gap_note = _gap_note(traj, spacing)
    if gap_note:
        say(f"note: {gap_note}")
    n_ctrl = _knots.n_ctrl(float(train.times[-1] - train.times[0]), spacing, degree)
    say(f"knot spacing {spacing:g} s: {why}")
    say(f"B-spline ({form} form): degree {degree}, {n_ctrl} control points, fitted to "
        f"{len(fit_idx)} poses "
        f"(1 in {holdout}), {len(held_idx)} held out")
    rate_hz = _nominal_rate(info["median_rate_hz"]) if rate is None else float(rate)
    joint = None
    if imu is not None:  # it takes the steps asked even where the poses alone need none
        from .fit_imu import fit_with_imu

        joint = functools.partial(fit_with_imu, imu=imu, time_offset=time_offset,
                                  steps=max(steps, 1), say=say)
    result, fit = _fit_and_measure(traj, fit_idx, held_idx, spacing, degree, form, fit_steps,
                                   rate_hz, dtype, verbose, joint,
                                   gate=refine == "auto" and imu is None,
                                   kept=_kept_reason(steps, fit_steps),
                                   announce=lambda fit: say(_steps_line(fit, imu is not None)))
    fit["seconds"]["read"] = read_s
    fit["warnings"] = read_warnings + fit["warnings"] + ([gap_note] if gap_note else [])
    model = {"degree": degree, "form": form, "n_ctrl": n_ctrl, "knot_spacing_s": spacing,
             "knot_spacing_reason": why}
    summary = _summarize(say, result, fit, {**info, "format": format}, model, holdout, dtype,
                         rate_hz)
    summary["reload"] = _reload_text(os.path.join(out, "spline.pt"))
    paths = _write(out, path, result, summary, plots)
    say(f"wrote {', '.join(sorted(paths))} to {out}")
    say(f"reload: {summary['reload']}")
    return summary


def _kept_reason(steps: int, fit_steps: int) -> str | None:
    """Why the least-squares start is kept where the knot search or ``steps=0`` kept it
    (None: the fit refines)."""
    if fit_steps:
        return None
    return "--steps 0" if not steps else "refining chases the poses' noise, see the knot spacing"


def _check_inputs(path: str, out: str, times, imu, time_offset, overwrite: bool,
                  plots: bool) -> None:
    """The IMU options agree, and ``out`` writes over no input (:func:`_check_out`)."""
    if time_offset not in (None, "estimate"):
        raise ValueError(f"fit: time_offset must be None or 'estimate', got {time_offset!r}")
    if time_offset and imu is None:
        raise OptionError("--time-offset estimate needs an IMU file: pass --imu IMU_FILE")
    inputs = [path] + [os.fspath(f) for f in (times, imu) if isinstance(f, (str, os.PathLike))]
    for source in inputs:  # a missing input first: before what --out holds
        if os.path.isdir(source):
            raise IsADirectoryError(errno.EISDIR, "a folder, not a file", source)
        if not os.path.isfile(source):
            raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), source)
    _check_out(out, inputs, overwrite, plots)


def _steps_line(fit: dict, imu: bool) -> str:
    """The report's line on the pose-only fit: its refinement steps and what stopped them,
    or why the least-squares start was kept (never a bare "0 steps"); with an ``imu``, that
    the joint fit (printed next) gives the curve reported and written."""
    seconds = (f"{fit['seconds']['fit_total']:.2f} s (least-squares start "
               f"{fit['seconds']['least_squares_start']:.2f} s)")
    n = fit["steps"]
    if not fit["refined"]:
        what = f"the least-squares start, not refined ({fit['reason']}), in {seconds}"
    elif n == 0:
        what = f"0 steps: the least-squares start already fits ({fit['reason']}), {seconds}"
    else:
        what = f"{n} step{'s' * (n != 1)} in {seconds}: {fit['reason']}"
    joint = ("; next the poses and the IMU fitted together, whose curve the errors, "
             "trajectory.csv and spline.pt are of") if imu else ""
    return f"fit{' (poses alone)' if imu else ''}: {what}{joint}"


def _summarize(say, result: FitResult, fit: dict, info: dict, model: dict, holdout: int,
               dtype: torch.dtype, rate_hz: float) -> dict[str, Any]:
    """Print the errors; the summary of ``summary.json`` (but the reload
    line and the outputs). ``model`` gives the pose-only fit's knots, replaced by the IMU
    fit's where there was one."""
    fit_idx, held_idx = result.fit_idx, result.held_idx
    heldout = _errors(result.pred, result.poses, result.report_idx)
    _print_errors(say, result, heldout, fit["imu"] is not None)
    if fit["imu"] is not None:  # the IMU fit's knots
        knots = fit["imu"]["knots"]
        model = {**model, "n_ctrl": knots["n_ctrl"], "knot_spacing_s": knots["spacing_s"],
                 "knot_spacing_reason": knots["reason"]}
    return {
        "input": info,
        "model": {"class": "torch_dq.nn.BSpline", **model,
                  "dtype": str(dtype).replace("torch.", ""),
                  "domain_s": list(result.spline.domain)},
        "holdout": {"every": holdout, "fitted": len(fit_idx), "held_out": len(held_idx),
                    "errors_on": "held-out poses" if len(held_idx) else "fitted poses",
                    "curve": "poses and IMU fitted together" if fit["imu"] is not None
                    else "poses alone"},
        "heldout_errors": heldout,
        "fit_errors": _errors(result.pred, result.poses, fit_idx),
        "fit": {k: v for k, v in fit.items() if k not in ("seconds", "warnings", "imu")},
        "imu": fit["imu"],
        "seconds": fit["seconds"],
        "resampled": {"rate_hz": rate_hz, "samples": len(result.grid)},
        "warnings": fit["warnings"],
    }


#: The defaults of :func:`run_fit` (``knot_spacing``, ``degree``, ``holdout``, ``steps``, ...),
#: read from its signature: the command line takes its defaults from here.
DEFAULTS = {name: p.default for name, p in inspect.signature(run_fit).parameters.items()
            if p.default is not inspect.Parameter.empty}

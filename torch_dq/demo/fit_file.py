r"""The application behind ``python -m torch_dq fit FILE``: fit a B-spline to a trajectory file.

Reads a TUM, KITTI or EuRoC trajectory (:func:`torch_dq.io.read_trajectory`, float64 times
in the file's own seconds, UNIX seconds included), then

1. splits the poses: every ``holdout``-th one (and the last) is fitted, the others are held
   out to measure the fit (``holdout=1``: fit all, report the fit residuals);
2. fits a dual-quaternion B-spline with a knot every ``knot_spacing`` seconds over the
   fitted poses' time span: :meth:`torch_dq.nn.BSpline.from_poses` (local least squares)
   then :func:`torch_dq.nn.fit`, with a progress bar on a terminal (tqdm, optional);
3. prints the held-out errors (translation in mm, rotation in degrees: mean, median, max)
   and the fit time;
4. writes to the output folder ``trajectory.csv`` (the curve resampled at ``rate`` Hz with
   world-frame velocities and accelerations, :func:`torch_dq.io.write_csv`), ``spline.pt``
   (the module's ``state_dict``), ``summary.json`` and the figures ``components.png`` (the
   8 dual-quaternion components against time, as the paper's Fig. 1), ``kinematics.png``
   (speed and angular rate against time) and ``residuals.png`` (errors of the fitted and
   held-out poses against time).

Matplotlib is optional (``pip install 'torch_dq[plot]'``): without it the figures are
skipped with a warning.

Reload the fitted curve with::

    spline = nn.BSpline(dq.identity((n_ctrl,), dtype=torch.float64), degree=degree)
    spline.load_state_dict(torch.load("spline.pt"))  # knots and time origin included

(``n_ctrl`` and ``degree`` are in ``summary.json``).

Example:
    >>> from torch_dq.demo.fit_file import run_fit
    >>> summary = run_fit("tests/data/tum_fr1_xyz_sub.txt", out="/tmp/fit",
    ...                   steps=5, plots=False, verbose=False)  # doctest: +SKIP
    >>> summary["heldout_errors"]["translation_mm"]["median"]  # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from typing import Any

import torch
from torch import Tensor

from .. import dualquat, io, losses
from .. import nn as dqnn

__all__ = ["FIGURES", "OUTPUTS", "run_fit"]

#: Figures written when matplotlib is available.
FIGURES = ("components.png", "kinematics.png", "residuals.png")

#: Files always written.
OUTPUTS = ("trajectory.csv", "spline.pt", "summary.json")

_PLOT_HINT = "pip install 'torch_dq[plot]'"


def _split(n: int, holdout: int) -> tuple[Tensor, Tensor]:
    """Indices of the fitted poses (every ``holdout``-th and the last) and of the others."""
    fitted = torch.zeros(n, dtype=torch.bool)
    fitted[::holdout] = True
    fitted[-1] = True
    return fitted.nonzero().squeeze(1), (~fitted).nonzero().squeeze(1)


def _stats(values: Tensor) -> dict:
    v = values.detach().double().cpu()
    if v.numel() == 0:
        return {"mean": math.nan, "median": math.nan, "max": math.nan}
    return {"mean": float(v.mean()), "median": float(v.median()), "max": float(v.max())}


def _errors(pred: Tensor, truth: Tensor) -> tuple[Tensor, Tensor]:
    """Per-pose translation error (mm) and rotation error (deg), sign-invariant."""
    return (1e3 * losses.translation_error(pred, truth).double(),
            torch.rad2deg(losses.rotation_angle(pred, truth).double()))


def _median_rate(times: Tensor) -> float:
    return 1.0 / float(torch.diff(times).median())


def run_fit(path: str | os.PathLike[str], *, format: str = "auto",
            times: str | os.PathLike[str] | Tensor | None = None, duplicates: str = "error",
            knot_spacing: float = 0.1, degree: int = 3, holdout: int = 2, steps: int = 50,
            rate: float | None = None, dtype: torch.dtype = torch.float64,
            out: str = "torch_dq_fit", plots: bool = True, verbose: bool = True) -> dict:
    r"""Fit a B-spline to a trajectory file, measure it on held-out poses, write the results.

    Args:
        path: the trajectory file (TUM, KITTI or EuRoC; see :mod:`torch_dq.io`).
        format: ``"auto"``, ``"tum"``, ``"kitti"`` or ``"euroc"``.
        times: KITTI only: its times file.
        duplicates: ``"error"`` or ``"first"`` (keep the first pose of a repeated time).
        knot_spacing: seconds between knots (``n_ctrl = ceil(duration / knot_spacing) +
            degree``).
        degree: B-spline degree.
        holdout: fit every ``holdout``-th pose (and the last), hold the others out
            (``1``: fit them all).
        steps: maximum steps of :func:`torch_dq.nn.fit` (``0``: keep the least-squares
            start).
        rate: resampling rate of ``trajectory.csv`` in Hz (default: the file's median rate).
        dtype: dtype of the module (times stay float64).
        out: output folder (created).
        plots: write the figures (needs matplotlib).
        verbose: print the report and show the progress bar.

    Returns:
        The summary written to ``summary.json``: input, model, fit and held-out errors
        (``{"translation_mm": {"mean", "median", "max"}, "rotation_deg": {...}}``),
        timings and the paths written.

    Raises:
        torch_dq.io.TrajectoryFileError: malformed file (names the file and the line).
        ValueError: bad options, or too few poses for the knots (the message says what to
            change).
        OSError: unreadable file, unwritable output folder.
    """
    fn = "fit"
    for name, value, low in (("degree", degree, 1), ("holdout", holdout, 1), ("steps", steps, 0)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{fn}: {name} must be an int >= {low}, got {value!r}")
    if not (isinstance(knot_spacing, (int, float)) and math.isfinite(knot_spacing)
            and knot_spacing > 0):
        raise ValueError(f"{fn}: knot spacing must be a finite number of seconds > 0, got "
                         f"{knot_spacing!r}")
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"{fn}: rate must be a finite number of Hz > 0, got {rate!r}")
    say = print if verbose else (lambda *a, **k: None)

    start = time.perf_counter()
    traj = io.read_trajectory(path, format=format, times=times, duplicates=duplicates)
    read_s = time.perf_counter() - start
    n = len(traj)
    if n < 2:
        raise ValueError(f"{fn}: {os.fspath(path)} holds {n} pose; a fit needs at least 2")
    fit_idx, held_idx = _split(n, holdout)
    train = traj.select(fit_idx)
    t0, t1 = float(traj.times[0]), float(traj.times[-1])
    duration = t1 - t0
    n_ctrl = math.ceil(duration / knot_spacing - 1e-9) + degree
    if n_ctrl > len(train):
        raise ValueError(
            f"{fn}: a knot every {knot_spacing:g} s over {duration:.3f} s needs {n_ctrl} "
            f"control points, more than the {len(train)} fitted poses: raise --knot-spacing "
            f"(at least {duration / (len(train) - degree):.3g} s) or lower --holdout")
    file_rate = _median_rate(traj.times)
    say(f"torch_dq fit: {os.fspath(path)}: {n} poses over {duration:.3f} s "
        f"({file_rate:.4g} Hz), from UNIX time {t0:.6f} s" if t0 > 1e8 else
        f"torch_dq fit: {os.fspath(path)}: {n} poses over {duration:.3f} s ({file_rate:.4g} Hz)")
    gaps = torch.diff(traj.times) > 2 * knot_spacing
    if bool(gaps.any()):
        worst = int(torch.diff(traj.times).argmax())
        say(f"note: {int(gaps.sum())} gaps between poses longer than 2 knot spacings (the "
            f"longest {float(traj.times[worst + 1] - traj.times[worst]):.3f} s after "
            f"{float(traj.times[worst] - t0):.3f} s): the curve bridges them smoothly")
    say(f"B-spline: degree {degree}, {n_ctrl} control points (a knot every {knot_spacing:g} s), "
        f"fitted to {len(train)} poses (1 in {holdout}), {len(held_idx)} held out")

    dev: dict[str, Any] = dict(dtype=dtype)
    poses = traj.poses()
    start = time.perf_counter()
    spline = dqnn.BSpline.from_poses(train.rotations.to(**dev), train.translations.to(**dev),
                                     train.times, n_ctrl=n_ctrl, degree=degree)
    init_s = time.perf_counter() - start
    with torch.no_grad():
        init_pred = spline(traj.times)
    history = None
    if steps > 0:
        history = dqnn.fit(spline, train.times, poses[fit_idx].to(**dev), steps=steps,
                           verbose=verbose)
    fit_s = time.perf_counter() - start
    with torch.no_grad():
        pred = spline(traj.times).double()
    trans_mm, rot_deg = _errors(pred, poses)
    init_trans_mm, init_rot_deg = _errors(init_pred.double(), poses)
    report = held_idx if len(held_idx) else fit_idx
    heldout = {"translation_mm": _stats(trans_mm[report]), "rotation_deg": _stats(rot_deg[report])}
    summary: dict[str, Any] = {
        "input": {"file": os.fspath(path), "format": format, "poses": n,
                  "start_time_s": t0, "duration_s": duration, "median_rate_hz": file_rate,
                  "gaps_over_2_knot_spacings": int(gaps.sum())},
        "model": {"class": "torch_dq.nn.BSpline", "degree": degree, "n_ctrl": n_ctrl,
                  "knot_spacing_s": knot_spacing, "dtype": str(dtype).replace("torch.", ""),
                  "domain_s": list(spline.domain)},
        "holdout": {"every": holdout, "fitted": len(fit_idx), "held_out": len(held_idx),
                    "errors_on": "held-out poses" if len(held_idx) else "fitted poses"},
        "heldout_errors": heldout,
        "fit_errors": {"translation_mm": _stats(trans_mm[fit_idx]),
                       "rotation_deg": _stats(rot_deg[fit_idx])},
        "start_errors": {"translation_mm": _stats(init_trans_mm[report]),
                         "rotation_deg": _stats(init_rot_deg[report])},
        "fit": {"steps": history.steps if history else 0,
                "loss_start": history.loss[0] if history and history.loss else None,
                "loss_final": history.final_loss if history else None},
        "seconds": {"read": read_s, "least_squares_start": init_s, "fit_total": fit_s},
    }
    n_steps = summary["fit"]["steps"]
    say(f"fit: {n_steps} step{'s' * (n_steps != 1)} in {fit_s:.2f} s (least-squares start "
        f"{init_s:.2f} s)")
    what = "held-out" if len(held_idx) else "fit (nothing held out)"
    say(f"{what + f' errors ({len(report)} poses)':<34}{'mean':>9}{'median':>9}{'max':>9}")
    for label, key in (("translation [mm]", "translation_mm"), ("rotation [deg]", "rotation_deg")):
        s = heldout[key]
        say(f"  {label:<32}{s['mean']:9.3f}{s['median']:9.3f}{s['max']:9.3f}")

    # resampled trajectory with derivatives
    os.makedirs(out, exist_ok=True)
    rate_hz = file_rate if rate is None else float(rate)
    count = math.floor(duration * rate_hz + 1e-9) + 1
    grid = (t0 + torch.arange(count, dtype=torch.float64) / rate_hz).clamp(max=t1)
    with torch.no_grad():
        x = spline(grid).double()
        kin = spline.kinematics(grid)
    q, p = dualquat.to_rt(x)
    resampled = io.Trajectory(grid, q, p)
    paths = {"trajectory.csv": os.path.join(out, "trajectory.csv"),
             "spline.pt": os.path.join(out, "spline.pt"),
             "summary.json": os.path.join(out, "summary.json")}
    io.write_csv(paths["trajectory.csv"], resampled, _double(kin), comments=[
        f"torch_dq fit of {os.fspath(path)}: B-spline of degree {degree}, {n_ctrl} control "
        f"points (a knot every {knot_spacing:g} s), resampled at {rate_hz:.6g} Hz"])
    torch.save(spline.state_dict(), paths["spline.pt"])
    summary["resampled"] = {"rate_hz": rate_hz, "samples": count}
    if plots:
        try:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure
        except ImportError:
            warnings.warn(f"matplotlib is not installed: figures skipped ({_PLOT_HINT})",
                          stacklevel=2)
        else:
            figs = _plots(Figure, FigureCanvasAgg, out, t0, traj, poses, pred, fit_idx,
                          held_idx, grid, x, kin, trans_mm, rot_deg)
            paths.update({os.path.basename(f): f for f in figs})
    summary["outputs"] = paths
    with open(paths["summary.json"], "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=2)
    say(f"wrote {', '.join(sorted(paths))} to {out}")
    return summary


def _double(kin):
    return type(kin)(*(None if v is None else v.double() for v in kin))


# ----------------------------------------------------------------------------- figures

def _plots(Figure, Canvas, out, t0, traj, poses, pred, fit_idx, held_idx, grid, x, kin,
           trans_mm, rot_deg) -> list[str]:
    import numpy as np

    rel = (grid - t0).numpy()
    t_rel = (traj.times - t0).numpy()
    xlabel = f"time since the first pose (UNIX {t0:.3f} s) [s]" if t0 > 1e8 else \
        f"time since the first pose ({t0:g} s) [s]"
    written = []

    def save(fig, name):
        Canvas(fig)
        path = os.path.join(out, name)
        fig.savefig(path, dpi=110)
        written.append(path)

    # 1. the 8 components (paper's Fig. 1): samples sign-aligned with the curve
    sign = torch.where((poses[:, :4] * pred[:, :4]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    aligned = (sign * poses).numpy()
    fig = Figure(figsize=(11.0, 7.0), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    names = (("$r_w$", "$r_x$", "$r_y$", "$r_z$"), ("$d_w$", "$d_x$", "$d_y$", "$d_z$"))
    xs = x.numpy()
    held = held_idx.numpy()
    shown = held if held.size else fit_idx.numpy()
    for part, ax in enumerate(axes):
        for j in range(4):
            k = 4 * part + j
            ax.plot(rel, xs[:, k], color=f"C{j}", lw=1.4, label=f"{names[part][j]}")
            ax.plot(t_rel[shown], aligned[shown, k], ".", color=f"C{j}", ms=2.5, alpha=0.5)
        ax.plot([], [], ".", color="0.4", label="held-out poses" if held.size else "poses")
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=9,
                  title="B-spline", title_fontsize=9)
    axes[0].set_title("Real part $r$: the rotation quaternion")
    axes[0].set_ylabel("real part (unitless)")
    axes[1].set_title(r"Dual part $d = \frac{1}{2}(0, t)\,r$")
    axes[1].set_ylabel("dual part [m]")
    axes[1].set_xlabel(xlabel)
    fig.suptitle("The 8 dual-quaternion components of the fitted B-spline")
    save(fig, "components.png")

    # 2. speed and angular rate, with finite differences of the file's poses over ~0.04 s
    # (a shorter step only shows the file's rounding noise) for reference
    speed = kin.linear_velocity.double().norm(dim=-1).numpy()
    omega = torch.rad2deg(kin.angular_velocity.double().norm(dim=-1)).numpy()
    k = max(1, round(0.04 / float(np.median(np.diff(t_rel)))))
    dt = t_rel[k:] - t_rel[:-k]
    fd_speed = np.linalg.norm(traj.translations[k:].numpy() - traj.translations[:-k].numpy(),
                              axis=-1) / dt
    dot = (traj.rotations[k:] * traj.rotations[:-k]).sum(-1).abs().clamp(max=1.0).numpy()
    fd_omega = np.rad2deg(2 * np.arccos(dot)) / dt
    mid = 0.5 * (t_rel[k:] + t_rel[:-k])
    step_ms = 1e3 * float(np.median(dt))
    fig = Figure(figsize=(11.0, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, fd, curve, color, label, unit, title in (
            (axes[0], fd_speed, speed, "C0", "B-spline |v| (exact derivative)", "speed [m/s]",
             "Linear speed of the body origin"),
            (axes[1], fd_omega, omega, "C3", "B-spline |ω| (exact derivative)",
             "angular rate [deg/s]", "Angular rate")):
        ax.plot(mid, fd, color="0.6", lw=0.8,
                label=f"finite differences of the poses ({step_ms:.0f} ms apart)")
        ax.plot(rel, curve, color=color, lw=1.5, label=label)
        # outliers of the differences (gaps, glitches) would squash the curve: clip the view
        top = max(float(curve.max()), float(np.percentile(fd, 99.5)) if fd.size else 0.0)
        ax.set_ylim(0.0, 1.15 * top + 1e-12)
        ax.set_ylabel(unit)
        ax.set_title(title)
    axes[1].set_xlabel(xlabel)
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    save(fig, "kinematics.png")

    # 3. residuals of the fitted and the held-out poses
    fig = Figure(figsize=(11.0, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    fitted = fit_idx.numpy()
    for ax, err, unit, title in ((axes[0], trans_mm, "translation error [mm]", "Translation"),
                                 (axes[1], rot_deg, "rotation error [deg]", "Rotation")):
        e = err.numpy()
        ax.plot(t_rel[fitted], e[fitted], ".", ms=3, color="C0", label="fitted poses")
        if held.size:
            ax.plot(t_rel[held], e[held], ".", ms=3, color="C1", label="held-out poses")
        ax.set_ylabel(unit)
        ax.set_title(f"{title} error of the B-spline at the file's poses")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel(xlabel)
    save(fig, "residuals.png")
    return written

r"""The figures of ``python -m torch_dq fit`` (matplotlib, Agg canvas; pyplot untouched).

Each function draws one PNG from a :class:`torch_dq.cli.fit_file.FitResult`:

- :func:`plot_components`: the 8 dual-quaternion components of the curve against time (the
  paper's Fig. 1) with the held-out poses as hollow markers on top.
- :func:`plot_kinematics`: speed and angular rate (exact derivatives) with finite
  differences of the file's poses drawn as dots over the curve.
- :func:`plot_residuals`: the curve's error at the fitted poses (dots on top) and at the
  held-out ones (hollow rings below).
"""

from __future__ import annotations

import numpy as np
import torch

from .._report import align

__all__ = ["PLOTS", "plot_components", "plot_kinematics", "plot_residuals"]

_DPI = 110

#: At most this many held-out poses drawn per component (more would merge into a line).
MAX_MARKERS = 150


def _save(fig, Canvas, path: str) -> str:
    Canvas(fig)
    fig.savefig(path, dpi=_DPI)
    return path


def _xlabel(t0: float) -> str:
    """The time axis: seconds since the first pose, saying where that is when it matters."""
    if t0 > 1e8:
        return f"time since the first pose (UNIX {t0:.3f} s) [s]"
    if t0 == 0.0:
        return "time [s]"
    return f"time since the first pose (t = {t0:g} s) [s]"


def _thin(idx: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` entries of ``idx``, evenly spread."""
    if idx.size <= most:
        return idx
    return idx[np.linspace(0, idx.size - 1, most).round().astype(int)]


def plot_components(Figure, Canvas, path: str, r) -> str:
    """The 8 components of the curve (lines) and of the held-out poses (hollow markers,
    sign-aligned with the curve) against time."""
    rel = (r.grid - r.t0).numpy()
    t_rel = (r.traj.times - r.t0).numpy()
    aligned = align(r.poses, r.pred).numpy()
    shown = _thin(r.report_idx.numpy(), MAX_MARKERS)
    held = len(r.held_idx) > 0
    fig = Figure(figsize=(11.0, 7.0), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    names = (("$r_w$", "$r_x$", "$r_y$", "$r_z$"), ("$d_w$", "$d_x$", "$d_y$", "$d_z$"))
    xs = r.x.numpy()
    for part, ax in enumerate(axes):
        for j in range(4):
            k = 4 * part + j
            ax.plot(rel, xs[:, k], color=f"C{j}", lw=1.0, label=names[part][j], zorder=2)
            ax.plot(t_rel[shown], aligned[shown, k], "o", ms=4.0, mfc="none", mew=0.9,
                    color=f"C{j}", zorder=3)
        label = "held-out poses" if held else "poses"
        if len(shown) < len(r.report_idx):
            label += f" ({len(shown)} of {len(r.report_idx)})"
        ax.plot([], [], "o", ms=4.0, mfc="none", color="0.3", label=label)
        ax.grid(alpha=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=9,
                  title="B-spline", title_fontsize=9)
    axes[0].set_title("Real part $r$: the rotation quaternion")
    axes[0].set_ylabel("real part (unitless)")
    axes[1].set_title(r"Dual part $d = \frac{1}{2}(0, t)\,r$")
    axes[1].set_ylabel("dual part [m]")
    axes[1].set_xlabel(_xlabel(r.t0))
    fig.suptitle("The 8 dual-quaternion components of the fitted B-spline")
    return _save(fig, Canvas, path)


def _finite_differences(r) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Speed and angular rate (deg/s) from the file's poses ~0.04 s apart (a shorter step
    only shows the file's rounding; at most the whole file for a short one): (mid times,
    speeds, rates, step in ms)."""
    t_rel = (r.traj.times - r.t0).numpy()
    k = min(max(1, round(0.04 / float(np.median(np.diff(t_rel))))), len(t_rel) - 1)
    dt = t_rel[k:] - t_rel[:-k]
    p = r.traj.translations.numpy()
    speed = np.linalg.norm(p[k:] - p[:-k], axis=-1) / dt
    dot = (r.traj.rotations[k:] * r.traj.rotations[:-k]).sum(-1).abs().clamp(max=1.0).numpy()
    rate = np.rad2deg(2 * np.arccos(dot)) / dt
    return 0.5 * (t_rel[k:] + t_rel[:-k]), speed, rate, 1e3 * float(np.median(dt))


def plot_kinematics(Figure, Canvas, path: str, r) -> str:
    """Speed and angular rate of the curve, with finite differences of the poses on top."""
    rel = (r.grid - r.t0).numpy()
    speed = r.kin.linear_velocity.norm(dim=-1).numpy()
    omega = torch.rad2deg(r.kin.angular_velocity.norm(dim=-1)).numpy()
    mid, fd_speed, fd_rate, step_ms = _finite_differences(r)
    fig = Figure(figsize=(11.0, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, fd, curve, color, label, unit, title in (
            (axes[0], fd_speed, speed, "C0", "B-spline |v| (exact derivative)", "speed [m/s]",
             "Linear speed of the body origin"),
            (axes[1], fd_rate, omega, "C3", "B-spline |ω| (exact derivative)",
             "angular rate [deg/s]", "Angular rate")):
        ax.plot(rel, curve, color=color, lw=1.6, alpha=0.8, label=label, zorder=2)
        if bool(r.in_gap.any()):
            ax.fill_between(rel, 0, 1, where=r.in_gap.numpy(), color="0.85", zorder=1,
                            transform=ax.get_xaxis_transform(),
                            label="no poses (gap > 2 knot spacings)")
        ax.plot(mid, fd, ".", color="k", ms=1.8, zorder=3,
                label=f"finite differences of the poses ({step_ms:.0f} ms apart)")
        # outliers of the differences (gaps, glitches) would squash the curve: clip the view
        top = max(float(curve.max()), float(np.percentile(fd, 99.5)) if fd.size else 0.0)
        ax.set_ylim(0.0, 1.15 * top + 1e-12)
        ax.set_ylabel(unit)
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8, markerscale=4)
    axes[1].set_xlabel(_xlabel(r.t0))
    return _save(fig, Canvas, path)


def plot_residuals(Figure, Canvas, path: str, r) -> str:
    """Errors of the curve at the fitted poses (dots, on top) and the held-out ones (rings)."""
    t_rel = (r.traj.times - r.t0).numpy()
    fitted, held = r.fit_idx.numpy(), r.held_idx.numpy()
    fig = Figure(figsize=(11.0, 6.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, err, unit, title in ((axes[0], r.trans_mm, "translation error [mm]", "Translation"),
                                 (axes[1], r.rot_deg, "rotation error [deg]", "Rotation")):
        e = err.numpy()
        if held.size:
            ax.plot(t_rel[held], e[held], "o", ms=4.5, mfc="none", mew=0.8, color="C1",
                    zorder=2, label=f"held-out poses (mean {e[held].mean():.3g})")
        ax.plot(t_rel[fitted], e[fitted], ".", ms=3.0, color="C0", zorder=3,
                label=f"fitted poses (mean {e[fitted].mean():.3g})")
        ax.set_ylabel(unit)
        ax.set_title(f"{title} error of the B-spline at the file's poses")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    axes[1].set_xlabel(_xlabel(r.t0))
    return _save(fig, Canvas, path)


#: The figure functions, in the order of :data:`torch_dq.cli.fit_file.FIGURES`.
PLOTS = (plot_components, plot_kinematics, plot_residuals)

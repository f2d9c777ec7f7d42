r"""The demo behind ``python -m torch_dq demo``: fit dual-quaternion curves to a knee motion.

On the embedded synthetic knee flexion of :mod:`torch_dq.demo.knee` (no download) it

1. samples noisy poses of the tibia relative to the femur (seeded ``torch.Generator``;
   noise in degrees and millimetres);
2. fits a cubic B-spline and a Bézier curve of unit dual quaternions with
   :mod:`torch_dq.nn` (``from_poses`` least-squares initialisation, then :func:`torch_dq.nn.fit`
   with Adam, progress bar on a terminal);
3. writes to the output folder ``fig1_components.png`` (the paper's Fig. 1: the 8
   components, real part on top, dual part below, Bézier solid, spline dotted, control
   points marked), ``frames_3d.png`` (tibia frames along the fitted motion),
   ``axode.png`` (the ruled surface swept by the instantaneous screw axis of the fitted
   spline, the paper's Fig. 2 idea), ``loss.png`` and ``summary.json``;
4. prints the fit errors (rotation in degrees, translation in mm, mean and max over
   held-out times, against the noise-free motion) and timings.

Matplotlib is optional (``pip install 'torch_dq[plot]'``): without it the figures are
skipped with a warning, and the table and ``summary.json`` are still written. Figures are
drawn with the Agg canvas (no display, no change to pyplot's global backend).

Example:
    >>> from torch_dq.demo import run_demo
    >>> summary = run_demo("/tmp/torch_dq_demo", steps=5, plots=False, verbose=False)
    >>> sorted(summary["curves"])
    ['bezier', 'bspline']
"""

from __future__ import annotations

import functools
import json
import math
import os
import sys
import time
from dataclasses import dataclass, field

import torch
from torch import Tensor

from .. import curves, dualquat, losses
from .. import nn as dqnn
from .knee import KneeModel, KneeSamples, sample_poses

__all__ = ["FIGURES", "PLOT_HINT", "run_demo"]

#: What to run when matplotlib is missing.
PLOT_HINT = "pip install 'torch_dq[plot]'"

#: The figures the demo writes (when matplotlib is available).
FIGURES = ("fig1_components.png", "frames_3d.png", "axode.png", "loss.png")

_COMPONENTS = ("w", "x", "y", "z")
_CURVE_LABELS = {"bspline": "B-spline", "bezier": "Bézier"}


# ----------------------------------------------------------------------------- fitting

@dataclass
class _Fit:
    name: str
    module: torch.nn.Module
    history: dqnn.FitHistory
    init_errors: dict
    errors: dict
    seconds: float
    degree: int
    n_ctrl: int
    extra: dict = field(default_factory=dict)


def _errors(pred: Tensor, truth: Tensor) -> dict:
    """Mean and max rotation (deg) and translation (mm) errors."""
    rot = torch.rad2deg(losses.rotation_angle(pred, truth)).double()
    trans = losses.translation_error(pred, truth).double()
    return {"rot_deg_mean": float(rot.mean()), "rot_deg_max": float(rot.max()),
            "trans_mm_mean": float(trans.mean()), "trans_mm_max": float(trans.max())}


def _evaluate(module, times: Tensor) -> Tensor:
    with torch.no_grad():
        return module(module.normalize_time(times))


def _greville(module) -> Tensor:
    """Abscissae of the control points in raw time (Greville's for a B-spline)."""
    n = module.n_ctrl
    tr = module.time_range.detach().cpu().double()
    if isinstance(module, dqnn.BSpline):
        k, p = module.knots.detach().cpu().double(), module.degree
        u = torch.stack([k[i + 1:i + p + 1].mean() for i in range(n)])
        lo, hi = k[p], k[n]
        u = (u - lo) / (hi - lo)
    else:
        u = torch.linspace(0.0, 1.0, n, dtype=torch.float64)
    return tr[0] + u * (tr[1] - tr[0])


def _align(x: Tensor, ref: Tensor) -> Tensor:
    """``x`` with each element's sign flipped to face ``ref`` (same transforms)."""
    dot = (x[..., :4] * ref[..., :4]).sum(-1, keepdim=True)
    return torch.where(dot < 0, -x, x)


def _screw_axes(fn, t: Tensor) -> dict:
    """Instantaneous screw axes (femur frame) of the motion ``fn`` at ``t``.

    ``fn`` maps times to ``(T, 8)`` poses; the spatial twist of ``(x, dx/dt)`` gives the
    axis direction ``l``, moment ``m``, pitch ``h`` and the axis point nearest to the
    femoral origin ``c = l x m`` (all in the femur frame, mm).
    """
    with torch.no_grad():
        x, dx = curves.velocity(fn, t)
    xi = curves.twists(x, dx, frame="spatial")
    l, m, h = curves.screw_axis(xi[..., :3], xi[..., 3:])
    c = torch.linalg.cross(l, m, dim=-1)
    return {"direction": l, "moment": m, "pitch": h, "point": c, "omega": xi[..., :3]}


def _fit_curve(name: str, samples: KneeSamples, n_ctrl: int, degree: int, steps: int,
               optimizer: str, lr: float | None, loss, held_out: Tensor, truth: Tensor,
               verbose: bool) -> _Fit:
    start = time.perf_counter()
    if name == "bspline":
        module = dqnn.BSpline.from_poses(samples.rotations, samples.translations, samples.times,
                                         n_ctrl=n_ctrl, degree=degree)
        deg = degree
    else:
        module = dqnn.Bezier.from_poses(samples.rotations, samples.translations, samples.times,
                                        n_ctrl=n_ctrl)
        deg = n_ctrl - 1
    init_errors = _errors(_evaluate(module, held_out), truth)
    history = dqnn.fit(module, samples.times, samples.poses, optimizer=optimizer, steps=steps,
                       lr=lr, loss=loss, verbose=verbose)
    errors = _errors(_evaluate(module, held_out), truth)
    return _Fit(name, module, history, init_errors, errors, time.perf_counter() - start, deg,
                n_ctrl)


# ----------------------------------------------------------------------------- plots

def _import_matplotlib():
    """``(Figure, FigureCanvasAgg)``; raises ImportError when matplotlib is missing."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3d projection)

    return Figure, FigureCanvasAgg


def _save(fig, canvas_cls, path: str) -> str:
    canvas_cls(fig)
    fig.savefig(path, dpi=110)
    return path


def _np(x: Tensor):
    return x.detach().cpu().double().numpy()


def _plot_components(Figure, Canvas, path, fits, samples, model, plot_t):
    """The paper's Fig. 1: 8 components, real part on top, dual part below."""
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(10.5, 7.0), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    ref_t = model.poses(plot_t.double())
    colors = [f"C{i}" for i in range(4)]
    styles = {"bezier": dict(ls="-", lw=1.8), "bspline": dict(ls=":", lw=2.4)}
    markers = {"bezier": dict(marker="o", ms=7, mfc="none", mew=1.6),
               "bspline": dict(marker="s", ms=6, mfc="none", mew=1.6)}
    sample_x = _align(samples.poses.cpu().double(), samples.truth.cpu().double())
    for f in fits:
        x = _align(_evaluate(f.module, plot_t.to(samples.times)).cpu().double(), ref_t)
        g = _greville(f.module)
        ctrl = _align(f.module.control_points.detach().cpu().double(), model.poses(g))
        for part, ax in enumerate(axes):
            for j in range(4):
                k = 4 * part + j
                ax.plot(_np(plot_t), _np(x[:, k]), color=colors[j], **styles[f.name])
                ax.plot(_np(g), _np(ctrl[:, k]), color=colors[j], ls="none", **markers[f.name])
    for part, ax in enumerate(axes):
        for j in range(4):
            ax.plot(_np(samples.times), _np(sample_x[:, 4 * part + j]), ".", color=colors[j],
                    ms=3, alpha=0.35)
        ax.grid(alpha=0.3)
    axes[0].set_title("Real part: rotation quaternion $r = (r_w, r_x, r_y, r_z)$")
    axes[0].set_ylabel("real part components (unitless)")
    axes[1].set_title(r"Dual part: $d = \frac{1}{2}(0, t)\,r$ (translation $t$ in mm)")
    axes[1].set_ylabel("dual part components (mm)")
    axes[1].set_xlabel("time (s)")
    by_name = {f.name: f for f in fits}
    handles = [Line2D([], [], color=c, lw=2, label=f"component {n}")
               for c, n in zip(colors, _COMPONENTS, strict=True)]
    if "bezier" in by_name:
        f = by_name["bezier"]
        handles += [Line2D([], [], color="k", label=f"Bézier (degree {f.degree})",
                           **styles["bezier"]),
                    Line2D([], [], color="k", ls="none", label="Bézier control points",
                           **markers["bezier"])]
    if "bspline" in by_name:
        f = by_name["bspline"]
        handles += [Line2D([], [], color="k", label=f"B-spline (degree {f.degree})",
                           **styles["bspline"]),
                    Line2D([], [], color="k", ls="none",
                           label="B-spline control points\n(at Greville abscissae)",
                           **markers["bspline"])]
    handles.append(Line2D([], [], color="0.4", ls="none", marker=".", alpha=0.6,
                          label="noisy samples"))
    fig.legend(handles=handles, loc="outside right center", fontsize=9)
    fig.suptitle("Dual-quaternion Bézier (solid) vs B-spline (dotted) fitted to a knee "
                 "flexion (paper's Fig. 1)")
    return _save(fig, Canvas, path)


def _set_equal_3d(ax, pts, pad: float = 5.0, min_span: float = 30.0):
    """Equal scale on the three axes: box aspect proportional to the data ranges."""
    lo, hi = pts.min(0) - pad, pts.max(0) + pad
    mid, span = (lo + hi) / 2, (hi - lo).clip(min=min_span)
    lo, hi = mid - span / 2, mid + span / 2
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(span))


def _label_3d(ax):
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(5))
    ax.set_xlabel("x lateral (mm)")
    ax.set_ylabel("y anterior (mm)")
    ax.set_zlabel("z proximal (mm)")


def _plot_frames(Figure, Canvas, path, fit, samples, model):
    """Tibia frames along the fitted B-spline, seen in the femur frame (two views)."""
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(14.0, 7.0), layout="constrained")
    ax_all = fig.add_subplot(1, 2, 1, projection="3d", computed_zorder=False)
    ax_zoom = fig.add_subplot(1, 2, 2, projection="3d", computed_zorder=False)
    dur = model.duration_s
    rgb = ("tab:red", "tab:green", "tab:blue")
    names = ("x (lateral)", "y (anterior)", "z (proximal)")
    f64 = torch.float64
    dense = torch.linspace(0.0, dur, 200, dtype=f64)
    p_fit = dualquat.to_rt(_evaluate(fit.module, dense.to(samples.times)).cpu().double())[1]
    p_true = dualquat.to_rt(model.poses(dense))[1]
    p_obs = samples.translations.cpu().double()
    shaft = 60.0

    def frames(ax, times, axis_len, lw):
        x = _evaluate(fit.module, times.to(samples.times)).cpu().double()
        origin = dualquat.apply(x, torch.zeros(3, dtype=f64))
        for i in range(len(times)):
            for j, c in enumerate(rgb):
                e = torch.zeros(3, dtype=f64)
                e[j] = axis_len
                seg = zip(_np(origin[i]), _np(dualquat.apply(x[i], e)), strict=True)
                ax.plot(*seg, color=c, lw=lw, zorder=4)
        return x

    def paths(ax):
        ax.scatter(*_np(p_obs).T, s=5, color="0.35", alpha=0.5, zorder=2,
                   label="noisy samples")
        ax.plot(*_np(p_true).T, color="k", lw=1.2, ls="--", zorder=3,
                label="tibia origin, true motion")
        ax.plot(*_np(p_fit).T, color="darkorange", lw=2.5, zorder=3,
                label="tibia origin, fitted B-spline")

    # left: the whole leg, the tibial shaft at a few flexion angles
    ax_all.plot([0, 0], [0, 0], [0, shaft], color="0.55", lw=7, alpha=0.45, zorder=1)
    ax_all.text(0, 0, shaft + 6, "femur", ha="center", zorder=5)
    times = torch.linspace(0.0, dur, 7, dtype=f64)
    x = frames(ax_all, times, 10.0, 2.0)
    tip = dualquat.apply(x, torch.tensor([0.0, 0.0, -shaft], dtype=f64))
    origin = dualquat.apply(x, torch.zeros(3, dtype=f64))
    for i, phi in enumerate(model.flexion(times).tolist()):
        seg = zip(_np(origin[i]), _np(tip[i]), strict=True)
        ax_all.plot(*seg, color="0.55", lw=5, alpha=0.3, zorder=1)
        ax_all.text(*_np(tip[i]), f" {phi:.0f}°", fontsize=9, zorder=5)
    paths(ax_all)
    pts = torch.cat((p_true, tip, torch.tensor([[0.0, 0.0, shaft + 6], [-20.0, 0, 0],
                                                [20.0, 0, 0]], dtype=f64)))
    _set_equal_3d(ax_all, _np(pts))
    ax_all.set_title("Tibia relative to the femur (femur frame, mm) at 7 times of the\n"
                     "fitted motion (labels: true flexion; shaft schematic, 60 mm)")
    # right: close-up of the frames along the fitted path
    paths(ax_zoom)
    frames(ax_zoom, torch.linspace(0.0, dur, 13, dtype=f64), 6.0, 1.8)
    for j, c in enumerate(rgb):  # the femur frame at the origin
        e = [0.0, 0.0, 0.0]
        e[j] = 10.0
        ax_zoom.plot([0, e[0]], [0, e[1]], [0, e[2]], color=c, lw=3.5, zorder=4)
    ax_zoom.text(0, 0, 12, "femur frame", ha="center", fontsize=9, zorder=5)
    _set_equal_3d(ax_zoom, _np(torch.cat((p_true, p_obs, 10.0 * torch.eye(3, dtype=f64),
                                          torch.tensor([[0.0, 0.0, 13.0]], dtype=f64)))),
                  pad=3.0, min_span=15.0)
    ax_zoom.set_title("Close-up: tibia frames (6 mm axes) at 13 times of the fitted B-spline")
    for ax in (ax_all, ax_zoom):
        _label_3d(ax)
        ax.view_init(elev=14, azim=-50)
    handles, _ = ax_zoom.get_legend_handles_labels()
    handles += [Line2D([], [], color=c, lw=2, label=f"frame {n} axis")
                for c, n in zip(rgb, names, strict=True)]
    fig.legend(handles=handles, loc="outside upper center", ncol=6, fontsize=9)
    return _save(fig, Canvas, path)


def _sagittal(axes: dict) -> tuple:
    """Where each screw axis pierces the sagittal plane x = 0, and its tilt (deg)."""
    l, c = axes["direction"].double(), axes["point"].double()
    s = -c[..., 0] / l[..., 0]
    pierce = c + s[..., None] * l
    tilt = torch.rad2deg(torch.acos(l[..., 0].abs().clamp(max=1.0)))
    return pierce, tilt


#: Fraction of the motion left out at each end of the axode plots: the velocity of a
#: curve fitted to noisy samples is poorly constrained at its ends.
AXODE_MARGIN = 0.05


def _plot_axode(Figure, Canvas, path, fits, samples, model):
    """Fixed axode (ruled surface of the instantaneous screw axis) of the fitted spline."""
    from matplotlib import cm
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(14.0, 7.0), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=(1.4, 1.0))
    ax3 = fig.add_subplot(grid[:, 0], projection="3d", computed_zorder=False)
    ax_s = fig.add_subplot(grid[0, 1])
    ax_t = fig.add_subplot(grid[1, 1])
    dur = model.duration_s
    t = torch.linspace(AXODE_MARGIN * dur, (1 - AXODE_MARGIN) * dur, 61, dtype=torch.float64)
    flex = _np(model.flexion(t))
    truth = _screw_axes(model.poses, t)
    by_name = {f.name: f for f in fits}
    fitted = {}
    for f in fits:
        tt = f.module.normalize_time(t.to(samples.times)).detach()
        fitted[f.name] = {k: v.cpu().double() for k, v in _screw_axes(f.module, tt).items()}
    half = 40.0  # half length of the drawn rulings (mm), about half a knee's width
    s = torch.linspace(-half, half, 2, dtype=torch.float64)
    norm = Normalize(0.0, model.flexion_deg)
    cmap = cm.viridis
    main = "bspline" if "bspline" in fitted else next(iter(fitted))
    axis_fit = fitted[main]
    l = axis_fit["direction"] * torch.sign(-axis_fit["direction"][..., :1])  # medial (-x)
    surf = axis_fit["point"][:, None, :] + s[None, :, None] * l[:, None, :]
    colors = cmap(norm(flex))[:, None, :].repeat(2, axis=1)
    ax3.plot_surface(*(_np(surf[..., k]) for k in range(3)), facecolors=colors,
                     shade=False, alpha=0.8, linewidth=0.25, edgecolor="k",
                     rstride=1, cstride=1, zorder=1)
    lt = truth["direction"] * torch.sign(-truth["direction"][..., :1])
    every = 10
    for i in range(0, len(t), every):
        seg = truth["point"][i] + s[:, None] * lt[i]
        ax3.plot(*_np(seg).T, color="crimson", lw=1.6, ls="--", zorder=3)
    p_true = dualquat.to_rt(model.poses(t))[1]
    ax3.plot(*_np(p_true).T, color="k", lw=1.5, zorder=3)
    ax3.plot([0, 0], [0, 0], [0, 35], color="0.55", lw=6, alpha=0.45, zorder=2)
    ax3.scatter([0], [0], [0], color="k", s=18, zorder=4)
    ax3.text(0, 0, 38, "femur", ha="center", fontsize=9, zorder=5)
    pts = torch.cat((surf.reshape(-1, 3), p_true, p_true.new_tensor([[0.0, 0.0, 38.0]])))
    _set_equal_3d(ax3, _np(pts))
    _label_3d(ax3)
    ax3.view_init(elev=18, azim=-40)
    fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax3, shrink=0.55, pad=0.1,
                 label="flexion (deg)")
    ax3.legend(handles=[
        Line2D([], [], color=cmap(0.6), lw=6, alpha=0.8,
               label=f"axode of the fitted {_CURVE_LABELS[main]} (rulings of ±{half:.0f} mm)"),
        Line2D([], [], color="crimson", ls="--",
               label="true screw axis (one ruling in ten)"),
        Line2D([], [], color="k", label="tibia origin path (true)"),
        Line2D([], [], color="0.55", lw=6, alpha=0.45, label="femoral shaft (schematic)")],
        loc="upper left", fontsize=8)
    ax3.set_title("Axode: the ruled surface swept by the instantaneous screw axis\n"
                  "(femur frame; the origin is the femoral epicondylar midpoint)")
    styles = {"bezier": dict(ls="-", lw=1.8, color="C0"),
              "bspline": dict(ls=":", lw=2.4, color="C3")}
    pt, tilt_t = _sagittal(truth)
    ax_s.plot(_np(pt[:, 1]), _np(pt[:, 2]), color="k", ls="--", lw=1.2, label="true motion")
    ax_t.plot(flex, _np(tilt_t), color="k", ls="--", lw=1.2, label="true motion")
    for name, axis_f in fitted.items():
        p, tilt = _sagittal(axis_f)
        label = f"fitted {_CURVE_LABELS[name]} (degree {by_name[name].degree})"
        ax_s.plot(_np(p[:, 1]), _np(p[:, 2]), label=label, **styles[name])
        ax_t.plot(flex, _np(tilt), label=label, **styles[name])
    marks = [0, len(t) // 2, len(t) - 1]
    for i in marks:
        ax_s.plot(float(pt[i, 1]), float(pt[i, 2]), "ko", ms=4)
        ax_s.annotate(f"{flex[i]:.0f}°", (float(pt[i, 1]), float(pt[i, 2])), fontsize=8,
                      textcoords="offset points", xytext=(5, -10))
        for name, axis_f in fitted.items():
            p = _sagittal(axis_f)[0]
            ax_s.plot(float(p[i, 1]), float(p[i, 2]), "o", ms=4, mfc="none",
                      color=styles[name]["color"])
    ax_s.set_xlabel("y anterior (mm)")
    ax_s.set_ylabel("z proximal (mm)")
    ax_s.set_title("Where the screw axis crosses the mid-sagittal plane x = 0\n"
                   "(circles: same flexion; the ends of a noisy fit are the least certain)",
                   fontsize=10)
    ax_s.set_aspect("equal", adjustable="datalim")
    ax_s.grid(alpha=0.3)
    ax_s.legend(fontsize=8)
    ax_t.set_xlabel("flexion (deg)")
    ax_t.set_ylabel("tilt from the medial-lateral axis (deg)")
    ax_t.set_title("Screw axis tilt (from the coupled internal rotation)")
    ax_t.grid(alpha=0.3)
    ax_t.legend(fontsize=8)
    lo, hi = 100 * AXODE_MARGIN, 100 * (1 - AXODE_MARGIN)
    fig.suptitle(f"Instantaneous screw axis of the knee flexion, {lo:.0f}-{hi:.0f}% of the "
                 f"motion (paper's Fig. 2 idea)")
    return _save(fig, Canvas, path)


def _plot_loss(Figure, Canvas, path, fits, optimizer, lr, trans_weight):
    fig = Figure(figsize=(8.0, 4.8), layout="constrained")
    ax = fig.add_subplot()
    styles = {"bezier": dict(ls="-", lw=1.8, color="C0"),
              "bspline": dict(ls=":", lw=2.4, color="C3")}
    for f in fits:
        loss = [*f.history.loss, f.history.final_loss]
        change = 100.0 * (loss[-1] - loss[0]) / loss[0]
        ax.plot(range(len(loss)), loss, label=f"{_CURVE_LABELS[f.name]} (degree {f.degree}, "
                f"{f.n_ctrl} control points): {change:+.2f}% from the init", **styles[f.name])
        ax.plot([0], [loss[0]], "o", color=styles[f.name]["color"], mfc="none")
    ax.set_xlabel("optimizer step (step 0: least-squares init from_poses)")
    ax.set_ylabel(r"pose loss: mean of $\theta^2 + w\,|\Delta t|^2$ (rad$^2$)")
    lr_txt = "default lr" if lr is None else f"lr {lr:g}"
    ax.set_title(f"nn.fit on the noisy poses ({optimizer}, {lr_txt}; "
                 f"w = {trans_weight:.3g} rad$^2$/mm$^2$)")
    ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    return _save(fig, Canvas, path)


# ----------------------------------------------------------------------------- driver

def _table(summary: dict) -> str:
    rows = [("noisy samples (at sample times)", summary["noise_errors"], "", "", "")]
    for name in ("bspline", "bezier"):
        c = summary["curves"].get(name)
        if c is None:
            continue
        label = f"{_CURVE_LABELS[name]} ({c['n_ctrl']} ctrl, degree {c['degree']})"
        rows.append((label + ", init", c["init_errors"], "", "", ""))
        rows.append((label + ", fit", c["errors"], str(c["steps"]), f"{c['final_loss']:.3e}",
                     f"{c['seconds']:.1f}"))
    head = (f"{'':41s}{'rotation (deg)':>16s}{'translation (mm)':>18s}\n"
            f"{'curve':41s}{'mean':>8s}{'max':>8s}{'mean':>9s}{'max':>9s}"
            f"{'steps':>7s}{'loss':>11s}{'time (s)':>10s}")
    lines = [head, "-" * len(head.splitlines()[1])]
    for label, e, steps, loss, secs in rows:
        lines.append(f"{label:41s}{e['rot_deg_mean']:8.2f}{e['rot_deg_max']:8.2f}"
                     f"{e['trans_mm_mean']:9.2f}{e['trans_mm_max']:9.2f}{steps:>7s}{loss:>11s}"
                     f"{secs:>10s}")
    return "\n".join(lines)


def run_demo(out: str = "torch_dq_demo", *, n_ctrl: int = 8, degree: int = 3, steps: int = 300,
             seed: int = 0, device: str = "cpu", dtype: torch.dtype = torch.float32,
             n_samples: int = 100, rot_noise_deg: float = 1.0, trans_noise_mm: float = 1.0,
             optimizer: str = "adam", lr: float | None = 1e-3, plots: bool = True,
             verbose: bool = True, stream=None) -> dict:
    """Run the demo; returns the summary written to ``out/summary.json``.

    Args:
        out: output folder (created).
        n_ctrl: control points of each curve (the Bézier curve has degree ``n_ctrl - 1``).
        degree: degree of the B-spline, ``< n_ctrl``.
        steps: maximum optimizer steps of each fit.
        seed: seed of the noise generator.
        device: torch device of the fit (``"cpu"``, ``"cuda"``).
        dtype: floating dtype of the fit.
        n_samples: number of noisy poses.
        rot_noise_deg: rotation noise per axis (degrees).
        trans_noise_mm: translation noise per axis (mm).
        optimizer: ``"adam"``, ``"lbfgs"`` or ``"sgd"`` (see :func:`torch_dq.nn.fit`).
        lr: learning rate (``None``: the optimizer's default in :func:`torch_dq.nn.fit`);
            1e-3 suits Adam here, the least-squares initialisation being already close.
        plots: write the PNG figures (needs matplotlib).
        verbose: print the table (and show fit progress bars on a terminal).
        stream: where to print (default ``sys.stdout``).

    Returns:
        The summary dict (settings, errors per curve, timings, files written, warnings).
    """
    stream = sys.stdout if stream is None else stream
    t_start = time.perf_counter()
    os.makedirs(out, exist_ok=True)
    device = torch.device(device)
    model = KneeModel()
    gen = torch.Generator().manual_seed(seed)
    samples = sample_poses(model, n=n_samples, rot_noise_deg=rot_noise_deg,
                           trans_noise_mm=trans_noise_mm, generator=gen, dtype=dtype,
                           device=device)
    # Held-out times: midway between a fine grid, never a sample time.
    n_held = 400
    held_out = ((torch.arange(n_held, dtype=torch.float64) + 0.5) / n_held * model.duration_s)
    truth = model.poses(held_out).to(dtype=dtype, device=device)
    held_out = held_out.to(dtype=dtype, device=device)
    # Weigh rotation and translation errors by the noise levels: one noise sigma in
    # degrees counts like one noise sigma in mm.
    sigma_r = math.radians(rot_noise_deg) if rot_noise_deg > 0 else math.radians(1.0)
    sigma_t = trans_noise_mm if trans_noise_mm > 0 else 1.0
    trans_weight = (sigma_r / sigma_t) ** 2
    loss = functools.partial(losses.pose_loss, trans_weight=trans_weight)
    fits = [_fit_curve(name, samples, n_ctrl, degree, steps, optimizer, lr, loss, held_out,
                       truth, verbose) for name in ("bspline", "bezier")]
    noise_errors = _errors(samples.poses, samples.truth)

    summary = {
        "description": "torch_dq demo: dual-quaternion curves fitted to a synthetic knee "
                       "flexion (tibia relative to femur, mm); errors against the noise-free "
                       "motion at held-out times",
        "settings": {"n_ctrl": n_ctrl, "degree": degree, "steps": steps, "seed": seed,
                     "device": str(device), "dtype": str(dtype).replace("torch.", ""),
                     "n_samples": n_samples, "rot_noise_deg": rot_noise_deg,
                     "trans_noise_mm": trans_noise_mm, "optimizer": optimizer, "lr": lr,
                     "trans_weight_rad2_per_mm2": trans_weight, "n_held_out": n_held,
                     "threads": torch.get_num_threads()},
        "knee_model": model.as_dict(),
        "noise_errors": noise_errors,
        "curves": {f.name: {"n_ctrl": f.n_ctrl, "degree": f.degree, "errors": f.errors,
                            "init_errors": f.init_errors, "steps": f.history.steps,
                            "initial_loss": f.history.loss[0] if f.history.loss else None,
                            "final_loss": f.history.final_loss,
                            "converged": f.history.converged, "seconds": f.seconds}
                   for f in fits},
        "figures": [],
        "warnings": [],
    }

    if plots:
        try:
            Figure, Canvas = _import_matplotlib()
        except ImportError:
            msg = (f"matplotlib is not installed: no figures were written (the table and "
                   f"summary.json were). Install the plotting extra with:  {PLOT_HINT}")
            summary["warnings"].append(msg)
            print(f"warning: {msg}", file=sys.stderr)
        else:
            plot_t = torch.linspace(0.0, model.duration_s, 300, dtype=torch.float64)
            by_name = {f.name: f for f in fits}
            paths = [os.path.join(out, name) for name in FIGURES]
            _plot_components(Figure, Canvas, paths[0], fits, samples, model, plot_t)
            _plot_frames(Figure, Canvas, paths[1], by_name["bspline"], samples, model)
            _plot_axode(Figure, Canvas, paths[2], fits, samples, model)
            _plot_loss(Figure, Canvas, paths[3], fits, optimizer, lr, trans_weight)
            summary["figures"] = [os.path.basename(p) for p in paths]

    summary["seconds_total"] = time.perf_counter() - t_start
    with open(os.path.join(out, "summary.json"), "w", encoding="utf-8") as fh:
        json.dump(summary, fh, indent=2)
    if verbose:
        print(f"torch_dq demo: knee flexion 0-{model.flexion_deg:g} deg, {n_samples} noisy "
              f"poses (noise {rot_noise_deg:g} deg, {trans_noise_mm:g} mm per axis), seed "
              f"{seed}, {optimizer} up to {steps} steps on {device} "
              f"({summary['settings']['dtype']})", file=stream)
        print(f"errors vs the noise-free motion at {n_held} held-out times:\n", file=stream)
        print(_table(summary), file=stream)
        files = ", ".join(summary["figures"] + ["summary.json"])
        print(f"\nwrote {files} to {os.path.abspath(out)}", file=stream)
        if plots and not summary["figures"]:
            print(f"figures skipped: matplotlib is missing; install it with  {PLOT_HINT}",
                  file=stream)
        print(f"total time {summary['seconds_total']:.1f} s", file=stream)
    return summary

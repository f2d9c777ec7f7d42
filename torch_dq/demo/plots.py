r"""The demo's figures (matplotlib, Agg canvas; no display, pyplot's state untouched).

Each function draws one PNG from the demo's fitted curves (objects with ``name``
(``"bspline"`` or ``"bezier"``), ``module``, ``degree``, ``n_ctrl`` and ``history``), the
noisy samples and the knee model. Every panel has its own legend, axis labels with units, and
the figure is saved with a tight bounding box so that no label is clipped.

- :func:`plot_components`: the paper's Fig. 1, the 8 components over time.
- :func:`plot_frames`: the tibia's frames along the fitted motion, in the femur frame.
- :func:`plot_axode`: the axodes (ruled surfaces of the instantaneous screw axis) of both
  fitted curves against the true motion.
- :func:`plot_loss`: what :func:`torch_dq.nn.fit` does, for two optimizers.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from .. import curves, dualquat
from .._report import align as _align
from .._report import evaluate as _evaluate
from .._report import import_matplotlib

__all__ = ["import_matplotlib", "plot_axode", "plot_components", "plot_frames", "plot_loss"]

CURVE_LABELS = {"bspline": "B-spline", "bezier": "Bézier"}
# Bézier: a wide pale band; B-spline: a thin dashed line on top, so both show where they meet.
_LINE: dict[str, dict[str, Any]] = {
    "bezier": {"ls": "-", "lw": 3.2, "alpha": 0.4, "solid_capstyle": "butt"},
    "bspline": {"ls": (0, (4, 2)), "lw": 1.3, "alpha": 1.0}}
_CTRL: dict[str, dict[str, Any]] = {
    "bezier": {"marker": "o", "ms": 7, "mfc": "none", "mew": 1.4},
    "bspline": {"marker": "s", "ms": 5, "mfc": "white", "mew": 1.4}}
_CURVE_COLOR = {"bezier": "tab:blue", "bspline": "tab:red"}
_DPI = 120

#: Fraction of the motion left out at each end of the axode plots: the velocity of a
#: curve fitted to noisy samples is poorly constrained at its ends.
AXODE_MARGIN = 0.05


def _save(fig, canvas_cls, path: str) -> str:
    canvas_cls(fig)
    fig.savefig(path, dpi=_DPI, bbox_inches="tight", pad_inches=0.15)
    return path


def _np(x: Tensor):
    return x.detach().cpu().double().numpy()


def _abscissae(module) -> Tensor:
    """Times at which to draw the control points: Greville abscissae of a B-spline's knots,
    evenly spaced over a Bézier curve's domain."""
    if hasattr(module, "knots"):
        k, p = module.knots.detach().cpu().double(), module.degree
        return torch.stack([k[i + 1:i + p + 1].mean() for i in range(module.n_ctrl)])
    t0, t1 = module.domain
    return torch.linspace(float(t0), float(t1), module.n_ctrl, dtype=torch.float64)


def _screw_axes(x: Tensor, dx: Tensor) -> dict:
    """Instantaneous screw axes (femur frame, mm) of poses ``x`` moving at ``dx = dx/dt``:
    direction ``l``, moment ``m``, pitch and the axis point nearest to the femoral origin."""
    xi = curves.twists(x, dx, frame="spatial")
    direction, moment, pitch = curves.screw_axis(xi[..., :3], xi[..., 3:])
    point = torch.linalg.cross(direction, moment, dim=-1)
    return {"direction": direction, "moment": moment, "pitch": pitch, "point": point}


def _fitted_axes(module, t: Tensor) -> dict:
    with torch.no_grad():
        x, dx = module.derivatives(t.to(module.control_points.device), order=1)
    return {k: v.cpu().double() for k, v in _screw_axes(x.double(), dx.double()).items()}


def _true_axes(model, t: Tensor) -> dict:
    with torch.no_grad():
        x, dx = curves.velocity(model.poses, t)  # forward-mode AD through the model
    return _screw_axes(x, dx)


def _legend_right(ax, handles, labels, **kwargs):
    """A legend right of ``ax``; a tuple of handles is drawn side by side (one entry in the
    colours of the four components)."""
    from matplotlib.legend_handler import HandlerTuple

    kw = {"loc": "center left", "bbox_to_anchor": (1.01, 0.5), "fontsize": 8.5,
          "frameon": False, "handler_map": {tuple: HandlerTuple(ndivide=None, pad=0.0)},
          "handlelength": 3.2}
    kw.update(kwargs)
    return ax.legend(handles, labels, **kw)


def _legend_below(ax, handles, ncol: int = 2):
    """A legend under a 3-D axes, clear of its panes."""
    return ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.02),
                     ncol=ncol, fontsize=8.5, frameon=False)


# ----------------------------------------------------------------------------- Fig. 1

def plot_components(Figure, Canvas, path, fits, samples, model):
    """The paper's Fig. 1: the 8 components over time, real part on top, dual part below."""
    from matplotlib.lines import Line2D

    fig = Figure(figsize=(11.0, 7.6), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    t = torch.linspace(0.0, model.duration_s, 400, dtype=torch.float64)
    ref = model.poses(t)
    colors = [f"C{i}" for i in range(4)]
    samples_x = _align(samples.poses.cpu().double(), samples.truth.cpu().double())
    times = _np(samples.times)
    for part, ax in enumerate(axes):
        for j in range(4):
            ax.plot(times, _np(samples_x[:, 4 * part + j]), ".", color=colors[j], ms=3,
                    alpha=0.35, zorder=1)
    for f in sorted(fits, key=lambda f: f.name != "bezier"):  # the band first, the line on top
        x = _align(_evaluate(f.module, t), ref)
        g = _abscissae(f.module)
        ctrl = _align(f.module.control_points.detach().cpu().double(), model.poses(g))
        for part, ax in enumerate(axes):
            for j in range(4):
                k = 4 * part + j
                ax.plot(_np(t), _np(x[:, k]), color=colors[j], zorder=2, **_LINE[f.name])
                ax.plot(_np(g), _np(ctrl[:, k]), ls="none", color=colors[j], zorder=3,
                        **_CTRL[f.name])
    by_name = {f.name: f for f in fits}
    for part, (ax, sym) in enumerate(zip(axes, ("r", "d"), strict=True)):
        handles: list[Any] = [Line2D([], [], color=c, lw=2) for c in colors]
        labels = [f"${sym}_{n}$" for n in "wxyz"]
        for name in ("bezier", "bspline"):  # each style in the colours of its curves
            if name in by_name:
                handles += [tuple(Line2D([], [], color=c, **_LINE[name]) for c in colors),
                            tuple(Line2D([], [], color=c, ls="none", **_CTRL[name])
                                  for c in colors)]
                labels += [f"{CURVE_LABELS[name]} (degree {by_name[name].degree})",
                           f"{CURVE_LABELS[name]} control points"]
        handles.append(tuple(Line2D([], [], color=c, ls="none", marker=".", alpha=0.6)
                             for c in colors))
        labels.append("noisy samples")
        _legend_right(ax, handles, labels, title="component" if part == 0 else None)
        ax.grid(alpha=0.3)
    axes[0].set_title(r"Real part: rotation quaternion $r = (r_w, r_x, r_y, r_z)$")
    axes[0].set_ylabel("real part (unitless)")
    axes[1].set_title(r"Dual part $d = \frac{1}{2}(0, t)\,r$, translation $t$ in mm")
    axes[1].set_ylabel("dual part (mm)")
    axes[1].set_xlabel("time (s)")
    fig.suptitle("Dual-quaternion Bézier curve and B-spline fitted to a knee flexion "
                 "(paper's Fig. 1); control points drawn at their Greville abscissae")
    return _save(fig, Canvas, path)


# ----------------------------------------------------------------------------- frames

def _set_equal_3d(ax, pts, pad: float = 5.0, min_span: float = 30.0, zoom: float = 0.88):
    """Equal scale on the three axes; ``zoom`` < 1 leaves room for the axis labels."""
    lo, hi = pts.min(0) - pad, pts.max(0) + pad
    mid, span = (lo + hi) / 2, (hi - lo).clip(min=min_span)
    lo, hi = mid - span / 2, mid + span / 2
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(span), zoom=zoom)


def _label_3d(ax):
    """Axis labels, and ticks in proportion to each axis's drawn length (a short axis gets
    fewer, so that its labels do not crowd)."""
    from matplotlib.ticker import MaxNLocator

    spans = [abs(hi - lo) for lo, hi in (ax.get_xlim(), ax.get_ylim(), ax.get_zlim())]
    for axis, span in zip((ax.xaxis, ax.yaxis, ax.zaxis), spans, strict=True):
        axis.set_major_locator(MaxNLocator(max(2, round(5 * span / max(spans)))))
    ax.set_xlabel("x lateral (mm)", labelpad=8)
    ax.set_ylabel("y anterior (mm)", labelpad=8)
    ax.set_zlabel("z proximal (mm)", labelpad=8)


def _equal_arc_times(p: Tensor, t: Tensor, n: int) -> Tensor:
    """``n`` times from ``t`` whose points ``p`` are evenly spaced along the path."""
    s = torch.cat((p.new_zeros(1), (p[1:] - p[:-1]).norm(dim=-1).cumsum(0)))
    idx = torch.searchsorted(s, torch.linspace(0.0, float(s[-1]), n, dtype=s.dtype))
    return t[idx.clamp(max=len(t) - 1)]


def _plot_leg(ax_leg, fit, model, paths, p_true) -> None:
    """The frames figure's left panel: the tibial shaft at a few flexion angles (no frames:
    they would crowd), the femoral shaft and the paths (``paths(ax)`` draws them)."""
    from matplotlib.lines import Line2D

    f64 = torch.float64
    shaft = 60.0
    ax_leg.plot([0, 0], [0, 0], [0, shaft], color="0.45", lw=7, alpha=0.5, zorder=1)
    times = torch.linspace(0.0, model.duration_s, 7, dtype=f64)
    x = _evaluate(fit.module, times)
    origin = dualquat.apply(x, torch.zeros(3, dtype=f64))
    tip = dualquat.apply(x, torch.tensor([0.0, 0.0, -shaft], dtype=f64))
    for i, phi in enumerate(model.flexion(times).tolist()):
        ax_leg.plot(*zip(_np(origin[i]), _np(tip[i]), strict=True), color="tab:purple", lw=4,
                    alpha=0.35, zorder=1)
        ax_leg.text(*_np(tip[i]), f" {phi:.0f}°", fontsize=9, zorder=5)
    paths(ax_leg)
    ax_leg.scatter([0], [0], [0], color="k", s=20, zorder=4)
    pts = torch.cat((p_true, tip, torch.tensor([[0.0, 0.0, shaft], [-20.0, 0, 0], [20.0, 0, 0]],
                                               dtype=f64)))
    _set_equal_3d(ax_leg, _np(pts))
    ax_leg.set_title("Tibia relative to the femur at 7 times of the fitted motion\n"
                     "(labels: true flexion; shafts schematic, 60 mm)", fontsize=11)
    leg_handles, _ = ax_leg.get_legend_handles_labels()
    leg_handles += [
        Line2D([], [], color="0.45", lw=6, alpha=0.5, label="femoral shaft (schematic)"),
        Line2D([], [], color="tab:purple", lw=4, alpha=0.35, label="tibial shaft (schematic)"),
        Line2D([], [], color="k", ls="none", marker="o", ms=5,
               label="femoral origin (epicondylar midpoint)")]
    _legend_below(ax_leg, leg_handles)


def plot_frames(Figure, Canvas, path, fit, samples, model):
    """The tibia relative to the femur along the fitted B-spline (femur frame, mm)."""
    from matplotlib.lines import Line2D

    f64 = torch.float64
    fig = Figure(figsize=(14.0, 7.4), layout="constrained")
    ax_leg = fig.add_subplot(1, 2, 1, projection="3d", computed_zorder=False)
    ax_zoom = fig.add_subplot(1, 2, 2, projection="3d", computed_zorder=False)
    rgb = ("tab:red", "tab:green", "tab:blue")
    names = ("x (lateral)", "y (anterior)", "z (proximal)")
    dense = torch.linspace(0.0, model.duration_s, 400, dtype=f64)
    p_fit = dualquat.to_rt(_evaluate(fit.module, dense))[1]
    p_true = dualquat.to_rt(model.poses(dense))[1]
    p_obs = samples.translations.cpu().double()

    def paths(ax):
        ax.plot(*_np(p_true).T, color="k", lw=1.2, ls="--", zorder=3,
                label="tibia origin, true motion")
        ax.plot(*_np(p_fit).T, color="darkorange", lw=2.5, zorder=3,
                label="tibia origin, fitted B-spline")

    _plot_leg(ax_leg, fit, model, paths, p_true)

    # right: close-up, tibia frames evenly spaced along the fitted path
    paths(ax_zoom)
    ax_zoom.scatter(*_np(p_obs).T, s=5, color="0.35", alpha=0.5, zorder=2, label="noisy samples")
    frame_t = _equal_arc_times(p_fit, dense, 9)
    xf = _evaluate(fit.module, frame_t)
    of = dualquat.apply(xf, torch.zeros(3, dtype=f64))
    axis_len, femur_len = 3.5, 10.0
    for j, c in enumerate(rgb):
        e = torch.zeros(3, dtype=f64)
        e[j] = axis_len
        ends = dualquat.apply(xf, e)
        for i in range(len(frame_t)):
            ax_zoom.plot(*zip(_np(of[i]), _np(ends[i]), strict=True), color=c, lw=1.8, zorder=4)
        femur_axis = e * (femur_len / axis_len)
        ax_zoom.plot([0, femur_axis[0]], [0, femur_axis[1]], [0, femur_axis[2]], color=c,
                     lw=3.5, zorder=4)
    for i in (0, len(frame_t) - 1):
        phi = float(model.flexion(frame_t[i:i + 1]))
        ax_zoom.text(*_np(of[i] + torch.tensor([1.5, 0.0, -3.0], dtype=f64)),
                     f"flexion {phi:.0f}°", fontsize=9, zorder=5)
    _set_equal_3d(ax_zoom, _np(torch.cat((p_true, p_obs, 10.0 * torch.eye(3, dtype=f64)))),
                  pad=3.0, min_span=15.0)
    ax_zoom.set_title(f"Close-up: tibia frames ({axis_len:g} mm axes) at {len(frame_t)} "
                      "points evenly spaced\nalong the fitted path; femur frame at the origin "
                      f"({femur_len:g} mm axes)", fontsize=11)
    zoom_handles, _ = ax_zoom.get_legend_handles_labels()
    zoom_handles += [Line2D([], [], color=c, lw=2, label=f"frame axis {n}")
                     for c, n in zip(rgb, names, strict=True)]
    _legend_below(ax_zoom, zoom_handles)
    for ax, azim in ((ax_leg, -50), (ax_zoom, -25)):  # the close-up seen more from the side
        _label_3d(ax)
        ax.view_init(elev=14, azim=azim)
    fig.suptitle("Knee flexion in the femur frame (mm), fitted dual-quaternion B-spline "
                 f"(degree {fit.degree}, {fit.n_ctrl} control points)")
    return _save(fig, Canvas, path)


# ----------------------------------------------------------------------------- axode

def _sagittal(axes: dict) -> tuple[Tensor, Tensor]:
    """Where each screw axis pierces the mid-sagittal plane x = 0, and its tilt (deg)."""
    l, c = axes["direction"].double(), axes["point"].double()
    s = -c[..., 0] / l[..., 0]
    pierce = c + s[..., None] * l
    tilt = torch.rad2deg(torch.acos(l[..., 0].abs().clamp(max=1.0)))
    return pierce, tilt


def _plot_sagittal(fig, grid, order, truth, fitted, by_name, flex) -> None:
    """The axode figure's lower row: where the screw axes cross the mid-sagittal plane, and
    their tilt against flexion, true and fitted."""
    ax_s = fig.add_subplot(grid[1, 0])
    ax_t = fig.add_subplot(grid[1, 1] if len(order) > 1 else grid[1, 0])
    pt, tilt_t = _sagittal(truth)
    ax_s.plot(_np(pt[:, 1]), _np(pt[:, 2]), color="k", ls="--", lw=1.2, label="true motion")
    ax_t.plot(flex, _np(tilt_t), color="k", ls="--", lw=1.2, label="true motion")
    marks = [0, len(flex) // 2, len(flex) - 1]
    ax_s.plot(_np(pt[marks, 1]), _np(pt[marks, 2]), "ko", ms=4)
    for i in marks:
        ax_s.annotate(f"{flex[i]:.0f}°", (float(pt[i, 1]), float(pt[i, 2])), fontsize=8,
                      textcoords="offset points", xytext=(5, -10))
    for name in order:
        p, tilt = _sagittal(fitted[name])
        style = {"color": _CURVE_COLOR[name], **_LINE[name]}
        label = f"fitted {CURVE_LABELS[name]} (degree {by_name[name].degree})"
        ax_s.plot(_np(p[:, 1]), _np(p[:, 2]), label=label, **style)
        ax_s.plot(_np(p[marks, 1]), _np(p[marks, 2]), "o", ms=5, mfc="none",
                  color=_CURVE_COLOR[name])
        ax_t.plot(flex, _np(tilt), label=label, **style)
    ax_s.plot([], [], "o", color="0.3", mfc="none", ms=5,
              label="fitted axes at the marked flexions")
    ax_s.set_xlabel("y anterior (mm)")
    ax_s.set_ylabel("z proximal (mm)")
    ax_s.set_title("Where the screw axis crosses the mid-sagittal plane x = 0\n"
                   "(the ends of a curve fitted to noisy poses are the least certain)",
                   fontsize=10.5)
    ax_s.set_aspect("equal", adjustable="datalim")
    ax_s.grid(alpha=0.3)
    ax_s.legend(fontsize=8.5)
    ax_t.set_xlabel("flexion (deg)")
    ax_t.set_ylabel("tilt from the medial-lateral axis (deg)")
    ax_t.set_title("Screw axis tilt (from the coupled internal rotation)", fontsize=10.5)
    ax_t.grid(alpha=0.3)
    ax_t.legend(fontsize=8.5)


def _plot_axode_3d(fig, cell, fit, surf, truth, t, flex, model, p_true, pts, half: float,
                   colorbar: bool) -> None:
    """One fitted curve's axode in 3-D (its rulings ``surf``, coloured by flexion) with the
    true screw axis (one in ten), the tibia origin's path and the femoral shaft."""
    from matplotlib import cm
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    norm, cmap = Normalize(0.0, model.flexion_deg), cm.viridis
    s = torch.linspace(-half, half, 2, dtype=torch.float64)
    lt = truth["direction"] * torch.sign(-truth["direction"][..., :1])  # point medially (-x)
    ax3 = fig.add_subplot(cell, projection="3d", computed_zorder=False)
    colors = cmap(norm(flex))[:, None, :].repeat(2, axis=1)
    ax3.plot_surface(*(_np(surf[..., k]) for k in range(3)), facecolors=colors,
                     shade=False, alpha=0.75, linewidth=0.2, edgecolor="0.3",
                     rstride=1, cstride=1, zorder=1)
    for i in range(0, len(t), 10):
        seg = truth["point"][i] + s[:, None] * lt[i]
        ax3.plot(*_np(seg).T, color="crimson", lw=1.5, ls="--", zorder=3)
    ax3.plot(*_np(p_true).T, color="k", lw=1.5, zorder=3)
    ax3.plot([0, 0], [0, 0], [0, 35], color="0.45", lw=6, alpha=0.5, zorder=2)
    ax3.scatter([0], [0], [0], color="k", s=18, zorder=4)
    _set_equal_3d(ax3, _np(pts), zoom=0.95)
    _label_3d(ax3)
    ax3.view_init(elev=18, azim=-40)
    ax3.set_title(f"Axode of the fitted {CURVE_LABELS[fit.name]} (degree {fit.degree}, "
                  f"{fit.n_ctrl} control points)", fontsize=11)
    _legend_below(ax3, [
        Line2D([], [], color=cmap(0.6), lw=6, alpha=0.75,
               label=f"fitted screw axes, ±{half:.0f} mm (colour: flexion)"),
        Line2D([], [], color="crimson", ls="--", label="true screw axis (one in ten)"),
        Line2D([], [], color="k", label="tibia origin path (true)"),
        Line2D([], [], color="0.45", lw=6, alpha=0.5, label="femoral shaft (schematic)"),
        Line2D([], [], color="k", ls="none", marker="o", ms=4,
               label="femoral origin (epicondylar midpoint)")])
    if colorbar:
        fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax3, shrink=0.6,
                     pad=0.08, label="flexion (deg)")


def plot_axode(Figure, Canvas, path, fits, samples, model):
    """Fixed axodes (ruled surfaces of the instantaneous screw axis) of both fitted curves."""
    f64 = torch.float64
    dur = model.duration_s
    t = torch.linspace(AXODE_MARGIN * dur, (1 - AXODE_MARGIN) * dur, 61, dtype=f64)
    flex = _np(model.flexion(t))
    truth = _true_axes(model, t)
    fitted = {f.name: _fitted_axes(f.module, t) for f in fits}
    by_name = {f.name: f for f in fits}
    order = [n for n in ("bspline", "bezier") if n in fitted]

    fig = Figure(figsize=(14.0, 11.5), layout="constrained")
    grid = fig.add_gridspec(2, len(order), height_ratios=(1.25, 1.0))
    half = 40.0  # half length of the drawn rulings (mm), about half a knee's width
    s = torch.linspace(-half, half, 2, dtype=f64)
    p_true = dualquat.to_rt(model.poses(t))[1]
    surfaces = {}
    for name in order:
        ax = fitted[name]
        l = ax["direction"] * torch.sign(-ax["direction"][..., :1])
        surfaces[name] = ax["point"][:, None, :] + s[None, :, None] * l[:, None, :]
    pts = torch.cat([*(v.reshape(-1, 3) for v in surfaces.values()), p_true,
                     p_true.new_tensor([[0.0, 0.0, 38.0]])])
    for col, name in enumerate(order):
        _plot_axode_3d(fig, grid[0, col], by_name[name], surfaces[name], truth, t, flex,
                       model, p_true, pts, half, colorbar=col == len(order) - 1)
    _plot_sagittal(fig, grid, order, truth, fitted, by_name, flex)
    lo, hi = 100 * AXODE_MARGIN, 100 * (1 - AXODE_MARGIN)
    fig.suptitle("Instantaneous screw axis of the knee flexion in the femur frame, "
                 f"{lo:.0f}-{hi:.0f}% of the motion (paper's Fig. 2 idea)")
    return _save(fig, Canvas, path)


# ----------------------------------------------------------------------------- loss

def plot_loss(Figure, Canvas, path, runs, trans_weight):
    """Loss above the best found, per optimizer step, one panel per curve.

    Args:
        runs: ``{curve name: [(label, FitHistory, color), ...]}``: the fits of one curve from
            the same least-squares start (step 0) with different optimizers.
        trans_weight: the loss's translation weight (rad² per mm²), for the axis label.
    """
    fig = Figure(figsize=(12.0, 6.0), layout="constrained")
    axes = fig.subplots(1, len(runs), sharey=False, squeeze=False)[0]
    for ax, (name, fits) in zip(axes, runs.items(), strict=True):
        losses = {label: torch.tensor([*h.loss, h.final_loss], dtype=torch.float64)
                  for label, h, _ in fits}
        best = min(float(v.min()) for v in losses.values())
        for label, h, color in fits:
            excess = losses[label] - best
            excess[excess <= 0] = float("nan")  # the lowest loss itself has no place on a log axis
            text = f"{label}:\n{len(h.loss)} steps, final {h.final_loss:.6e} rad$^2$"
            ax.semilogy(range(len(excess)), _np(excess), color=color, lw=1.8, marker=".", ms=3,
                        label=text)
            ax.plot([0], [float(excess[0])], "o", color=color, mfc="none", ms=7)
        ax.set_xlabel("optimizer step (step 0: the least-squares start of from_poses;\n"
                      "Levenberg-Marquardt: one Gauss-Newton iteration per step)")
        ax.set_ylabel(r"loss $-$ lowest value found (rad$^2$)")
        ax.set_title(f"{CURVE_LABELS[name]}: lowest value {best:.6e} rad$^2$", fontsize=10.5)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8.5, loc="upper center", bbox_to_anchor=(0.5, -0.24), frameon=False)
    fig.suptitle(r"nn.fit on the noisy knee poses: pose loss, mean of $\theta^2 + w\,|\Delta t|^2$"
                 f" with w = {trans_weight:.3g} rad$^2$/mm$^2$\n(Levenberg-Marquardt minimises "
                 "it plus a weak pull towards its least-squares start, so it may stop slightly "
                 "above the loss's minimum)")
    return _save(fig, Canvas, path)

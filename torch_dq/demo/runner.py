r"""The demo behind ``python -m torch_dq demo``: fit dual-quaternion curves to a knee motion.

On the embedded synthetic knee flexion of :mod:`torch_dq.demo.knee` (no download) it

1. samples noisy poses of the tibia relative to the femur (seeded ``torch.Generator``;
   noise in degrees and millimetres, times in seconds);
2. fits a cubic B-spline and a Bézier curve of unit dual quaternions with
   :mod:`torch_dq.nn`: ``from_poses`` (least-squares start over the sample times, in
   seconds), then :func:`torch_dq.nn.fit` (progress bar on a terminal);
3. writes to the output folder (figures by :mod:`torch_dq.demo.plots`)
   ``fig1_components.png`` (the paper's Fig. 1: the 8 components over time),
   ``frames_3d.png`` (the tibia's frames along the fitted motion), ``axode.png`` (the ruled
   surfaces swept by the instantaneous screw axis of both fitted curves, the paper's Fig. 2
   idea), ``loss.png`` (the fit's loss per step, for the chosen optimizer and for a second one
   from the same start) and ``summary.json``;
4. prints the fit errors (rotation in degrees, translation in mm, mean and max over
   held-out times, against the noise-free motion) and timings.

Defaults: the optimizer, its learning rate and the step budget are those of
:func:`torch_dq.nn.fit` (:data:`FIT_DEFAULTS`, read from its signature).

Matplotlib is optional (``pip install 'torch_dq[plot]'``): without it the figures are
skipped with a warning, and the table and ``summary.json`` are still written.

Example:
    >>> from torch_dq.demo import run_demo
    >>> summary = run_demo("/tmp/torch_dq_demo", steps=5, plots=False, verbose=False)
    >>> sorted(summary["curves"])
    ['bezier', 'bspline']
"""

from __future__ import annotations

import functools
import inspect
import json
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from .. import _report as _shared
from .. import losses
from .. import nn as dqnn
from .._report import evaluate, no_matplotlib, pose_errors, say_warnings
from . import plots as _plots
from .knee import KneeModel, KneeSamples, sample_poses

__all__ = ["DEFAULTS", "FIGURES", "FIT_DEFAULTS", "PLOT_HINT", "run_demo"]

#: The command that installs matplotlib for the figures, ``pip install 'torch_dq[plot]'``
#: (the demo and the fit print it once when they skip their figures).
PLOT_HINT = _shared.PLOT_HINT

#: The figures the demo writes (when matplotlib is available).
FIGURES = ("fig1_components.png", "frames_3d.png", "axode.png", "loss.png")

#: The defaults of :func:`torch_dq.nn.fit` (``optimizer``, ``steps``, ``lr``, ...), read from
#: its signature: the demo and its command line take theirs from here, never restate them.
FIT_DEFAULTS = {name: p.default for name, p in inspect.signature(dqnn.fit).parameters.items()
                if p.default is not inspect.Parameter.empty}


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


def _errors(pred: Tensor, truth: Tensor) -> dict:
    """Mean and max rotation (deg) and translation (mm: the knee's unit) errors."""
    rot, trans = pose_errors(pred.cpu().double(), truth.cpu().double())
    return {"rot_deg_mean": float(rot.mean()), "rot_deg_max": float(rot.max()),
            "trans_mm_mean": float(trans.mean()), "trans_mm_max": float(trans.max())}


def _start(name: str, samples: KneeSamples, n_ctrl: int, degree: int):
    """The least-squares start of one curve, over the sample times (seconds)."""
    if name == "bspline":
        return dqnn.BSpline.from_poses(samples.rotations, samples.translations, samples.times,
                                       n_ctrl=n_ctrl, degree=degree), degree
    return dqnn.Bezier.from_poses(samples.rotations, samples.translations, samples.times,
                                  n_ctrl=n_ctrl), n_ctrl - 1


def _fit_curve(name: str, samples: KneeSamples, n_ctrl: int, degree: int, fit_kwargs: dict,
               held_out: Tensor, truth: Tensor) -> _Fit:
    begin = time.perf_counter()
    module, deg = _start(name, samples, n_ctrl, degree)
    init_errors = _errors(evaluate(module, held_out), truth)
    history = dqnn.fit(module, samples.times, samples.poses, **fit_kwargs)
    errors = _errors(evaluate(module, held_out), truth)
    return _Fit(name, module, history, init_errors, errors, time.perf_counter() - begin, deg,
                n_ctrl)


def _optimizer_text(name: str, lr: float | None) -> str:
    if name == "lm" or (name == "auto" and lr is None):
        # fit's history records Levenberg-Marquardt's regularised objective
        return (f"{name} (Levenberg-Marquardt; loss + prior term, "
                f"prior {FIT_DEFAULTS['prior']:g})")
    if name == "auto":
        return f"{name} (Adam, lr {lr:g})"
    return f"{name} ({'default lr' if lr is None else f'lr {lr:g}'})"


def _loss_runs(fits: list[_Fit], samples: KneeSamples, fit_kwargs: dict) -> dict:
    """Each curve's history with the chosen optimizer, and with a second one from the same
    least-squares start: Adam at :func:`torch_dq.nn.fit`'s default learning rate, or
    Levenberg-Marquardt when Adam was chosen."""
    chosen = fit_kwargs["optimizer"]
    other = "adam" if chosen in ("auto", "lm") else "lm"
    lr = fit_kwargs.get("lr")
    runs = {}
    for f in fits:
        with warnings.catch_warnings():  # the same start as the fit's, whose warnings were said
            warnings.simplefilter("ignore")
            module, _ = _start(f.name, samples, f.n_ctrl, f.degree)
        kwargs = {**fit_kwargs, "optimizer": other, "verbose": False}
        kwargs.pop("lr", None)
        history = dqnn.fit(module, samples.times, samples.poses, **kwargs)
        runs[f.name] = [(f"{_optimizer_text(chosen, lr)}, this run", f.history, "tab:red"),
                        (_optimizer_text(other, None), history, "tab:blue")]
    return runs


# ----------------------------------------------------------------------------- driver

def _table(summary: dict) -> str:
    rows = [("noisy samples (at sample times)", summary["noise_errors"], "", "", "")]
    for name in ("bspline", "bezier"):
        c = summary["curves"].get(name)
        if c is None:
            continue
        label = f"{_plots.CURVE_LABELS[name]} ({c['n_ctrl']} ctrl, degree {c['degree']})"
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


def run_demo(out: str = "torch_dq_demo", *, n_ctrl: int = 8, degree: int = 3,
             steps: int = FIT_DEFAULTS["steps"], seed: int = 0,
             device: str | torch.device = "cpu", dtype: torch.dtype = torch.float32,
             n_samples: int = 100,
             rot_noise_deg: float = 1.0, trans_noise_mm: float = 1.0,
             optimizer: str = FIT_DEFAULTS["optimizer"], lr: float | None = FIT_DEFAULTS["lr"],
             plots: bool = True, verbose: bool = True, stream=None) -> dict:
    """Run the demo; returns the summary written to ``out/summary.json``.

    Args:
        out: output folder (created).
        n_ctrl: control points of each curve (the Bézier curve has degree ``n_ctrl - 1``).
        degree: degree of the B-spline, ``< n_ctrl``.
        steps: maximum optimizer steps of each fit (default: :func:`torch_dq.nn.fit`'s).
        seed: seed of the noise generator.
        device: torch device of the fit (``"cpu"``, ``"cuda"``).
        dtype: floating dtype of the fit.
        n_samples: number of noisy poses.
        rot_noise_deg: rotation noise per axis (degrees).
        trans_noise_mm: translation noise per axis (mm).
        optimizer: ``"auto"``, ``"lm"``, ``"adam"``, ``"lbfgs"`` or ``"sgd"`` (see
            :func:`torch_dq.nn.fit`; default: its default).
        lr: learning rate (default ``None``: :func:`torch_dq.nn.fit`'s default for the
            optimizer).
        plots: write the PNG figures (needs matplotlib); ``loss.png`` fits each curve a
            second time with another optimizer, for comparison.
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
    samples, held_out, truth = _data(model, n_samples, rot_noise_deg, trans_noise_mm, seed,
                                     dtype, device)
    trans_weight = _trans_weight(rot_noise_deg, trans_noise_mm)
    loss = functools.partial(losses.pose_loss, trans_weight=trans_weight)
    fit_kwargs = {"optimizer": optimizer, "steps": steps, "loss": loss, "verbose": verbose}
    if lr is not None:
        fit_kwargs["lr"] = lr
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fits = [_fit_curve(name, samples, n_ctrl, degree, fit_kwargs, held_out, truth)
                for name in ("bspline", "bezier")]
    settings = {"n_ctrl": n_ctrl, "degree": degree, "steps": steps, "seed": seed,
                "device": str(device), "dtype": str(dtype).replace("torch.", ""),
                "n_samples": n_samples, "rot_noise_deg": rot_noise_deg,
                "trans_noise_mm": trans_noise_mm, "optimizer": optimizer, "lr": lr,
                "trans_weight_rad2_per_mm2": trans_weight, "n_held_out": len(held_out),
                "threads": torch.get_num_threads()}
    summary = _summary(settings, model, samples, fits, say_warnings("torch-dq demo", caught))
    if plots:
        summary["figures"] = _figures(out, fits, samples, model, fit_kwargs, trans_weight,
                                      summary["warnings"])
    summary["seconds_total"] = time.perf_counter() - t_start
    with open(os.path.join(out, "summary.json"), "w", encoding="utf-8") as fh:
        json.dump(summary, fh, indent=2)
    if verbose:
        _report(summary, model, out, stream)
    return summary


def _data(model: KneeModel, n_samples: int, rot_noise_deg: float, trans_noise_mm: float,
          seed: int, dtype: torch.dtype, device: torch.device
          ) -> tuple[KneeSamples, Tensor, Tensor]:
    """The noisy poses (seeded), the held-out times (float64 s, midway between a fine grid,
    never a sample time) and the noise-free poses there."""
    gen = torch.Generator().manual_seed(seed)
    samples = sample_poses(model, n=n_samples, rot_noise_deg=rot_noise_deg,
                           trans_noise_mm=trans_noise_mm, generator=gen, dtype=dtype,
                           device=device)
    n_held = 400
    held_out = ((torch.arange(n_held, dtype=torch.float64) + 0.5) / n_held * model.duration_s)
    truth = model.poses(held_out).to(dtype=dtype, device=device)
    return samples, held_out.to(device=device), truth  # float64 s: the layers take wide times


def _trans_weight(rot_noise_deg: float, trans_noise_mm: float) -> float:
    """The loss's weight of translation against rotation errors, from the noise levels: one
    noise sigma in degrees counts like one noise sigma in mm."""
    sigma_r = math.radians(rot_noise_deg) if rot_noise_deg > 0 else math.radians(1.0)
    sigma_t = trans_noise_mm if trans_noise_mm > 0 else 1.0
    return (sigma_r / sigma_t) ** 2


def _summary(settings: dict, model: KneeModel, samples: KneeSamples, fits: list[_Fit],
             warned: list[str]) -> dict[str, Any]:
    """The summary written to ``summary.json`` (without the figures and the total time)."""
    return {
        "description": "torch_dq demo: dual-quaternion curves fitted to a synthetic knee "
                       "flexion (tibia relative to femur, mm); errors against the noise-free "
                       "motion at held-out times",
        "settings": settings,
        "knee_model": model.as_dict(),
        "noise_errors": _errors(samples.poses, samples.truth),
        "curves": {f.name: {"n_ctrl": f.n_ctrl, "degree": f.degree, "errors": f.errors,
                            "init_errors": f.init_errors, "steps": f.history.steps,
                            "initial_loss": f.history.loss[0] if f.history.loss else None,
                            "final_loss": f.history.final_loss,
                            "converged": f.history.converged, "seconds": f.seconds}
                   for f in fits},
        "figures": [],
        "warnings": warned,
    }


def _figures(out: str, fits: list[_Fit], samples: KneeSamples, model: KneeModel,
             fit_kwargs: dict, trans_weight: float, notes: list[str]) -> list[str]:
    """Write :data:`FIGURES` (the names written; none, with a note, without matplotlib)."""
    try:
        Figure, Canvas = _plots.import_matplotlib()
    except ImportError:
        notes.append(no_matplotlib("torch-dq demo"))
        return []
    by_name = {f.name: f for f in fits}
    paths = [os.path.join(out, name) for name in FIGURES]
    _plots.plot_components(Figure, Canvas, paths[0], fits, samples, model)
    _plots.plot_frames(Figure, Canvas, paths[1], by_name["bspline"], samples, model)
    _plots.plot_axode(Figure, Canvas, paths[2], fits, samples, model)
    _plots.plot_loss(Figure, Canvas, paths[3], _loss_runs(fits, samples, fit_kwargs),
                     trans_weight)
    return [os.path.basename(p) for p in paths]


def _report(summary: dict, model: KneeModel, out: str, stream) -> None:
    """Print the settings, the error table and what was written."""
    s = summary["settings"]
    print(f"torch_dq demo: knee flexion 0-{model.flexion_deg:g} deg, {s['n_samples']} noisy "
          f"poses (noise {s['rot_noise_deg']:g} deg, {s['trans_noise_mm']:g} mm per axis), "
          f"seed {s['seed']}, {s['optimizer']} up to {s['steps']} steps on {s['device']} "
          f"({s['dtype']})", file=stream)
    print(f"errors vs the noise-free motion at {s['n_held_out']} held-out times:\n",
          file=stream)
    print(_table(summary), file=stream)
    files = ", ".join(summary["figures"] + ["summary.json"])
    print(f"\nwrote {files} to {os.path.abspath(out)}", file=stream)
    print(f"total time {summary['seconds_total']:.1f} s", file=stream)


#: The defaults of :func:`run_demo` (``n_ctrl``, ``degree``, ``n_samples``, ...), read from its
#: signature: ``python -m torch_dq demo`` takes its defaults from here.
DEFAULTS = {name: p.default for name, p in inspect.signature(run_demo).parameters.items()
            if p.default is not inspect.Parameter.empty}

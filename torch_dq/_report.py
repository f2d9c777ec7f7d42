"""What the applications share (private): pose errors, evaluation, sign alignment,
matplotlib, warnings on stderr.

Written once here, below both, so that the knee demo (:mod:`torch_dq.demo`) and the command
line (:mod:`torch_dq.cli`: ``fit``, its figures) agree on units and conventions.
"""

from __future__ import annotations

import sys
import warnings

import torch
from torch import Tensor

from . import losses

__all__ = ["PLOT_HINT", "align", "evaluate", "import_matplotlib", "no_matplotlib",
           "pose_errors", "say_warnings"]

#: What to run when matplotlib is missing.
PLOT_HINT = "pip install 'torch_dq[plot]'"


def pose_errors(pred: Tensor, truth: Tensor) -> tuple[Tensor, Tensor]:
    """Per-pose rotation angle (degrees) and translation error (the poses' unit), float64,
    sign-invariant (``x`` and ``-x`` are the same pose).

    Args:
        pred, truth: ``(..., 8)`` unit dual quaternions.

    Returns:
        ``(rot_deg, trans)``, each of the batch shape.
    """
    return (torch.rad2deg(losses.rotation_angle(pred, truth).double()),
            losses.translation_error(pred, truth).double())


def evaluate(module, t: Tensor) -> Tensor:
    """Poses of a fitted layer at times ``t`` (its own time), float64 on the CPU, no grad."""
    with torch.no_grad():
        return module(t.to(module.control_points.device)).cpu().double()


def align(x: Tensor, ref: Tensor) -> Tensor:
    """``x`` with each element's sign flipped to face ``ref`` (the same transforms)."""
    dot = (x[..., :4] * ref[..., :4]).sum(-1, keepdim=True)
    return torch.where(dot < 0, -x, x)


def import_matplotlib():
    """``(Figure, FigureCanvasAgg)``, with the 3-D projection registered; raises
    ``ImportError`` when matplotlib is missing (pyplot's global state is never touched)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d import Axes3D  # noqa: F401  (registers the 3d projection)

    return Figure, FigureCanvasAgg


def no_matplotlib(program: str, stream=None) -> str:
    """Say once, on one line (stderr by default), that the figures were skipped and how to
    get them; returns the message."""
    message = f"matplotlib is not installed: figures skipped (install them with {PLOT_HINT})"
    print(f"{program}: warning: {message}", file=sys.stderr if stream is None else stream)
    return message


def say_warnings(program: str, caught: list[warnings.WarningMessage]) -> list[str]:
    """Each warning caught (``warnings.catch_warnings(record=True)``) once, as one line on
    stderr without a source line; returns their texts (for the JSON summary)."""
    seen: list[str] = []
    for w in caught:
        text = " ".join(str(w.message).split())
        if text not in seen:
            seen.append(text)
            print(f"{program}: warning: {text}", file=sys.stderr)
    return seen

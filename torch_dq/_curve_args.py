"""Argument and saved-state checks of the curve layers (private): integer settings, the
floats and origins of a layer's extra state, poses given as rotations and translations."""

from __future__ import annotations

import math
import numbers

import torch
from torch import Tensor

from . import _checks, dualquat, quat

__all__ = ["check_int", "extra_float", "extra_origins", "nan_safe", "nan_where",
           "poses_to_dq"]


def check_int(fn: str, name: str, value, low: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        _checks.fail(fn, f"{name} must be an int {what}, got {value!r}")
    return int(value)


def extra_float(fn: str, state, key: str, positive: bool = False) -> float:
    """``state[key]`` of a saved extra state: a finite real number (``> 0`` if ``positive``)."""
    value = state.get(key) if isinstance(state, dict) else None
    if (isinstance(value, bool) or not isinstance(value, numbers.Real)
            or not math.isfinite(value) or (positive and not float(value) > 0)):
        _checks.fail(fn, f"expected a finite{' positive' if positive else ''} {key!r} in the "
                         f"extra state, got {state!r}")
    return float(value)


def extra_origins(fn: str, state, knots: Tensor) -> Tensor:
    """``state["origin"]`` of a layer with ``(..., K)`` knots: a finite float64 tensor
    ``(..., 1)`` (one origin per trajectory), moved to the knots' device."""
    value = state.get("origin") if isinstance(state, dict) else None
    shape = (*knots.shape[:-1], 1)
    if (not isinstance(value, Tensor) or value.dtype != torch.float64
            or tuple(value.shape) != shape or not bool(torch.isfinite(value).all())):
        _checks.fail(fn, f"expected a finite float64 'origin' tensor of shape "
                         f"{_checks.shape_str(shape)} (one per trajectory) in the extra state, "
                         f"got {state!r}")
    return value.detach().to(knots.device)


def poses_to_dq(fn: str, rotations, translations) -> Tensor:
    """``(..., N, 8)`` dual quaternions from quaternions or matrices and translations."""
    _checks.tensor(fn, "rotations", rotations)
    _checks.tensor(fn, "translations", translations, 3)
    _checks.same_dtype_device(fn, rotations=rotations, translations=translations)
    if rotations.dim() >= 3 and tuple(rotations.shape[-2:]) == (3, 3):
        _checks.rigid_matrix(fn, "rotations", rotations)
        q, nd = quat.from_matrix(rotations), 2
    elif rotations.dim() >= 2 and rotations.shape[-1] == 4:
        q, nd = quat.normalize(rotations), 1
    else:
        _checks.fail(fn, f"expected (..., N, 4) quaternions or (..., N, 3, 3) matrices for "
                         f"rotations, got shape {_checks.shape_str(rotations.shape)}")
    if translations.dim() < 2:
        _checks.fail(fn, f"expected a (..., N, 3) tensor for translations, got shape "
                         f"{_checks.shape_str(translations.shape)}")
    if translations.shape[-2] != rotations.shape[rotations.dim() - nd - 1]:
        _checks.fail(fn, f"rotations and translations must hold the same number N of poses, "
                         f"got rotations {_checks.shape_str(rotations.shape)} and "
                         f"translations {_checks.shape_str(translations.shape)}")
    _checks.broadcast_batch(fn, rotations=(q, 2), translations=(translations, 2))
    return dualquat.from_rt(q, translations)


def nan_safe(dom, rel: Tensor) -> tuple[Tensor, Tensor]:
    """Safe where for the times a curve cannot evaluate: the NaN relative times (a NaN ``t``,
    or one beyond the domain under the domain rules, :meth:`KnotDomain.admit`) replaced by
    the domain's start, and the mask of them for :func:`nan_where`. Evaluating NaN times
    would send ``0 * NaN`` into the gradients of the control points that the other samples
    share; now those samples' outputs are NaN and their gradient contributions 0."""
    bad = torch.isnan(rel)
    return torch.where(bad, dom.ends(rel.dtype)[0].detach()[..., None], rel), bad


def nan_where(bad: Tensor, x: Tensor) -> Tensor:
    """``x (..., T, k)`` with NaN at the samples :func:`nan_safe` replaced."""
    return torch.where(bad[..., None], torch.nan, x)

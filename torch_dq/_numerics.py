"""Per-dtype thresholds and helpers for removable singularities (private).

The pattern used everywhere (jaxlie's "safe where"): for a function with a removable
singularity at ``x = 0`` (``sin(x) / x`` and friends), compute a mask ``small``, replace the
unsafe inputs by a harmless constant *before* evaluating the exact formula, and select the
Taylor branch where ``small`` holds. Reverse mode then never differentiates through an
unselected ``0 / 0`` (pytorch issue 52248).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "THRESHOLDS", "compute_dtype", "eps", "nan_unless", "safe_denominator", "safe_norm", "sinc",
    "taylor_threshold", "threshold",
]


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype used for internal arithmetic: float16/bfloat16 compute in float32."""
    return torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype


def _unit_atol(eps: float) -> float:
    # 1e-10 in float64 and 1e-5 in float32 (rounding of products of unit inputs over long
    # chains stays far below); 10 eps for float16/bfloat16, whose rounding of a unit dual
    # quaternion alone leaves defects of one eps.
    return {torch.finfo(torch.float64).eps: 1e-10, torch.finfo(torch.float32).eps: 1e-5}.get(
        eps, 10.0 * eps)


#: The threshold table (jaxlie's ``get_epsilon``): every switch point and tolerance of the
#: package, as a function of the machine epsilon ``eps`` of the dtype it applies to. Read an
#: entry with :func:`threshold`; each line says where it is used and why it has that value.
THRESHOLDS = {
    # sin(theta) below which two rotations count as equal or opposite and eq. 6 replaces
    # eq. 5 in the dual angle: eq. 5's error eps |t| / sin(theta) reaches sqrt(eps) |t|.
    "dual_angle_degenerate": lambda eps: eps ** 0.5,
    # y = 1 - cos(theta) below which the dual weights of eq. 11 use their power series
    # (5 terms): series error sqrt(y) (y/2)^4 against the closed form's eps / sqrt(y).
    "screw_series": lambda eps: (16.0 * eps) ** (1.0 / 5.0),
    # Relative tolerance of the curves' domain check on t (multiply by the domain's scale
    # max(|t0|, |t1|)): 4 ulps of rounding in the caller's time arithmetic are accepted.
    "domain_rtol": lambda eps: 4.0 * eps,
    # |omega| <= eps |v|: a twist or screw counts as a pure translation (its axis would lie
    # beyond 1 / eps lengths); also sin(theta / 2) <= eps in dualquat.to_screw and
    # |t| <= eps for "no translation direction".
    "pure_translation": lambda eps: eps,
    # |r| (the residual of q1 orthogonal to q0) below which quat.slerp treats q1 as -q0.
    "antipodal": lambda eps: eps,
    # Default atol of dualquat.is_unit.
    "unit_atol": _unit_atol,
    # scipy's gimbal-lock threshold of as_euler (a fixed 1e-7 rad, not eps-based: kept
    # for agreement with scipy in every dtype).
    "gimbal_lock": lambda eps: 1e-7,
}


def eps(dtype: torch.dtype) -> float:
    """Machine epsilon of the compute dtype of ``dtype`` (float32's for float16/bfloat16)."""
    return float(torch.finfo(compute_dtype(dtype)).eps)


def threshold(name: str, dtype: torch.dtype) -> float:
    """Entry ``name`` of :data:`THRESHOLDS` for ``dtype``.

    Pass the dtype the compared quantity is computed in (the compute dtype, float32 for
    float16 input, unless the tolerance is about the input's own rounding, as in
    ``dualquat.is_unit``).

    Example:
        >>> threshold("dual_angle_degenerate", torch.float64)  # sqrt(eps)
        1.4901161193847656e-08
    """
    return float(THRESHOLDS[name](torch.finfo(dtype).eps))


def taylor_threshold(dtype: torch.dtype, order: int) -> float:
    r"""Switch point between a Taylor branch and the exact formula.

    A truncated series with first neglected term of degree ``order`` has relative error
    ``x**order``; the exact formula of a function whose numerator cancels to second order
    has relative error ``eps / x**2``. Balancing the two gives
    ``x0 = eps ** (1 / (order + 2))``.

    Args:
        dtype: the compute dtype.
        order: degree of the first neglected Taylor term.
    """
    return float(eps(dtype) ** (1.0 / (order + 2)))


def safe_denominator(x: Tensor, small: Tensor) -> Tensor:
    """``x`` with the entries where ``small`` holds replaced by 1 (to divide safely)."""
    return torch.where(small, torch.ones_like(x), x)


def nan_unless(finite: Tensor, x: Tensor) -> Tensor:
    """``x`` where ``finite`` holds, NaN elsewhere (``finite`` broadcasts against ``x``).

    For results with a finite limit as an input component goes to infinity (``q / |q|``,
    ``atan2(|v|, w)``, ``2 / |q|^2``): a non-finite input must come back as NaN, never as
    a plausible finite number (API.md). Apply it to a reduced quantity (a norm) where
    possible: the mask costs one pass over it.
    """
    return torch.where(finite, x, torch.nan)


def sinc(x: Tensor) -> Tensor:
    r"""Unnormalised :math:`\sin(x) / x`, exact and smooth at 0 in value and gradient.

    Taylor branch :math:`1 - x^2/6 + x^4/120 - x^6/5040` below the threshold.
    """
    small = x.abs() < taylor_threshold(x.dtype, 8)
    xs = safe_denominator(x, small)
    x2 = x * x
    series = 1.0 - x2 / 6.0 * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0))
    return torch.where(small, series, torch.sin(xs) / xs)


def safe_norm(x: Tensor) -> Tensor:
    """``|x|`` over the last dim, with the zero subgradient at ``x = 0`` (not NaN).

    Safe where: ``sqrt`` is evaluated at 1 where ``|x|^2 == 0``, so its infinite derivative
    never meets the zero upstream gradient; NaN and inf still propagate.
    """
    n2 = (x * x).sum(-1)
    zero = n2 == 0
    return torch.where(zero, 0.0, torch.sqrt(torch.where(zero, 1.0, n2)))

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
    "compute_dtype", "nan_unless", "safe_denominator", "safe_norm", "sinc", "taylor_threshold",
]


def compute_dtype(dtype: torch.dtype) -> torch.dtype:
    """The dtype used for internal arithmetic: float16/bfloat16 compute in float32."""
    return torch.float32 if dtype in (torch.float16, torch.bfloat16) else dtype


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
    eps = torch.finfo(compute_dtype(dtype)).eps
    return float(eps ** (1.0 / (order + 2)))


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

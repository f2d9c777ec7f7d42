"""Per-dtype thresholds and helpers for removable singularities (private).

The pattern used everywhere (jaxlie's "safe where"): for a function with a removable
singularity at ``x = 0`` (``sin(x) / x`` and friends), compute a mask ``small``, replace the
unsafe inputs by a harmless constant *before* evaluating the exact formula, and select the
Taylor branch where ``small`` holds. Reverse mode then never differentiates through an
unselected ``0 / 0`` (pytorch issue 52248).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

__all__ = [
    "THRESHOLDS", "compute_dtype", "eps", "even", "nan_unless", "power_of_two_scale",
    "safe_denominator", "safe_norm", "threshold",
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
    # 1 + q0 . q1 at or below which dualquat.sclerp(shortest=False) counts the real parts as
    # exactly opposite (no unique path: NaN): the dot of two rounded unit quaternions is
    # off by up to ~3 eps (measured), so closer pairs cannot be told from opposite ones.
    "opposite_real_parts": lambda eps: 8.0 * eps,
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


def safe_denominator(x: Tensor, small: Tensor) -> Tensor:
    """``x`` with the entries where ``small`` holds replaced by 1 (to divide safely)."""
    return torch.where(small, torch.ones_like(x), x)


def nan_unless(finite: Tensor, x: Tensor) -> Tensor:
    """``x`` where ``finite`` holds, NaN elsewhere (``finite`` broadcasts against ``x``).

    For results with a finite limit as an input component goes to infinity (``q / |q|``,
    ``atan2(|v|, w)``, ``2 / |q|^2``): a non-finite input must come back as NaN, never as
    a plausible finite number (docs/api_contract.md). Apply it to a reduced quantity (a
    norm) where possible: the mask costs one pass over it.
    """
    return torch.where(finite, x, torch.nan)


def _series(coefficient: Callable[[int], float]) -> tuple[float, ...]:
    return tuple(coefficient(k) for k in range(_EVEN_TERMS + 1))


_EVEN_TERMS = 8  # terms c_0 .. c_7 of the series in x2 = theta^2 (through theta^14)
_BERNOULLI = (1.0, 1 / 6, -1 / 30, 1 / 42, -1 / 30, 5 / 66, -691 / 2730, 7 / 6, -3617 / 510,
              43867 / 798)  # B_0, B_2, ..., B_18
_FACT = math.factorial

#: Even analytic functions of theta, evaluated from x2 = theta^2 by :func:`even`: for each,
#: the coefficients c_k of ``f = sum_k c_k x2^k`` (one more than used: the first neglected
#: term sets the switch point) and the closed form in theta.
_EVEN = {
    # cos(theta)
    "cos": (_series(lambda k: (-1) ** k / _FACT(2 * k)), torch.cos),
    # sin(theta) / theta
    "sinc": (_series(lambda k: (-1) ** k / _FACT(2 * k + 1)), lambda th: torch.sin(th) / th),
    # atan(theta) / theta (series radius 1)
    "atanc": (_series(lambda k: (-1) ** k / (2 * k + 1)), lambda th: torch.atan(th) / th),
    # (1 - cos theta) / theta^2: the c_1 of the SE(3) exponential
    "se3_c1": (_series(lambda k: (-1) ** k / _FACT(2 * k + 2)),
               lambda th: (1.0 - torch.cos(th)) / (th * th)),
    # (theta - sin theta) / theta^3: the c_2 of the SE(3) exponential
    "se3_c2": (_series(lambda k: (-1) ** k / _FACT(2 * k + 3)),
               lambda th: (th - torch.sin(th)) / (th * th * th)),
    # (1 - (theta / 2) cot(theta / 2)) / theta^2: the c_3 of the SE(3) logarithm, from
    # x cot x = sum_n (-1)^n B_2n (2x)^2n / (2n)! (series radius 2 pi)
    "se3_c3": (_series(lambda k: (-1) ** k * _BERNOULLI[k + 1] / _FACT(2 * k + 2)),
               lambda th: (1.0 - 0.5 * th / torch.tan(0.5 * th)) / (th * th)),
}


def even(name: str, x2: Tensor) -> Tensor:
    r"""An even function :math:`f(\theta)` of :data:`_EVEN`, evaluated from :math:`x_2 = \theta^2`.

    Why from the square: :math:`\theta = |v|` is a cone at :math:`v = 0`, so ``f(|v|)``
    differentiated by the chain rule gets a wrong (zero) second derivative there, even with
    a Taylor branch in :math:`\theta`; :math:`x_2 = v \cdot v` is a polynomial, and
    :math:`f` is analytic in :math:`x_2`, so every derivative of ``even(name, v @ v)`` is
    right to all orders, in reverse, forward and nested modes.

    Below the switch point the series :math:`\sum_{k<K} c_k x_2^k` is used (its first
    neglected term is below an ulp of the result: the switch is at
    :math:`x_2 = \min(1, \frac14 (\epsilon / |c_K|)^{1/K})`, large, so that the closed
    form never meets the cancellation of its derivatives near 0; at most 1, where the
    alternating series would start to cancel). Above it, the closed form is
    evaluated at :math:`\sqrt{x_2}` with the series' elements replaced by 1 first (safe
    where), so no branch ever produces a NaN or an infinite derivative.
    """
    coeffs, exact = _EVEN[name]
    switch = min(1.0, 0.25 * (eps(x2.dtype) / abs(coeffs[-1])) ** (1.0 / _EVEN_TERMS))
    small = x2 < switch
    series: Tensor | float = coeffs[_EVEN_TERMS - 1]
    for c in reversed(coeffs[:_EVEN_TERMS - 1]):
        series = series * x2 + c
    return torch.where(small, series, exact(torch.sqrt(torch.where(small, 1.0, x2))))


def power_of_two_scale(x: Tensor) -> Tensor:
    """A power of two near ``max |x|`` over the last dim (kept), detached; 1 where the max is
    0 or non-finite.

    Dividing by it is exact, so it changes no digit of a scale-invariant result
    (``q / |q|``, a rotation of ``q``), while it keeps the squares of tiny (1e-25) or huge
    (1e20) components away from underflow and overflow (as ``hypot`` does).
    """
    m = x.detach().abs().amax(-1, keepdim=True)
    ok = (m > 0) & torch.isfinite(m)
    return torch.where(ok, torch.exp2(torch.floor(torch.log2(torch.where(ok, m, 1.0)))), 1.0)


def safe_norm(x: Tensor) -> Tensor:
    """``|x|`` over the last dim, with the zero subgradient at ``x = 0`` (not NaN).

    Safe where: ``sqrt`` is evaluated at 1 where ``|x|^2 == 0``, so its infinite derivative
    never meets the zero upstream gradient; NaN and inf still propagate.
    """
    n2 = (x * x).sum(-1)
    zero = n2 == 0
    return torch.where(zero, 0.0, torch.sqrt(torch.where(zero, 1.0, n2)))

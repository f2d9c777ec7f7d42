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
from typing import cast

import torch
from torch import Tensor
from torch._C._functorch import is_functorch_wrapped_tensor

__all__ = [
    "ANGLE_SQUARE_TERMS", "THRESHOLDS", "compute_dtype", "even", "even_slope", "even_slopes",
    "evens", "may_hold", "nan_unless", "piecewise", "plain_range", "power_of_two_scale",
    "prescale", "safe_denominator", "safe_norm", "screw_series_terms", "select", "series_mask",
    "threshold", "unscaled",
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
THRESHOLDS: dict[str, Callable[..., float]] = {
    # sin(theta) below which two rotations count as equal or opposite and eq. 6 replaces
    # eq. 5 in the dual angle: eq. 5's error eps |t| / sin(theta) reaches sqrt(eps) |t|.
    "dual_angle_degenerate": lambda eps: eps ** 0.5,
    # y = 1 - cos(theta) below which the dual weights of eq. 11 use their power series in y
    # (times max(1, s^2) when extrapolating), for jets of order ``order`` (0: the fused
    # kernels); derivation and number of terms: screw_series_terms.
    "screw_series": lambda eps, order=0: _screw_series(eps, order),
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
    # x2 = theta^2 below which even() uses the series of an even function whose first
    # neglected coefficient is c (derivation in even()).
    "even_series": lambda eps, c: min(1.0, 0.25 * (eps / abs(c)) ** (1.0 / _EVEN_TERMS)),
    # y = 1 - cos(theta) below which theta^2 = acos(1 - y)^2 and its y-derivative
    # 2 theta / sin(theta) use their power series in y (_kernels.weights.angle_square, N = 12
    # terms ~ (y/2)^k): the closed forms' second derivatives in y lose eps / y^2, the
    # series' N^2 (y/2)^(N-2); they meet at y^N = 2^(N-2) eps / N^2: 0.058 in float64, 0.31
    # in float32 (measured against mpmath in tests/test_weights.py).
    "angle_square_series": lambda eps: (eps * 2.0 ** (ANGLE_SQUARE_TERMS - 2)
                                        / ANGLE_SQUARE_TERMS**2) ** (1.0 / ANGLE_SQUARE_TERMS),
    # B-spline basis value above which a sample counts in the support of a control point
    # (_start.check_determined, Schoenberg-Whitney): a control point whose values all lie
    # below 2^12 eps has a normal-equations pivot below 2^24 eps^2 <~ eps of the largest
    # (the values sum to 1), singular to working precision (9.1e-13 in float64).
    "basis_nonzero": lambda eps: 4096.0 * eps,
    # Rotation angle 2 atan2(|v|, w) in [0, 2 pi] within which of 2 pi a relative rotation
    # counts as a full turn (angle - 2 pi, _start._rt_twists): a fixed 1e-6 rad, far
    # above the rounding of the angle there in float64, and at least 4 ulps of 2 pi
    # (8 pi eps: 3e-6 in float32, where 1e-6 would be 2 ulps).
    "full_turn": lambda eps: max(1e-6, 8.0 * math.pi * eps),
    # scipy's gimbal-lock threshold of as_euler (a fixed 1e-7 rad, not eps-based: kept
    # for agreement with scipy in every dtype).
    "gimbal_lock": lambda eps: 1e-7,
    # Residual of camera.unproject's Newton iterations (relative to 1 + |distorted point|)
    # below which the root counts as found (valid): rounding leaves a few eps, a pixel
    # without a preimage (beyond a lens' fold) a residual of order 1e-3 or more.
    "camera_root": lambda eps: 256.0 * eps,
    # tan of the angle off axis (|x| / z or |y| / z) beyond which camera.project counts a
    # point of the pinhole models as invalid: within eps radians of the plane z = 0 their
    # pixels (r^5 of radtan) or derivatives would overflow.
    "camera_off_axis": lambda eps: 1.0 / eps,
}


ANGLE_SQUARE_TERMS = 12  # terms of the series of acos(1 - y)^2 (THRESHOLDS "angle_square_series")


def screw_series_terms(order: int) -> int:
    r"""Number ``N`` of terms :math:`a_0 \dots a_{N-1}` of the power series of eq. 11's weights
    (:mod:`torch_dq._kernels.weights`) for jets of order ``order`` (:mod:`torch_dq._taylor`).

    Order 0 is the fused kernels' case: ``F, G`` for the values and
    :math:`H = \partial_y G`, :math:`F_s, G_s` for the gradients, 5 terms (fewest for their
    hot path). Jets of order ``K >= 1`` take ``N = 6 + 2K``: their coefficients need
    ``K + 1`` derivatives in :math:`y`, each of which costs the closed forms a division by
    :math:`\sin^2\theta \approx 2y`, so their switch point moves up and the series needs
    more terms to stay exact there. Switch points: :data:`THRESHOLDS` ``"screw_series"``.
    """
    return 5 if order == 0 else 6 + 2 * order


def _screw_series(eps: float, order: int) -> float:
    r"""Switch point in :math:`y = 1 - \cos\theta` of the weights' series with
    :func:`screw_series_terms` ``(order)`` terms (:math:`a_k \approx s\,(y/2)^k`).

    - Order 0 (5 terms, the kernels): the series of ``G`` loses about
      :math:`\sqrt y\,(y/2)^4`, the closed form :math:`\epsilon/\sqrt y`; they meet at
      :math:`y^5 = 16\epsilon`: 1.3e-3 in float64 (:math:`\theta` 2.9 degrees), 0.072 in
      float32 (22 degrees, so that a smooth float32 trajectory needs no transcendental);
      measured in float64 (``tests/test_weights.py``): ``F`` 1 ulp, ``G`` 1e-13, the
      gradients' ``H`` 2e-10.
    - Order ``K >= 1`` (``N = 6 + 2K`` terms): the ``j``-th derivative in ``y`` loses
      :math:`N^j (y/2)^{N-j}` in the series and :math:`\epsilon / y^j` in the closed forms;
      with :math:`j = K + 2` (one more than the ``K + 1`` the jets of ``G`` need, for their
      reverse-mode gradients) they meet at :math:`y^N = \epsilon\, 2^N / N^{K+2}`: ``y``
      0.010 to 0.035 in float64 (0.13 to 0.19 in float32); measured against mpmath
      around the switch (``tests/test_weights.py``), the float64 Taylor coefficients are
      off by at most 2e-12 (the third), 4e-13 (the second), 2e-13 (the first).
    """
    if order == 0:
        return (16.0 * eps) ** (1.0 / 5.0)
    terms = screw_series_terms(order)
    return (eps * 2.0**terms / terms ** (order + 2)) ** (1.0 / terms)


def threshold(name: str, dtype: torch.dtype, *args: float) -> float:
    """Entry ``name`` of :data:`THRESHOLDS` for ``dtype``.

    Pass the dtype the compared quantity is computed in (the compute dtype, float32 for
    float16 input, unless the tolerance is about the input's own rounding, as in
    ``dualquat.is_unit``). ``args``: the entry's further arguments (the jet order of
    ``"screw_series"``, the first neglected coefficient of ``"even_series"``).

    Example:
        >>> threshold("dual_angle_degenerate", torch.float64)  # sqrt(eps)
        1.4901161193847656e-08
    """
    return float(THRESHOLDS[name](torch.finfo(dtype).eps, *args))


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


def series_mask(y: Tensor, scale: Tensor, switch: float) -> Tensor:
    """Float 0/1 mask of the elements below a series' switch point: ``y max(1, scale) <
    switch`` (``scale``: how the series' terms grow beyond ``y``, e.g. ``s^2``)."""
    return (y * torch.clamp(scale, min=1.0) < switch).to(y.dtype)


def select(mask: Tensor, x: Tensor | None, y: Tensor | None) -> Tensor | None:
    """``where(mask, x, y)`` for a float 0/1 ``mask`` and finite ``x``, ``y`` (``None``: zero):
    exact (``x * 1 + y * 0``) and several times faster than ``torch.where`` on CPU."""
    if x is None:
        return None if y is None else y * (1.0 - mask)
    return x * mask if y is None else torch.addcmul(y * (1.0 - mask), x, mask)


Parts = list[Tensor | None]  # the outputs of both branches of piecewise (None: zero)


def piecewise(small: Tensor, host: bool, series: Callable[[Callable[[Tensor], Tensor]], Parts],
              closed: Callable[[], Parts]) -> Parts:
    """A series where the float 0/1 mask ``small`` holds, closed forms elsewhere (safe where:
    ``closed`` must guard its inputs so that it is finite on the series' elements).

    With ``host`` (eager on CPU: one host read of a count) only the branches that some
    element takes are evaluated, and the series on its elements alone when they are few;
    the result is the same to the bit. Otherwise (compiled, under ``torch.func``
    transforms, on other devices) both run on every element, selected arithmetically.

    Args:
        small: float 0/1 mask, the shape of every output.
        host: whether the count may be read.
        series: the series' parts, given how to pick its inputs' elements (the identity or
            an expansion to ``small.shape`` indexed at the series' elements).
        closed: the closed forms' parts, on every element.

    Returns:
        The parts, each of ``small.shape`` (``None`` where both branches give ``None``).
    """
    n_small = int(small.count_nonzero()) if host else -1
    if n_small == small.numel():
        return series(lambda x: x)
    out = closed()
    if 0 < n_small < small.numel() // 4:
        # Out of place where autograd records (a double backward may have saved the closed
        # forms); in place otherwise (closed must return fresh tensors), saving a copy.
        at = (small > 0).nonzero(as_tuple=True)
        part = series(lambda x: x.expand(small.shape)[at])
        put = torch.index_put if torch.is_grad_enabled() else torch.index_put_
        return [e if e is None and x is None
                else put(torch.zeros_like(small) if e is None else e, at,
                         small.new_zeros(()) if x is None else x)
                for x, e in zip(part, out, strict=True)]
    if n_small != 0:
        return [select(small, x, e) for x, e in zip(series(lambda x: x), out, strict=True)]
    return out


def _coefficients(coefficient: Callable[[int], float]) -> tuple[float, ...]:
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
    "cos": (_coefficients(lambda k: (-1) ** k / _FACT(2 * k)), torch.cos),
    # sin(theta) / theta
    "sinc": (_coefficients(lambda k: (-1) ** k / _FACT(2 * k + 1)), lambda th: torch.sin(th) / th),
    # atan(theta) / theta (series radius 1)
    "atanc": (_coefficients(lambda k: (-1) ** k / (2 * k + 1)), lambda th: torch.atan(th) / th),
    # (1 - cos theta) / theta^2: the c_1 of the SE(3) exponential
    "se3_c1": (_coefficients(lambda k: (-1) ** k / _FACT(2 * k + 2)),
               lambda th: (1.0 - torch.cos(th)) / (th * th)),
    # (theta - sin theta) / theta^3: the c_2 of the SE(3) exponential
    "se3_c2": (_coefficients(lambda k: (-1) ** k / _FACT(2 * k + 3)),
               lambda th: (th - torch.sin(th)) / (th * th * th)),
    # (1 - (theta / 2) cot(theta / 2)) / theta^2: the c_3 of the SE(3) logarithm, from
    # x cot x = sum_n (-1)^n B_2n (2x)^2n / (2n)! (series radius 2 pi)
    "se3_c3": (_coefficients(lambda k: (-1) ** k * _BERNOULLI[k + 1] / _FACT(2 * k + 2)),
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
    neglected term is below an ulp of the result: the switch, :data:`THRESHOLDS`
    ``"even_series"``, is at :math:`x_2 = \min(1, \frac14 (\epsilon / |c_K|)^{1/K})`
    (:math:`\epsilon` of the compute dtype), large, so that the closed
    form never meets the cancellation of its derivatives near 0; at most 1, where the
    alternating series would start to cancel). Above it, the closed form is
    evaluated at :math:`\sqrt{x_2}` with the series' elements replaced by 1 first (safe
    where), so no branch ever produces a NaN or an infinite derivative. Eager on the CPU,
    where every element is below the switch (or every one above it and finite), only that
    branch is evaluated, and (outside reverse mode, from 16384 elements) where fewer than a
    quarter of them, all finite, are below it, the series on those alone: the same values
    and derivatives (the other branch's share of them is zero).
    """
    coeffs, exact = _EVEN[name]
    switch = threshold("even_series", compute_dtype(x2.dtype), coeffs[-1])
    least, most = _extremes(x2)  # eager CPU: where every element takes one branch, only it
    if switch <= least and most < math.inf:
        return exact(torch.sqrt(x2))
    if most < switch:
        return _series(coeffs, x2)
    small = x2 < switch
    # Not where autograd records: its sums of the series' terms into the gradient of x2
    # interleave with those of other functions of x2 (cos and sinc), in another order.
    if (small.numel() >= _FEW_MIN and most < math.inf
            and not (x2.requires_grad and torch.is_grad_enabled())
            and int(small.count_nonzero()) < small.numel() // 4):
        at = small.nonzero(as_tuple=True)
        closed = exact(torch.sqrt(torch.where(small, 1.0, x2)))
        return closed.index_put_(at, _series(coeffs, x2[at]))
    series = _series(coeffs, x2)
    return torch.where(small, series, exact(torch.sqrt(torch.where(small, 1.0, x2))))


_FEW_MIN = 16384  # elements from which even()'s series on a few of them pays its indexing


def _series(coeffs: tuple[float, ...], x2: Tensor) -> Tensor:
    """Horner's :math:`\\sum_{k < K} c_k x_2^k` of :func:`even` (``x2`` a tensor)."""
    series: Tensor | float = coeffs[_EVEN_TERMS - 1]
    for c in reversed(coeffs[:_EVEN_TERMS - 1]):
        series = series * x2 + c
    return cast(Tensor, series)


def _sinc_slope(th: Tensor) -> Tensor:
    return (torch.cos(th) - torch.sin(th) / th) / (2.0 * th * th)


def _c3_slope(th: Tensor) -> Tensor:
    s, c = th * th, 0.5 * th / torch.tan(0.5 * th)
    return -(0.5 * c / s - 0.125 / torch.sin(0.5 * th) ** 2 + (1.0 - c) / s) / s


#: ``d f / d x2`` of some functions of :data:`_EVEN`, closed forms in theta (from
#: :math:`f' = (d f / d\theta) / (2 \theta)`; :math:`\beta = (1 - \sigma) / x_2`,
#: :math:`\gamma = (1 - c) / x_2` with :math:`c = \frac\theta2 \cot\frac\theta2`).
_EVEN_SLOPES = {
    "sinc": _sinc_slope,
    "se3_c1": lambda th: (torch.sin(th) / th - 2.0 * (1.0 - torch.cos(th)) / (th * th))
    / (2.0 * th * th),
    "se3_c2": lambda th: -(_sinc_slope(th) + (th - torch.sin(th)) / th**3) / (th * th),
    "se3_c3": _c3_slope,
}


def even_slope(name: str, x2: Tensor) -> tuple[Tensor, Tensor]:
    r""":func:`even` and its derivative :math:`df / dx_2` (``"sinc"``, ``"se3_c1"``,
    ``"se3_c2"``, ``"se3_c3"``): the series and its term-by-term derivative below the same
    switch point (its first neglected term, times the number of terms, stays far below an ulp
    there), the closed forms of :data:`_EVEN_SLOPES` above it (their cancellation, about
    :math:`\epsilon / x_2`, is small at the switch). For dual numbers:
    :math:`f(x_2 + \varepsilon y) = f(x_2) + \varepsilon f'(x_2) y`. (:func:`even_slopes`
    of one function.)"""
    return even_slopes((name,), x2)[0]


def even_slopes(names: tuple[str, ...], x2: Tensor) -> list[tuple[Tensor, Tensor]]:
    r""":func:`even_slope` of several functions at the same ``x2``, the same numbers: the
    series of all of them in one Horner pass over ``(len(names), ...)`` rows, and the closed
    forms only where some element is above its switch point (on the CPU a read of one flag
    decides whether they are evaluated at all: near the identity, the common case, they are
    not; other devices evaluate them always, without a host sync). Not for ``torch.func``
    transforms (the flag), which the span kernels that use it do not run under."""
    series, slope = _even_rows(names, x2, True)
    return list(zip(series.unbind(0), cast(Tensor, slope).unbind(0), strict=True))


def evens(names: tuple[str, ...], x2: Tensor) -> list[Tensor]:
    """:func:`even` of several functions at the same ``x2``, the same numbers, as
    :func:`even_slopes` evaluates them (values alone: ``"cos"`` too)."""
    return list(_even_rows(names, x2, False)[0].unbind(0))


def _even_rows(names: tuple[str, ...], x2: Tensor, slopes: bool,
               ) -> tuple[Tensor, Tensor | None]:
    """:func:`even_slopes`' values and (``slopes``) slopes, ``(len(names), ...)`` each."""
    rows = (len(names),) + (1,) * x2.dim()
    dtype = compute_dtype(x2.dtype)
    coeffs = [_EVEN[n][0] for n in names]
    small = x2 < x2.new_tensor([threshold("even_series", dtype, c[-1]) for c in coeffs]).view(rows)
    # columns (len(names), 1, ...) of the coefficients and of the slope's, i c_i
    cs = x2.new_tensor([[c[i] for c in coeffs] for i in range(_EVEN_TERMS)]).view(-1, *rows)
    ds = x2.new_tensor([[i * c[i] for c in coeffs] for i in range(_EVEN_TERMS)]).view(-1, *rows)
    # Horner's steps in place after the first (fresh arrays' page faults cost as much as
    # the arithmetic; the same operations, the same bits)
    series = cs[-1] * x2 + cs[-2]
    slope = ds[-1] * x2 + ds[-2] if slopes else None
    for i in reversed(range(_EVEN_TERMS - 2)):
        series.mul_(x2).add_(cs[i])
        if i and slope is not None:
            slope.mul_(x2).add_(ds[i])
    if x2.device.type != "cpu" or not bool(small.all()):
        th = torch.sqrt(torch.where(small, 1.0, x2))
        series = torch.where(small, series, torch.stack(
            [_EVEN[n][1](t) for n, t in zip(names, th, strict=True)]))
        if slope is not None:
            slope = torch.where(small, slope, torch.stack(
                [_EVEN_SLOPES[n](t) for n, t in zip(names, th, strict=True)]))
    return series, slope


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


def plain_range(dtype: torch.dtype, power: int = 2) -> tuple[float, float]:
    r"""``(low, high)``: the squared norms :math:`|x|^2` of rows (of at most 4) within which
    plain arithmetic, and its first and second derivatives, have the bits of the same
    arithmetic on the rows divided by :func:`power_of_two_scale` (``power``: the bounds of
    :math:`|x|^{power}` instead).

    ``low = (tiny / eps)^{1/4}`` (:math:`2^{-242.5}` in float64, :math:`2^{-25.75}` in
    float32), ``high = 1 / low``: the second derivatives' :math:`|x|^{-6}` stays within
    :math:`(eps / tiny)^{3/4}` of 1, so no square, product or quotient of the largest
    components over- or underflows, and one that is subnormal in either form is far below
    the terms it is summed with. Where the division by a power of two changes nothing else,
    it commutes with every rounding; the exception is a result in the subnormal range, or a
    product of components many orders apart (``1e-300`` next to ``1e2``), where one form
    rounds a subnormal intermediate: the results differ there by at most a subnormal unit
    times the row's scale, far below an ulp of its largest entries.
    """
    key = (dtype, power)
    if key not in _PLAIN_RANGE:
        info = torch.finfo(dtype)
        low = (info.tiny / info.eps) ** (power / 8)
        _PLAIN_RANGE[key] = (low, 1.0 / low)
    return _PLAIN_RANGE[key]


_PLAIN_RANGE: dict[tuple[torch.dtype, int], tuple[float, float]] = {}


def prescale(x: Tensor, size: Tensor, power: int = 2) -> Tensor | None:
    r"""The divisor of rows ``x (..., k)`` that keeps their squares in range, given their
    plain norms to the ``power``, ``size (..., 1)`` (``power`` 1: :math:`|x|`, 2:
    :math:`|x|^2`); ``None`` where no row needs one.

    Rows whose :math:`|x|^2` lies within :func:`plain_range` are divided by 1 (their plain
    arithmetic has the prescaled bits), the others (huge, tiny, zero, non-finite) by
    :func:`power_of_two_scale`. Eager on the CPU one read of the extremes of ``size``
    returns ``None`` when every row is within (the common case: no division at all); other
    devices, ``torch.compile`` and ``torch.func`` transforms always get the divisor (no host
    sync), the same bits. Detached.
    """
    low, high = plain_range(x.dtype, power)
    least, most = _extremes(size)
    if low <= least and most <= high:
        return None
    size = size.detach()
    return torch.where((size >= low) & (size <= high), 1.0, power_of_two_scale(x))


def _readable(x: Tensor) -> bool:
    """Whether the values of ``x`` may be read on the host: eager on the CPU (not on other
    devices, under ``torch.compile`` or in ``torch.func`` transforms)."""
    return x.is_cpu and not torch.compiler.is_compiling() and not is_functorch_wrapped_tensor(x)


def may_hold(mask: Tensor) -> bool:
    """False only where the bool ``mask`` is read on the host (:func:`_readable`) and holds
    no True: the caller may then skip a branch that no element takes (one pass over it)."""
    return not _readable(mask) or bool(mask.any())


def _extremes(x: Tensor) -> tuple[float, float]:
    """``(min, max)`` of ``x`` read on the host, eager on the CPU (``(1, 1)`` if empty);
    ``(nan, nan)`` where ``x`` holds a NaN, and elsewhere (other devices, ``torch.compile``,
    ``torch.func`` transforms: no host read), so that every comparison with them fails."""
    if not _readable(x):
        return math.nan, math.nan
    if x.numel() <= 1:  # one read
        v = x.item() if x.numel() else 1.0
        return v, v
    least, most = torch.aminmax(x.detach())
    return float(least), float(most)


def unscaled(x: Tensor) -> Tensor:
    """``x`` itself, through an identity node of autograd where it records (a view): stands
    for :func:`prescale`'s division where none is needed, so that the double backward
    sums its terms in the same order as with the division, and a row's second derivatives
    keep their bits whichever form its batch takes."""
    return x.view_as(x) if x.requires_grad and torch.is_grad_enabled() else x


def safe_norm(x: Tensor) -> Tensor:
    """``|x|`` over the last dim, with the zero subgradient at ``x = 0`` (not NaN).

    Safe where: ``sqrt`` is evaluated at 1 where ``|x|^2 == 0``, so its infinite derivative
    never meets the zero upstream gradient; NaN and inf still propagate.
    """
    n2 = (x * x).sum(-1)
    zero = n2 == 0
    return torch.where(zero, 0.0, torch.sqrt(torch.where(zero, 1.0, n2)))

r"""Dual weights of the screw interpolation, eq. 11, as one power series (private).

Notation (paper section 3): for unit dual quaternions :math:`a = P + \epsilon Q` and
:math:`b = R + \epsilon S`, the dual scalar product (eq. 1) is
:math:`c + \epsilon\delta` with :math:`c = P\cdot R = \cos\theta` and
:math:`\delta = P\cdot S + R\cdot Q = -\hat\theta \sin\theta` (eqs. 4, 5, 7).

Interpolation (eq. 11) uses the dual weight :math:`F(s, \bar\theta)` with
:math:`F(s, \theta) = \sin(s\theta)/\sin\theta`, :math:`s = 1 - t` for ``a`` and
:math:`s = t` for ``b``. Its dual part is :math:`\hat\theta\, \partial_\theta F
= -\delta\, G` with :math:`G = \partial_\theta F / \sin\theta`, so that

.. math::
    q(t) = F_0 a + F_1 b - \epsilon\, \delta\, (G_0 P + G_1 R)

and no :math:`\hat\theta = -\delta/\sin\theta` (a 0/0 when the rotations agree) is ever
formed. In the variable :math:`y = 1 - \cos\theta` every weight is one power series,

.. math::
    F = \sum_k a_k(s)\, y^k, \quad a_0 = s, \quad
    a_k = a_{k-1}\,\frac{k^2 - s^2}{k (2k + 1)},

and :math:`G = \partial_y F`, :math:`H = \partial_y G` (needed by the gradients, together
with :math:`F_s = \partial_s F`, :math:`G_s = \partial_s G`). Near :math:`y = 0` the
truncated series is used, elsewhere the closed forms

.. math::
    G = \frac{s\cos s\theta - F\cos\theta}{\sin^2\theta},\quad
    H = \frac{(1 - s^2) F - 3 G \cos\theta}{\sin^2\theta},\quad
    F_s = \frac{\theta\cos s\theta}{\sin\theta},\quad
    G_s = \frac{\cos s\theta - s\theta\sin s\theta - F_s\cos\theta}{\sin^2\theta}.

``F`` and ``G`` are computed once, on jets (:func:`torch_dq._taylor.weight_parts`): the kernels
call its series and closed forms with one Taylor coefficient and add :math:`H, F_s, G_s`.
Switch point and number of terms: :data:`torch_dq._numerics.THRESHOLDS` ``"screw_series"``
(order 0).
"""

from __future__ import annotations

import math
from typing import NamedTuple, cast

import torch
from torch import Tensor

from .. import _taylor
from .._numerics import (
    ANGLE_SQUARE_TERMS,
    Parts,
    piecewise,
    screw_series_terms,
    series_mask,
    threshold,
)

_TERMS = screw_series_terms(0)  # the kernels' series: a jet of order 0


class Weights(NamedTuple):
    """Dual weights of eq. 11, each ``(2, ...)``: row 0 for ``a`` (``s = 1 - t``), row 1 for
    ``b`` (``s = t``)."""

    F: Tensor  # sin(s theta) / sin(theta)
    G: Tensor  # dF/dtheta / sin(theta) = dF/dy


class WeightSlopes(NamedTuple):
    """:class:`Weights` and the derivatives the gradients need, each ``(2, ...)``."""

    F: Tensor
    G: Tensor
    H: Tensor  # dG/dy
    Fs: Tensor | None  # dF/ds (None when the time derivatives were not asked for)
    Gs: Tensor | None  # dG/ds
    Hs: Tensor | None = None  # dH/ds (asked for with h_slope)


class RotationWeights(NamedTuple):
    """Weights of quaternion slerp (:func:`slerp_weights`), each ``(2, ...)``."""

    F: Tensor  # sin(s theta) / sin(theta)
    G: Tensor | None  # dF/dy (with derivatives)
    Fs: Tensor | None  # dF/ds (with derivatives and time_slopes)


class Angle(NamedTuple):
    r""":math:`\theta = \arccos c` with its sine and cosine, on guarded inputs.

    The fused curve scheme computes these once per pair of neighbouring control points
    (level 0 of De Casteljau / De Boor reads the same pairs at every time of a span) and
    hands them to :func:`screw_weights`.
    """

    theta: Tensor
    sin: Tensor
    cos: Tensor


def angle(c: Tensor) -> Angle:
    r""":class:`Angle` of cosines ``c`` (:func:`torch_dq._taylor.angle` of order 0), with
    ``c`` replaced by 0 (``theta = pi / 2``) where :math:`c \ge 1` (equal rotations, or
    rounding above 1), the only cosines whose closed forms are not finite;
    :func:`screw_weights` takes the series branch there for every ``t``. The guard cannot be
    wider: with extrapolation (:math:`|s| > 1`) the closed forms are selected down to
    :math:`1 - c` = threshold / :math:`s^2`, and need the true angle."""
    jets = _taylor.angle([c], (c >= 1.0).to(c.dtype))
    return Angle(*(cast(Tensor, x[0]) for x in jets))


def angle_square(c: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r""":math:`\theta^2 = \arccos(c)^2`, :math:`\kappa = d\theta^2/dy = 2\theta/\sin\theta`
    (:math:`y = 1 - c`) and :math:`\kappa' = d\kappa/dy = 2 (\sin\theta - \theta\cos\theta)
    / \sin^3\theta`, the constants of the weights' equations in ``s``:
    :math:`\partial_s^2 F = -\theta^2 F` (``F = sin(s theta) / sin(theta)``) and, taking
    :math:`\partial_y` of it, :math:`\partial_s^2 G = -\kappa F - \theta^2 G` and
    :math:`\partial_s^2 H = -\kappa' F - 2 \kappa G - \theta^2 H` (``H = dG/dy``).

    Analytic in ``y``, so differentiable any number of times at equal rotations (``c = 1``,
    where :math:`\arccos` is not): below the switch point (:data:`THRESHOLDS`
    ``"angle_square_series"``) the series
    :math:`\theta^2 = 2 \sum_{k \ge 1} (2y)^k / (k^2 \binom{2k}{k})` (from
    :math:`\theta = 2 \arcsin\sqrt{y/2}`) and its derivatives, above it the closed forms
    on guarded inputs. ``c`` in ``[0, 1]`` up to rounding (sign-aligned pairs).
    """
    y = 1.0 - c
    small = y < threshold("angle_square_series", c.dtype)
    b = [2.0 * 2.0**k / (k * k * math.comb(2 * k, k)) for k in range(1, ANGLE_SQUARE_TERMS + 1)]
    ys = torch.where(small, y, 0.0)
    # 0-d coefficients made by a fill on the device (no host copy)
    th2 = ys * _horner([ys.new_full((), x) for x in b], ys)
    kappa = _horner([ys.new_full((), k * x) for k, x in enumerate(b, 1)], ys)
    kappa_y = _horner([ys.new_full((), k * (k - 1) * x) for k, x in enumerate(b, 1)][1:], ys)
    theta = torch.acos(torch.where(small, 0.0, c))
    sin = torch.sin(theta)
    return (torch.where(small, th2, theta * theta),
            torch.where(small, kappa, 2.0 * theta / sin),
            torch.where(small, kappa_y, 2.0 * (sin - theta * c) / (sin * sin * sin)))


def _horner(coeffs: list[Tensor], y: Tensor) -> Tensor:
    out = coeffs[-1]
    for a in reversed(coeffs[:-1]):
        out = torch.addcmul(a, y, out)
    return out


def _series_branch(s: Tensor, s2: Tensor, y: Tensor, derivatives: bool, time_slopes: bool,
                   dual: bool, h_slope: bool = False) -> Parts:
    """Series branch (module docstring): ``F, G`` (and ``H, Fs, Gs``, and ``Hs`` with
    ``h_slope``) near ``y = 0``, each the exact derivative of the truncated series before it;
    without ``dual`` only ``F`` (and ``G, Fs``), the others ``None``."""
    series = _taylor.series([y], [s], [s2], _TERMS, with_G=dual or derivatives)
    F, G = series.F[0], series.G[0] if series.G else None
    if not derivatives:
        return [F, G, None, None, None, None]
    a1 = cast(Tensor, series.a1[0])
    H = 0.2 * a1 * (4.0 - s2) * cast(Tensor, _taylor.nested(series.u, 2)[0]) if dual else None
    if not time_slopes:
        return [F, G, H, None, None, None]
    # d a_k / ds by differentiating the recurrence a_k = a_{k-1} (k^2 - s^2) / (k (2k + 1)).
    a, da = [s], [torch.ones_like(s)]
    for k in range(1, _TERMS):
        d = k * (2 * k + 1)
        da.append((da[-1] * (k * k - s2) - 2.0 * s * a[-1]) / d)
        a.append(a[-1] * (k * k - s2) / d)
    Gs = _horner([k * da[k] for k in range(1, _TERMS)], y) if dual else None
    Hs = _horner([k * (k - 1) * da[k] for k in range(2, _TERMS)], y) if h_slope else None
    return [F, G, H, _horner(da, y), Gs, Hs]


def _closed_branch(s: Tensor, ang: Angle, derivatives: bool, time_slopes: bool,
                   dual: bool, h_slope: bool = False) -> Parts:
    """Closed forms (module docstring) at the angles ``ang`` (``dual``: as
    :func:`_series_branch`)."""
    jets = _taylor.AngleJets([ang.theta], [ang.sin], [ang.cos])
    closed = _taylor.closed([s], jets, with_G=dual or derivatives)
    F = cast(Tensor, closed.F[0])
    if not (dual or derivatives):
        return [F, None, None, None, None, None]
    G, sin2 = cast(Tensor, closed.G[0]), cast(Tensor, closed.sin2[0])
    if not derivatives:
        return [F, G, None, None, None, None]
    H = ((1.0 - s * s) * F - 3.0 * G * ang.cos) / sin2 if dual else None
    if not time_slopes:
        return [F, G, H, None, None, None]
    st, sin_st, cos_st = (cast(Tensor, x[0]) for x in (closed.st, closed.sin_st, closed.cos_st))
    Fs = ang.theta * cos_st / ang.sin
    Gs = (cos_st - st * sin_st - Fs * ang.cos) / sin2 if dual else None
    Hs = (((1.0 - s * s) * Fs - 2.0 * s * F - 3.0 * cast(Tensor, Gs) * ang.cos) / sin2
          if h_slope else None)
    return [F, G, H, Fs, Gs, Hs]


def screw_weights(c: Tensor, t: Tensor, derivatives: bool = False, *,
                  time_slopes: bool = True, ang: Angle | None = None,
                  host_branch: bool = False, y: Tensor | None = None,
                  h_slope: bool = False) -> Weights | WeightSlopes:
    r"""Interpolation weights at :math:`\cos\theta = c` for ``s = (1 - t, t)``.

    Args:
        c: ``(N,)`` cosines, in ``[-1, 1]`` up to rounding (any shape broadcasting with
            ``t``).
        t: ``(N,)`` interpolation parameters.
        derivatives: also return :math:`H, F_s, G_s` (for the gradients).
        time_slopes: with ``derivatives``, also :math:`F_s, G_s` (``None`` otherwise: only
            the gradient with respect to ``t`` needs them).
        ang: :func:`angle` of ``c`` if already known (the fused curve scheme computes it
            once per pair of control points).
        host_branch: evaluate only the branches that some element takes, and the series
            only at its elements when they are few (one host read of a count; the result is
            the same to the bit). For the eager fused kernels on
            CPU: in float32 the series covers relative rotations up to ~40 degrees, so for
            a smooth trajectory no transcendental function is evaluated at all.
        y: :math:`1 - c` if known more precisely than from the rounded ``c`` (computed in
            a wider dtype): below float32's resolution at 1 a small angle's ``y`` is 0 or
            one ulp of 1, and the series loses its :math:`\theta^2` terms.
        h_slope: with ``derivatives`` and ``time_slopes``, also :math:`H_s = \partial_s H`
            (closed form :math:`((1 - s^2) F_s - 2 s F - 3 G_s \cos\theta) /
            \sin^2\theta`; the cumulative form's written-out backward of its time
            derivatives needs it).

    Returns:
        :class:`Weights` ``(F, G)``, or :class:`WeightSlopes` ``(F, G, H, Fs, Gs, Hs)`` with
        ``derivatives``; each ``(2, N)``: row 0 for ``a`` (``s = 1 - t``), row 1 for ``b``
        (``s = t``).
    """
    F, G, H, Fs, Gs, Hs = _weights(c, t, derivatives, time_slopes, ang, host_branch,
                                   dual=True, y=y, h_slope=h_slope)
    F, G = cast(Tensor, F), cast(Tensor, G)  # computed with dual
    return WeightSlopes(F, G, cast(Tensor, H), Fs, Gs, Hs) if derivatives else Weights(F, G)


def slerp_weights(c: Tensor, t: Tensor, derivatives: bool = False, *, time_slopes: bool = True,
                  host_branch: bool = False) -> RotationWeights:
    r"""The weights :math:`F` of quaternion slerp (the real part of eq. 11) at
    :math:`\cos\theta = c`, for ``s = (1 - t, t)``: :func:`screw_weights` without the dual
    part's :math:`G, H, G_s` (for the gradients, :math:`G = \partial_y F` and :math:`F_s`).

    Args:
        c: ``(N,)`` cosines (any shape broadcasting with ``t``).
        t: ``(N,)`` interpolation parameters.
        derivatives: also return :math:`G` and (with ``time_slopes``) :math:`F_s`.
        time_slopes: as in :func:`screw_weights`.
        host_branch: as in :func:`screw_weights`.

    Returns:
        :class:`RotationWeights`, each ``(2, N)`` (or ``None`` where not asked for).
    """
    F, G, _, Fs, _, _ = _weights(c, t, derivatives, time_slopes, None, host_branch,
                                 dual=False)
    return RotationWeights(cast(Tensor, F), G, Fs)


def _weights(c: Tensor, t: Tensor, derivatives: bool, time_slopes: bool, ang: Angle | None,
             host_branch: bool, dual: bool, y: Tensor | None = None,
             h_slope: bool = False) -> Parts:
    """:func:`screw_weights` (``dual``) or :func:`slerp_weights`: ``[F, G, H, Fs, Gs, Hs]``,
    ``None`` where not computed.

    The series where ``y max(1, s^2)`` (its terms scale like :math:`(s^2 y)^k`) is below the
    switch point, the closed forms elsewhere, on guarded inputs (:func:`angle`: series
    elements with ``c >= 1`` see ``theta = pi / 2``). No clamp: ``c > 1`` only occurs in the
    series branch, and ``c < -1`` (opposite real parts with ``shortest=False``, undefined) or
    an infinite ``c`` must give NaN, not a finite ``theta = pi``.
    """
    s = torch.stack((1.0 - t, t))
    s2 = s * s
    y = 1.0 - c if y is None else y
    small = series_mask(y, s2, threshold("screw_series", c.dtype))
    return piecewise(
        small, host_branch,
        lambda pick: _series_branch(pick(s), pick(s2), pick(y), derivatives, time_slopes, dual,
                                    h_slope),
        lambda: _closed_branch(s, angle(c) if ang is None else ang, derivatives, time_slopes,
                               dual, h_slope))

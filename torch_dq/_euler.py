r"""Euler angles of quaternions (private; public as :func:`torch_dq.quat.from_euler` and
:func:`torch_dq.quat.to_euler`).

A sequence of three axes from ``'xyz'`` (extrinsic: rotations about the fixed axes) or
``'XYZ'`` (intrinsic: about the rotated axes), no two consecutive equal, scipy's
``Rotation.from_euler`` / ``as_euler`` convention; quaternions ``(w, x, y, z)`` as in
:mod:`torch_dq.quat`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from . import _checks, _numerics
from ._core import lift, qmul

__all__ = ["from_euler", "to_euler"]


def _safe_hypot(x: Tensor, y: Tensor) -> Tensor:
    """``hypot(x, y)`` (scipy's rounding) whose gradient at ``x = y = 0`` is 0, not NaN."""
    zero = (x == 0) & (y == 0)
    return torch.where(zero, 0.0, torch.hypot(torch.where(zero, 1.0, x), y))


def _wrap(angle: Tensor) -> Tensor:
    """Map angles in [-2 pi, 2 pi] into [-pi, pi] (keeping pi and -pi as they are)."""
    two_pi = 2.0 * math.pi
    return torch.where(angle > math.pi, angle - two_pi,
                       torch.where(angle < -math.pi, angle + two_pi, angle))


def _parse_seq(fn: str, seq) -> tuple[list[int], bool]:
    """Axis indices of an Euler sequence and whether it is extrinsic (lower case)."""
    if not isinstance(seq, str):
        _checks.fail(fn, f"expected seq to be a str, got {type(seq).__name__}", TypeError)
    low = seq.lower()
    valid = (len(seq) == 3 and set(low) <= set("xyz")
             and low[0] != low[1] and low[1] != low[2])
    if valid and seq not in (low, seq.upper()):
        _checks.fail(fn, f"seq mixes lower case (extrinsic) and upper case (intrinsic) "
                         f"axes, got {seq!r}")
    if not valid:
        _checks.fail(fn, f"expected seq to be 3 axes from 'xyz' (extrinsic) or 'XYZ' "
                         f"(intrinsic), no two consecutive equal, e.g. 'xyz' or 'ZXZ', "
                         f"got {seq!r}")
    return ["xyz".index(c) for c in low], seq == low


def from_euler(angles: Tensor, seq: str) -> Tensor:
    """Quaternion of Euler / Tait-Bryan angles, scipy's ``Rotation.from_euler`` convention.

    Args:
        angles: ``(..., 3)`` angles in radians, in the order of ``seq``.
        seq: 3 axes from ``'xyz'`` (extrinsic: rotations about the fixed frame's axes) or
            ``'XYZ'`` (intrinsic: about the moving frame's axes), no two consecutive
            equal: the 6 Tait-Bryan (``'xyz'``, ...) and 6 proper Euler (``'zxz'``, ...)
            sequences. ``'XYZ'`` with ``(a, b, c)`` equals ``'zyx'`` with ``(c, b, a)``.

    Returns:
        ``(..., 4)`` unit quaternions (the product of the three elementary rotations,
        sign not canonicalised).

    Raises:
        ValueError: ``seq`` is not one of the 24 sequences or mixes cases.
        TypeError: ``seq`` is not a str.

    Example:
        >>> from_euler(torch.tensor([0., 0., torch.pi / 2]), "xyz").round(decimals=4)
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    fn = "quat.from_euler"
    _checks.tensor(fn, "angles", angles, 3)
    axes, extrinsic = _parse_seq(fn, seq)
    half = lift(angles)[..., None] / 2.0
    basis = torch.eye(3, dtype=half.dtype, device=half.device)
    q: Tensor | None = None
    for n, ax in enumerate(axes):
        e = torch.cat((torch.cos(half[..., n, :]), torch.sin(half[..., n, :]) * basis[ax]), -1)
        q = e if q is None else (qmul(e, q) if extrinsic else qmul(q, e))
    assert q is not None  # _parse_seq gives three axes
    return q.to(angles.dtype)


def to_euler(q: Tensor, seq: str) -> Tensor:
    """Euler / Tait-Bryan angles of a rotation, scipy's ``Rotation.as_euler`` convention.

    Quaternion-based method of Bernardes & Viollet (2022), "Quaternion to Euler angles
    conversion: a direct, general and computationally efficient method", vectorised.

    Args:
        q: ``(..., 4)`` non-zero quaternions (need not be unit).
        seq: as in :func:`from_euler`.

    Returns:
        ``(..., 3)`` angles in radians, in scipy's ranges: first and third in [-pi, pi],
        second in [-pi/2, pi/2] (Tait-Bryan) or [0, pi] (proper Euler).

    Gimbal lock (second angle within 1e-7 of 0 or pi for proper Euler, of -pi/2 or pi/2
    for Tait-Bryan, scipy's threshold): only the sum or difference of the first and third
    angles is defined; like scipy the third angle is set to 0 (silently, no warning).
    Gradients stay finite there.

    Example:
        >>> to_euler(from_euler(torch.tensor([0.1, 0.2, 0.3]), "ZYX"), "ZYX")
        tensor([0.1000, 0.2000, 0.3000])
    """
    fn = "quat.to_euler"
    _checks.tensor(fn, "q", q, 4)
    axes, extrinsic = _parse_seq(fn, seq)
    i, j, k = axes if extrinsic else axes[::-1]
    symmetric = i == k
    if symmetric:
        k = 3 - i - j
    sign = (i - j) * (j - k) * (k - i) // 2  # +1 if (i, j, k) is a cyclic permutation
    ql = lift(q)
    ql = ql / _numerics.power_of_two_scale(ql)  # exact; no square over- or underflows
    w, qi, qj, qk = ql[..., 0], ql[..., 1 + i], ql[..., 1 + j], sign * ql[..., 1 + k]
    # Step 1: rotate the problem onto a proper Euler sequence (i, j, i).
    a, b, c, d = (w, qi, qj, qk) if symmetric else (w - qj, qi + qk, qj + w, qk - qi)
    # Step 2: the second angle, then the half sum and half difference of the
    # other two, each undefined at one gimbal lock: safe-where their atan2.
    theta = 2.0 * torch.atan2(_safe_hypot(c, d), _safe_hypot(a, b))
    lock = _numerics.threshold("gimbal_lock", theta.dtype)
    lock0 = theta <= lock
    lock_pi = (theta - math.pi).abs() <= lock
    free = ~(lock0 | lock_pi)
    half_sum = torch.atan2(torch.where(lock_pi, 0.0, b), torch.where(lock_pi, 1.0, a))
    half_diff = torch.atan2(torch.where(lock0, 0.0, d), torch.where(lock0, 1.0, c))
    # Step 3: in gimbal lock angle 0 takes the whole rotation and angle 2 is zero.
    locked = torch.where(lock0, 2.0 * half_sum, (-2.0 if extrinsic else 2.0) * half_diff)
    out: dict[int, Tensor] = {}
    first, third = (0, 2) if extrinsic else (2, 0)
    out[first] = torch.where(free, half_sum - half_diff, locked if first == 0 else 0.0)
    out[third] = torch.where(free, half_sum + half_diff, locked if third == 0 else 0.0)
    out[1] = theta
    if not symmetric:
        out[third] = sign * out[third]
        out[1] = theta - math.pi / 2
    angles = torch.stack((_wrap(out[0]), out[1], _wrap(out[2])), dim=-1)
    # Non-finite q: NaN, not the finite limits of the atan2s.
    return _numerics.nan_unless(torch.isfinite(ql).all(-1, keepdim=True), angles).to(q.dtype)

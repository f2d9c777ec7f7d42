r"""Dual quaternions from and to other pose representations (private; public as
``torch_dq.dualquat.from_rt``, ``to_rt``, ``from_matrix``, ``to_matrix``, ``from_pose7``,
``to_pose7``, ``from_screw``, ``to_screw``).

Rotation quaternion and translation, 4x4 homogeneous matrices, 7-vectors ``(x, y, z, qx,
qy, qz, qw)`` and screw parameters, in the conventions of :mod:`torch_dq.dualquat`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _checks, quat
from ._core import canonical, dq_from_rt, join, lift, lower, split, translation
from ._numerics import nan_unless, safe_denominator, threshold

__all__ = ["from_matrix", "from_pose7", "from_rt", "from_screw", "to_matrix", "to_pose7", "to_rt",
           "to_screw"]


def from_rt(q: Tensor, t: Tensor) -> Tensor:
    r"""Rigid transform :math:`x \mapsto R(q) x + t` as a dual quaternion.

    Args:
        q: ``(..., 4)`` unit rotation quaternions ``(w, x, y, z)`` (not checked).
        t: ``(..., 3)`` translations, batch broadcastable with ``q``.

    Returns:
        ``(..., 8)``: ``real = q``, ``dual = 0.5 (0, t) q``.

    Example:
        >>> from_rt(torch.tensor([1., 0., 0., 0.]), torch.tensor([2., 0., 0.]))
        tensor([1., 0., 0., 0., 0., 1., 0., 0.])
    """
    fn = "dualquat.from_rt"
    _checks.tensor(fn, "q", q, 4)
    _checks.tensor(fn, "t", t, 3)
    _checks.same_dtype_device(fn, q=q, t=t)
    _checks.broadcast_batch(fn, q=(q, 1), t=(t, 1))
    return lower(dq_from_rt(lift(q), lift(t)), q.dtype)


def to_rt(x: Tensor) -> tuple[Tensor, Tensor]:
    r"""Rotation quaternion and translation of a unit dual quaternion.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).

    Returns:
        ``(q, t)``: ``(..., 4)`` (a copy of the real part, sign as given) and
        ``(..., 3)`` translation :math:`t = 2\,\mathrm{vec}(d r^*)`.
    """
    _checks.tensor("dualquat.to_rt", "x", x, 8)
    r, d = split(lift(x))
    return x[..., :4].clone(), lower(translation(r, d), x.dtype)


def from_matrix(T: Tensor, check: bool = False) -> Tensor:
    """Dual quaternion of ``(..., 4, 4)`` homogeneous rigid transforms.

    The rotation block is converted with :func:`torch_dq.quat.from_matrix` (robust at every
    angle, real part ``w >= 0``); the bottom row is not read.

    Args:
        T: ``(..., 4, 4)`` homogeneous matrices ``[[R, t], [0, 1]]`` (``R`` orthogonal, not
            checked unless ``check``: see :func:`torch_dq.quat.from_matrix`).
        check: raise ``ValueError`` unless every matrix is rigid: ``R`` a rotation within
            1e-3 (``max |R^T R - I|``, determinant > 0), the bottom row ``(0, 0, 0, 1)``
            within 1e-3, all finite (one device sync). Without it a scaled, sheared or
            reflecting matrix gives some unit dual quaternion, not an error.

    Returns:
        ``(..., 8)`` unit dual quaternions.
    """
    _checks.tensor("dualquat.from_matrix", "T", T, (4, 4))
    if _checks.flag("dualquat.from_matrix", "check", check):
        _checks.rigid_matrix("dualquat.from_matrix", "T", T)
    Tl = lift(T)
    return lower(dq_from_rt(quat.from_matrix(Tl[..., :3, :3]), Tl[..., :3, 3]), T.dtype)


def to_matrix(x: Tensor) -> Tensor:
    """Homogeneous ``(..., 4, 4)`` matrices ``[[R, t], [0, 1]]`` of unit dual quaternions.

    Args:
        x: unit dual quaternions, not checked (``x`` and ``-x`` give the same matrix).
    """
    _checks.tensor("dualquat.to_matrix", "x", x, 8)
    r, d = split(lift(x))
    top = torch.cat((quat.to_matrix(r), translation(r, d)[..., None]), dim=-1)
    bottom = top.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(*top.shape[:-2], 1, 4)
    return lower(torch.cat((top, bottom), dim=-2), x.dtype)


def from_pose7(p: Tensor) -> Tensor:
    """From the 7-vector ``(tx, ty, tz, qx, qy, qz, qw)`` of pypose and ROS.

    Args:
        p: ``(..., 7)``: translation then a unit quaternion in scalar-last order
            (not checked).
    """
    _checks.tensor("dualquat.from_pose7", "p", p, 7)
    pl = lift(p)
    return lower(dq_from_rt(pl[..., [6, 3, 4, 5]], pl[..., :3]), p.dtype)


def to_pose7(x: Tensor) -> Tensor:
    """To the 7-vector ``(tx, ty, tz, qx, qy, qz, qw)`` of pypose and ROS.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked); the quaternion keeps the sign of
            the real part.
    """
    _checks.tensor("dualquat.to_pose7", "x", x, 8)
    r, d = split(lift(x))
    return lower(torch.cat((translation(r, d), r[..., [1, 2, 3, 0]]), dim=-1), x.dtype)


def from_screw(axis: Tensor, moment: Tensor, theta: Tensor | float, d: Tensor | float,
               ) -> Tensor:
    r"""Screw motion as a dual quaternion (the paper's eq. 2 with its typos fixed).

    :math:`\cos\frac{\theta + \epsilon d}{2} + \sin\frac{\theta + \epsilon d}{2}
    (l + \epsilon m)`, i.e. real part :math:`(\cos\frac\theta2, \sin\frac\theta2 l)` and dual
    part :math:`(-\frac d2 \sin\frac\theta2,\ \sin\frac\theta2 m + \frac d2\cos\frac\theta2 l)`:
    a rotation by ``theta`` about the line with Plücker coordinates ``(l, m)`` followed by a
    translation ``d`` along it. ``theta = 0`` is a pure translation by ``d l``.

    Args:
        axis: ``(..., 3)`` unit direction ``l`` of the screw axis (not checked).
        moment: ``(..., 3)`` moment ``m = p x l`` for any point ``p`` on the axis
            (orthogonal to ``l``).
        theta: ``(...)`` rotation angle in radians (tensor or float).
        d: ``(...)`` translation along the axis (tensor or float).

    Returns:
        ``(..., 8)`` unit dual quaternions.
    """
    fn = "dualquat.from_screw"
    _checks.tensor(fn, "axis", axis, 3)
    _checks.tensor(fn, "moment", moment, 3)
    theta = _checks.as_float_tensor(fn, "theta", theta, axis, "axis")
    d = _checks.as_float_tensor(fn, "d", d, axis, "axis")
    _checks.same_dtype_device(fn, axis=axis, moment=moment)
    batch = _checks.broadcast_batch(fn, axis=(axis, 1), moment=(moment, 1), theta=(theta, 0),
                                    d=(d, 0))
    dtype = axis.dtype
    axis, moment = lift(axis), lift(moment)
    theta, d = lift(theta).expand(batch), lift(d).expand(batch)
    s, c = torch.sin(0.5 * theta)[..., None], torch.cos(0.5 * theta)[..., None]
    h = 0.5 * d[..., None]
    real = torch.cat((c, s * axis), dim=-1)
    dual = torch.cat((-h * s, s * moment + h * c * axis), dim=-1)
    return lower(join(real, dual), dtype)


def to_screw(x: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    r"""Screw parameters ``(axis, moment, theta, d)`` of unit dual quaternions.

    The representative with :math:`r_w \ge 0` is used (at :math:`r_w = 0`, the one whose first
    non-zero of x, y, z is positive, as in :func:`torch_dq.quat.to_axis_angle`), so ``theta``
    is in ``[0, pi]`` and ``x``, ``-x`` give the same parameters.
    With :math:`t` the translation and :math:`l` the rotation axis: :math:`d = t \cdot l` and
    :math:`m = \frac12 (t \times l + (t - d l) \cot\frac\theta2)` (pytransform3d's formula).
    A pure translation (``sin(theta / 2)`` below machine epsilon) gives ``axis = t / |t|``,
    ``moment = 0``, ``theta = 0``, ``d = |t|``; the identity gives axis ``(1, 0, 0)`` and
    zeros. Inverse of :func:`from_screw` up to the sign of (axis, theta, d).

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).

    Returns:
        ``axis (..., 3)``, ``moment (..., 3)``, ``theta (...)``, ``d (...)``.
    """
    _checks.tensor("dualquat.to_screw", "x", x, 8)
    dtype, x = x.dtype, lift(x)
    r, dq_ = split(x)
    t = translation(r, dq_)
    # scipy's canonical sign (w > 0, ties at w = 0 broken by x, y, z): x and -x agree at 180 deg
    rc = canonical(r)
    w, v = rc[..., :1], rc[..., 1:]
    sin_half = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    theta = 2.0 * torch.atan2(sin_half, w)
    eps = threshold("pure_translation", x.dtype)
    translation_only = sin_half <= eps
    t_norm = torch.linalg.vector_norm(t, dim=-1, keepdim=True)
    fallback = torch.zeros_like(t)
    fallback[..., 0] = 1.0
    # A non-finite translation fails `t_norm <= eps` and gives a NaN axis (never the fallback).
    no_dir = t_norm <= eps
    t_dir = torch.where(no_dir, fallback, t / safe_denominator(t_norm, no_dir))
    l = torch.where(translation_only, t_dir, v / safe_denominator(sin_half, translation_only))
    d = (t * l).sum(-1, keepdim=True)
    cot_half = w / safe_denominator(sin_half, translation_only)
    m = 0.5 * (torch.linalg.cross(t, l, dim=-1) + (t - d * l) * cot_half)
    m = torch.where(translation_only, torch.zeros_like(m), m)
    theta = torch.where(translation_only, torch.zeros_like(theta), theta)
    # A non-finite x gives NaN everywhere, not the finite limits of atan2 or of the branches.
    finite = torch.isfinite(x).all(-1, keepdim=True)
    l, m, theta, d = (nan_unless(finite, y).to(dtype) for y in (l, m, theta, d))
    return l, m, theta[..., 0], d[..., 0]

r"""Velocities, accelerations and IMU readings of rigid motions (private; public names are
re-exported by :mod:`torch_dq.curves`).

A motion is given by its pose :math:`x = r + \epsilon d` (a unit dual quaternion, the
rigid transform :math:`p \mapsto R p + t`) and time derivatives :math:`\dot x, \ddot x`
(e.g. from :func:`torch_dq.curves.bspline_derivatives`). With :math:`t = 2\,\mathrm{vec}(d
r^*)` and :math:`\dot R = [\omega]_\times R`:

.. math::
    \omega = 2\,\mathrm{vec}(\dot r r^*),\quad
    \dot\omega = 2\,\mathrm{vec}(\ddot r r^*),\quad
    \dot t = 2\,\mathrm{vec}(\dot d r^* + d \dot r^*),\quad
    \ddot t = 2\,\mathrm{vec}(\ddot d r^* + 2 \dot d \dot r^* + d \ddot r^*)

(:math:`\dot r \dot r^* = |\dot r|^2` is real, so :math:`\dot\omega` has no second term).
Every formula is invariant under :math:`(x, \dot x, \ddot x) \to -(x, \dot x, \ddot x)`.
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Sequence
from typing import NamedTuple, cast

import torch
from torch import Tensor

from . import _checks
from ._core import dq_mul, lift, qconj, qmul, qrotate, split
from ._numerics import compute_dtype, safe_denominator, threshold

__all__ = ["Kinematics", "imu", "kinematics", "screw_axis", "twists", "velocity"]

_FRAMES = ("world", "body")


class Kinematics(NamedTuple):
    """Velocities and accelerations of a rigid motion, each ``(..., 3)`` (see
    :func:`kinematics`); the accelerations are ``None`` when no second derivative was given."""

    angular_velocity: Tensor
    linear_velocity: Tensor
    angular_acceleration: Tensor | None
    linear_acceleration: Tensor | None


def _vec2(q: Tensor) -> Tensor:
    """Twice the vector part of a quaternion."""
    return 2.0 * q[..., 1:]


def _check_motion(fn: str, x, dx, ddx, ddx_required: bool) -> None:
    named = {"x": x, "dx": dx} if ddx is None else {"x": x, "dx": dx, "ddx": ddx}
    if ddx is None and ddx_required:
        _checks.fail(fn, "expected a torch.Tensor for ddx, got NoneType", TypeError)
    for name, v in named.items():
        _checks.tensor(fn, name, v, 8)
    _checks.same_dtype_device(fn, **named)
    _checks.broadcast_batch(fn, **{name: (v, 1) for name, v in named.items()})


_ALL = (True, True, True, True)


def _world(x: Tensor, dx: Tensor, ddx: Tensor | None, fields: tuple[bool, ...] = _ALL):
    """World-axes angular and linear velocity (and accelerations), module docstring; those
    not in ``fields`` (flags in :class:`Kinematics`' order) None, their products skipped."""
    r, d = split(x)
    rd, dd = split(dx)
    rc, rdc = qconj(r), qconj(rd)
    omega = _vec2(qmul(rd, rc)) if fields[0] else None
    v = _vec2(qmul(dd, rc) + qmul(d, rdc)) if fields[1] else None
    if ddx is None:
        return omega, v, None, None
    rdd, ddd = split(ddx)
    alpha = _vec2(qmul(rdd, rc)) if fields[2] else None
    a = _vec2(qmul(ddd, rc) + 2.0 * qmul(dd, rdc) + qmul(d, qconj(rdd))) if fields[3] else None
    return omega, v, alpha, a


def _evaluate(x: Tensor, dx: Tensor, ddx: Tensor | None, frame: str,
              fields: tuple[bool, ...] = _ALL) -> tuple[Tensor | None, ...]:
    """:func:`kinematics`' fields (those in ``fields``; the others None), arguments not
    checked."""
    dtype = x.dtype
    x, dx = lift(x), lift(dx)
    ddx = None if ddx is None else lift(ddx)
    out = _world(x, dx, ddx, fields)
    if frame == "body":
        rc = qconj(x[..., :4])
        out = tuple(None if v is None else qrotate(rc, v) for v in out)
    batch = _checks.broadcast_shapes(*(v.shape[:-1] for v in (x, dx, ddx) if v is not None))
    return tuple(None if u is None else u.expand(*batch, 3).to(dtype) for u in out)


def body_field(x: Tensor, dx: Tensor, ddx: Tensor | None, field: int) -> Tensor:
    """Field ``field`` (:class:`Kinematics`' order) of ``kinematics(x, dx, ddx,
    frame="body")`` alone: the same numbers without the other fields' products (the IMU
    terms' residuals read one each); arguments not checked."""
    out = _evaluate(x, dx, ddx, "body", tuple(i == field for i in range(4)))[field]
    assert out is not None  # the field asked for is computed
    return out


def kinematics(x: Tensor, dx: Tensor, ddx: Tensor | None = None,
               frame: str = "world") -> Kinematics:
    r"""Angular and linear velocity and acceleration of a motion from its pose derivatives.

    With :math:`x(t) = ` ``from_rt(q(t), p(t))``, i.e. :math:`T(t) = [[R, p], [0, 1]]`:

    - ``frame="world"``: :math:`\omega` with :math:`\dot R = [\omega]_\times R`,
      :math:`v = \dot p` (the velocity of the body's origin), :math:`\alpha = \dot\omega`,
      :math:`a = \ddot p`, all in world axes;
    - ``frame="body"``: the same vectors in body axes: :math:`R^T\omega` (then
      :math:`\dot R = R [R^T\omega]_\times`), :math:`R^T v`, :math:`R^T\alpha`, :math:`R^T a`.

    Note that :math:`v` is the velocity of the body's origin, not the linear part of the
    spatial twist (:func:`twists` with ``frame="spatial"`` gives :math:`v - \omega \times p`),
    and the body-axes acceleration :math:`R^T \ddot p` is not the derivative of the body
    velocity (:math:`\frac{d}{dt}(R^T v) = R^T a - (R^T\omega) \times (R^T v)`).
    Formulas in the module docstring; ``(x, dx, ddx)`` and ``-(x, dx, ddx)`` agree.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).
        dx: ``(..., 8)`` their first time derivatives (e.g. from
            :func:`torch_dq.curves.bspline_derivatives`).
        ddx: ``(..., 8)`` second time derivatives, or ``None`` (no accelerations).
        frame: ``"world"`` or ``"body"``.

    Returns:
        :class:`Kinematics` ``(angular_velocity, linear_velocity, angular_acceleration,
        linear_acceleration)``, each ``(..., 3)`` over the broadcast batch of the inputs
        (the accelerations ``None`` when ``ddx`` is ``None``), in the inputs' dtype, per unit
        of the time of the derivatives.

    Raises:
        ValueError: trailing dim not 8, batch shapes that do not broadcast, an unknown
            ``frame``.
        TypeError: non-tensors, non-floating dtypes, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> x = dq.identity()
        >>> dx = torch.tensor([0., 0., 0., 0.5, 0., 1., 0., 0.])  # 1 rad/s about z, 2 m/s along x
        >>> kinematics(x, dx)[:2]
        (tensor([0., 0., 1.]), tensor([2., 0., 0.]))
    """
    fn = "curves.kinematics"
    _check_motion(fn, x, dx, ddx, False)
    if not isinstance(frame, str) or frame not in _FRAMES:
        _checks.fail(fn, f"frame must be 'world' or 'body', got {frame!r}")
    omega, v, alpha, a = _evaluate(x, dx, ddx, frame)
    assert omega is not None and v is not None  # velocities are always computed
    return Kinematics(omega, v, alpha, a)


def imu(x: Tensor, dx: Tensor, ddx: Tensor,
        gravity: Tensor | Sequence[float] = (0.0, 0.0, -9.81)) -> tuple[Tensor, Tensor]:
    r"""What an ideal IMU rigidly attached at the body's origin reads along a motion.

    The gyroscope measures the angular velocity in body axes, :math:`R^T\omega`; the
    accelerometer the specific force :math:`R^T(a - g)`, with :math:`a = \ddot p` the
    acceleration of the body's origin in world axes and :math:`g` the gravity vector in
    world axes (at rest it reads :math:`-R^T g`, "up"). No bias, noise or lever arm: mount
    the IMU at the body origin, or compose the poses with the IMU's extrinsic transform
    first (:func:`torch_dq.dualquat.mul` by a constant ``x_body_imu`` on the right, and the
    same on the derivatives).

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked): world-from-body poses.
        dx: ``(..., 8)`` first time derivatives.
        ddx: ``(..., 8)`` second time derivatives (e.g. from
            :func:`torch_dq.curves.bspline_derivatives`, ``order=2``).
        gravity: the gravity vector in world axes: three real numbers or a ``(..., 3)``
            floating tensor on ``x``'s device (computed in ``x``'s dtype, like the numbers),
            batch broadcastable. Default ``(0, 0, -9.81)``: z up, in m/s^2 (use the units of
            your translations and times).

    Returns:
        ``(gyro, accel)``, each ``(..., 3)`` in body axes, in ``x``'s dtype.

    Raises:
        ValueError: shapes as :func:`kinematics`; ``gravity`` not three numbers or a
            ``(..., 3)`` tensor.
        TypeError: as :func:`kinematics`; ``ddx`` missing; a ``gravity`` tensor not
            floating or on another device.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> x, z = dq.identity(), torch.zeros(8)
        >>> imu(x, z, z)  # at rest: no rotation, 9.81 m/s^2 upwards
        (tensor([0., 0., 0.]), tensor([0.0000, 0.0000, 9.8100]))
    """
    fn = "curves.imu"
    _check_motion(fn, x, dx, ddx, True)
    if isinstance(gravity, Tensor):
        _checks.tensor(fn, "gravity", gravity, 3)
        gravity = gravity.to(x.dtype)  # a constant, like the three numbers: x's dtype
        _checks.same_dtype_device(fn, x=x, gravity=gravity)
        _checks.broadcast_batch(fn, x=(x, 1), dx=(dx, 1), ddx=(ddx, 1), gravity=(gravity, 1))
        g = lift(gravity)
    else:
        try:
            values = [float(v) for v in gravity]
            ok = len(values) == 3 and not any(isinstance(v, bool) for v in gravity)
        except (TypeError, ValueError):
            ok = False
        if not ok or not all(isinstance(v, numbers.Real) for v in gravity):
            _checks.fail(fn, f"expected gravity to be three real numbers or a (..., 3) tensor, "
                             f"got {gravity!r}")
        g = torch.tensor(values, dtype=compute_dtype(x.dtype), device=x.device)
    dtype = x.dtype
    x, dx, ddx = lift(x), lift(dx), lift(ddx)
    omega, _, _, a = _world(x, dx, ddx)
    rc = qconj(x[..., :4])
    gyro, accel = qrotate(rc, omega), qrotate(rc, a - g)
    batch = _checks.broadcast_shapes(x.shape[:-1], dx.shape[:-1], ddx.shape[:-1], g.shape[:-1])
    return gyro.expand(*batch, 3).to(dtype), accel.expand(*batch, 3).to(dtype)



def velocity(fn: Callable[[Tensor], Tensor], t: Tensor) -> tuple[Tensor, Tensor]:
    r"""Pose and its time derivative along a curve, by forward-mode differentiation.

    ``torch.func.jvp`` of ``fn`` at ``t`` with tangent ones: exact to rounding (no finite
    differences), one pass, and differentiable again. ``fn`` must act pointwise in time:
    output sample ``k`` may depend on ``t[..., k]`` only (true of :func:`bezier` and
    :func:`bspline`); the derivative of a B-spline at a knot is the one of the span that
    contains it (the right-hand derivative, the left-hand one at the domain's right end).

    Args:
        fn: callable ``t -> (..., T, 8)``, e.g. ``lambda t: bspline(ctrl, t)``.
        t: ``(T,)`` or ``(..., T)`` times.

    Returns:
        ``(x, dx)``: ``fn(t)`` and :math:`dx/dt`, both ``(..., T, 8)``; feed them to
        :func:`twists`.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> ctrl = torch.stack((dq.identity(), dq.from_rt(torch.tensor([1., 0, 0, 0]),
        ...                                                torch.tensor([2., 0, 0]))))
        >>> x, dx = velocity(lambda t: bezier(ctrl, t), torch.tensor([0.5]))
        >>> twists(x, dx)  # constant speed 2 along x
        tensor([[0., 0., 0., 2., 0., 0.]])
    """
    name = "curves.velocity"
    if not callable(fn):
        _checks.fail(name, f"expected a callable for fn, got {type(fn).__name__}", TypeError)
    _checks.tensor(name, "t", t)
    # jvp's return type covers has_aux=True (a triple); here it is (fn(t), d fn / dt).
    return cast("tuple[Tensor, Tensor]", torch.func.jvp(fn, (t,), (torch.ones_like(t),)))


def twists(x: Tensor, dx: Tensor, frame: str = "body") -> Tensor:
    r"""Body or spatial twists :math:`(\omega, v)` of a motion from its pose and derivative.

    For :math:`x(t) = ` ``from_rt(q(t), p(t))``, i.e. :math:`T(t) = [[R, p], [0, 1]]`:

    - ``frame="body"``: :math:`T^{-1}\dot T = [[\,[\omega_b]_\times, v_b], [0, 0]]`, i.e.
      :math:`\dot R = R\,[\omega_b]_\times` and :math:`\dot p = R\, v_b` (velocities in the
      moving frame). From :math:`x^* \dot x = \tfrac12 (0, \omega_b)
      + \epsilon\, \tfrac12 (0, v_b)`.
    - ``frame="spatial"``: :math:`\dot T T^{-1} = [[\,[\omega_s]_\times, v_s], [0, 0]]`, i.e.
      :math:`\omega_s = R\,\omega_b` and :math:`v_s = \dot p - \omega_s \times p` (the
      velocity of the body point momentarily at the origin). From
      :math:`\dot x x^* = \tfrac12 (0, \omega_s) + \epsilon\, \tfrac12 (0, v_s)`.

    Both are twice the vector parts of those products; ``(x, dx)`` and ``(-x, -dx)`` give
    the same twist.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).
        dx: ``(..., 8)`` their time derivatives (tangent to the unit dual quaternions),
            batch broadcastable with ``x``; see :func:`velocity`.
        frame: ``"body"`` or ``"spatial"``.

    Returns:
        ``(..., 6)`` twists ``(omega_x, omega_y, omega_z, v_x, v_y, v_z)``, the convention of
        :func:`torch_dq.dualquat.exp` (a constant twist ``xi`` gives
        ``x(t) = x(0) exp(t xi)`` in the body frame, ``exp(t xi) x(0)`` in the spatial one).

    Example:
        >>> import torch_dq.dualquat as dq
        >>> x = dq.identity()
        >>> dx = torch.tensor([0., 0., 0., 0.5, 0., 0., 0., 0.])  # d/dt of exp(t (0,0,1,0,0,0))
        >>> twists(x, dx)
        tensor([0., 0., 1., 0., 0., 0.])
    """
    fn = "curves.twists"
    _checks.tensor(fn, "x", x, 8)
    _checks.tensor(fn, "dx", dx, 8)
    _checks.same_dtype_device(fn, x=x, dx=dx)
    _checks.broadcast_batch(fn, x=(x, 1), dx=(dx, 1))
    if frame not in ("body", "spatial"):
        _checks.fail(fn, f"frame must be 'body' or 'spatial', got {frame!r}")
    dtype = compute_dtype(x.dtype)
    r, d = split(x.to(dtype))
    xc, dx = torch.cat((qconj(r), qconj(d)), -1), dx.to(dtype)
    # body: conj(x) dx; spatial: dx conj(x); both pure (zero scalar parts) for unit x.
    prod = dq_mul(xc, dx) if frame == "body" else dq_mul(dx, xc)
    return (2.0 * torch.cat((prod[..., 1:4], prod[..., 5:]), dim=-1)).to(x.dtype)


def screw_axis(omega: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r"""Instantaneous screw axis of a spatial twist :math:`(\omega, v)`.

    The motion is momentarily a rotation about a line with angular velocity :math:`\omega`
    plus a translation along it at speed :math:`h|\omega|`:

    - direction :math:`l = \omega / |\omega|`;
    - pitch :math:`h = \omega \cdot v / |\omega|^2`;
    - point of the axis nearest to the origin :math:`c = \omega \times v / |\omega|^2`
      (``= cross(direction, moment)``); points on the axis move along it:
      :math:`v + \omega \times c = h\,\omega`;
    - moment :math:`m = c \times l = (v - h\,\omega) / |\omega|` (Plücker coordinates
      ``(l, m)``, the convention of :func:`torch_dq.dualquat.from_screw`).

    Pure translation (:math:`|\omega| \le \epsilon |v|` with :math:`\epsilon` the dtype's
    machine epsilon: the axis would lie beyond ``1 / eps`` lengths): direction
    :math:`v / |v|`, moment 0, pitch ``inf``. At rest (:math:`\omega = v = 0`) there is no
    axis: all three outputs are NaN, as for a non-finite twist. Tracing the axis over the
    times of a curve (with the spatial twists of :func:`twists`) gives the fixed axode.

    Args:
        omega: ``(..., 3)`` angular velocity of a spatial twist.
        v: ``(..., 3)`` its linear part, batch broadcastable with ``omega``.

    Returns:
        ``(direction (..., 3), moment (..., 3), pitch (...))``.

    Example:
        >>> l, m, h = screw_axis(torch.tensor([0., 0., 2.]), torch.tensor([2., 0., 1.]))
        >>> l, torch.linalg.cross(l, m), h  # z-parallel axis through (0, 1, 0), pitch 1/2
        (tensor([0., 0., 1.]), tensor([0., 1., 0.]), tensor(0.5000))
    """
    fn = "curves.screw_axis"
    _checks.tensor(fn, "omega", omega, 3)
    _checks.tensor(fn, "v", v, 3)
    _checks.same_dtype_device(fn, omega=omega, v=v)
    batch = _checks.broadcast_batch(fn, omega=(omega, 1), v=(v, 1))
    dtype = compute_dtype(omega.dtype)
    w, u = omega.to(dtype).expand(*batch, 3), v.to(dtype).expand(*batch, 3)
    w2 = (w * w).sum(-1, keepdim=True)
    v2 = (u * u).sum(-1, keepdim=True)
    eps = threshold("pure_translation", dtype)
    translation = w2 <= (eps * eps) * v2  # includes rest (0 <= 0)
    # At rest, and for a non-finite twist, there is no axis: NaN (never a finite limit).
    rest = (translation & (v2 <= 0)) | ~(torch.isfinite(w2) & torch.isfinite(v2))
    # Safe where: the rotation branch divides by |omega|, the translation one by |v|.
    w2s = safe_denominator(w2, translation)
    wn = torch.sqrt(w2s)
    vn = torch.sqrt(safe_denominator(v2, v2 <= 0))
    pitch = (w * u).sum(-1, keepdim=True) / w2s
    direction = torch.where(translation, u / vn, w / wn)
    moment = torch.where(translation, 0.0, (u - pitch * w) / wn)
    pitch = torch.where(translation, torch.inf, pitch)
    nan = torch.full_like(pitch, torch.nan)
    direction = torch.where(rest, nan, direction)
    moment = torch.where(rest, nan, moment)
    pitch = torch.where(rest, nan, pitch)
    out = omega.dtype
    return direction.to(out), moment.to(out), pitch[..., 0].to(out)

r"""Nuisance parameters of the measurement terms: absent, fixed or estimated (:class:`Free`).

Every nuisance argument of a term (``extrinsic``, ``lever_arm``, ``bias``, ``gravity``,
``time_offset``) is resolved into a :class:`Slot`: ``None`` / ``False`` absent (identity or
zero), a tensor or float fixed, ``True`` / ``"estimate"`` estimated from a default start,
a :class:`Free` estimated from its ``start`` with an optional Gaussian prior. One
:class:`Free` given to several terms is one parameter. Each kind has a chart, the local
coordinates in which :func:`~torch_dq.fitting.estimate` steps and reports uncertainties:

============  ==========  ====  ===============================================
kind          value       dim   chart
============  ==========  ====  ===============================================
vector        ``(3,)``    3     ``v + delta`` (bias, lever arm)
offset        ``()``      1     ``dt + delta`` (time offset, seconds)
pose          ``(8,)``    6     ``e exp(delta)`` (extrinsic; body-frame twist)
gravity       ``(3,)``    2     ``Exp(B delta) g``, ``B`` an orthonormal basis of the
                                plane orthogonal to ``g`` (world axes; magnitude kept)
params        ``(P,)``    P     ``v + delta`` (camera intrinsics; ``P`` the slot's size)
============  ==========  ====  ===============================================

Line delays (seconds per row) are of kind ``offset``, a target's pose of kind ``pose``.
"""

from __future__ import annotations

import numbers

import torch
from torch import Tensor

from .. import _checks, dualquat, quat

__all__ = ["Free", "Slot"]

_DIMS = {"vector": 3, "offset": 1, "pose": 6, "gravity": 2}
_SHAPES = {"vector": (3,), "offset": (), "pose": (8,), "gravity": (3,)}
_SIZED = ("params",)  # kinds whose shape (size,) is the slot's


class Free:
    """An estimated nuisance parameter: start value and optional Gaussian prior.

    Args:
        start: start value (the parameter's shape: ``(3,)`` bias or lever arm, a float time
            offset in seconds, an ``(8,)`` extrinsic, a ``(3,)`` gravity vector whose norm is
            kept); None: the kind's default start (zero, identity; gravity's direction from
            the mean accelerometer reading; a gyroscope's time offset from cross-correlating
            angular rates).
        prior_std: None (no prior) or the standard deviation of a Gaussian prior around
            ``start`` in the parameter's chart (a positive float, or one per chart axis). It
            is part of the estimate and of its uncertainties (it is information the caller
            gave, unlike :func:`~torch_dq.fitting.estimate`'s numerical ``prior``).

    Attributes:
        value: the current value, set by :func:`~torch_dq.fitting.estimate` (None before);
            a second estimate continues from it.

    Example:
        >>> clock = Free(start=0.0, prior_std=0.05)  # one IMU clock for Gyro and Accel
    """

    def __init__(self, start=None, prior_std=None) -> None:
        fn = "fitting.Free"
        if start is not None and not isinstance(start, (Tensor, numbers.Real)) or isinstance(
                start, bool):
            _checks.fail(fn, f"start must be None, a float or a tensor, got {start!r}",
                         TypeError)
        if isinstance(start, Tensor):
            _checks.tensor(fn, "start", start)
            if not bool(torch.isfinite(start).all()):
                _checks.fail(fn, "start must be finite")
        if prior_std is not None:
            p = torch.as_tensor(prior_std, dtype=torch.float64)
            if p.dim() > 1 or not bool((p > 0).all()) or not bool(torch.isfinite(p).all()):
                _checks.fail(fn, f"prior_std must be None or positive finite float(s), got "
                                 f"{prior_std!r}")
        self.start = start
        self.prior_std = prior_std
        self.value: Tensor | None = None

    def __repr__(self) -> str:
        return f"Free(start={self.start!r}, prior_std={self.prior_std!r})"


class Slot:
    """A term's nuisance argument resolved: absent, fixed, or estimated (``free``).

    Args:
        fn: public name of the term, for messages.
        name: argument name (``"bias"``, ...).
        kind: ``"vector"``, ``"offset"``, ``"pose"``, ``"gravity"`` or ``"params"``.
        arg: the user's argument.
        size: the value's length for the kind ``"params"`` (camera intrinsics).
    """

    def __init__(self, fn: str, name: str, kind: str, arg, size: int | None = None) -> None:
        self.name, self.kind = name, kind
        self.shape = (int(size or 0),) if kind in _SIZED else _SHAPES[kind]
        self.free: Free | None = None
        self.fixed: Tensor | None = None
        if arg is None or arg is False:
            return
        if arg is True or (isinstance(arg, str) and arg == "estimate"):
            self.free = Free()
        elif isinstance(arg, Free):
            self.free = arg
            if arg.start is not None:
                self._check_value(fn, f"{name} start", arg.start)
        elif isinstance(arg, str) or isinstance(arg, bool):
            _checks.fail(fn, f"{name} must be None, False, a tensor or float, True, "
                             f"'estimate' or fitting.Free, got {arg!r}")
        else:
            self.fixed = self._check_value(fn, name, arg)

    def _check_value(self, fn: str, name: str, value) -> Tensor:
        if isinstance(value, numbers.Real) and not isinstance(value, bool):
            value = torch.tensor(float(value), dtype=torch.float64)
        if not isinstance(value, Tensor):
            _checks.fail(fn, f"{name} must be a tensor or a float, got "
                             f"{type(value).__name__}", TypeError)
        _checks.tensor(fn, name, value)
        shape = self.shape
        if tuple(value.shape[value.dim() - len(shape):]) != shape or value.dim() < len(shape):
            _checks.fail(fn, f"expected {name} of shape (..., {', '.join(map(str, shape))}) "
                             f"(batch first), got {_checks.shape_str(value.shape)}"
                         if shape else f"expected a float or a tensor for {name}")
        if not bool(torch.isfinite(value).all()):
            _checks.fail(fn, f"{name} must be finite")
        if self.kind == "pose" and not bool(dualquat.is_unit(value.double(), 1e-6).all()):
            _checks.fail(fn, f"{name} must be unit dual quaternions")
        if self.kind == "gravity" and not bool((value.norm(dim=-1) > 0).all()):
            _checks.fail(fn, f"{name} must be non-zero")
        return value

    @property
    def estimated(self) -> bool:
        return self.free is not None

    @property
    def present(self) -> bool:
        return self.free is not None or self.fixed is not None

    @property
    def dim(self) -> int:
        """Dimension of the chart."""
        return self.shape[0] if self.kind in _SIZED else _DIMS[self.kind]

    def identity(self, like: Tensor) -> Tensor:
        """The absent value (zero, identity) in ``like``'s dtype and device."""
        if self.kind == "pose":
            return dualquat.identity(dtype=like.dtype, device=like.device)
        return like.new_zeros(self.shape)

    def value(self, like: Tensor) -> Tensor | None:
        """Current value (fixed, estimated, or start if given), None if a default start is
        still to be computed; in ``like``'s dtype and device."""
        if self.fixed is not None:
            return self.fixed.to(dtype=like.dtype, device=like.device)
        if self.free is None:
            return self.identity(like)
        v = self.free.value if self.free.value is not None else self.free.start
        if v is None:
            return None
        return torch.as_tensor(v).to(dtype=like.dtype, device=like.device)


def retract(kind: str, value: Tensor, delta: Tensor) -> Tensor:
    """The parameter moved by ``delta`` in its chart (see the module table).

    Args:
        kind: the parameter's kind.
        value: ``(..., *shape)`` current values.
        delta: ``(..., dim)`` chart steps (batch broadcast with ``value``'s).

    Returns:
        The moved values, batch broadcast.
    """
    if kind in ("vector", "params"):
        return value + delta
    if kind == "offset":
        return value + delta[..., 0]
    if kind == "pose":
        return dualquat.mul(value, dualquat.exp(delta))
    phi = (gravity_basis(value.detach()) @ delta[..., None])[..., 0]  # world rotation vector
    return quat.rotate(quat.from_rotvec(phi), value)


def gravity_basis(g: Tensor) -> Tensor:
    """``(..., 3, 2)`` orthonormal basis of the plane orthogonal to ``g (..., 3)``."""
    u = g / g.norm(dim=-1, keepdim=True)
    e = torch.zeros_like(u)
    e[..., 0] = 1.0
    alt = torch.zeros_like(u)
    alt[..., 1] = 1.0
    e = torch.where((u[..., :1].abs() > 0.9), alt, e)
    a = torch.linalg.cross(u, e)
    a = a / a.norm(dim=-1, keepdim=True)
    b = torch.linalg.cross(u, a)
    return torch.stack((a, b), dim=-1)


def chart_distance(kind: str, start: Tensor, value: Tensor) -> Tensor:
    """``(..., dim)`` chart coordinates of ``value`` around ``start`` (for priors)."""
    if kind in ("vector", "params"):
        return value - start
    if kind == "offset":
        return (value - start)[..., None]
    if kind == "pose":
        return dualquat.log(dualquat.mul(dualquat.conj(start), value))
    u0 = start / start.norm(dim=-1, keepdim=True)
    u1 = value / value.norm(dim=-1, keepdim=True)
    axis = torch.linalg.cross(u0, u1)
    ang = torch.atan2(axis.norm(dim=-1), (u0 * u1).sum(-1))
    phi = axis * (ang / axis.norm(dim=-1).clamp_min(1e-300))[..., None]
    return (gravity_basis(start).mT @ phi[..., None])[..., 0]

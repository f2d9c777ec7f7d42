r"""Charts of the estimated parameters (theseus' ``Manifold``): one class per kind.

A parameter's value has the chart's :attr:`~Chart.shape` (batch first); the solver steps it
by ``delta (..., dim)`` with :meth:`~Chart.retract`, measures priors with
:meth:`~Chart.local` and reports its uncertainty in the chart's coordinates, mapped by
:meth:`~Chart.report` where those are not the ones a user reads:

=============  ==========  ====  =================================================
chart          value       dim   retract
=============  ==========  ====  =================================================
``Vector(P)``  ``(P,)``    P     ``v + delta`` (bias, lever arm: ``P = 3``; camera
                                 intrinsics)
``Scalar``     ``()``      1     ``clamp(v + delta, low, high)`` (time offset,
                                 line delay: seconds, seconds per row)
``Pose``       ``(8,)``    6     ``e exp(delta)`` (extrinsic, a target's pose;
                                 body-frame twist)
``Direction``  ``(3,)``    2     ``Exp(B delta) g``, ``B`` an orthonormal basis of
                                 the plane orthogonal to ``g`` (gravity: its norm
                                 kept; reported in world axes, ``(3,)``)
=============  ==========  ====  =================================================

Only :class:`Scalar` parameters may move a sample's time (a term's
:meth:`~torch_dq.fitting.Term.time_rates`). Every chart class is registered in
:data:`CHARTS` (the tests run the chart laws over it).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .. import _checks, dualquat, quat

__all__ = ["CHARTS", "Chart", "Direction", "Pose", "Scalar", "Vector", "register"]

CHARTS: dict[str, type[Chart]] = {}


def register(cls: type[Chart]) -> type[Chart]:
    """Class decorator: enter a chart class in :data:`CHARTS` under its ``name``."""
    CHARTS[cls.name] = cls
    return cls


class Chart:
    """Local coordinates of one kind of parameter (base class).

    Attributes:
        name: the kind's name (messages, :data:`CHARTS`).
        shape: the value's event shape.
        dim: the chart's dimension.
    """

    name = "chart"
    shape: tuple[int, ...] = ()
    dim = 0

    def identity(self, like: Tensor) -> Tensor:
        """The absent value (zero; the identity pose) in ``like``'s dtype and device."""
        return like.new_zeros(self.shape)

    def retract(self, value: Tensor, delta: Tensor) -> Tensor:
        """``value (..., *shape)`` moved by ``delta (..., dim)`` (batch broadcast)."""
        raise NotImplementedError

    def local(self, start: Tensor, value: Tensor) -> Tensor:
        """``(..., dim)`` chart coordinates of ``value`` around ``start`` (``retract``'s
        inverse)."""
        raise NotImplementedError

    def report(self, value: Tensor) -> Tensor | None:
        """``(..., r, dim)`` map from the chart to the reported coordinates at ``value``
        (None: the chart's own coordinates are reported)."""
        return None

    def check(self, fn: str, name: str, value: Tensor) -> None:
        """Fail (naming ``fn`` and ``name``) for a value outside the kind's set."""

    def per_sample(self, value: Tensor) -> Tensor:
        """``value`` with a sample dim inserted before its event dims."""
        return value.unsqueeze(value.dim() - len(self.shape))

    def same_kind(self, other: Chart) -> bool:
        """Whether ``other`` is a chart of the same kind and shape (one parameter)."""
        return type(other) is type(self) and other.shape == self.shape

    def describe(self) -> str:
        """The kind and the value's shape, for messages."""
        shape = self.shape
        return f"{self.name} ({', '.join(map(str, shape))},)" if shape else self.name


@register
class Vector(Chart):
    """A ``(size,)`` vector, chart ``v + delta`` (bias, lever arm, camera intrinsics)."""

    name = "vector"

    def __init__(self, size: int = 3) -> None:
        self.shape, self.dim = (int(size),), int(size)

    def retract(self, value: Tensor, delta: Tensor) -> Tensor:
        return value + delta

    def local(self, start: Tensor, value: Tensor) -> Tensor:
        return value - start


@register
class Scalar(Chart):
    """A scalar within ``[low, high]``, chart ``clamp(v + delta, low, high)`` (time offset,
    line delay): the only kind that may move a sample's time.

    Args:
        low, high: the bounds (``-inf``, ``inf`` for none).
    """

    name = "scalar"
    dim = 1

    def __init__(self, low: float = -math.inf, high: float = math.inf) -> None:
        self.low, self.high = float(low), float(high)

    def retract(self, value: Tensor, delta: Tensor) -> Tensor:
        return (value + delta[..., 0]).clamp(self.low, self.high)

    def local(self, start: Tensor, value: Tensor) -> Tensor:
        return (value - start)[..., None]

    def bounded(self, low: float, high: float) -> Scalar:
        """The chart within the intersection of its bounds and ``[low, high]`` (one
        parameter shared by terms with different bounds)."""
        return Scalar(max(self.low, low), min(self.high, high))

    def pinned(self, value: Tensor) -> Tensor:
        """Bool, the shape of ``value``: on the upper bound, or on a negative lower bound
        (to ``1e-9`` relatively; a lower bound of zero, a line delay's, is its natural end
        and not reported)."""
        pinned = value >= self.high * (1.0 - 1e-9)
        if self.low < 0:
            pinned = pinned | (value <= self.low * (1.0 - 1e-9))
        return pinned

    def outward(self, value: Tensor, gradient: Tensor) -> Tensor:
        """Bool: pinned with a descent direction ``-gradient`` pointing out of the range (up
        on the upper bound, down on a negative lower one: a ``max_time_offset=0`` offset at
        0 with the descent upwards is outward too)."""
        up = (value >= self.high * (1.0 - 1e-9)) & (gradient < 0)
        return self.pinned(value) & (up | ((value < 0) & (gradient > 0)))

    def at_end(self, value: Tensor) -> Tensor:
        """Bool, the shape of ``value``: on a lower bound of zero, the parameter's natural
        end (a line delay), where a step that would go below holds it
        (``torch_dq.fitting._solver.DampedStep``); the other bounds are search limits."""
        return (value <= 0.0) & (self.low == 0.0)


@register
class Pose(Chart):
    """A unit dual quaternion ``(8,)``, chart ``e exp(delta)`` (body-frame twist)."""

    name = "pose"
    shape = (8,)
    dim = 6

    def identity(self, like: Tensor) -> Tensor:
        return dualquat.identity(dtype=like.dtype, device=like.device)

    def retract(self, value: Tensor, delta: Tensor) -> Tensor:
        return dualquat.mul(value, dualquat.exp(delta))

    def local(self, start: Tensor, value: Tensor) -> Tensor:
        return dualquat.log(dualquat.mul(dualquat.conj(start), value))

    def check(self, fn: str, name: str, value: Tensor) -> None:
        if not bool(dualquat.is_unit(value.double(), 1e-6).all()):
            _checks.fail(fn, f"{name} must be unit dual quaternions")


@register
class Direction(Chart):
    """A non-zero ``(3,)`` vector whose norm is kept, chart ``Exp(B delta) g`` (gravity)."""

    name = "direction"
    shape = (3,)
    dim = 2

    def retract(self, value: Tensor, delta: Tensor) -> Tensor:
        phi = (basis(value.detach()) @ delta[..., None])[..., 0]  # world rotation vector
        return quat.rotate(quat.from_rotvec(phi), value)

    def local(self, start: Tensor, value: Tensor) -> Tensor:
        u0 = start / start.norm(dim=-1, keepdim=True)
        u1 = value / value.norm(dim=-1, keepdim=True)
        axis = torch.linalg.cross(u0, u1)
        ang = torch.atan2(axis.norm(dim=-1), (u0 * u1).sum(-1))
        phi = axis * (ang / axis.norm(dim=-1).clamp_min(1e-300))[..., None]
        return (basis(start).mT @ phi[..., None])[..., 0]

    def report(self, value: Tensor) -> Tensor:
        """World axes: ``d(Exp(B d) g)/dd = -[g]x B`` ``(..., 3, 2)``."""
        eye = torch.eye(3, dtype=value.dtype, device=value.device)
        cross = torch.linalg.cross(value[..., :, None].expand(*value.shape, 3),
                                   eye.expand(*value.shape[:-1], 3, 3), dim=-2)  # g x e_j
        return -cross @ basis(value)

    def check(self, fn: str, name: str, value: Tensor) -> None:
        if not bool((value.norm(dim=-1) > 0).all()):
            _checks.fail(fn, f"{name} must be non-zero")


def basis(g: Tensor) -> Tensor:
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

r"""``DualQuaternion``: a thin frozen wrapper over a ``(..., 8)`` tensor for readable code.

Every method delegates to :mod:`torch_dq.dualquat`, which stays the reference (no math
here). ``.shape`` is the batch shape, the tensor's shape without the trailing 8, and
indexing applies to the batch dimensions only.

Example:
    >>> import torch
    >>> from torch_dq import DualQuaternion
    >>> half_turn_z = torch.tensor([0., 0., 0., 1.])
    >>> a = DualQuaternion.from_rt(half_turn_z, torch.tensor([1., 0., 0.]))
    >>> b = DualQuaternion.identity()
    >>> (a * b.inverse()).apply(torch.tensor([1., 2., 3.]))
    tensor([ 0., -2.,  3.])
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
import torch.utils._pytree as _pytree
from torch import Tensor

from . import _checks, dualquat, quat
from ._core import Frozen
from .dual import Dual

__all__ = ["DualQuaternion"]

# Batches with at most this many poses get a per-pose summary in the repr.
_REPR_MAX_ITEMS = 4


class DualQuaternion(Frozen):
    r"""Unit dual quaternions ``(..., 8)`` as an immutable object.

    Layout, conventions and the meaning of every operation are those of
    :mod:`torch_dq.dualquat`: ``(rw, rx, ry, rz, dw, dx, dy, dz)``, the rigid transform
    :math:`x \mapsto R x + t` is ``real = r``, ``dual = 0.5 (0, t) r``, and ``a * b`` applies
    ``b`` first. Not a ``Tensor`` subclass and not an ``nn.Module``; it is registered as a
    pytree node, so it passes through ``torch.func`` transforms and compiled functions.

    Attributes:
        tensor: the wrapped ``(..., 8)`` tensor (not copied; do not modify it in place).
        shape: batch shape, ``tensor.shape[:-1]``.
        dtype, device: those of ``tensor``.

    Args:
        tensor: floating ``(..., 8)`` tensor (unit norm is not checked: see :meth:`is_unit`).

    Raises:
        TypeError: ``tensor`` is not a floating-point tensor.
        ValueError: its last dimension is not 8.

    ``==`` is identity (not overloaded); there is no iteration, index explicitly.

    Example:
        >>> x = DualQuaternion(dualquat.exp(torch.tensor([[0., 0, torch.pi / 2, 1, 0, 0],
        ...                                               [0., 0, 0, 0, 2, 0]])))
        >>> x.shape, len(x), x[0].shape, x.tensor.shape
        (torch.Size([2]), 2, torch.Size([]), torch.Size([2, 8]))
        >>> x
        DualQuaternion(shape=(2,), dtype=torch.float32)
          [0] rotation 90 deg about (0, 0, 1), translation (0.6366, 0.6366, 0)
          [1] rotation 0 deg about (1, 0, 0), translation (0, 2, 0)
    """

    __slots__ = ("_tensor",)
    _tensor: Tensor  # the (..., 8) tensor, set once by __init__ or _make
    __iter__ = None  # indexing is over the batch; no implicit iteration protocol

    def __init__(self, tensor: Tensor):
        _checks.tensor("DualQuaternion", "tensor", tensor, 8)
        object.__setattr__(self, "_tensor", tensor)

    @classmethod
    def _make(cls, tensor: Tensor) -> DualQuaternion:
        """Wrap without checks (``tensor`` comes from a checked dualquat call)."""
        self = object.__new__(cls)
        object.__setattr__(self, "_tensor", tensor)
        return self

    def __reduce__(self):
        return (DualQuaternion, (self._tensor,))

    # -- constructors --------------------------------------------------------------------------

    @classmethod
    def identity(cls, shape: int | Sequence[int] = (), dtype: torch.dtype | None = None,
                 device: torch.device | str | None = None) -> DualQuaternion:
        """Identity transforms of batch shape ``shape`` (:func:`torch_dq.dualquat.identity`).

        Example:
            >>> DualQuaternion.identity((2,)).shape
            torch.Size([2])
        """
        return cls._make(dualquat.identity(shape, dtype=dtype, device=device))

    @classmethod
    def from_rt(cls, q: Tensor, t: Tensor) -> DualQuaternion:
        """Rigid transform ``x -> R(q) x + t`` (:func:`torch_dq.dualquat.from_rt`).

        Args:
            q: ``(..., 4)`` unit quaternions ``(w, x, y, z)``.
            t: ``(..., 3)`` translations.

        Example:
            >>> x = DualQuaternion.from_rt(torch.tensor([0., 0, 0, 1]), torch.tensor([1., 2, 3]))
            >>> x.apply(torch.zeros(3))
            tensor([1., 2., 3.])
        """
        return cls._make(dualquat.from_rt(q, t))

    @classmethod
    def from_matrix(cls, T: Tensor) -> DualQuaternion:
        """From ``(..., 4, 4)`` homogeneous matrices (:func:`torch_dq.dualquat.from_matrix`).

        Example:
            >>> DualQuaternion.from_matrix(torch.eye(4)).tensor
            tensor([1., 0., 0., 0., 0., 0., 0., 0.])
        """
        return cls._make(dualquat.from_matrix(T))

    @classmethod
    def from_screw(cls, axis: Tensor, moment: Tensor, theta: Tensor | float,
                   d: Tensor | float) -> DualQuaternion:
        """Screw motion (:func:`torch_dq.dualquat.from_screw`): rotation ``theta`` about the
        Plücker line ``(axis, moment)`` and translation ``d`` along it.

        Example:
            >>> z = torch.tensor([0., 0., 1.])
            >>> DualQuaternion.from_screw(z, torch.zeros(3), 0.0, 2.0).to_rt()[1]
            tensor([0., 0., 2.])
        """
        return cls._make(dualquat.from_screw(axis, moment, theta, d))

    @classmethod
    def from_pose7(cls, p: Tensor) -> DualQuaternion:
        """From pypose/ROS 7-vectors ``(tx, ty, tz, qx, qy, qz, qw)``
        (:func:`torch_dq.dualquat.from_pose7`).

        Example:
            >>> DualQuaternion.from_pose7(torch.tensor([1., 2, 3, 0, 0, 0, 1])).to_rt()[1]
            tensor([1., 2., 3.])
        """
        return cls._make(dualquat.from_pose7(p))

    @classmethod
    def exp(cls, xi: Tensor) -> DualQuaternion:
        """Rigid-motion exponential of twists ``(omega, v)`` (:func:`torch_dq.dualquat.exp`).

        Example:
            >>> DualQuaternion.exp(torch.tensor([0., 0, 0, 1, 2, 3])).to_rt()[1]
            tensor([1., 2., 3.])
        """
        return cls._make(dualquat.exp(xi))

    # -- tensor-like attributes ------------------------------------------------------------------

    @property
    def tensor(self) -> Tensor:
        """The wrapped ``(..., 8)`` tensor."""
        return self._tensor

    @property
    def shape(self) -> torch.Size:
        """The batch shape (the tensor's shape without the trailing 8)."""
        return self._tensor.shape[:-1]

    @property
    def ndim(self) -> int:
        """Number of batch dimensions."""
        return self._tensor.dim() - 1

    @property
    def dtype(self) -> torch.dtype:
        return self._tensor.dtype

    @property
    def device(self) -> torch.device:
        return self._tensor.device

    def __len__(self) -> int:
        if self._tensor.dim() == 1:
            raise TypeError("len() of a DualQuaternion with batch shape ()")
        return self._tensor.shape[0]

    def __getitem__(self, index: Any) -> DualQuaternion:
        """Index the batch dimensions (ints, slices, ``None``, ``...``, index and bool tensors);
        the trailing 8 is never indexed.

        Example:
            >>> x = DualQuaternion.identity((4, 3))
            >>> x[0].shape, x[:, 1].shape, x[..., 0].shape, x[None, 1:3].shape
            (torch.Size([3]), torch.Size([4]), torch.Size([4]), torch.Size([1, 2, 3]))
        """
        items = index if isinstance(index, tuple) else (index,)
        tail = (slice(None),) if any(i is Ellipsis for i in items) else (Ellipsis, slice(None))
        try:
            out = self._tensor[items + tail]
        except IndexError as e:
            raise IndexError(f"DualQuaternion: index {index!r} does not fit the batch shape "
                             f"{_checks.shape_str(self.shape)} (indices apply to the batch "
                             f"dimensions only): {e}") from None
        return DualQuaternion._make(out)

    def to(self, *args: Any, **kwargs: Any) -> DualQuaternion:
        """Through ``Tensor.to`` (dtype and/or device); the result must stay floating.

        Example:
            >>> DualQuaternion.identity().to(torch.float64).dtype
            torch.float64
        """
        return DualQuaternion(self._tensor.to(*args, **kwargs))

    def detach(self) -> DualQuaternion:
        """Detached from the autograd graph."""
        return DualQuaternion._make(self._tensor.detach())

    def __repr__(self) -> str:
        head = (f"DualQuaternion(shape={_checks.shape_str(self.shape)}, dtype={self.dtype}"
                + ("" if self.device.type == "cpu" else f", device={self.device}") + ")")
        n = self.shape.numel()
        if n == 0 or n > _REPR_MAX_ITEMS or self.device.type == "meta":
            return head
        x = self._tensor.detach().to("cpu", torch.float64)
        q, t = dualquat.to_rt(x)
        axis, angle = quat.to_axis_angle(q)
        eps = torch.finfo(self.dtype).eps
        rows = zip(axis.reshape(-1, 3), angle.reshape(-1), t.reshape(-1, 3), strict=True)
        lines = [f"rotation {_fmt(torch.rad2deg(a).item(), eps)} deg about {_vec(u, eps)}, "
                 f"translation {_vec(v, eps)}" for u, a, v in rows]
        if not self.shape:
            return f"{head}: {lines[0]}"
        idx = [tuple(i.tolist()) for i in torch.ones(self.shape).nonzero()]
        return head + "".join(f"\n  [{', '.join(map(str, i))}] {line}"
                              for i, line in zip(idx, lines, strict=True))

    # -- group operations -----------------------------------------------------------------------

    def __mul__(self, other: DualQuaternion) -> DualQuaternion:
        """``a * b``: :func:`torch_dq.dualquat.mul`, the transform ``b`` followed by ``a``."""
        return DualQuaternion._make(dualquat.mul(self._tensor, _operand("*", other)))

    def __rmul__(self, other):
        _operand("*", other, left=True)

    def inverse(self) -> DualQuaternion:
        """The inverse transform (:func:`torch_dq.dualquat.inv`; equals :meth:`conj` for unit
        input).

        Example:
            >>> a = DualQuaternion.exp(torch.tensor([0.1, 0.2, 0.3, 1., 2., 3.]))
            >>> torch.allclose((a * a.inverse()).tensor, DualQuaternion.identity().tensor)
            True
        """
        return DualQuaternion._make(dualquat.inv(self._tensor))

    def conj(self) -> DualQuaternion:
        """Quaternion conjugate of both parts (:func:`torch_dq.dualquat.conj`)."""
        return DualQuaternion._make(dualquat.conj(self._tensor))

    def normalize(self) -> DualQuaternion:
        """Projection onto unit dual quaternions (:func:`torch_dq.dualquat.normalize`)."""
        return DualQuaternion._make(dualquat.normalize(self._tensor))

    def is_unit(self, atol: float | None = None) -> Tensor:
        """Per-element bool tensor of the batch shape (:func:`torch_dq.dualquat.is_unit`)."""
        return dualquat.is_unit(self._tensor, atol)

    def log(self) -> Tensor:
        """Twists ``(..., 6)`` = ``(omega, v)`` (:func:`torch_dq.dualquat.log`)."""
        return dualquat.log(self._tensor)

    def sclerp(self, other: DualQuaternion, t: Tensor | float,
               shortest: bool = True) -> DualQuaternion:
        """Screw linear interpolation from ``self`` (``t = 0``) to ``other`` (``t = 1``)
        (:func:`torch_dq.dualquat.sclerp`; ``t`` broadcasts against the batch).

        Example:
            >>> a = DualQuaternion.identity()
            >>> b = DualQuaternion.from_rt(torch.tensor([1., 0, 0, 0]), torch.tensor([2., 0, 0]))
            >>> a.sclerp(b, 0.5).to_rt()[1]
            tensor([1., 0., 0.])
        """
        return DualQuaternion._make(
            dualquat.sclerp(self._tensor, _operand("sclerp", other), t, shortest))

    def angle(self, other: DualQuaternion) -> Dual:
        """Dual angle to ``other`` (:func:`torch_dq.dualquat.angle`)."""
        return dualquat.angle(self._tensor, _operand("angle", other))

    # -- actions and conversions ----------------------------------------------------------------

    def apply(self, points: Tensor) -> Tensor:
        """Transform ``(..., 3)`` points, ``R p + t`` (:func:`torch_dq.dualquat.apply`)."""
        return dualquat.apply(self._tensor, points)

    def apply_line(self, direction: Tensor, moment: Tensor) -> tuple[Tensor, Tensor]:
        """Transform Plücker lines (:func:`torch_dq.dualquat.apply_line`)."""
        return dualquat.apply_line(self._tensor, direction, moment)

    def to_matrix(self) -> Tensor:
        """``(..., 4, 4)`` homogeneous matrices (:func:`torch_dq.dualquat.to_matrix`)."""
        return dualquat.to_matrix(self._tensor)

    def to_rt(self) -> tuple[Tensor, Tensor]:
        """Rotation quaternion ``(..., 4)`` and translation ``(..., 3)``
        (:func:`torch_dq.dualquat.to_rt`)."""
        return dualquat.to_rt(self._tensor)

    def to_screw(self) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """``(axis, moment, theta, d)`` (:func:`torch_dq.dualquat.to_screw`)."""
        return dualquat.to_screw(self._tensor)

    def to_pose7(self) -> Tensor:
        """pypose/ROS 7-vectors ``(t, qx, qy, qz, qw)`` (:func:`torch_dq.dualquat.to_pose7`)."""
        return dualquat.to_pose7(self._tensor)


def _operand(op: str, other, left: bool = False) -> Tensor:
    """The tensor of a DualQuaternion operand; TypeError naming the operand otherwise."""
    if isinstance(other, DualQuaternion):
        return other._tensor
    hint = (" (wrap a (..., 8) tensor with DualQuaternion(tensor) first)"
            if isinstance(other, Tensor) else "")
    side = "left operand" if left else "other"
    raise TypeError(f"DualQuaternion {op}: expected a DualQuaternion for {side}, got "
                    f"{type(other).__name__}{hint}")


def _fmt(v: float, tiny: float) -> str:
    """4 significant digits; rounding noise below ``tiny`` (and -0) prints as 0."""
    return f"{0.0 if abs(v) <= tiny else v:.4g}"


def _vec(v: Tensor, eps: float) -> str:
    """``(x, y, z)`` with components below ``10 eps max(1, max|v|)`` shown as 0."""
    tiny = 10 * eps * max(1.0, v.abs().max().item())
    return "(" + ", ".join(_fmt(c, tiny) for c in v.tolist()) + ")"


_pytree.register_pytree_node(
    DualQuaternion,
    lambda x: ([x.tensor], None),
    lambda parts, _: DualQuaternion._make(*parts),  # parts: the one child, [x.tensor]
    serialized_type_name="torch_dq.object.DualQuaternion",
)

r"""Quaternions on plain ``(..., 4)`` tensors.

Conventions: components ``(w, x, y, z)`` (scalar first), Hamilton product
(``i j = k``), and unit quaternions rotate vectors actively, :math:`v' = q v q^*`.
``q`` and ``-q`` are the same rotation. Batch dimensions come first and broadcast like
torch ops; dtype and device follow the inputs.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _checks

__all__ = [
    "conj",
    "dot",
    "identity",
    "inv",
    "mul",
    "norm",
    "normalize",
    "rotate",
]


def _mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product without argument checks (used by the hot paths)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def _conj(q: Tensor) -> Tensor:
    """Conjugate without argument checks."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def _rotate(q: Tensor, v: Tensor) -> Tensor:
    r"""Unchecked ``q v q*``: :math:`v + w t + u \times t` with :math:`t = 2 u \times v`."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * torch.linalg.cross(u, v.expand(torch.broadcast_shapes(u.shape, v.shape)), dim=-1)
    return v + w * t + torch.linalg.cross(u.expand_as(t), t, dim=-1)


def _pair(fn: str, a: Tensor, b: Tensor, names: tuple[str, str] = ("a", "b")) -> None:
    _checks.tensor(fn, names[0], a, 4)
    _checks.tensor(fn, names[1], b, 4)
    _checks.same_dtype_device(fn, **{names[0]: a, names[1]: b})
    _checks.broadcast_batch(fn, **{names[0]: (a, 1), names[1]: (b, 1)})


def identity(shape=(), dtype: torch.dtype | None = None, device=None) -> Tensor:
    """Identity quaternions ``(1, 0, 0, 0)`` of batch shape ``shape``.

    Args:
        shape: batch shape (int or tuple of ints).
        dtype: floating dtype (default: torch's default dtype).
        device: device (default: torch's default device).

    Returns:
        ``(*shape, 4)`` tensor.

    Example:
        >>> identity((2,))
        tensor([[1., 0., 0., 0.],
                [1., 0., 0., 0.]])
    """
    shape = (shape,) if isinstance(shape, int) else tuple(shape)
    if any(not isinstance(d, int) or d < 0 for d in shape):
        _checks.fail("quat.identity", f"expected shape to be a tuple of non-negative ints, "
                     f"got {shape!r}")
    dtype = dtype or torch.get_default_dtype()
    if not dtype.is_floating_point:
        _checks.fail("quat.identity", f"expected a floating dtype, got {dtype}", TypeError)
    q = torch.zeros((*shape, 4), dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a b``.

    Args:
        a: ``(..., 4)`` quaternions.
        b: ``(..., 4)`` quaternions, batch broadcastable with ``a``.

    Returns:
        ``(..., 4)``: the rotation ``b`` followed by ``a`` when both are unit.

    Example:
        >>> mul(torch.tensor([0., 1., 0., 0.]), torch.tensor([0., 0., 1., 0.]))  # i j = k
        tensor([0., 0., 0., 1.])
    """
    _pair("quat.mul", a, b)
    return _mul(a, b)


def conj(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``; the inverse rotation for a unit ``q``.

    Args:
        q: ``(..., 4)`` quaternions.
    """
    _checks.tensor("quat.conj", "q", q, 4)
    return _conj(q)


def norm(q: Tensor) -> Tensor:
    """Euclidean norm ``|q|``.

    Args:
        q: ``(..., 4)`` quaternions.

    Returns:
        ``(...)`` tensor.
    """
    _checks.tensor("quat.norm", "q", q, 4)
    return torch.linalg.vector_norm(q, dim=-1)


def inv(q: Tensor) -> Tensor:
    """Inverse ``q* / |q|^2``.

    Args:
        q: ``(..., 4)`` non-zero quaternions; a zero quaternion gives non-finite values.
    """
    _checks.tensor("quat.inv", "q", q, 4)
    return _conj(q) / (q * q).sum(-1, keepdim=True)


def normalize(q: Tensor, check: bool = False) -> Tensor:
    """Project onto unit quaternions, ``q / |q|``.

    Args:
        q: ``(..., 4)`` quaternions.
        check: if True, raise ``ValueError`` when some ``q`` is zero or non-finite (this
            synchronises with the device). Otherwise a zero quaternion, which has no
            direction, gives NaN in its own output row only.

    Returns:
        ``(..., 4)`` unit quaternions.
    """
    _checks.tensor("quat.normalize", "q", q, 4)
    n = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    if check and not bool(torch.all(torch.isfinite(n) & (n > 0))):
        _checks.fail("quat.normalize", "q contains zero or non-finite quaternions")
    return q / torch.where(n > 0, n, torch.nan)


def dot(a: Tensor, b: Tensor) -> Tensor:
    """Euclidean scalar product of quaternions, ``cos`` of the half-angle between unit ones.

    Args:
        a: ``(..., 4)``.
        b: ``(..., 4)``, broadcastable with ``a``.

    Returns:
        ``(...)`` tensor.
    """
    _pair("quat.dot", a, b)
    return (a * b).sum(-1)


def rotate(q: Tensor, v: Tensor) -> Tensor:
    r"""Rotate vectors actively, :math:`v' = q v q^*`.

    Args:
        q: ``(..., 4)`` unit quaternions (not checked; a non-unit ``q`` also scales).
        v: ``(..., 3)`` vectors, batch broadcastable with ``q``.

    Returns:
        ``(..., 3)`` rotated vectors.

    Example:
        >>> q = from_axis_angle(torch.tensor([0., 0., 1.]), torch.tensor(torch.pi / 2))
        >>> rotate(q, torch.tensor([1., 0., 0.])).round(decimals=6)
        tensor([0., 1., 0.])
    """
    _checks.tensor("quat.rotate", "q", q, 4)
    _checks.tensor("quat.rotate", "v", v, 3)
    _checks.same_dtype_device("quat.rotate", q=q, v=v)
    _checks.broadcast_batch("quat.rotate", q=(q, 1), v=(v, 1))
    return _rotate(q, v)

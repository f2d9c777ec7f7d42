"""Argument validation shared by every public function (private).

Every check raises ``TypeError`` (not a tensor, not floating point, mixed dtypes or
devices) or ``ValueError`` (wrong shape, shapes that do not broadcast, bad values) with a
message of the form ``"<function>: <argument> <expected>, got <actual>"``.
These checks only read shapes and dtypes: they never synchronise with a device.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import NoReturn

import torch
from torch import Tensor

__all__ = [
    "LATEST",
    "TIME_UNITS",
    "as_float_tensor",
    "broadcast_batch",
    "broadcast_shapes",
    "control_points",
    "factory_args",
    "fail",
    "first_index",
    "flag",
    "host_all",
    "integer",
    "pair",
    "poses",
    "real",
    "rigid_matrix",
    "same_device",
    "same_dtype_device",
    "shape_str",
    "tensor",
    "times",
    "unix_unit",
]


def shape_str(shape) -> str:
    """Format a shape as ``(5, 7)``; ``()`` for a scalar."""
    dims = tuple(shape)
    return "(" + ", ".join(str(d) for d in dims) + ("," if len(dims) == 1 else "") + ")"


def fail(fn: str, message: str, kind: type[Exception] = ValueError) -> NoReturn:
    """Raise ``kind`` with the message prefixed by the function name."""
    raise kind(f"{fn}: {message}")


def tensor(fn: str, name: str, x, last: int | tuple[int, ...] | None = None) -> Tensor:
    """Check that ``x`` is a floating-point tensor whose trailing dims equal ``last``.

    Args:
        fn: public name of the calling function, e.g. ``"dualquat.mul"``.
        name: argument name as the user wrote it.
        x: the value to check.
        last: required trailing size (``8``), trailing shape (``(4, 4)``) or ``None``.

    Returns:
        ``x`` unchanged.
    """
    if not isinstance(x, Tensor):
        fail(fn, f"expected a torch.Tensor for {name}, got {type(x).__name__}", TypeError)
    if not x.is_floating_point():
        fail(fn, f"expected a floating-point tensor for {name}, got dtype {x.dtype}", TypeError)
    if last is not None:
        shape = x.shape
        if isinstance(last, int) and shape and shape[-1] == last:  # the common case, at once
            return x
        event = (last,) if isinstance(last, int) else tuple(last)
        if len(shape) < len(event) or tuple(shape[len(shape) - len(event):]) != event:
            expected = "(..., " + ", ".join(str(d) for d in event) + ")"
            fail(fn, f"expected a {expected} tensor for {name}, got shape {shape_str(x.shape)}")
    return x


def same_dtype_device(fn: str, **named: Tensor) -> None:
    """Check that all tensors share one dtype and one device."""
    items = list(named.items())
    first_name, first = items[0]
    for name, x in items[1:]:
        if x.dtype != first.dtype:
            fail(fn, f"{name} has dtype {x.dtype} but {first_name} has dtype {first.dtype}",
                 TypeError)
        if x.device != first.device:
            fail(fn, f"{name} is on {x.device} but {first_name} is on {first.device}", TypeError)


def broadcast_shapes(*shapes: Sequence[int] | int) -> torch.Size:
    """``torch.broadcast_shapes`` of shapes (sequences of ints) in plain Python: the same
    result (an int ``n`` reads as ``(n,)``), and the same ``RuntimeError`` where they do not
    broadcast, without the first
    call's import of sympy (about a second of a process's start).

    Example:
        >>> broadcast_shapes((2, 1), (3,), ())
        torch.Size([2, 3])
    """
    out: list[int] = []
    for shape in shapes:
        dims = [shape] if isinstance(shape, int) else list(shape)
        if len(dims) > len(out):
            out = [1] * (len(dims) - len(out)) + out
        for k, d in enumerate(dims, start=len(out) - len(dims)):
            if d < 0:
                raise RuntimeError(f"broadcast_shapes: negative dimension {d} in {tuple(dims)}")
            if d != out[k] and d != 1:
                if out[k] != 1:
                    raise RuntimeError(f"shape mismatch: objects cannot be broadcast to a "
                                       f"single shape, {tuple(dims)} against {tuple(out)}")
                out[k] = d
    return torch.Size(out)


def broadcast_batch(fn: str, **named: tuple[Tensor, int]) -> torch.Size:
    """Broadcast the batch shapes of several arguments.

    Args:
        fn: public name of the calling function.
        **named: ``name=(tensor, event_ndim)``: the last ``event_ndim`` dims of each tensor
            are its event (8 for a dual quaternion, 0 for a scalar) and are not broadcast.

    Returns:
        The broadcast batch shape.
    """
    shapes = {name: x.shape[: x.dim() - nd] for name, (x, nd) in named.items()}
    first, *rest = shapes.values()
    if all(s == first for s in rest):  # the common case: one batch shape
        return first
    try:
        return broadcast_shapes(*shapes.values())
    except RuntimeError:
        listed = ", ".join(f"{n} {shape_str(s)}" for n, s in shapes.items())
        fail(fn, f"batch shapes do not broadcast: {listed}")


def as_float_tensor(fn: str, name: str, t, like: Tensor, like_name: str) -> Tensor:
    """Turn a Python number or a tensor into a floating tensor matching ``like``.

    Python numbers become 0-d tensors of ``like``'s dtype and device; tensors must be
    floating point and share ``like``'s dtype and device (``like_name`` names ``like``).
    """
    if isinstance(t, numbers.Real) and not isinstance(t, bool):
        return torch.tensor(float(t), dtype=like.dtype, device=like.device)
    tensor(fn, name, t)
    same_dtype_device(fn, **{like_name: like, name: t})
    return t


def factory_args(fn: str, shape, dtype) -> tuple[tuple[int, ...], torch.dtype]:
    """Validate a factory's ``shape`` (int or tuple of non-negative ints) and ``dtype``.

    Returns:
        The shape as a tuple and the dtype (torch's default dtype when ``None``).
    """
    try:
        dims = (shape,) if isinstance(shape, int) else tuple(shape)
    except TypeError:
        dims = None
    if dims is None or any(isinstance(n, bool) or not isinstance(n, int) or n < 0 for n in dims):
        fail(fn, f"expected shape to be an int or a tuple of non-negative ints, got {shape!r}")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        fail(fn, f"expected a floating dtype, got {dtype}", TypeError)
    return dims, dtype


def pair(fn: str, a: Tensor, b: Tensor, last: int, names: tuple[str, str] = ("a", "b")) -> None:
    """Check two ``(..., last)`` tensors of one dtype and device with broadcastable batches."""
    tensor(fn, names[0], a, last)
    tensor(fn, names[1], b, last)
    same_dtype_device(fn, **{names[0]: a, names[1]: b})
    broadcast_batch(fn, **{names[0]: (a, 1), names[1]: (b, 1)})


def flag(fn: str, name: str, value) -> bool:
    """Check that a boolean flag (``shortest``, ``check``) is a ``bool``.

    A truthy string such as ``"no"`` would otherwise silently mean True.
    """
    if not isinstance(value, bool):
        fail(fn, f"expected {name} to be a bool (True or False), got {value!r}", TypeError)
    return value


def integer(fn: str, name: str, value, low: int, high: int | None = None,
            rule: str | None = None) -> int:
    """``value`` as an ``int``: an integral number (not a ``bool``) in ``[low, high]``
    (``high=None``: no upper bound), else ``ValueError`` ``"<name> must be an int <rule>,
    got <value>"`` (``rule``: ``">= low"`` or ``"in low..high"`` unless given)."""
    if (isinstance(value, bool) or not isinstance(value, numbers.Integral) or int(value) < low
            or (high is not None and int(value) > high)):
        if rule is None:
            rule = f">= {low}" if high is None else f"in {low}..{high}"
        fail(fn, f"{name} must be an int {rule}, got {value!r}")
    return int(value)


def real(fn: str, name: str, value, rule: str, ok: Callable[[float], bool] = lambda v: True,
         finite: bool = True) -> float:
    """``value`` as a ``float``: a real number (not a ``bool``), finite unless ``finite`` is
    false, for which ``ok`` holds (NaN fails any comparison), else ``ValueError`` ``"<name>
    must be <rule>, got <value>"``."""
    if (isinstance(value, bool) or not isinstance(value, numbers.Real)
            or (finite and not math.isfinite(value)) or not ok(float(value))):
        fail(fn, f"{name} must be {rule}, got {value!r}")
    return float(value)


def listed(value):
    """A 1-D array (numpy's, a tensor) as a list of Python numbers, for checks written for
    lists; any other value as it is."""
    return value.tolist() if getattr(value, "ndim", None) == 1 else value


def first_index(mask: Tensor) -> tuple[int, ...]:
    """The index of the first ``True`` of a bool tensor (row-major order), read on the host
    (a device sync, for error messages); ``mask`` must hold one."""
    return tuple(int(i) for i in mask.nonzero()[0])


def rigid_matrix(fn: str, name: str, T: Tensor, atol: float = 1e-3) -> None:
    """Opt-in value check (a device sync): every ``(..., 3, 3)`` matrix of ``T`` a rotation
    (``max |R^T R - I| <= atol``, determinant > 0), every ``(..., 4, 4)`` one homogeneous
    rigid (its rotation block so, its bottom row ``(0, 0, 0, 1)`` within ``atol``, all
    finite); else a ``ValueError`` naming the first bad matrix and what is wrong with it.
    ``atol`` grows to 8 ulp of a coarser dtype (float16, bfloat16 round rotations so)."""
    atol = max(atol, 8.0 * torch.finfo(T.dtype).eps)
    R = T[..., :3, :3].double()
    err = (R.mT @ R - torch.eye(3, dtype=R.dtype, device=R.device)).abs().amax((-2, -1))
    det = torch.linalg.det(R)
    bottom = (T[..., 3, :].double() - torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=R.dtype,
                                                   device=R.device)).abs().amax(-1) \
        if T.shape[-1] == 4 else torch.zeros_like(det)
    ok = (err <= atol) & (det > 0) & (bottom <= atol) & torch.isfinite(T).flatten(-2).all(-1)
    if host_all(fn, "check=True", ok):
        return
    i = first_index(~ok)
    where = f"{name}[{', '.join(map(str, i))}]" if i else name
    kind = "rigid transform" if T.shape[-1] == 4 else "rotation"
    fail(fn, f"{where} is not a {kind}: max |R^T R - I| = {float(err[i]):.3g}, "
             f"det R = {float(det[i]):.3g}"
             + (f", bottom row {T[i][3].tolist()}" if T.shape[-1] == 4 else "")
             + f" (a rotation has max |R^T R - I| <= {atol:g} and det R = +1"
             + (", a bottom row (0, 0, 0, 1)" if T.shape[-1] == 4 else "") + ")")


#: Time units finer than seconds, and the factor to seconds (the readers' and the terms'
#: unit checks).
TIME_UNITS = (("nanoseconds", 1e-9), ("microseconds", 1e-6), ("milliseconds", 1e-3))
LATEST = 1e11  # seconds (3170 years): beyond any clock's seconds (UNIX time is 1.8e9)


def unix_unit(last: float) -> tuple[str, float] | None:
    """The unit of :data:`TIME_UNITS` in which the time ``last`` is a UNIX time (1e8 to
    1e10 s), or None."""
    return next(((name, scale) for name, scale in TIME_UNITS if 1e8 <= last * scale <= 1e10),
                None)


def poses(fn: str, name: str, x: Tensor) -> None:
    """Value check (a device sync; none on meta tensors): every ``(..., 8)`` dual quaternion
    of ``x`` finite with a non-zero real part, else a ``ValueError`` naming the first bad one."""
    bad = ~(torch.isfinite(x).all(-1) & (x[..., :4] != 0).any(-1))
    if x.device.type != "meta" and bool(bad.any()):
        i = first_index(bad)
        fail(fn, f"{name}{list(i)} = {x[i].tolist()} is no pose: control points must be "
                 f"finite with a non-zero real part")


def same_device(fn: str, ref: Tensor, ref_name: str, name: str, x: Tensor) -> None:
    """Check that ``x`` is on the device of ``ref`` (``TypeError`` naming both)."""
    if x.device != ref.device:
        fail(fn, f"{name} is on {x.device} but {ref_name} is on {ref.device}", TypeError)


def control_points(fn: str, ctrl, min_points: int, what: str) -> None:
    """Check ``ctrl``: ``(..., n, 8)`` floating dual quaternions, ``n >= min_points``
    (``what`` says why, e.g. ``"at least 2 control points"``)."""
    tensor(fn, "ctrl", ctrl, 8)
    if ctrl.dim() < 2 or ctrl.shape[-2] < min_points:
        fail(fn, f"expected a (..., n, 8) tensor for ctrl with n >= {min_points} ({what}), "
                 f"got shape {shape_str(ctrl.shape)}")


def times(fn: str, t, ctrl: Tensor) -> torch.Size:
    """Check the times ``t`` ``(T,)`` or ``(..., T)`` of curves ``ctrl`` ``(..., n, 8)`` (on
    its device); returns the broadcast batch shape of the two."""
    tensor(fn, "t", t)
    if t.dim() < 1:
        fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
    same_device(fn, ctrl, "ctrl", "t", t)
    return broadcast_batch(fn, ctrl=(ctrl, 2), t=(t, 1))


def host_all(fn: str, what: str, mask: Tensor) -> bool:
    """``bool(mask.all())``, read on the host (a device sync), for opt-in value checks.

    Under ``torch.func.vmap`` (or another transform whose tensors have no host values) the
    read is impossible: raise a ``RuntimeError`` that names the function and the way out,
    instead of torch's data-dependent control-flow error.
    """
    try:
        return bool(torch.all(mask))
    except RuntimeError as e:
        raise RuntimeError(f"{fn}: {what} reads the values on the host, which this transform "
                           f"(e.g. torch.func.vmap) does not allow; pass check=False inside "
                           f"the transform and check outside it") from e

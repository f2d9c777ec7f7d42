"""Fused kernels behind the public functions (private).

Each kernel computes the same mathematics as a readable reference in the public module
that owns the concept, faster: component-row layout, cache-sized chunks, custom autograd
``Function``s with an analytic (twice differentiable) backward. ``tests/test_kernels.py``
runs each against its reference over random and degenerate inputs.

- :mod:`.weights`: the dual weights of eq. 11 as one power series (shared by all kernels).
- :mod:`.layout`: component rows and chunking.
- :mod:`.sclerp`: eq. 11 (reference: :func:`torch_dq.dualquat._eq11`).
- :mod:`.slerp`: quaternion slerp on the shortest path, the real part of eq. 11, in the
  caller's ``(N, 4)`` layout (reference: :func:`torch_dq._kernels.slerp.plain`, the same
  forward to the bit).
- :mod:`.dual_angle`: eqs. 4-5 (reference: :func:`torch_dq.dualquat._eqs4_5`).
- :mod:`.pyramid`: the fused De Casteljau / De Boor scheme (references in
  :mod:`torch_dq.curves`).
- :mod:`.products`: dual-quaternion products as matrix products, for small batches (the
  cumulative B-spline's span tables, :mod:`torch_dq._cumulative`).

The dual sine and cosine (:class:`torch_dq.dual._SinCos`) follow the same dispatch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
import torch.autograd.forward_ad as _forward_ad
from torch import Tensor
from torch._C._functorch import is_functorch_wrapped_tensor, is_legacy_batchedtensor

__all__ = ["batched", "fused_path", "index_add", "opaque_scatter", "reference_vjp", "save",
           "saved", "written_backward"]


def fused_path(*tensors: Tensor) -> bool:
    """Whether the fused ops may run on these inputs.

    The fused ops give exact derivatives in reverse mode, double backward included, but a
    custom ``Function`` cannot pass an outer transform's tangents through its own derivative
    rules: a forward-mode rule would make nested forward mode (``jvp`` of ``jvp``) come back
    as zeros. So under a ``torch.func`` transform (``jvp``, ``vmap``, ``grad``, ``hessian``,
    ...) or inside a ``forward_ad.dual_level`` the public functions run their readable
    references instead: plain torch ops, differentiable to any order in any mode. Under
    ``torch.compile`` the fused ops run (Dynamo traces them).

    Args:
        *tensors: the inputs of the op (any of them may be a transform's wrapped tensor).

    Returns:
        ``True`` where the fused op may run, ``False`` where the reference must.
    """
    if torch.compiler.is_compiling():  # Dynamo traces the fused ops
        return True
    if _forward_ad._current_level >= 0:
        return False
    return not any(is_functorch_wrapped_tensor(x) for x in tensors)


def written_backward(differentiated: list[Tensor | None],
                     constant: list[Tensor | None]) -> bool:
    """Whether an op whose backward is written out for some of its inputs may run: eager
    reverse mode (grad enabled, not compiling, :func:`fused_path`) where one of
    ``differentiated`` requires grad and none of ``constant`` does (their gradients, and
    every other mode, go through the op's plain torch ops).

    Args:
        differentiated: the inputs the written-out backward differentiates (``None``: zero).
        constant: the inputs it treats as constants.
    """
    known = [x for x in (*differentiated, *constant) if x is not None]
    return (torch.is_grad_enabled() and not torch.compiler.is_compiling()
            and any(x is not None and x.requires_grad for x in differentiated)
            and not any(x is not None and x.requires_grad for x in constant)
            and fused_path(*known))


def save(ctx: Any, items: list[Tensor | None]) -> None:
    """``ctx.save_for_backward`` of ``items``, ``None`` entries allowed (:func:`saved` gives
    them back in order): a written-out backward's intermediates are then freed after the
    backward and seen by saved-tensor hooks (checkpointing, ``save_on_cpu``), unlike tensors
    kept as attributes of ``ctx``."""
    ctx.known = [x is not None for x in items]
    ctx.save_for_backward(*(x for x in items if x is not None))


def saved(ctx: Any) -> list[Tensor | None]:
    """The ``items`` of :func:`save`, in order."""
    tensors = iter(ctx.saved_tensors)
    return [next(tensors) if known else None for known in ctx.known]


def batched(*grads: Tensor | None) -> bool:
    """Whether a fused op's backward runs with batched cotangents.

    ``torch.autograd.functional.jacobian`` / ``hessian`` with ``vectorize=True`` and
    ``torch.autograd.grad(..., is_grads_batched=True)`` run the backward under ``vmap``
    after the forward has already taken the fused path. The fused backwards (chunk loops,
    ``out=`` writes, host reads) cannot be batched; they return :func:`reference_vjp`
    instead.

    Args:
        *grads: the backward's cotangents (``None`` for outputs without one).
    """
    if torch.compiler.is_compiling():  # traced backwards are never batched this way
        return False
    return any(g is not None and (is_legacy_batchedtensor(g) or is_functorch_wrapped_tensor(g))
               for g in grads)


def reference_vjp(reference: Callable[..., Any], inputs: tuple[Tensor, ...],
                  grads: Any) -> tuple[Tensor, ...]:
    """The vector-Jacobian product of a fused op's readable ``reference`` (plain torch ops)
    at ``inputs``, for batched cotangents ``grads`` (:func:`batched`): exact, and
    differentiable again (double backward, ``hessian(vectorize=True)``).

    Args:
        reference: function of ``inputs`` computing the op's outputs in plain ops.
        inputs: the op's saved differentiable inputs.
        grads: the cotangents, structured as ``reference``'s outputs.

    Returns:
        One cotangent per input.
    """
    vjp_fn = torch.func.vjp(reference, *inputs)[1]
    return vjp_fn(grads)


def opaque_scatter(x: Tensor) -> bool:
    """Whether a fused backward's sum onto a few rows (span starts, pairs, control points) of
    ``x``'s device should run as an opaque op: compiled on CPU, outside a differentiated
    backward. There inductor lowers such scatters to atomic adds from every thread, which
    onto a few rows (64 control points from 4e5 level rows) cost several times aten's serial
    kernel (:func:`index_add`; the cumulative form's ``_segment_outer``)."""
    return (torch.compiler.is_compiling() and x.device.type == "cpu"
            and not torch.is_grad_enabled())


def index_add(x: Tensor, dim: int, index: Tensor, source: Tensor) -> Tensor:
    """``x.index_add(dim, index, source)`` for the fused backwards' sums onto control points
    and pairs; an op that ``torch.compile`` calls as it is (:func:`_index_add_op`) where
    :func:`opaque_scatter`."""
    if opaque_scatter(x):
        return _index_add_op(x, dim, index, source)
    return x.index_add(dim, index, source)


@torch.library.custom_op("torch_dq::index_add", mutates_args=())
def _index_add_op(x: Tensor, dim: int, index: Tensor, source: Tensor) -> Tensor:
    """:func:`index_add` behind an opaque op (aten's kernel; not differentiable), contiguous
    whatever the layout of ``x``."""
    return x.contiguous().index_add(dim, index, source)


@_index_add_op.register_fake
def _(x: Tensor, dim: int, index: Tensor, source: Tensor) -> Tensor:
    return x.new_empty(x.shape)

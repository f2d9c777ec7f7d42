"""Helpers of the custom autograd ``Function``s (private): saved intermediates, the plain
ops' vector-Jacobian product for batched or differentiated backwards, and an index add that
``torch.compile`` leaves opaque where its scatter would be slow (:mod:`torch_dq._dispatch`
says where).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import Tensor

from ._dispatch import opaque_scatter

__all__ = ["InputsSaved", "index_add", "reference_vjp", "save", "saved"]


def save(ctx: Any, items: list[Tensor | None]) -> None:
    """``ctx.save_for_backward`` of ``items``, ``None`` entries allowed (:func:`saved` gives
    them back in order): a written-out backward's intermediates are then freed after the
    backward and seen by saved-tensor hooks (checkpointing, ``save_on_cpu``), unlike tensors
    kept as attributes of ``ctx``."""
    ctx.known = [x is not None for x in items]
    ctx.save_for_backward(*(x for x in items if x is not None))


class InputsSaved(torch.autograd.Function):
    """Base of the ops whose ``setup_context`` saves their tensor inputs for the backward
    (back, in order, from ``ctx.saved_tensors``) and keeps their other inputs (Python
    constants) as the tuple ``ctx.constants``."""

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*(x for x in inputs if isinstance(x, Tensor)))
        ctx.constants = tuple(x for x in inputs if not isinstance(x, Tensor))


def saved(ctx: Any) -> list[Tensor | None]:
    """The ``items`` of :func:`save`, in order."""
    tensors = iter(ctx.saved_tensors)
    return [next(tensors) if known else None for known in ctx.known]


def reference_vjp(reference: Callable[..., Any], inputs: tuple[Tensor, ...],
                  grads: Any) -> tuple[Tensor, ...]:
    """The vector-Jacobian product of a fused op's readable ``reference`` (plain torch ops)
    at ``inputs``, for batched cotangents ``grads`` (:func:`torch_dq._dispatch.batched`):
    exact, and differentiable again (double backward, ``hessian(vectorize=True)``).

    Args:
        reference: function of ``inputs`` computing the op's outputs in plain ops.
        inputs: the op's saved differentiable inputs.
        grads: the cotangents, structured as ``reference``'s outputs.

    Returns:
        One cotangent per input.
    """
    vjp_fn = torch.func.vjp(reference, *inputs)[1]
    return vjp_fn(grads)


def index_add(x: Tensor, dim: int, index: Tensor, source: Tensor) -> Tensor:
    """``x.index_add(dim, index, source)`` for the fused backwards' sums onto control points
    and pairs; an op that ``torch.compile`` calls as it is (:func:`_index_add_op`) where
    :func:`~torch_dq._dispatch.opaque_scatter`."""
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

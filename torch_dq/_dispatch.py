"""Dispatch predicates (private): which path an op takes for its inputs.

The public functions run a fused kernel (:mod:`torch_dq._kernels`: component rows, chunks,
custom autograd ``Function``s with a written-out backward) or its readable reference in
plain torch ops. The choice depends on the mode only, never on values: a ``torch.func``
transform or forward AD (:func:`fused_path`), eager reverse mode on some inputs alone
(:func:`written_backward`), a batched backward (:func:`batched`), a compiled CPU scatter
(:func:`opaque_scatter`). Below every module that dispatches (it imports torch alone).
"""

from __future__ import annotations

import torch
import torch.autograd.forward_ad as _forward_ad
from torch import Tensor
from torch._C._functorch import is_functorch_wrapped_tensor, is_legacy_batchedtensor

__all__ = ["batched", "fused_path", "opaque_scatter", "per_time_jets", "written_backward"]

TABLE_MIN_TIMES = 2  # times per span start below which the span tables do not pay


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


def batched(*grads: Tensor | None) -> bool:
    """Whether a fused op's backward runs with batched cotangents.

    ``torch.autograd.functional.jacobian`` / ``hessian`` with ``vectorize=True`` and
    ``torch.autograd.grad(..., is_grads_batched=True)`` run the backward under ``vmap``
    after the forward has already taken the fused path. The fused backwards (chunk loops,
    ``out=`` writes, host reads) cannot be batched; they return
    :func:`torch_dq._autograd.reference_vjp` instead.

    Args:
        *grads: the backward's cotangents (``None`` for outputs without one).
    """
    if torch.compiler.is_compiling():  # traced backwards are never batched this way
        return False
    return any(g is not None and (is_legacy_batchedtensor(g) or is_functorch_wrapped_tensor(g))
               for g in grads)


def opaque_scatter(x: Tensor) -> bool:
    """Whether a fused backward's sum onto a few rows (span starts, pairs, control points) of
    ``x``'s device should run as an opaque op: compiled on CPU, outside a differentiated
    backward. There inductor lowers such scatters to atomic adds from every thread, which
    onto a few rows (64 control points from 4e5 level rows) cost several times aten's serial
    kernel (:func:`torch_dq._autograd.index_add`; the cumulative form's ``segment_outer``)."""
    return (torch.compiler.is_compiling() and x.device.type == "cpu"
            and not torch.is_grad_enabled())


def per_time_jets(ctrl: Tensor, first: Tensor, p: int) -> bool:
    """Whether the cumulative form's product of powers runs per time
    (:func:`torch_dq._cumulative.jets`, not the span tables): eager, with fewer than
    :data:`TABLE_MIN_TIMES` times per span start, where the span tables cost more than they
    save (e.g. the estimator's one-span copies of each sample)."""
    return (not torch.compiler.is_compiling()
            and first.shape[0] < TABLE_MIN_TIMES * (ctrl.shape[0] - p))

"""Fused kernels behind the public functions (private).

Each kernel computes the same mathematics as a readable reference in the public module
that owns the concept, faster: component-row layout, cache-sized chunks, custom autograd
``Function``s with analytic backward (and compile-safe twins without forward-mode rules).

- :mod:`.weights`: the dual weights of eq. 11 as one power series (shared by all kernels).
- :mod:`.layout`: component rows and chunking.
- :mod:`.sclerp`: eq. 11 (reference: :func:`torch_dq.dualquat.sclerp`).
- :mod:`.dual_angle`: eqs. 4-5 (reference: :func:`torch_dq.dualquat.angle`).
- :mod:`.pyramid`: the fused De Casteljau / De Boor scheme (references in
  :mod:`torch_dq.curves`).
"""

from __future__ import annotations

import torch
import torch.autograd.forward_ad as _forward_ad
from torch import Tensor
from torch._C._functorch import is_functorch_wrapped_tensor

__all__ = ["fused_path"]


def fused_path(*tensors: Tensor) -> bool:
    """Whether the fused ops may run on these inputs.

    They give exact first derivatives in reverse and forward mode, and double backward, but
    a custom ``Function`` cannot pass an outer transform's tangents through its own
    derivative rules: nested forward mode (``jvp`` of ``jvp``) would come back as zeros. So
    under a ``torch.func`` transform (``jvp``, ``vmap``, ``grad``, ``hessian``, ...) or
    inside a ``forward_ad.dual_level`` the public functions run their readable references
    instead: plain torch ops, differentiable to any order in any mode.
    """
    if torch.compiler.is_compiling():  # dynamo traces the compile-safe twins
        return True
    if _forward_ad._current_level >= 0:
        return False
    return not any(is_functorch_wrapped_tensor(x) for x in tensors)

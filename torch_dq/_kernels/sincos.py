"""The dual sine and cosine together as one autograd op (private; reference:
:func:`torch_dq.dual._sincos`)."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["SinCos"]


class SinCos(torch.autograd.Function):
    r"""``(a, b) -> (sin a, b cos a, cos a, -b sin a)``: dual sine and cosine together.

    The forward evaluates ``sin a`` and ``cos a`` once; the backward saves only ``a`` and
    ``b`` and recomputes them, with differentiable ops (so double backward works). No
    forward-mode rule (a custom ``jvp`` is first order only: nested forward mode would give
    zeros): :func:`torch_dq.dual.sincos` runs the plain ops of
    :func:`torch_dq.dual._sincos` under ``torch.func``
    transforms and forward-mode AD.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor):
        s, c = torch.sin(a), torch.cos(a)
        return s, b * c, c, -b * s

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, g_s, g_sd, g_c, g_cd):
        a, b = ctx.saved_tensors
        s, c = torch.sin(a), torch.cos(a)
        # d/da: (cos a, -b sin a, -sin a, -b cos a); d/db: (0, cos a, 0, -sin a).
        grad_a = c * (g_s - b * g_cd) - s * (g_c + b * g_sd)
        grad_b = c * g_sd - s * g_cd
        return grad_a, grad_b

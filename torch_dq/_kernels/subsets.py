r"""The dual weights of the cumulative form's subsets (private): :math:`w_S = \prod_{j \in S}
\alpha_j \prod_{j \notin S} \beta_j` level by level, on jets (Cauchy products of dual
numbers), and their cotangents written out (:class:`SubsetJets`)."""

from __future__ import annotations

import torch
from torch import Tensor

from .._autograd import reference_vjp
from .._dispatch import batched

__all__ = ["SubsetJets", "subset_jets", "subset_levels", "subset_vjp"]


def _cauchy(a: Tensor, b: Tensor) -> Tensor:
    r"""Cauchy products :math:`(ab)_k = \sum_{i \le k} a_i b_{k-i}` of jets stacked along the
    leading dim (``L`` coefficients; the other dims broadcast): one product per
    coefficient of ``a``, added into the shifted rows."""
    out = a[0] * b
    for i in range(1, a.shape[0]):
        out[i:] += a[i] * b[:-i]
    return out


def _cauchy_vjp(a: Tensor, g: Tensor) -> Tensor:
    r"""The cotangent of ``b`` in :func:`_cauchy` ``(a, b)`` (unreduced over broadcast
    dims): :math:`\sum_{k \ge i} g_k a_{k-i}`."""
    out = a[0] * g
    for i in range(1, a.shape[0]):
        out[:-i] += a[i] * g[i:]
    return out


def subset_levels(b_r: Tensor, b_d: Tensor) -> list[tuple[Tensor, Tensor]]:
    r"""The dual weights :math:`w_S` level by level, on jets stacked coefficient first:
    ``b_r, b_d (L, 2, p, n)`` the Taylor coefficients of the real and dual parts of
    :math:`(\beta_j, \alpha_j)` (``L = 1``: their values); level ``j`` holds the products over
    ``1..j``, ``(L, 2^j, n)`` each (index ``m``: bit ``i - 1`` set for :math:`\alpha_i`),
    Cauchy products of dual numbers (:func:`_cauchy`)."""
    levels = [(b_r[:, :, 0], b_d[:, :, 0])]
    for j in range(1, b_r.shape[2]):
        w_r, w_d = (x[:, None] for x in levels[-1])  # (L, 1, 2^j, n) beside (L, 2, 1, n)
        r, d = b_r[:, :, j, None], b_d[:, :, j, None]
        levels.append((_cauchy(r, w_r).flatten(1, 2),
                       (_cauchy(r, w_d) + _cauchy(d, w_r)).flatten(1, 2)))
    return levels


def subset_vjp(levels: list[tuple[Tensor, Tensor]], b_r: Tensor, b_d: Tensor,
                grad: Tensor) -> tuple[Tensor, Tensor]:
    """Cotangents of ``b_r, b_d (L, o, p, n)`` (``o`` options per factor) from ``grad (L,
    2 o^p, n)``, those of the last level's real and dual parts one above the other (as the
    bags' weights): the levels' products transposed (:func:`_cauchy_vjp`)."""
    g_r, g_d = grad.chunk(2, 1)
    gb_r, gb_d = [], []
    for j in range(b_r.shape[2] - 1, 0, -1):
        w_r, w_d = (x[:, None] for x in levels[j - 1])
        r, d = b_r[:, :, j, None], b_d[:, :, j, None]
        g_r, g_d = (x.unflatten(1, (b_r.shape[1], -1)) for x in (g_r, g_d))
        gb_r.append((_cauchy_vjp(w_r, g_r) + _cauchy_vjp(w_d, g_d)).sum(2))
        gb_d.append(_cauchy_vjp(w_r, g_d).sum(2))
        g_r, g_d = ((_cauchy_vjp(r, g_r) + _cauchy_vjp(d, g_d)).sum(1),
                    _cauchy_vjp(r, g_d).sum(1))
    gb_r.append(g_r)
    gb_d.append(g_d)
    return torch.stack(gb_r[::-1], 2), torch.stack(gb_d[::-1], 2)


def subset_jets(b_r: Tensor, b_d: Tensor) -> Tensor:
    """:class:`SubsetJets`' output in differentiable torch ops, ``(L, 2K, n)``."""
    return torch.cat(subset_levels(b_r, b_d)[-1], 1)


class SubsetJets(torch.autograd.Function):
    r"""The dual subset weights :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S}
    \beta_j` on jets: ``b_r, b_d (L, 2, p, n)``, the Taylor coefficients of the real and
    dual parts of :math:`(\beta_j, \alpha_j)` -> ``(L, 2K, n)``, real parts above dual
    parts (:func:`subset_levels`); with one option per factor, ``(L, 1, p, n)``, their
    product ``(L, 2, n)``. The backward is written out (:func:`subset_vjp`) instead of
    autograd over hundreds of small products; where it is itself differentiated or batched,
    the plain-op VJP of :func:`subset_jets`."""

    @staticmethod
    def forward(b_r: Tensor, b_d: Tensor) -> Tensor:
        return subset_jets(b_r, b_d)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        b_r, b_d = ctx.saved_tensors
        if batched(grad) or torch.is_grad_enabled():
            return reference_vjp(subset_jets, (b_r, b_d), grad)
        return subset_vjp(subset_levels(b_r, b_d), b_r, b_d, grad)

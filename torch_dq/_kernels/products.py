r"""Dual-quaternion products as matrix products, for small batches (private).

The product is bilinear: :math:`(ab)_k = \sum_{i,j} C_{kij}\, a_i b_j` with a constant
structure tensor ``C (8, 8, 8)`` (entries 0 and :math:`\pm 1`). Written as
:math:`ab = R(b)\, a` with the right-multiplication matrix :math:`R(b)_{ki} = \sum_j C_{kij}
b_j` (:func:`right_matrix`), products by ``b`` are one matrix product each instead of the
~90 elementwise ops of the component form (:func:`torch_dq._taylor.dq_rows`): for a few
hundred products (the cumulative B-spline's span tables) the per-op overhead, not the
arithmetic, is the cost, in the forward and in autograd's backward alike. For large
batches the component form is faster (no ``8 x 8`` matrix per element).
"""

from __future__ import annotations

import torch
from torch import Tensor

_HAMILTON = (  # (k, i, j, sign): the coefficient of a_i b_j in (ab)_k
    (0, 0, 0, 1), (0, 1, 1, -1), (0, 2, 2, -1), (0, 3, 3, -1),
    (1, 0, 1, 1), (1, 1, 0, 1), (1, 2, 3, 1), (1, 3, 2, -1),
    (2, 0, 2, 1), (2, 1, 3, -1), (2, 2, 0, 1), (2, 3, 1, 1),
    (3, 0, 3, 1), (3, 1, 2, 1), (3, 2, 1, -1), (3, 3, 0, 1),
)


def _structure() -> Tensor:
    """``(8, 64)`` float64: ``S[j, 8 k + i] = C[k, i, j]`` for
    :math:`(r_a r_b, r_a d_b + d_a r_b)`."""
    C = torch.zeros(8, 8, 8, dtype=torch.float64)
    for k, i, j, s in _HAMILTON:
        C[k, i, j] = s  # r_a r_b
        C[4 + k, i, 4 + j] = s  # r_a d_b
        C[4 + k, 4 + i, j] = s  # d_a r_b
    return C.permute(2, 0, 1).reshape(8, 64)


_STRUCTURE = _structure()


def right_matrix(b: Tensor) -> Tensor:
    r"""``(..., 8, 8)``: the matrix :math:`R(b)` with :math:`a b = R(b)\, a` for ``(..., 8)``
    dual quaternions ``a`` and ``b`` (components ``w, x, y, z`` of the real then the dual
    part; batch dims broadcast in the matrix product)."""
    return (b @ _STRUCTURE.to(device=b.device, dtype=b.dtype)).unflatten(-1, (8, 8))

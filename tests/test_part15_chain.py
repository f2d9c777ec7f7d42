"""The control points' sign-aligned chain kept between a long record's parts (session 15,
``torch_dq._core.aligned_chain``) against a numpy sign alignment written here: reused
only for the same, unmodified points and an unmodified chain, never for points with a
gradient."""

from __future__ import annotations

import numpy as np
import torch

from torch_dq._core import aligned_chain

F64 = torch.float64


def _numpy_aligned(x: np.ndarray) -> np.ndarray:
    """Each element's sign flipped so its real part's dot with the previous one is >= 0."""
    out = x.copy()
    for i in range(1, len(out)):
        if out[i, :4] @ out[i - 1, :4] < 0:
            out[i] = -out[i]
    return out


def test_aligned_chain_kept_only_while_unchanged():
    g = torch.Generator().manual_seed(3)
    ctrl = torch.randn(40, 8, generator=g, dtype=F64)
    first = aligned_chain(ctrl)
    np.testing.assert_array_equal(first.numpy(), _numpy_aligned(ctrl.numpy()))
    assert aligned_chain(ctrl) is first  # the same points: kept
    ctrl[7] = -ctrl[7]  # modified in place: aligned again
    again = aligned_chain(ctrl)
    np.testing.assert_array_equal(again.numpy(), _numpy_aligned(ctrl.numpy()))
    again[0] = 0.0  # the chain itself modified: not reused
    np.testing.assert_array_equal(aligned_chain(ctrl).numpy(), _numpy_aligned(ctrl.numpy()))
    other = ctrl.clone()  # other points (equal values): aligned for themselves
    assert aligned_chain(other) is not aligned_chain(ctrl)
    leaf = ctrl.clone().requires_grad_()
    assert aligned_chain(leaf).grad_fn is not None  # a graph: never kept


def test_aligned_chain_batch():
    g = torch.Generator().manual_seed(4)
    ctrl = torch.randn(3, 25, 8, generator=g, dtype=F64)
    got = aligned_chain(ctrl)
    for b in range(3):
        np.testing.assert_array_equal(got[b].numpy(), _numpy_aligned(ctrl[b].numpy()))

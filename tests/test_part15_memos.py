"""What an estimation keeps between its parts and points (session 15): the sign-aligned
chain of the control points (``torch_dq._curve.aligned_chain``) against a numpy sign
alignment written here, and the basis memo (``torch_dq._time.BasesMemo``) against scipy's
B-spline derivatives: kept values are reused only at the same times, spans and order,
and never once modified."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline as SciBSpline

from torch_dq._curve import aligned_chain
from torch_dq._time import BasesMemo, KnotDomain

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
    leaf = ctrl.clone().requires_grad_()
    assert aligned_chain(leaf).grad_fn is not None  # a graph: never kept


def _scipy_cumulative(knots: np.ndarray, p: int, t: np.ndarray, r: np.ndarray,
                      order: int) -> list[np.ndarray]:
    """Cumulative basis ``sum_{m >= j} B_{r-p+m}`` (j = 1..p) and its time derivatives."""
    n = len(knots) - p - 1
    out = []
    for o in range(order + 1):
        plain = np.zeros((len(t), n))
        for i in range(n):
            c = np.zeros(n)
            c[i] = 1.0
            spline = SciBSpline(knots, c, p)
            plain[:, i] = (spline.derivative(o) if o else spline)(t)
        rows = np.stack([plain[k, r[k] - p:r[k] + 1] for k in range(len(t))])
        out.append(np.flip(np.flip(rows[:, 1:], -1).cumsum(-1), -1))
    return out


@pytest.mark.parametrize("order", [0, 2])
def test_bases_memo_reuses_only_the_same_times(order):
    p = 3
    knots = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.4, 1.0, 1.3, 2.0, 2.0, 2.0, 2.0], dtype=F64)
    dom = KnotDomain(knots, p)
    rel = torch.linspace(0.05, 1.95, 23, dtype=F64)
    r = dom.span(rel)
    memo = BasesMemo(1 << 20)
    ref = _scipy_cumulative(knots.numpy(), p, rel.numpy(), r.numpy(), 2)
    with memo.active():
        lower = dom.bases(rel, r, order, cumulative=True)
        full = dom.bases(rel, r, 2, cumulative=True)  # a higher order: computed again
        kept = dom.bases(rel.clone(), r.clone(), order, cumulative=True)  # equal times
    assert len(memo.entries) == 1 and all(a is b for a, b in zip(kept, full, strict=False))
    for got in (lower, full, kept):
        for o, x in enumerate(got):
            np.testing.assert_allclose(x.numpy(), ref[o], rtol=0, atol=1e-9 * 10 ** o)
    moved = rel + 0.01  # a moving clock: computed again at the new times
    r = dom.span(moved)
    ref = _scipy_cumulative(knots.numpy(), p, moved.numpy(), r.numpy(), order)
    with memo.active():
        got = dom.bases(moved, r, order, cumulative=True)
    for o, x in enumerate(got):
        np.testing.assert_allclose(x.numpy(), ref[o], rtol=0, atol=1e-9 * 10 ** o)
    got[0].mul_(2.0)  # a kept value modified in place: not reused
    with memo.active():
        again = dom.bases(moved, r, order, cumulative=True)
    np.testing.assert_allclose(again[0].numpy(), ref[0], rtol=0, atol=1e-9)


def test_bases_memo_budget_and_scope():
    dom = KnotDomain(torch.arange(12, dtype=F64), 3)
    rel = torch.linspace(3.1, 7.9, 50, dtype=F64)
    r = dom.span(rel)
    memo = BasesMemo(100)  # smaller than one entry: nothing kept
    with memo.active():
        dom.bases(rel, r, 1, cumulative=True)
    assert memo.entries == {} and memo.left == 100
    big = BasesMemo(1 << 20)
    with big.active():
        dom.bases(rel, r, 1, cumulative=True)
    dom.bases(rel + 1.0, r + 1, 1, cumulative=True)  # outside the scope: not kept
    size = 50 * 8 * 2 + 2 * 50 * 3 * 8
    assert len(big.entries) == 1 and big.left == (1 << 20) - size
    assert math.isclose(float(dom.bases(rel, r)[0].sum()), 50.0)

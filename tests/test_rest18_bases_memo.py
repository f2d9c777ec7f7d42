"""rest18: ``KnotDomain.bases`` with a ``memo`` (the estimation's, kept between calls) gives
the basis of the times it is called with, whatever it holds: hits, misses of the same shape,
a caller's tensor changed in place, other knots; against scipy's B-spline basis."""

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline as SciBSpline

from torch_dq._time import KnotDomain


def _scipy_basis(knots: np.ndarray, p: int, t: np.ndarray, r: np.ndarray, order: int):
    """``(T, p + 1)``: the ``order``-th derivative of B_{r-p..r,p} at ``t`` (scipy)."""
    n = len(knots) - p - 1
    out = np.zeros((len(t), p + 1))
    for j in range(n):
        c = np.zeros(n)
        c[j] = 1.0
        vals = SciBSpline(knots, c, p, extrapolate=False).derivative(order)(t) if order else \
            SciBSpline(knots, c, p, extrapolate=False)(t)
        for i in range(len(t)):
            m = j - (r[i] - p)
            if 0 <= m <= p:
                out[i, m] = vals[i]
    return out


def _knots(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    inner = torch.sort(torch.rand(6, generator=g, dtype=torch.float64) * 4).values
    return torch.cat((torch.zeros(4, dtype=torch.float64), inner,
                      torch.full((4,), 4.0, dtype=torch.float64)))


@pytest.mark.parametrize("cumulative", [False, True])
def test_memo_follows_the_times(cumulative):
    p, order, memo = 3, 2, {}
    g = torch.Generator().manual_seed(0)
    dom = KnotDomain(_knots(1), p)
    t1 = torch.rand(50, generator=g, dtype=torch.float64) * 3.99
    t2 = torch.rand(50, generator=g, dtype=torch.float64) * 3.99  # same shape, other times
    calls = [t1, t1.clone(), t2, t1]
    for t in calls:
        r = dom.span(t)
        got = dom.bases(t, r, order, cumulative=cumulative, memo=memo)
        kn = dom.knots.numpy()
        for d in range(order + 1):
            ref = _scipy_basis(kn, p, t.numpy(), r.numpy(), d)
            if cumulative:
                ref = np.flip(np.flip(ref, 1).cumsum(1), 1)[:, 1:]
            np.testing.assert_allclose(got[d].numpy(), ref, rtol=1e-10, atol=1e-10)
    hit = dom.bases(t1, dom.span(t1), order, cumulative=cumulative, memo=memo)
    assert hit[0] is dom.bases(t1.clone(), dom.span(t1), order, cumulative=cumulative,
                               memo=memo)[0]  # equal arguments: the kept result


def test_memo_in_place_change_and_other_knots():
    p, memo = 3, {}
    t = torch.linspace(0.1, 3.9, 40, dtype=torch.float64)
    dom = KnotDomain(_knots(2), p)
    r = dom.span(t)
    dom.bases(t, r, 1, memo=memo)
    t.mul_(0.5)  # the caller's tensor changed in place: not the kept times
    r = dom.span(t)
    got = dom.bases(t, r, 1, memo=memo)
    for d in range(2):
        ref = _scipy_basis(dom.knots.numpy(), p, t.numpy(), r.numpy(), d)
        np.testing.assert_allclose(got[d].numpy(), ref, rtol=1e-10, atol=1e-10)
    other = KnotDomain(_knots(3), p)  # other knots, the same times and spans
    r2 = other.span(t)
    got = other.bases(t, r2, 0, memo=memo)
    ref = _scipy_basis(other.knots.numpy(), p, t.numpy(), r2.numpy(), 0)
    np.testing.assert_allclose(got[0].numpy(), ref, rtol=1e-10, atol=1e-10)


def test_memo_not_used_under_autograd():
    p, memo = 3, {}
    dom = KnotDomain(_knots(4), p)
    t = torch.linspace(0.2, 3.8, 30, dtype=torch.float64, requires_grad=True)
    r = dom.span(t.detach())
    b = dom.bases(t, r, 0, memo=memo)[0]
    assert b.requires_grad and not memo

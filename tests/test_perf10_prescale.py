"""The prescale only where a row needs it (perf10, ``_numerics.prescale``): ``quat.normalize``,
``quat.to_matrix``, ``quat.to_rotvec`` and ``dualquat.normalize`` take plain norms when every
row of the batch is in range (one eager CPU read) and divide by a power of two otherwise.
References: numpy and scipy on the unscaled rows; scale invariance across the switch (every
power of two from below the plain range to beyond it gives the bits of the unscaled row);
the bits, gradients and second derivatives of a row whatever its batch holds."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import _numerics, quat

F64 = torch.float64
OPS = {"normalize": quat.normalize, "to_matrix": quat.to_matrix, "to_rotvec": quat.to_rotvec}


def _rows(n=64, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=F64)
    q[:3] = torch.tensor([[1.0, 0, 0, 0], [0.6, 0, 0.8, 0], [1, 1e-9, 0, 0]])
    return q


def _numpy_reference(name, q):
    a = q.numpy()
    if name == "normalize":
        return a / np.sqrt((a * a).sum(-1, keepdims=True))
    r = Rotation.from_quat(a[:, [1, 2, 3, 0]])
    return r.as_matrix() if name == "to_matrix" else r.as_rotvec()


@pytest.mark.parametrize("dtype", [torch.float32, F64])
@pytest.mark.parametrize("name", list(OPS))
def test_scale_invariance_across_the_plain_range(name, dtype):
    """q 2^k for k from far below the plain range to far beyond it: the bits of q (the
    exact division by 2^k changes no digit), and numpy / scipy on q."""
    q = _rows().to(dtype)
    fn = OPS[name]
    ref = fn(q)
    tol = 1e-15 if dtype == F64 else 1e-6
    np.testing.assert_allclose(ref.double().numpy(), _numpy_reference(name, q.double()),
                               rtol=0, atol=4 * tol)
    info = torch.finfo(dtype)
    low = _numerics.plain_range(dtype, power=1)[0]
    k_edge = int(np.log2(low))
    small, large = q.abs()[q != 0].min().item(), q.abs().max().item()
    k_min, k_max = int(np.log2(info.tiny / small)) + 1, int(np.log2(info.max / large)) - 2
    ks = sorted({*range(k_min, k_max, 7), *range(k_edge - 3, k_edge + 4),
                 *range(-k_edge - 3, -k_edge + 4)})
    assert k_min < k_edge - 3 and -k_edge + 4 < k_max
    for k in ks:
        x = q * 2.0 ** k  # exact: no component leaves the normal range
        assert torch.equal(x / 2.0 ** k, q)
        assert torch.equal(fn(x), ref), (name, dtype, k)


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_dual_normalize_scale_invariance(dtype):
    g = torch.Generator().manual_seed(1)
    x = torch.cat((_rows(), torch.randn(64, 4, generator=g, dtype=F64)), -1).to(dtype)
    ref = dq.normalize(x)
    a = x.double().numpy()
    r = a[:, :4] / np.linalg.norm(a[:, :4], axis=-1, keepdims=True)
    d = a[:, 4:] / np.linalg.norm(a[:, :4], axis=-1, keepdims=True)
    d = d - r * (r * d).sum(-1, keepdims=True)
    tol = 1e-14 if dtype == F64 else 2e-6
    np.testing.assert_allclose(ref.double().numpy(), np.concatenate((r, d), -1), rtol=0,
                               atol=tol * np.abs(a).max())
    for k in (-300, -130, -120, -40, -14, -12, 12, 14, 40, 120, 130, 300):
        if abs(k) < 120 or dtype == F64:
            assert torch.equal(dq.normalize(x * 2.0 ** k), ref), (dtype, k)


BAD_ROWS = ["zero", "nan", "inf", "tiny", "huge"]


@pytest.mark.parametrize("bad", BAD_ROWS)
@pytest.mark.parametrize("name", [*OPS, "dq.normalize"])
def test_a_row_keeps_its_bits_and_derivatives_whatever_its_batch(name, bad):
    """One row out of range switches the batch to the divided form: the other rows keep
    their values, gradients and second derivatives to the bit (plain and prescaled
    arithmetic agree on them), and under ``torch.func.vmap`` (never a host read)."""
    q = _rows(8)
    if name == "dq.normalize":
        q = torch.cat((q, _rows(8, seed=2)), -1)
    fn = dq.normalize if name == "dq.normalize" else OPS[name]
    mixed = q.clone()
    if bad in ("tiny", "huge"):  # the whole row by 2^-+700: exact
        mixed[3] = q[3] * 2.0 ** (-700 if bad == "tiny" else 700)
    else:
        mixed[3, :4] = {"zero": 0.0, "nan": float("nan"), "inf": float("inf")}[bad]
    keep = [0, 1, 2, 4, 5, 6, 7]

    def derivatives(x):
        x = x.clone().requires_grad_()
        y = fn(x)
        w = torch.linspace(-1, 1, y[0].numel(), dtype=F64).view(y[0].shape)
        (g,) = torch.autograd.grad((y[keep] * w).sum(), x, create_graph=True)
        (gg,) = torch.autograd.grad((g[keep] * torch.linspace(0.5, 2, x.shape[-1],
                                                                 dtype=F64)).sum(), x)
        return y.detach(), g.detach(), gg

    for a, b in zip(derivatives(q), derivatives(mixed), strict=True):
        assert torch.equal(a[keep], b[keep])
    assert torch.equal(torch.func.vmap(fn)(mixed)[keep], fn(q)[keep])
    assert torch.equal(torch.func.vmap(fn)(q), fn(q))
    row = fn(mixed)[3]
    if bad in ("nan", "inf") or (bad == "zero" and name != "to_rotvec"):
        assert row.isnan().any()  # no direction: NaN
    elif bad == "zero":
        assert torch.equal(row, torch.zeros(3, dtype=F64))  # to_rotvec of 0: no rotation
    else:
        assert torch.equal(row, fn(q)[3])  # the exact scale changes no digit


@pytest.mark.parametrize("name", [*OPS, "dq.normalize"])
def test_derivatives_in_and_out_of_the_plain_range(name):
    """gradcheck and gradgradcheck (finite differences) in range; out of range (2^+-600,
    where no finite difference works) the Jacobian is the in-range one over the scale, to
    the bit (f(q s) = f(q), J(q s) = J(q) / s)."""
    fn = dq.normalize if name == "dq.normalize" else OPS[name]
    q = torch.tensor([[0.3, -0.5, 0.7, 0.2], [0.9, 0.1, -0.2, 0.3]], dtype=F64)
    if name == "dq.normalize":
        q = torch.cat((q, q.flip(-1)), -1)
    assert torch.autograd.gradcheck(fn, (q.clone().requires_grad_(),))
    assert torch.autograd.gradgradcheck(fn, (q.clone().requires_grad_(),))
    jac = torch.autograd.functional.jacobian(fn, q)
    for k in (-600, 600):
        assert torch.equal(torch.autograd.functional.jacobian(fn, q * 2.0 ** k) * 2.0 ** k, jac)


def test_empty_and_single_rows():
    for fn in OPS.values():
        assert fn(torch.zeros(0, 4, dtype=F64)).shape[0] == 0
    one = torch.tensor([0.0, 3.0, 0.0, 4.0], dtype=F64)
    np.testing.assert_array_equal(quat.normalize(one).numpy(), [0.0, 0.6, 0.0, 0.8])
    assert quat.normalize(torch.zeros(4, dtype=F64)).isnan().all()
    huge = torch.tensor([3.0, 0.0, 4.0, 0.0], dtype=F64) * 2.0 ** 1000
    assert quat.normalize(huge).tolist() == [0.6, 0.0, 0.8, 0.0]


# ---------------------------------------------------------------------------- even: one branch

EVEN_REFERENCE = {
    "cos": lambda th: np.cos(th),
    "sinc": lambda th: np.sin(th) / th,
    "atanc": lambda th: np.arctan(th) / th,
    "se3_c1": lambda th: (1 - np.cos(th)) / th**2,
}


@pytest.mark.parametrize("name", list(EVEN_REFERENCE))
def test_even_one_branch_keeps_the_bits_of_the_mixed_batch(name):
    """Eager on the CPU a batch whose elements all take one branch evaluates only it: each
    element's value, derivative and second derivative are those it has in a mixed batch,
    to the bit; the values match numpy's closed forms above the switch."""
    small = torch.tensor([0.0, 1e-12, 1e-6, 1e-4], dtype=F64)
    large = torch.tensor([0.3, 0.7, 1.3, 2.0], dtype=F64)

    def derivatives(x2):
        x2 = x2.clone().requires_grad_()
        y = _numerics.even(name, x2)
        (g,) = torch.autograd.grad(y.sum(), x2, create_graph=True)
        (gg,) = torch.autograd.grad(g.sum(), x2)
        return torch.stack((y.detach(), g.detach(), gg))

    mixed = derivatives(torch.cat((small, large)))
    assert torch.equal(derivatives(small), mixed[:, :4])
    assert torch.equal(derivatives(large), mixed[:, 4:])
    assert torch.equal(torch.func.vmap(lambda x: _numerics.even(name, x))(large),
                       mixed[0, 4:])
    th = np.sqrt(large.numpy())
    np.testing.assert_allclose(mixed[0, 4:].numpy(), EVEN_REFERENCE[name](th), rtol=0,
                               atol=1e-15)


def test_even_non_finite_takes_both_branches():
    """inf and NaN keep the mixed evaluation (the series' share of the derivative at inf
    is NaN, as before): the derivative's NaN pattern does not depend on the batch."""
    x2 = torch.tensor([0.5, float("inf"), 2.0], dtype=F64, requires_grad=True)
    (g,) = torch.autograd.grad(_numerics.even("atanc", x2).sum(), x2)
    assert g[1].isnan() and torch.isfinite(g[[0, 2]]).all()

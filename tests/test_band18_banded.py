"""The compiled banded Cholesky (``torch_dq._kernels.banded_native``, ``csrc/banded.c``)
behind ``torch_dq.fitting._banded.BandedCholesky``: its factor against numpy's dense
Cholesky (LAPACK ``dpotrf``), its solves against ``numpy.linalg.solve``, its selected
inverse against ``numpy.linalg.inv``'s blocks, and all of them against the block cyclic
reduction (``TORCH_DQ_NATIVE=0``), on random symmetric positive definite bands (batches,
shifts, every band width and block size), an ill-conditioned one and non-definite ones.
"""

import numpy as np
import pytest
import torch

from torch_dq._kernels import banded_native, native
from torch_dq.fitting._banded import BandedCholesky

pytestmark = pytest.mark.skipif(native.library() is None,
                                reason="the compiled kernels are not built")

F64 = torch.float64


def _spd(rng, batch, n, w, s, spread=0.0):
    """``band (*batch, n, w, s, s)`` and the dense ``(*batch, n s, n s)`` matrix: sums of
    ``J^T J`` over windows of ``w`` block rows plus a ridge, rows scaled by ``10^[-spread,
    spread]``."""
    N = n * s
    dense = np.zeros((*batch, N, N))
    for k in range(n):
        rows = slice(k * s, min(n, k + w) * s)
        J = rng.standard_normal((*batch, s + 2, rows.stop - rows.start))
        dense[..., rows, rows] += np.swapaxes(J, -1, -2) @ J
    dense += 0.1 * np.eye(N)
    scale = 10.0 ** (spread * rng.uniform(-1, 1, (*batch, N)))
    dense = scale[..., :, None] * dense * scale[..., None, :]
    band = np.zeros((*batch, n, w, s, s))
    for k in range(n):
        for d in range(min(w, n - k)):
            band[..., k, d, :, :] = dense[..., k * s:(k + 1) * s, (k + d) * s:(k + d + 1) * s]
    return torch.from_numpy(band), dense


def _reference(band, shift, monkeypatch):
    """The cyclic reduction's ``BandedCholesky`` (the compiled path off)."""
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    chol = BandedCholesky(band, shift)
    monkeypatch.delenv("TORCH_DQ_NATIVE")
    assert chol.levels and chol._factor is None
    return chol


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)


CASES = [((), 1, 1, 1), ((), 1, 3, 6), ((2,), 7, 4, 6), ((), 50, 4, 6), ((3,), 13, 2, 3),
         ((), 10, 5, 2), ((2, 2), 9, 1, 4), ((), 23, 3, 9), ((), 4, 5, 7), ((1,), 31, 4, 1),
         ((), 2, 2, 5), ((2,), 17, 5, 8)]


@pytest.mark.parametrize(("batch", "n", "w", "s"), CASES)
@pytest.mark.parametrize("shifted", [False, True])
def test_factor_solve_inverse_match_numpy_and_the_reduction(monkeypatch, batch, n, w, s,
                                                           shifted):
    rng = np.random.default_rng(n * 100 + w * 10 + s)
    band, dense = _spd(rng, batch, n, w, s)
    shift = torch.from_numpy(rng.uniform(0, 2, (*batch, n, s))) if shifted else None
    if shifted:
        dense = dense + np.vectorize(np.diag, signature="(k)->(k,k)")(
            shift.numpy().reshape(*batch, n * s))
    chol = BandedCholesky(band, shift)
    assert chol._factor is not None and not chol.levels  # the compiled path
    assert chol.ok.shape == batch and bool(chol.ok.all())
    ref = _reference(band, shift, monkeypatch)
    N, p = n * s, w * s - 1
    # the factor: numpy's dense Cholesky's band, row by row
    Ld = np.linalg.cholesky(dense)
    U = chol._factor.numpy()[..., :N, :]  # row j: U(j, j .. j + p) = L(j .. j + p, j)
    for j in range(N):
        hi = min(N, j + p + 1)
        assert _rel(U[..., j, :hi - j], Ld[..., j:hi, j]) < 1e-12
    # solves (several right-hand sides)
    rhs = rng.standard_normal((*batch, n, s, 3))
    x = chol.solve(torch.from_numpy(rhs))
    assert x.shape == rhs.shape
    want = np.linalg.solve(dense, rhs.reshape(*batch, N, 3))
    assert _rel(x.numpy().reshape(*batch, N, 3), want) < 1e-12
    assert _rel(x, ref.solve(torch.from_numpy(rhs))) < 1e-12
    # the selected inverse: numpy's inverse blocks; the reduction's layout (padding too)
    diag, sub = chol.selected_inverse()
    rdiag, rsub = ref.selected_inverse()
    assert diag.shape == rdiag.shape and sub.shape == rsub.shape
    assert _rel(diag, rdiag) < 1e-12 and _rel(sub, rsub) < 1e-12
    inv, b = np.linalg.inv(dense), chol.g * s
    for j in range(chol.G):
        r = slice(j * b, min((j + 1) * b, N))
        k = r.stop - r.start
        assert _rel(diag[..., j, :k, :k], inv[..., r, r]) < 1e-12
        if (j + 1) * b < N:
            nr = slice((j + 1) * b, min((j + 2) * b, N))
            assert _rel(sub[..., j, :nr.stop - nr.start, :k], inv[..., nr, r]) < 1e-12


@pytest.mark.parametrize(("n", "w"), [(9, 4), (12, 4), (13, 3), (2, 4), (6, 2), (5, 1)])
def test_trace_products_match_numpy(monkeypatch, n, w):
    """trace(M (A^-1 + U V^T)) (U V^T symmetric) on the compiled path, against numpy's
    dense inverse and the reduction."""
    rng = np.random.default_rng(3 * n + w)
    s = 6
    band, dense = _spd(rng, (2,), n, w, s)
    bM, M = _spd(rng, (2,), n, w, s)
    Z = rng.standard_normal((2, n * s, 3))
    U, V = Z, Z @ np.diag([1.0, -0.5, 2.0])
    Ut, Vt = (torch.from_numpy(x.reshape(2, n, s, 3)) for x in (U, V))
    chol = BandedCholesky(band)
    up, plain = chol.trace_products([bM, band], Ut, Vt)
    inv = np.linalg.inv(dense)
    want = np.einsum("bij,bji->b", M, inv + U @ V.transpose(0, 2, 1))
    assert _rel(up, want) < 1e-12
    assert _rel(plain, np.einsum("bij,bji->b", dense, inv + U @ V.transpose(0, 2, 1))) < 1e-12
    alone, = chol.trace_products([bM])
    assert _rel(alone, np.einsum("bij,bji->b", M, inv)) < 1e-12
    past = bM.clone()
    for d in range(1, w):  # the blocks past the last row are ignored, NaN too
        past[:, n - d:, d] = float("nan")
    assert _rel(chol.trace_products([past])[0], alone) < 1e-15
    # the inverse's blocks inside the band, as the band's layout
    Zb = banded_native.band_inverse(chol._factor, n, w, s).numpy()
    for k in range(n):
        for d in range(min(w, n - k)):
            blk = inv[:, k * s:(k + 1) * s, (k + d) * s:(k + d + 1) * s]
            assert _rel(Zb[:, k, d], blk) < 1e-12
    assert _rel(alone, _reference(band, None, monkeypatch).trace_products([bM])[0]) < 1e-12


def test_ill_conditioned():
    """Condition number ~1e12: the factor reproduces the matrix and the solve's residual
    is at rounding (backward stable), as LAPACK's; the solution agrees with numpy's to
    what the conditioning allows."""
    rng = np.random.default_rng(5)
    band, dense = _spd(rng, (), 40, 4, 6, spread=2.5)
    assert np.linalg.cond(dense) > 1e11
    chol = BandedCholesky(band)
    assert bool(chol.ok)
    N, p = 240, 23
    U = np.zeros((N, N))
    F = chol._factor.numpy()
    for j in range(N):
        hi = min(N, j + p + 1)
        U[j, j:hi] = F[j, :hi - j]
    assert np.abs(U.T @ U - dense).max() / np.abs(dense).max() < 1e-15
    rhs = rng.standard_normal((40, 6, 2))
    x = chol.solve(torch.from_numpy(rhs)).numpy().reshape(N, 2)
    res = np.abs(dense @ x - rhs.reshape(N, 2)).max()
    assert res / (np.abs(dense).max() * np.abs(x).max()) < 1e-14
    assert _rel(x, np.linalg.solve(dense, rhs.reshape(N, 2))) < 1e-12 * np.linalg.cond(dense)


@pytest.mark.parametrize("broken", ["indefinite", "nan", "singular"])
def test_not_positive_definite_is_reported_as_the_reduction_does(monkeypatch, broken):
    """A non-definite batch element: ``ok`` False there (as the reduction's), finite
    results; the other element's results unaffected."""
    rng = np.random.default_rng(11)
    band, dense = _spd(rng, (2,), 8, 3, 4)
    bad = band.clone()
    if broken == "indefinite":
        bad[1, 5, 0, 2, 2] = -1.0
    elif broken == "nan":
        bad[1, 3, 1, 0, 1] = float("nan")
    else:
        bad[1, :, :, 0, :] = 0.0
        bad[1, :, 0, :, 0] = 0.0
    chol, ref = BandedCholesky(bad), _reference(bad, None, monkeypatch)
    assert chol.ok.tolist() == ref.ok.tolist() == [True, False]
    rhs = torch.from_numpy(rng.standard_normal((2, 8, 4, 1)))
    x = chol.solve(rhs)
    assert bool(torch.isfinite(x).all())
    want = np.linalg.solve(dense[0], rhs[0].numpy().reshape(32, 1))
    assert _rel(x[0].numpy().reshape(32, 1), want) < 1e-12
    assert bool(torch.isfinite(chol.selected_inverse()[0]).all())


def test_shift_makes_definite_and_negative_shift_breaks(monkeypatch):
    """``shift`` enters the factor as the reduction's (the certificate's negative shift)."""
    rng = np.random.default_rng(2)
    band, dense = _spd(rng, (), 6, 2, 3)
    lam = np.linalg.eigvalsh(dense)[0]
    for c, ok in ((0.5, True), (1.5, False)):
        shift = torch.full((6, 3), -c * lam, dtype=F64)
        assert bool(BandedCholesky(band, shift).ok) is ok
        assert bool(_reference(band, shift, monkeypatch).ok) is ok


def test_dispatch_and_gradient_fallback(monkeypatch):
    """float32 and a band needing a gradient take the reduction; a right-hand side needing
    one on a compiled factor builds the reduction's levels (gradient as the reduction's)."""
    rng = np.random.default_rng(4)
    band, dense = _spd(rng, (), 7, 3, 2)
    assert BandedCholesky(band.float())._factor is None
    assert BandedCholesky(band.clone().requires_grad_())._factor is None
    chol = BandedCholesky(band)
    rhs = torch.from_numpy(rng.standard_normal((7, 2, 1))).requires_grad_()
    chol.solve(rhs).sum().backward()
    assert chol.levels  # built on that call
    g = np.linalg.solve(dense, np.ones(14))  # d sum(A^-1 b) / db = A^-1 1
    assert _rel(rhs.grad.numpy().reshape(14), g) < 1e-12
    before = rhs.detach().clone()
    x = banded_native.solve(chol._factor, rhs.detach())
    assert torch.equal(rhs.detach(), before)  # a single column's view is dense: not reused
    assert _rel(x.numpy().reshape(14), np.linalg.solve(dense, rhs.detach().numpy().ravel())) \
        < 1e-12


def test_right_hand_sides_broadcast_over_the_matrix_batch():
    """One matrix, a batch of right-hand sides (the factor broadcast), against numpy."""
    rng = np.random.default_rng(8)
    band, dense = _spd(rng, (), 9, 3, 4)
    rhs = rng.standard_normal((3, 9, 4, 2))
    x = BandedCholesky(band).solve(torch.from_numpy(rhs))
    assert x.shape == (3, 9, 4, 2)
    want = np.linalg.solve(dense, rhs.reshape(3, 36, 2))
    assert _rel(x.numpy().reshape(3, 36, 2), want) < 1e-12

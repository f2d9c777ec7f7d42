"""torch_dq.fitting._banded: block cyclic reduction of block-banded SPD matrices against
scipy's LAPACK banded Cholesky (``scipy.linalg.cholesky_banded``, ``solveh_banded``,
``cho_solve_banded``) in float64 and float32.

The matrices are Gauss-Newton-like: sums of ``J^T J`` over windows of ``w`` consecutive
block rows, scaled row by row over six orders of magnitude (condition numbers up to ~1e12),
as the spline fits' normal equations are.
"""

import numpy as np
import pytest
import scipy.linalg as sla
import torch

from torch_dq.fitting._banded import BandedCholesky

F32, F64 = torch.float32, torch.float64


def _gauss_newton(gen, batch, n, w, s=6, spread=3.0):
    """``band (*batch, n, w, s, s)`` and the dense ``(*batch, n s, n s)`` matrix."""
    N = n * s
    dense = torch.zeros(*batch, N, N, dtype=F64)
    for k in range(n):  # a window of w block rows per sample group
        rows = slice(k * s, min(n, k + w) * s)
        size = rows.stop - rows.start
        J = torch.randn(*batch, 2 * s, size, generator=gen, dtype=F64)
        dense[..., rows, rows] += J.mT @ J
    scale = 10.0 ** (spread * (2 * torch.rand(*batch, N, generator=gen, dtype=F64) - 1))
    dense = scale[..., :, None] * dense * scale[..., None, :]
    band = torch.zeros(*batch, n, w, s, s, dtype=F64)
    for k in range(n):
        for d in range(min(w, n - k)):
            band[..., k, d, :, :] = dense[..., k * s:(k + 1) * s, (k + d) * s:(k + d + 1) * s]
    return band, dense


def _scipy_upper(dense: np.ndarray, u: int) -> np.ndarray:
    """scipy's upper banded storage ``ab[u + i - j, j] = a[i, j]``."""
    N = dense.shape[0]
    ab = np.zeros((u + 1, N))
    for d in range(u + 1):
        ab[u - d, d:] = np.diagonal(dense, d)
    return ab


def _scipy_solve(dense, rhs, w, s=6):
    return sla.solveh_banded(_scipy_upper(dense, w * s - 1), rhs)


@pytest.mark.parametrize(("n", "w"), [(1, 1), (5, 1), (7, 2), (23, 4), (24, 4), (25, 4),
                                      (40, 3), (10, 10), (64, 5)])
def test_solve_matches_scipy_solveh_banded(n, w):
    gen = torch.Generator().manual_seed(n * 100 + w)
    band, dense = _gauss_newton(gen, (2,), n, w)
    rhs = torch.randn(2, n, 6, 3, generator=gen, dtype=F64)
    chol = BandedCholesky(band)
    assert chol.ok.tolist() == [True, True]
    x = chol.solve(rhs)
    for b in range(2):
        ref = _scipy_solve(dense[b].numpy(), rhs[b].reshape(-1, 3).numpy(), w)
        # relative to the solution's size (measured ~3e-16 at a condition number of 4e12)
        err = np.abs(x[b].reshape(-1, 3).numpy() - ref).max() / np.abs(ref).max()
        assert err < 1e-9


def test_factor_matches_scipy_cholesky_banded_determinant(monkeypatch):
    """The factors' log-determinant (sum over levels of the even blocks' log-diagonals)
    equals that of LAPACK's banded Cholesky: the same factorisation, permuted (the cyclic
    reduction's levels: the compiled path off)."""
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    gen = torch.Generator().manual_seed(7)
    band, dense = _gauss_newton(gen, (), 31, 4)
    chol = BandedCholesky(band)
    logdet = sum(2 * float(torch.log(torch.diagonal(lv.C, dim1=-2, dim2=-1)).sum())
                 for lv in chol.levels)
    cb = sla.cholesky_banded(_scipy_upper(dense.numpy(), 23))
    assert logdet == pytest.approx(2 * np.log(cb[-1]).sum(), rel=1e-12)


@pytest.mark.parametrize("batch", [(), (1,), (3,), (2, 3)])
def test_batch_shapes_and_broadcast_rhs(batch):
    gen = torch.Generator().manual_seed(3)
    band, dense = _gauss_newton(gen, batch, 11, 4)
    chol = BandedCholesky(band)
    assert chol.ok.shape == batch and bool(chol.ok.all())
    rhs = torch.randn(11, 6, 2, generator=gen, dtype=F64)  # one rhs for every matrix
    x = chol.solve(rhs)
    assert x.shape == (*batch, 11, 6, 2)
    ref = torch.linalg.solve(dense, rhs.reshape(66, 2))
    torch.testing.assert_close(x.reshape(*batch, 66, 2), ref, rtol=1e-8, atol=0.0)


@pytest.mark.parametrize(("n", "w", "width"), [(9, 4, 4), (17, 4, 4), (13, 3, 3), (6, 2, 2),
                                               (5, 1, 2), (33, 4, 2)])
def test_window_covariance_matches_scipy_inverse(n, w, width):
    gen = torch.Generator().manual_seed(n + w)
    band, dense = _gauss_newton(gen, (2,), n, w, spread=1.0)
    first = torch.arange(n - width + 1).expand(2, -1)
    S = BandedCholesky(band).window_covariance(first, width)
    for b in range(2):
        cb = sla.cholesky_banded(_scipy_upper(dense[b].numpy(), w * 6 - 1))
        inv = sla.cho_solve_banded((cb, False), np.eye(6 * n))
        for f in range(n - width + 1):
            ref = inv[6 * f:6 * (f + width), 6 * f:6 * (f + width)]
            np.testing.assert_allclose(S[b, f].numpy(), ref, rtol=1e-8,
                                       atol=1e-10 * np.abs(ref).max())


def test_float32_accuracy_against_float64_scipy():
    """float32 factor and solve on a moderately conditioned system (spread 1e+-1, cond
    ~2e5): relative error of the solution below 1e-3 (measured 5e-7)."""
    gen = torch.Generator().manual_seed(11)
    band, dense = _gauss_newton(gen, (), 50, 4, spread=1.0)
    rhs = torch.randn(50, 6, 1, generator=gen, dtype=F64)
    x = BandedCholesky(band.float()).solve(rhs.float())
    assert x.dtype == F32
    ref = _scipy_solve(dense.numpy(), rhs.reshape(-1, 1).numpy(), 4)
    err = np.abs(x.double().reshape(-1, 1).numpy() - ref).max() / np.abs(ref).max()
    assert err < 1e-3


@pytest.mark.parametrize("where", [0, 4, 10, 19])  # groups 0, 1, 3, 6 of 3 rows
def test_not_positive_definite_is_flagged_per_element(where):
    """A negative block anywhere (an even group of the first level or an odd one reduced
    later) flags its own batch element only; the other's solution stays exact."""
    gen = torch.Generator().manual_seed(5)
    band, dense = _gauss_newton(gen, (2,), 20, 4)
    band[1, where, 0] = -band[1, where, 0]
    chol = BandedCholesky(band)
    assert chol.ok.tolist() == [True, False]
    rhs = torch.randn(2, 20, 6, 1, generator=gen, dtype=F64)
    ref = _scipy_solve(dense[0].numpy(), rhs[0].reshape(-1, 1).numpy(), 4)
    err = np.abs(chol.solve(rhs)[0].reshape(-1, 1).numpy() - ref).max() / np.abs(ref).max()
    assert err < 1e-9


@pytest.mark.parametrize(("n", "w"), [(1, 1), (7, 2), (25, 4), (40, 3)])
def test_a_diagonal_shift_is_factored_without_copying_the_band(n, w):
    """``BandedCholesky(band, shift)`` solves with ``A + diag(shift)`` (scipy on the shifted
    dense matrix, padding rows included), the band left unchanged."""
    gen = torch.Generator().manual_seed(n * 10 + w)
    band, dense = _gauss_newton(gen, (2,), n, w)
    shift = torch.rand(2, n, 6, generator=gen, dtype=F64) * dense.diagonal(
        dim1=-2, dim2=-1).reshape(2, n, 6)
    before = band.clone()
    rhs = torch.randn(2, n, 6, 3, generator=gen, dtype=F64)
    x = BandedCholesky(band, shift=shift).solve(rhs)
    torch.testing.assert_close(band, before, rtol=0, atol=0)
    for b in range(2):
        shifted = dense[b].numpy() + np.diag(shift[b].reshape(-1).numpy())
        ref = _scipy_solve(shifted, rhs[b].reshape(n * 6, 3).numpy(), w)
        np.testing.assert_allclose(x[b].reshape(n * 6, 3).numpy(), ref, rtol=1e-8,
                                   atol=1e-8 * np.abs(ref).max())

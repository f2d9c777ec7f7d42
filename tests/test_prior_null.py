"""The combinations of control points that no sample determines (``fitting._prior``): found
by subspace iteration, or certified absent by one factorisation, against numpy's dense
generalised eigen-decomposition of the same band."""

import numpy as np
import pytest
import torch

from torch_dq.fitting import _prior

N, W = 8, 4  # control points, band width (blocks)


def _band(M: np.ndarray) -> torch.Tensor:
    """``(1, N, W, 6, 6)`` upper band of the dense ``(6 N, 6 N)`` matrix ``M``."""
    band = np.zeros((1, N, W, 6, 6))
    for k in range(N):
        for d in range(min(W, N - k)):
            band[0, k, d] = M[6 * k:6 * k + 6, 6 * (k + d):6 * (k + d) + 6]
    return torch.from_numpy(band)


def _windowed(rows_per_window: int, seed: int) -> np.ndarray:
    """``J^T J`` of random rows, each touching the ``W`` control points of one window."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in range(N - W + 1):
        J = np.zeros((rows_per_window, 6 * N))
        J[:, 6 * f:6 * (f + W)] = rng.standard_normal((rows_per_window, 6 * W))
        rows.append(J)
    J = np.concatenate(rows)
    return J.T @ J


def _generalised(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and vectors of the pencil ``(M, D)``, ``D`` the diagonal as the module
    floors it."""
    d = np.diag(M) + 1e-12 * np.diag(M).max()
    s = 1 / np.sqrt(d)
    lam, V = np.linalg.eigh(M * s[:, None] * s[None, :])
    return lam, V * s[:, None]


def test_full_rank_band_is_certified_without_null_combinations():
    M = _windowed(30, 0)  # 5 windows x 30 rows = 150 >= 48 unknowns
    lam, _ = _generalised(M)
    assert lam.min() > 1e3 * _prior.NULL  # the reference: no direction without information
    U, DU = _prior.control_null(_prior.Regularised(_band(M), torch.zeros(1, N, W, 6, 6)))
    assert U.shape == (1, N, 6, 0) and DU.shape == (1, N, 6, 0)


@pytest.mark.parametrize("rows", [8, 9])  # null dimensions 8 and 3 (at most _NULL_RANK)
def test_rank_deficient_band_gives_its_null_space(rows):
    M = _windowed(rows, 1)  # 5 windows x rows < 48 unknowns: combinations across blocks
    lam, V = _generalised(M)
    null = V[:, lam <= _prior.NULL]
    assert null.shape[1] == 6 * N - 5 * rows  # the reference's count (rank of J)
    U, DU = _prior.control_null(_prior.Regularised(_band(M), torch.zeros(1, N, W, 6, 6)))
    U = U.reshape(6 * N, -1).numpy()
    assert U.shape[1] == null.shape[1]
    # the same subspace: U D-orthonormal, each column in span(null) and M U ~ 0
    D = np.diag(M) + 1e-12 * np.diag(M).max()
    np.testing.assert_allclose(U.T @ (D[:, None] * U), np.eye(U.shape[1]), atol=1e-8)
    P = null @ np.linalg.lstsq(null, U, rcond=None)[0]
    np.testing.assert_allclose(P, U, atol=1e-7 * np.abs(U).max())
    assert np.abs(M @ U).max() <= 1e-7 * np.abs(M).max() * np.abs(U).max()
    np.testing.assert_allclose(DU.reshape(6 * N, -1).numpy(), D[:, None] * U, rtol=1e-12)

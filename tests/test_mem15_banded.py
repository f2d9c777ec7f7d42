"""torch_dq.fitting._banded after session 15's memory work: the selected inverse written
into place a chunk of groups at a time (no padded copies, no interleaving) and the traces'
low-rank update added a chunk of groups at a time, against numpy's dense inverse in float64;
chunks of one and two groups cross every chunk boundary, odd and even group counts reach
both ends."""

import numpy as np
import pytest
import torch

from torch_dq.fitting import _banded
from torch_dq.fitting._banded import BandedCholesky

S = 6


def _problem(rng, n, w, batch=2):
    """A Gauss-Newton-like ``A`` (banded, SPD), a symmetric banded ``M`` and a symmetric
    update ``U V^T``, dense, and the bands of ``A`` and ``M``."""
    block = np.arange(n * S) // S
    near = np.abs(block[:, None] - block[None, :]) < w
    J = rng.standard_normal((batch, 3 * n * S, n * S))
    A = (J.transpose(0, 2, 1) @ J) * near + 5 * np.eye(n * S)
    M = rng.standard_normal((batch, n * S, n * S))
    M = (M + M.transpose(0, 2, 1)) * near
    U = rng.standard_normal((batch, n * S, 3))
    H = rng.standard_normal((batch, 3, 3))
    V = U @ (H + H.transpose(0, 2, 1))

    def band(X):
        b = np.zeros((batch, n, w, S, S))
        for k in range(n):
            for d in range(min(w, n - k)):
                b[:, k, d] = X[:, k * S:(k + 1) * S, (k + d) * S:(k + d + 1) * S]
        return torch.from_numpy(b)

    return A, M, U, V, band(A), band(M)


@pytest.mark.parametrize("chunk", [1, 2, 4096])
@pytest.mark.parametrize(("n", "w"), [(9, 4), (12, 4), (13, 3), (2, 4), (6, 2)])
def test_trace_products_in_chunks_match_numpy(monkeypatch, chunk, n, w):
    """trace(M (A^-1 + U V^T)) for every chunk size of the update (G odd and even)."""
    monkeypatch.setattr(_banded, "_CHUNK", chunk)
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")  # the cyclic reduction's chunks
    rng = np.random.default_rng(7 * n + w)
    A, M, U, V, bA, bM = _problem(rng, n, w)
    chol = BandedCholesky(bA)
    up, plain = chol.trace_products(
        [bM, bM], *(torch.from_numpy(x.reshape(2, n, S, 3)) for x in (U, V)))
    inv = np.linalg.inv(A)
    ref = np.einsum("bij,bji->b", M, inv + U @ V.transpose(0, 2, 1))
    np.testing.assert_allclose(up.numpy(), ref, rtol=1e-10)
    np.testing.assert_allclose(plain.numpy(), ref, rtol=1e-10)
    alone, = chol.trace_products([bM])
    np.testing.assert_allclose(alone.numpy(), np.einsum("bij,bji->b", M, inv), rtol=1e-10)


@pytest.mark.parametrize("chunk", [1, 2, 4096])
@pytest.mark.parametrize(("n", "w"), [(3, 4), (9, 4), (12, 4), (15, 4), (14, 3), (5, 2)])
def test_selected_inverse_blocks_match_numpy(monkeypatch, chunk, n, w):
    """The grouped diagonal and sub-diagonal blocks of A^-1 (groups of g = w - 1 block
    rows; the rows past n and the last sub-diagonal block left out) against numpy, the
    even groups of a level ``chunk`` at a time."""
    monkeypatch.setattr(_banded, "_CHUNK", chunk)
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")  # the cyclic reduction's chunks
    rng = np.random.default_rng(n + 100 * w)
    A, *_, bA, _ = _problem(rng, n, w)
    chol = BandedCholesky(bA)
    diag, sub = (x.numpy() for x in chol.selected_inverse())
    inv = np.linalg.inv(A)
    b = max(w - 1, 1) * S
    G = diag.shape[1]
    assert G == -(-n // max(w - 1, 1)) and sub.shape == diag.shape
    for j in range(G):
        rows = slice(j * b, min((j + 1) * b, n * S))
        k = rows.stop - rows.start
        np.testing.assert_allclose(diag[:, j, :k, :k], inv[:, rows, rows], rtol=1e-9,
                                   atol=1e-12)
        if j + 1 < G:
            nxt = slice((j + 1) * b, min((j + 2) * b, n * S))
            m = nxt.stop - nxt.start
            np.testing.assert_allclose(sub[:, j, :m, :k], inv[:, nxt, rows], rtol=1e-9,
                                       atol=1e-12)
    np.testing.assert_array_equal(sub[:, -1], 0.0)

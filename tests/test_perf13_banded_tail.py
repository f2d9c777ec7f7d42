"""``BandedCholesky`` of a band whose rows are not a multiple of the grouping (identity rows
padded in ``_banded._grouped``, no copy of the band) with garbage in the blocks past the
last row: solves and the selected inverse against numpy's dense ones."""

import numpy as np
import pytest
import torch

from torch_dq.fitting import _banded


def _dense(band: np.ndarray) -> np.ndarray:
    n, w, s, _ = band.shape
    M = np.zeros((n * s, n * s))
    for k in range(n):
        for d in range(min(w, n - k)):
            M[s * k:s * k + s, s * (k + d):s * (k + d) + s] = band[k, d]
            M[s * (k + d):s * (k + d) + s, s * k:s * k + s] = band[k, d].T
    return M


@pytest.mark.parametrize(("n", "w"), [(7, 4), (8, 4), (2, 4), (5, 3), (4, 1)])
def test_tail_rows_and_garbage_past_the_band(n, w):
    rng = np.random.default_rng(n * 10 + w)
    s = 2
    band = 0.1 * rng.standard_normal((n, w, s, s))
    band[:, 0] = band[:, 0] + band[:, 0].transpose(0, 2, 1) + 4.0 * w * np.eye(s)
    M = _dense(band)  # reads no block past the last row
    for k in range(n):
        band[k, n - k:] = 1e6 * rng.standard_normal((max(w - n + k, 0), s, s))
    shift = rng.uniform(0.0, 1.0, (n, s))
    M = M + np.diag(shift.reshape(-1))
    rhs = rng.standard_normal((n, s, 3))
    F = _banded.BandedCholesky(torch.from_numpy(band), torch.from_numpy(shift))
    assert bool(F.ok)
    x = F.solve(torch.from_numpy(rhs)).numpy()
    np.testing.assert_allclose(x.reshape(n * s, 3), np.linalg.solve(M, rhs.reshape(n * s, 3)),
                               rtol=1e-10, atol=1e-12)
    cov = F.window_covariance(torch.arange(n), 1).numpy()  # the diagonal blocks
    inv = np.linalg.inv(M)
    for k in range(n):
        np.testing.assert_allclose(cov[k], inv[s * k:s * k + s, s * k:s * k + s], rtol=1e-10,
                                   atol=1e-12)

"""``_prior.control_pull`` (its windows written from the scaled band) against a dense numpy
reference: every window a principal submatrix of the full matrix, numpy's eigenvectors."""

import numpy as np
import pytest
import torch

from torch_dq.fitting import _prior


def _dense(band: np.ndarray, extra: int) -> np.ndarray:
    """The full symmetric matrix of ``band (n, w, 6, 6)`` with ``extra`` identity blocks."""
    n, w = band.shape[:2]
    M = np.zeros((6 * (n + extra), 6 * (n + extra)))
    for k in range(n):
        for d in range(min(w, n - k)):
            M[6 * k:6 * k + 6, 6 * (k + d):6 * (k + d) + 6] = band[k, d]
            if d:
                M[6 * (k + d):6 * (k + d) + 6, 6 * k:6 * k + 6] = band[k, d].T
    M[6 * n:, 6 * n:] = np.eye(6 * extra)
    return M


def _reference(band: np.ndarray, prior: float, nuisance: bool) -> np.ndarray:
    n, w = band.shape[:2]
    v = min(w, 4)
    threshold = min(prior, _prior.SPARSE) if nuisance else prior
    d = np.einsum("nii->ni", band[:, 0])
    used = d.sum(-1) > 0
    med = np.sort(d[used], axis=0)[(used.sum() - 1) // 2]
    s = np.tile(np.sqrt(np.maximum(np.clip(med, 0.0, None), 1e-12 * med.max())), v)
    M = _dense(band, v)
    P = np.zeros_like(M)
    for k in range(n):
        A = M[6 * k:6 * (k + v), 6 * k:6 * (k + v)] / np.outer(s, s)
        lam, V = np.linalg.eigh(A)
        cut = max(threshold * min(max(lam[-1], 0.0), 1.0), _prior.NULL) if nuisance else threshold
        P[6 * k:6 * (k + v), 6 * k:6 * (k + v)] += (V * np.where(lam < cut, prior, 0.0)) @ V.T \
            * np.outer(s, s)
    out = np.zeros_like(band)
    for k in range(n):
        for dd in range(min(w, n - k)):
            out[k, dd] = P[6 * k:6 * k + 6, 6 * (k + dd):6 * (k + dd) + 6]
    return out


@pytest.mark.parametrize("w", [1, 2, 4, 5])
@pytest.mark.parametrize("nuisance", [True, False])
def test_pull_matches_dense_numpy(w, nuisance):
    rng = np.random.default_rng(w)
    n = 23
    J = rng.standard_normal((40 * n, 6 * n)) * (np.arange(6 * n) // 6 < 6 * n - 6 * w)
    for k in range(n):  # rows touching up to w consecutive control points
        J[40 * k:40 * k + 40, :6 * k] = 0.0
        J[40 * k:40 * k + 40, 6 * (k + w):] = 0.0
    J[:, 6 * 9:6 * 11] *= 1e-6  # weakly determined (below SPARSE)
    J[:, 6 * 15 + 2] = 0.0  # a coordinate without information
    M = J.T @ J
    band = np.zeros((n, w, 6, 6))
    for k in range(n):
        for d in range(min(w, n - k)):
            band[k, d] = M[6 * k:6 * k + 6, 6 * (k + d):6 * (k + d) + 6]
    for prior in (2.0 ** -20, 2.0 ** -7):  # exact in float32 (the weight is rounded to it)
        ref = _reference(band, prior, nuisance)
        got = _prior.control_pull(torch.from_numpy(band)[None], prior, nuisance)[0].numpy()
        assert np.abs(ref).max() > 0
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-8 * np.abs(ref).max())

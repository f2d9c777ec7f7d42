"""``_prior.undetermined`` (its blocks screened by a Cholesky factorisation) against numpy's
eigenvalues of every scaled diagonal block."""

import numpy as np
import torch

from torch_dq.fitting import _prior


def _reference(band: np.ndarray) -> np.ndarray:
    """Count of scaled eigenvalues <= NULL per batch element, every block's eigenvalues."""
    out = []
    for blocks in band[:, :, 0]:
        d = np.einsum("nii->ni", blocks)
        used = d.sum(-1) > 0
        vals = np.sort(d[used], axis=0)
        med = vals[(len(vals) - 1) // 2]  # the lower median (torch's nanmedian)
        med = np.maximum(np.clip(med, 0.0, None), 1e-12 * med.max())
        s = np.sqrt(med)
        lam = np.linalg.eigvalsh(blocks / np.outer(s, s))
        out.append(int((lam <= _prior.NULL).sum()))
    return np.array(out)


def _block(rng: np.random.Generator, eig: np.ndarray) -> np.ndarray:
    q, _ = np.linalg.qr(rng.standard_normal((6, 6)))
    return (q * eig) @ q.T


def _band(seed: int, Bf: int = 3, n: int = 41, w: int = 4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    band = np.zeros((Bf, n, w, 6, 6))
    for b in range(Bf):
        scale = np.exp(rng.uniform(-3.0, 3.0, 6))  # per coordinate, like rotation/translation
        for k in range(n):
            kind = rng.integers(6)
            eig = np.exp(rng.uniform(-2.0, 2.0, 6))
            if kind == 0:
                eig[: rng.integers(1, 4)] = 0.0  # directions without information
            elif kind == 1:
                eig[0] = 3e-10  # below NULL, screened out by the factorisation
            elif kind == 2:
                eig[0] = 1.5e-9  # above NULL, yet the screen (2 NULL) fails: eigenvalues decide
            elif kind == 3 and k % 7 == 0:
                eig[:] = 0.0  # a time gap
            elif kind == 4:
                eig[-1] = 3e4  # a trace past _SCREENED: eigenvalues decide
            band[b, k, 0] = _block(rng, eig) * np.sqrt(np.outer(scale, scale))
            for d in range(1, w):
                band[b, k, d] = 1e-3 * rng.standard_normal((6, 6))
    return band


def test_counts_match_numpy_eigenvalues():
    for seed in range(6):
        band = _band(seed)
        got = _prior.undetermined(torch.from_numpy(band))
        assert got.dtype == torch.long
        np.testing.assert_array_equal(got.numpy(), _reference(band))


def test_counts_without_any_weak_block_and_with_every_block_null():
    rng = np.random.default_rng(7)
    band = np.zeros((2, 9, 3, 6, 6))
    for k in range(9):
        band[0, k, 0] = _block(rng, np.exp(rng.uniform(-1.0, 1.0, 6)))
    band[1, :, 0] = np.eye(6)
    band[1, 4, 0] = 0.0  # one gap: six directions
    band[1, 5, 0] = _block(rng, np.array([0.0, 0.0, 1.0, 1.0, 2.0, 1e5]))
    got = _prior.undetermined(torch.from_numpy(band)).numpy()
    np.testing.assert_array_equal(got, _reference(band))
    assert got.tolist() == [0, 8]

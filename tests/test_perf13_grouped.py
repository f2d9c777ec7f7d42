"""``_banded._grouped`` (blocks written once into place) against the dense matrix's blocks."""

import numpy as np
import pytest
import torch

from torch_dq.fitting import _banded


@pytest.mark.parametrize("w", [1, 2, 3, 4, 6])
def test_grouped_blocks_are_the_dense_matrix_blocks(w):
    rng = np.random.default_rng(w)
    g, s, G = max(w - 1, 1), 6, 5
    n = G * g
    band = rng.standard_normal((2, n, w, s, s))
    for b in range(2):
        M = np.zeros((n * s, n * s))
        for k in range(n):
            for d in range(min(w, n - k)):
                M[s * k:s * k + s, s * (k + d):s * (k + d) + s] = band[b, k, d]
                if d:
                    M[s * (k + d):s * (k + d) + s, s * k:s * k + s] = band[b, k, d].T
        D, E = (_banded._grouped(torch.from_numpy(band), g, below)[b].numpy()
                for below in (False, True))
        m = g * s
        for j in range(G):
            np.testing.assert_array_equal(D[j], M[m * j:m * j + m, m * j:m * j + m])
            ref = np.zeros((m, m)) if j == 0 else M[m * j:m * j + m, m * (j - 1):m * j]
            np.testing.assert_array_equal(E[j], ref)

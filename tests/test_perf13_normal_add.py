"""``_normal._Normal.add`` (consecutive windows: slices added in the scatter's order; else
the scatter) against a numpy loop over the windows' blocks."""

import numpy as np
import pytest
import torch

from torch_dq.fitting._normal import _Normal


def _reference(n, w, m, windows, block, gcols):
    band = np.zeros((n + w, w, 6, 6))
    gc = np.zeros((n + w, 6))
    cn = np.zeros((n + w, 6, m))
    nn = np.zeros((m, m))
    gn = np.zeros(m)
    M = gcols.shape[1]
    for u, f in enumerate(windows):
        B = block[u]
        for a in range(w):
            for d in range(w - a):
                band[f + a, d] += B[6 * a:6 * a + 6, 6 * (a + d):6 * (a + d) + 6]
            gc[f + a] += B[6 * a:6 * a + 6, -1]
            for j in range(M):
                cn[f + a, :, gcols[u, j]] += B[6 * a:6 * a + 6, 6 * w + j]
        for i in range(M):
            gn[gcols[u, i]] += B[6 * w + i, -1]
            for j in range(M):
                nn[gcols[u, i], gcols[u, j]] += B[6 * w + i, 6 * w + j]
    return band[:n], gc[:n], cn[:n], nn, gn


@pytest.mark.parametrize(("windows", "cols"), [
    ([3, 4, 5, 6, 7], [[1, 2]] * 5),             # consecutive, the same consecutive columns
    ([3, 4, 5, 6, 7], [[0, 2]] * 5),             # consecutive, columns with a gap
    ([2, 3, 4], [[1, 2], [0, 3], [1, 2]]),        # consecutive, columns per window
    ([1, 4, 5], [[1, 2]] * 3),                   # a gap between windows
    ([0, 1, 2, 3, 4, 5, 6, 7], [[]] * 8),         # no nuisance columns
])
def test_add_matches_a_loop_over_the_windows(windows, cols):
    rng = np.random.default_rng(len(windows))
    n, w, m = 10, 3, 4
    gcols = np.array(cols, dtype=np.int64).reshape(len(windows), -1)
    q = 6 * w + gcols.shape[1] + 1
    block = rng.standard_normal((len(windows), q, q))
    acc = _Normal(torch.zeros(1, dtype=torch.float64), 1, n, w, m)
    for _ in range(2):  # twice: the second adds to what the first left
        acc.add(torch.tensor(windows), torch.from_numpy(block), torch.from_numpy(gcols))
    s = acc.system([], [])
    ref = _reference(n, w, m, windows, 2 * block, gcols)
    for got, want in zip((s.band[0], s.gc[0], s.cn[0], s.nn[0], s.gn[0]), ref, strict=True):
        np.testing.assert_allclose(got.numpy(), want, rtol=1e-13, atol=1e-13)

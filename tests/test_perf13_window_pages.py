"""``_normal._window_normal`` where every window fits one page (its products returned as
they are, no sum of pages), with and without padding slots, against numpy sums."""

import numpy as np
import pytest
import torch

from torch_dq.fitting._normal import _window_normal


@pytest.mark.parametrize("counts", [[3, 3, 3, 3], [3, 1, 2, 3], [1]])
def test_one_page_per_window(counts):
    rng = np.random.default_rng(len(counts) + sum(counts))
    keys = np.concatenate([np.full(c, 5 * k + 2) for k, c in enumerate(counts)])
    keys = rng.permutation(keys)
    Y = rng.standard_normal((keys.size, 2, 4))
    win, block = _window_normal(torch.from_numpy(keys), torch.from_numpy(Y))
    ref = {k: sum(Y[i].T @ Y[i] for i in np.flatnonzero(keys == k)) for k in np.unique(keys)}
    assert win.tolist() == sorted(ref)
    for u, k in enumerate(win.tolist()):
        np.testing.assert_allclose(block[u].numpy(), ref[k], rtol=1e-13, atol=1e-13)

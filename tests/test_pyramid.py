"""Memory of the fused De Casteljau / De Boor scheme (:mod:`torch_dq._kernels.pyramid`).

The eager op promises memory O(output): its backward recomputes the levels chunk by chunk,
so autograd keeps nothing but its inputs. The saved tensors are counted with
``torch.autograd.graph.saved_tensors_hooks`` around one call of the op.
"""

import pytest
import torch
from strategies import unit_dq

from torch_dq import curves
from torch_dq._kernels.pyramid import pyramid


def _saved_bytes(fn):
    """Bytes of the tensors autograd saves while ``fn()`` runs, and its result."""
    sizes = []

    def pack(x):
        sizes.append(x.numel() * x.element_size())
        return x

    with torch.autograd.graph.saved_tensors_hooks(pack, lambda x: x):
        out = fn()
    return sum(sizes), out


@pytest.mark.parametrize("T", [100, 20000])  # one chunk, and several (PYRAMID_CHUNK = 8192)
def test_de_boor_op_saves_only_its_inputs(gen, T):
    """Cubic De Boor (m = 4) on 9 control points: the saved bytes are exactly the inputs'
    (control points, first indices, the 6 parameter rows), under the output's 8 floats per
    time: no level (3 + 2 + 1 points of 8 floats per time) is kept."""
    m, M = 4, 9
    ctrl = unit_dq((M,), gen).requires_grad_()
    first = torch.randint(0, M - m + 1, (T,), generator=gen)
    idx = first + torch.arange(m)[:, None]
    alphas = [torch.rand(m - j, T, generator=gen, dtype=torch.float64).requires_grad_()
              for j in range(1, m)]
    saved, out = _saved_bytes(lambda: pyramid(ctrl, idx, alphas))
    inputs = ctrl.nbytes + first.nbytes + sum(a.nbytes for a in alphas)
    assert saved == inputs
    assert saved - ctrl.nbytes < out.nbytes  # 56 B per time (int64 index, 6 float64) < 64 B
    # the backward runs from those alone
    grads = torch.autograd.grad(out.sum(), (ctrl, *alphas))
    assert all(torch.isfinite(g).all() for g in grads)


@pytest.mark.parametrize("degree", [1, 3])
def test_backward_under_vmap(gen, degree):
    """``jacobian(vectorize=True)`` runs the op's backward under ``vmap`` (the forward took the
    fused path): it equals the row-by-row jacobian, for the control points and the times."""
    ctrl = unit_dq((6,), gen)
    t = torch.tensor([0.0, 0.2, 0.5, 0.9], dtype=torch.float64)

    def f(c, t):
        return curves.bspline(c, t, degree=degree, check=False)

    vec = torch.autograd.functional.jacobian(f, (ctrl, t), vectorize=True)
    loop = torch.autograd.functional.jacobian(f, (ctrl, t))
    for v, e in zip(vec, loop, strict=True):
        assert e.abs().max() > 0.1
        assert (v - e).abs().max() <= 1e-12 * e.abs().max()

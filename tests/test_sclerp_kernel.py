"""The fused eq. 11 kernel (``torch_dq._kernels.sclerp``) over several chunks, against
independent references: pytransform3d's ``dual_quaternions_sclerp`` (numpy, float64) for the
values, central differences (``gradcheck``, ``gradgradcheck``) for the first and second
derivatives, and the per-row loop of ``torch.autograd.grad`` for the backward under vmap.

Pairs: random, equal, pure translations (same rotation), an exact half turn (orthogonal
real parts, a tie of the shortest path), tiny relative rotations with large translations;
``t`` inside and outside ``[0, 1]`` and exactly at the ends.
"""

from __future__ import annotations

import pytest
import pytransform3d.trajectories as ptr
import torch
from strategies import screw, unit_dq

import torch_dq.dualquat as dq
from torch_dq._kernels import layout
from torch_dq._kernels import sclerp as kernel

F64 = torch.float64


@pytest.fixture
def small_chunks(monkeypatch):
    """Chunks of 5 pairs, so that every test below runs several (and a ragged last one)."""
    monkeypatch.setattr(layout, "CHUNK", 5)


def pairs(gen, n=4):
    """``(a, b, t)`` float64, ``b`` on the shortest path from ``a`` (real parts' dot >= 0):
    ``n`` pairs of each kind (module docstring), ``t`` in ``[-0.5, 1.5]`` with ends."""
    a = unit_dq((5, n), gen)
    b = unit_dq((n,), gen)
    rot = a[1, :, :4]
    pure = dq.from_rt(rot, 3.0 * torch.randn(n, 3, generator=gen, dtype=F64))
    x = torch.tensor([0.0, 0.6, 0.8, 0.0], dtype=F64)  # half turn from the identity about x
    one = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64)
    half = dq.from_rt(one.expand(n, 4), torch.randn(n, 3, generator=gen, dtype=F64))
    turned = dq.from_rt(x.expand(n, 4), torch.randn(n, 3, generator=gen, dtype=F64))
    axis, moment, theta, d = screw((n,), gen, 1e-7, 50.0)
    tiny = dq.mul(a[4], dq.from_screw(axis, moment, theta, d))
    a = torch.cat((a[0], a[1], half, a[3], a[4]))
    b = torch.cat((b, pure, turned, a[3 * n:4 * n], tiny))
    b = torch.where(((a[:, :4] * b[:, :4]).sum(-1) < 0)[:, None], -b, b)
    t = 2.0 * torch.rand(len(a), generator=gen, dtype=F64) - 0.5
    t[::7], t[3::7] = 0.0, 1.0
    return a, b, t


def reference(a, b, t):
    """pytransform3d's screw interpolation of the same pairs, float64."""
    return torch.from_numpy(ptr.dual_quaternions_sclerp(a.numpy(), b.numpy(), t.numpy()))


def test_values_against_pytransform3d(gen, small_chunks):
    a, b, t = pairs(gen)
    ref = reference(a, b, t)
    scale = ref.abs().amax(-1, keepdim=True).clamp(min=1.0)
    # the kernel must undo these signs itself (not at the half turn's tie: there the sign of
    # the zero dot picks one of the two equally short paths)
    flip = (torch.arange(len(a)) % 2 == 1) & ((a[:, :4] * b[:, :4]).sum(-1) != 0)
    b_flipped = torch.where(flip[:, None], -b, b)
    for out in (kernel.sclerp(a, b_flipped, t, True), kernel.sclerp(a, b, t, False)):
        assert ((out - ref).abs() / scale).max() <= 64 * torch.finfo(F64).eps
    out32 = kernel.sclerp(a.float(), b_flipped.float(), t.float(), True).double()
    assert ((out32 - ref).abs() / scale).max() <= 2e-5  # float32 rounding of 8-byte inputs


def test_ends_are_exact(gen, small_chunks):
    a, b, _ = pairs(gen)
    for t, end in ((0.0, a), (1.0, b)):
        out = kernel.sclerp(a, b, torch.full((len(a),), t, dtype=F64), True)
        assert (out - end).abs().max() <= 4 * torch.finfo(F64).eps


def test_first_and_second_derivatives(gen, small_chunks):
    """The analytic backward (the path from ``a`` to ``b`` as given: the sign choice is not
    differentiable at the half turn's tie) against central differences, at every kind of
    pair; double backward on the degenerate kinds."""
    a, b, t = pairs(gen, n=2)

    def f(x, y, z):
        return kernel.sclerp(x, y, z, False)

    xs = [x.clone().requires_grad_() for x in (a, b, t)]
    assert torch.autograd.gradcheck(f, xs)
    assert torch.autograd.gradgradcheck(f, [x[2:8].detach().requires_grad_() for x in xs])


def test_backward_under_vmap(gen, small_chunks):
    """A batch of cotangents (the backward run under vmap, as ``jacobian(vectorize=True)``
    does) gives the per-row gradients of the loop."""
    a, b, t = pairs(gen, n=2)
    xs = [x.clone().requires_grad_() for x in (a, b, t)]
    out = kernel.sclerp(*xs, True)
    ws = torch.randn(3, *out.shape, generator=gen, dtype=F64)
    batched = torch.autograd.grad(out, xs, ws, retain_graph=True, is_grads_batched=True)
    for k, w in enumerate(ws):
        for g, r in zip(batched, torch.autograd.grad(out, xs, w, retain_graph=True),
                        strict=True):
            assert torch.allclose(g[k], r, rtol=0.0, atol=1e-15)

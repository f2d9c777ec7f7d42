"""``torch.compile`` (the default inductor backend) of the De Boor scheme in float32: its
backward gave gradients 25 % off (torch 2.13, CPU; float64, ``aot_eager`` and eager exact),
so compiled float32 pyramids run in float64. Reference: eager float64 gradients of the
same function (central differences of the public ``bspline`` agree with them elsewhere)."""

import pytest
import torch

import torch_dq.dualquat as dq
import torch_dq.quat as Q
from torch_dq import curves

pytest.importorskip("torch._inductor")


def test_compiled_float32_de_boor_gradient_matches_float64():
    gen = torch.Generator().manual_seed(0)
    W = torch.randn(8, generator=gen)
    ctrl = dq.from_rt(Q.from_rotvec(0.3 * torch.randn(8, 3, generator=gen)),
                      torch.randn(8, 3, generator=gen))
    tt = torch.linspace(0.0, 1.0, 50)

    def f(c):
        return (curves.bspline(c, tt, degree=3) * W.to(c.dtype)).sum()

    c64 = ctrl.double().requires_grad_()
    (ref,) = torch.autograd.grad(f(c64), c64)
    c32 = ctrl.clone().requires_grad_()
    (got,) = torch.autograd.grad(torch.compile(f, fullgraph=True)(c32), c32)
    assert got.dtype == torch.float32
    torch.testing.assert_close(got.double(), ref, rtol=1e-4, atol=1e-4 * float(ref.abs().max()))

"""float32 accuracy: every row of the registry (``registry.OPS``) against its float32 bound,
and the further distributions the README's "Numerical guarantees" float32 column quotes.

Each figure is the largest error of a float32 evaluation against the float64 evaluation of
the same float32-rounded inputs (so only the arithmetic is measured, not the rounding of the
inputs), relative to ``max(1, |value|)`` (the absolute error for outputs of unit scale).
Quaternion and dual quaternion outputs are compared up to their sign, angles modulo 2 pi.
The bounds (``Op.f32``) are the measured maxima (torch 2.13 CPU) with a margin of about 1.5x.

Distributions: the registry's sampler (``registry.KINDS``), 2e5 elements per row (2e3
control polygons for the curve rows): uniform random rotations, poses with Gaussian
translations (sigma 1), ``t`` uniform in [0, 1]. The README's further rows:
- ``rotate``: vectors uniform in the ball of radius 5;
- ``sclerp``: ``t`` extrapolated to [-0.7, 1.7], and near-degenerate pairs ``b = a exp(xi)``
  with ``|xi| ~ 10^-k``, ``k`` uniform in 2..9;
- ``to_euler`` / ``from_euler``: all 24 sequences;
- curves: 200 random 8-point control polygons (a random walk of twists with rotation steps
  of ~0.5 rad), 257 times in [0, 1], translations of scale 1 and 10.
"""

import math

import pytest
import torch
from registry import OPS, outs, sample_args

import torch_dq.dualquat as dq
from torch_dq import curves, quat

F64 = torch.float64
N = 200_000
SEQS = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b != c]
BOUNDED = [op for op in OPS if op.f32 is not None]


def _rounded(x):
    return x.float().double()


def _err(f, *args, signed=False, periodic=False):
    """Max error of f in float32 against f in float64 on the same inputs, relative to
    ``max(1, |ref|)``; ``signed``: (dual) quaternions compared up to their sign;
    ``periodic``: angles compared modulo 2 pi."""
    err = 0.0
    for out, ref in zip(outs(f(*(a.float() for a in args))), outs(f(*args)), strict=True):
        assert out.dtype == torch.float32
        out = out.double()
        if signed:
            flip = (out[..., :4] * ref[..., :4]).sum(-1, keepdim=True) < 0
            out = torch.where(flip, -out, out)
        d = (out - ref).abs()
        if periodic:
            d = torch.minimum(d, 2 * math.pi - d)
        err = max(err, (d / ref.abs().clamp(min=1.0)).max().item())
    return err


@pytest.mark.parametrize("op", BOUNDED, ids=[op.id for op in BOUNDED])
def test_registry_float32_bound(op):
    gen = torch.Generator().manual_seed(20261123)
    args = [_rounded(a) for a in sample_args(op, (N // 100 if op.curve else N,), gen)]
    err = _err(op.fn, *args, signed=op.signed or op.curve, periodic=op.periodic)
    assert err <= op.f32, (op.id, err)


def test_rotate_in_the_ball_of_radius_5():
    """Measured 1.5e-6 (absolute; 2.9e-7 relative to |v| <= 5)."""
    gen = torch.Generator().manual_seed(20261123)
    q = _rounded(quat.normalize(torch.randn(N, 4, generator=gen, dtype=F64)))
    v = torch.randn(N, 3, generator=gen, dtype=F64)
    r = 5 * torch.rand(N, 1, generator=gen, dtype=F64) ** (1 / 3)
    v = _rounded(v / v.norm(dim=-1, keepdim=True) * r)
    ref = quat.rotate(q, v)
    assert (quat.rotate(q.float(), v.float()).double() - ref).abs().max() < 2.2e-6


def test_euler_all_sequences():
    """All 24 sequences, both ways (measured: to_euler 6.9e-7, from_euler 1.8e-7)."""
    gen = torch.Generator().manual_seed(20261123)
    q = _rounded(quat.normalize(torch.randn(N // 4, 4, generator=gen, dtype=F64)))
    for seq in SEQS + [s.upper() for s in SEQS]:
        angles = _rounded(quat.to_euler(q, seq))
        assert _err(lambda a, seq=seq: quat.from_euler(a, seq), angles, signed=True) < 3e-7
        assert _err(lambda x, seq=seq: quat.to_euler(x, seq), q, periodic=True) < 1e-6, seq


def _poses(gen, n=N, scale=1.0):
    q = torch.randn(n, 4, generator=gen, dtype=F64)
    t = torch.randn(n, 3, generator=gen, dtype=F64) * scale
    return _rounded(dq.from_rt(q / q.norm(dim=-1, keepdim=True), t))


def test_sclerp_extrapolated_and_near_degenerate():
    gen = torch.Generator().manual_seed(2)
    a, b = _poses(gen), _poses(gen)
    t = _rounded(torch.rand(N, generator=gen, dtype=F64))
    t_out = _rounded(torch.rand(N, generator=gen, dtype=F64) * 2.4 - 0.7)
    k = torch.randint(2, 10, (N, 1), generator=gen).double()
    xi = torch.randn(N, 6, generator=gen, dtype=F64) * 10.0 ** -k
    near = _rounded(dq.mul(a, dq.exp(xi)))
    errs = {
        "t in [-0.7, 1.7]": (_err(dq.sclerp, a, b, t_out, signed=True), 1.5e-6),  # 1.0e-6
        "near-degenerate": (_err(dq.sclerp, a, near, t, signed=True), 4e-7),  # 2.4e-7
    }
    over = {k: v for k, v in errs.items() if not v[0] < v[1]}
    assert not over, over


@pytest.mark.parametrize(("scale", "bound"), [(1.0, 1.5e-6), (10.0, 1.2e-5)])
def test_curves_float32(scale, bound):
    """Smooth random-walk polygons (absolute errors). Measured: bezier 9.1e-7 / bspline
    5.6e-7 at scale 1; 8.5e-6 / 4.8e-6 at scale 10."""
    gen = torch.Generator().manual_seed(3)
    B, n = 200, 8
    q = torch.randn(B, 4, generator=gen, dtype=F64)
    ctrl = [dq.from_rt(q / q.norm(dim=-1, keepdim=True),
                       torch.randn(B, 3, generator=gen, dtype=F64) * scale)]
    step = torch.tensor([0.5] * 3 + [0.5 * scale] * 3, dtype=F64)
    for _ in range(n - 1):
        ctrl.append(dq.mul(ctrl[-1], dq.exp(torch.randn(B, 6, generator=gen, dtype=F64) * step)))
    ctrl = _rounded(torch.stack(ctrl, -2))
    t = _rounded(torch.linspace(0, 1, 257, dtype=F64))
    for f in (curves.bezier, curves.bspline):
        ref = f(ctrl, t)
        out = f(ctrl.float(), t.float()).double()
        flip = (out[..., :4] * ref[..., :4]).sum(-1, keepdim=True) < 0
        err = (torch.where(flip, -out, out) - ref).abs().max().item()
        assert err < bound, (f.__name__, scale, err)

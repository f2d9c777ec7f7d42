"""float32 accuracy: every row of the README's "Numerical guarantees" float32 column.

Each figure is the largest absolute error of a float32 evaluation against the float64
evaluation of the same float32-rounded inputs (so only the arithmetic is measured, not the
rounding of the inputs), over a stated, seeded input distribution. Quaternion and dual
quaternion outputs are compared up to their sign. The bounds below are the measured maxima
(in the comments, torch 2.13 CPU) with a margin of about 1.5x; the README quotes the
measurements.

Distributions:
- rotations: 2e5 uniform random unit quaternions (normalised Gaussian 4-vectors);
- vectors for ``rotate``: uniform in the ball of radius 5;
- poses: uniform rotations with Gaussian translations (sigma 1, so |t| up to ~5);
- ``sclerp``: 2e5 random pairs of such poses, ``t`` uniform in [0, 1], extrapolated
  ``t`` uniform in [-0.7, 1.7], and near-degenerate pairs ``b = a exp(xi)`` with
  ``|xi| ~ 10^-k``, ``k`` uniform in 2..9;
- curves: 200 random 8-point control polygons (a random walk of twists with rotation
  steps of ~0.5 rad), 257 times in [0, 1], translations of scale 1 and 10.
"""

import math

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import curves, quat

F64 = torch.float64
N = 200_000
SEQS = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b != c]


def _rounded(x):
    return x.float().double()


def _unit_quat(gen, n=N):
    q = torch.randn(n, 4, generator=gen, dtype=F64)
    return _rounded(q / q.norm(dim=-1, keepdim=True))


def _poses(gen, n=N, scale=1.0):
    q = torch.randn(n, 4, generator=gen, dtype=F64)
    t = torch.randn(n, 3, generator=gen, dtype=F64) * scale
    return _rounded(dq.from_rt(q / q.norm(dim=-1, keepdim=True), t))


def _err(f, *args, signed=False):
    """Max abs error of f in float32 against f in float64 on the same inputs; with
    ``signed``, the output is a (dual) quaternion compared up to its sign."""
    ref = f(*args)
    out = f(*(a.float() for a in args))
    assert out.dtype == torch.float32
    out = out.double()
    if signed:
        flip = (out[..., :4] * ref[..., :4]).sum(-1, keepdim=True) < 0
        out = torch.where(flip, -out, out)
    return (out - ref).abs().max().item()


@pytest.fixture(scope="module")
def rotations():
    gen = torch.Generator().manual_seed(20261123)
    return _unit_quat(gen), _unit_quat(gen), gen


QUAT_BOUNDS = {  # name: (bound, measured)
    "mul": (2e-7, 1.3e-7),
    "to_matrix": (6e-7, 3.7e-7),
    "from_matrix": (2e-7, 1.3e-7),
    "to_rotvec": (8e-7, 4.9e-7),
    "from_rotvec": (3e-7, 1.9e-7),
    "to_axis_angle": (4e-7, 2.4e-7),
    "log": (8e-7, 5.4e-7),
    "exp": (5e-7, 2.9e-7),
    "slerp": (5e-7, 3.0e-7),
    "from_euler": (3e-7, 1.8e-7),
    "to_euler": (1e-6, 6.9e-7),  # 24 sequences
    "rotate": (2.2e-6, 1.5e-6),  # |v| <= 5: 2.9e-7 relative
}


def test_quat_float32(rotations):
    q, q1, gen = rotations
    t = _rounded(torch.rand(N, generator=gen, dtype=F64))
    v = torch.randn(N, 3, generator=gen, dtype=F64)
    v = _rounded(v / v.norm(dim=-1, keepdim=True) * 5 * torch.rand(N, 1, generator=gen,
                                                                   dtype=F64) ** (1 / 3))
    errs = {
        "mul": _err(quat.mul, q, q1, signed=True),
        "to_matrix": _err(quat.to_matrix, q),
        "from_matrix": _err(quat.from_matrix, _rounded(quat.to_matrix(q)), signed=True),
        "to_rotvec": _err(quat.to_rotvec, q),
        "from_rotvec": _err(quat.from_rotvec, _rounded(quat.to_rotvec(q)), signed=True),
        "to_axis_angle": _err(lambda x: quat.to_axis_angle(x)[1], q),
        "log": _err(quat.log, q),
        "exp": _err(quat.exp, _rounded(quat.log(q)), signed=True),
        "slerp": _err(quat.slerp, q, q1, t, signed=True),
        "rotate": _err(quat.rotate, q, v),
        "from_euler": 0.0,
        "to_euler": 0.0,
    }
    for seq in SEQS + [s.upper() for s in SEQS]:
        errs["from_euler"] = max(errs["from_euler"], _err(
            lambda a, seq=seq: quat.from_euler(a, seq), _rounded(quat.to_euler(q, seq)),
            signed=True))
        # Angles wrap at +-pi: an error of 2 pi - e is an error of e.
        ref, out = quat.to_euler(q, seq), quat.to_euler(q.float(), seq).double()
        d = (out - ref).abs()
        errs["to_euler"] = max(errs["to_euler"], torch.minimum(d, 2 * math.pi - d).max().item())
    over = {k: (e, QUAT_BOUNDS[k][0]) for k, e in errs.items() if not e < QUAT_BOUNDS[k][0]}
    assert not over, over


DQ_BOUNDS = {  # name: (bound, measured)
    "mul": (5e-7, 3.3e-7),
    "apply": (1.2e-6, 8.1e-7),
    "apply_line": (1.6e-6, 1.1e-6),
    "to_matrix": (7e-7, 4.4e-7),
    "from_matrix": (4e-7, 2.8e-7),
    "log": (2e-6, 1.4e-6),
    "exp": (1.2e-6, 8.2e-7),
    "normalize": (5e-7, 2.9e-7),
    "inv": (8e-7, 5.6e-7),
    "to_screw": (4e-7, 2.2e-7),
}


def test_dualquat_float32():
    gen = torch.Generator().manual_seed(1)
    x, y = _poses(gen), _poses(gen)
    p = _rounded(torch.randn(N, 3, generator=gen, dtype=F64))
    line = p / p.norm(dim=-1, keepdim=True)
    moment = _rounded(torch.linalg.cross(torch.randn(N, 3, generator=gen, dtype=F64), line,
                                         dim=-1))
    errs = {
        "mul": _err(dq.mul, x, y, signed=True),
        "apply": _err(dq.apply, x, p),
        "apply_line": _err(lambda *a: torch.cat(dq.apply_line(*a), -1), x, _rounded(line),
                           moment),
        "to_matrix": _err(dq.to_matrix, x),
        "from_matrix": _err(dq.from_matrix, _rounded(dq.to_matrix(x)), signed=True),
        "log": _err(dq.log, x),
        "exp": _err(dq.exp, _rounded(dq.log(x)), signed=True),
        "normalize": _err(dq.normalize, _rounded(1.1 * x), signed=True),
        "inv": _err(dq.inv, x, signed=True),
        "to_screw": _err(lambda z: dq.to_screw(z)[2], x),
    }
    over = {k: (e, DQ_BOUNDS[k][0]) for k, e in errs.items() if not e < DQ_BOUNDS[k][0]}
    assert not over, over


def test_sclerp_float32():
    gen = torch.Generator().manual_seed(2)
    a, b = _poses(gen), _poses(gen)
    t = _rounded(torch.rand(N, generator=gen, dtype=F64))
    t_out = _rounded(torch.rand(N, generator=gen, dtype=F64) * 2.4 - 0.7)
    k = torch.randint(2, 10, (N, 1), generator=gen).double()
    xi = torch.randn(N, 6, generator=gen, dtype=F64) * 10.0 ** -k
    near = _rounded(dq.mul(a, dq.exp(xi)))
    errs = {
        "t in [0, 1]": (_err(dq.sclerp, a, b, t, signed=True), 8e-7),  # measured 5.0e-7
        "t in [-0.7, 1.7]": (_err(dq.sclerp, a, b, t_out, signed=True), 1.5e-6),  # 1.0e-6
        "near-degenerate": (_err(dq.sclerp, a, near, t, signed=True), 4e-7),  # 2.4e-7
    }
    over = {k: v for k, v in errs.items() if not v[0] < v[1]}
    assert not over, over


@pytest.mark.parametrize(("scale", "bound"), [(1.0, 1.5e-6), (10.0, 1.2e-5)])
def test_curves_float32(scale, bound):
    """Measured: bezier 9.1e-7 / bspline 5.6e-7 at scale 1; 8.5e-6 / 4.8e-6 at scale 10."""
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
        err = _err(f, ctrl, t, signed=True)
        assert err < bound, (f.__name__, scale, err)

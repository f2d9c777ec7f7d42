"""Every PyTorch execution mode on the hot paths: torch.compile, torch.func (vmap, jacrev,
jacfwd, jvp), CUDA, and run-to-run determinism.

Status (each line is asserted below):

- ``torch.compile(fullgraph=True)``: sclerp, angle and a ``torch_dq.nn`` layer compile
  without graph breaks, forward and backward, and match eager (backend ``aot_eager`` here to
  stay fast; one inductor test); sclerp (two sizes, both grad modes) and bezier/bspline
  with ``check=False`` in ``tests/test_compile.py``, angle (both branches, both grad modes)
  in ``tests/test_interp.py``. The plain
  algebra (``mul``, ``exp``, ``log``, ...) has no custom op and no branch on values.
  The value checks that need the host are skipped under compile (times outside the
  domain give NaN), so the default arguments compile with ``fullgraph=True`` too.
- ``torch.func.vmap`` / ``jacrev`` / ``jacfwd`` / ``jvp``, on every row of the one registry
  (``registry.OPS``, both B-spline forms included): supported (under these transforms the
  curves run their plain-op path); ``vmap`` equals the batched call, ``jacrev`` and
  ``jacfwd`` the eager Jacobian, ``jvp`` central differences. bezier/bspline need
  ``check=False`` under ``vmap`` over ``t`` (the checks are data-dependent).
- ``torch.jit`` (deprecated by PyTorch, which prints a DeprecationWarning for it) is not
  tested: use ``torch.compile`` or ``torch.export``.
- The time derivatives, kinematics and IMU readings of ``torch_dq.curves`` compile with
  ``fullgraph=True`` too (plain ops, no custom op), forward and backward.
- CUDA: every registry row gives the same results as on the CPU (skipped without a GPU).
- Determinism: every registry row gives bitwise equal outputs and gradients run to run, with
  ``torch.use_deterministic_algorithms(True)`` as well, and the eager chunking of large
  batches does not change a single bit.
"""

import shutil

import pytest
import torch
from registry import DIFFERENTIABLE, IDS, OPS, flat, sample_args
from strategies import unit_dq

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq import nn as dqnn
from torch_dq._kernels import layout

F64 = torch.float64
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
DIFF_IDS = [o.id for o in DIFFERENTIABLE]


def _data(gen):
    a, b = unit_dq((5,), gen), unit_dq((5,), gen)
    t = torch.rand(5, generator=gen, dtype=F64) * 1.4 - 0.2
    ctrl = unit_dq((2, 5), gen)
    times = torch.linspace(0, 1, 6, dtype=F64)
    return a, b, t, ctrl, times


def _curve_args(gen):
    """Two control polygons of 5 poses and 6 times in [0, 1]."""
    _, _, _, ctrl, times = _data(gen)
    return ctrl, times


def _grads(f, args):
    """Outputs and the gradients of a weighted sum of them (one or several tensors)."""
    xs = [x.clone().requires_grad_() for x in args]
    got = f(*xs)
    got = got if isinstance(got, tuple) else (got,)
    diff = [o for o in got if o.requires_grad]
    grads = [None] * len(xs)
    if diff:  # is_unit: no differentiable output
        loss = sum((torch.linspace(-1, 1, o.numel(), dtype=o.dtype, device=o.device)
                    .view(o.shape) * o).sum()
                   for o in diff)
        grads = torch.autograd.grad(loss, xs, allow_unused=True)
    grads = [torch.zeros_like(x) if g is None else g for g, x in zip(grads, xs, strict=True)]
    out = torch.cat([o.detach().reshape(-1).to(F64) for o in got])
    return out, grads


# ----------------------------------------------------------------------------- torch.compile

def test_compile_derivatives_kinematics_imu(gen):
    """Time derivatives, world/body kinematics and IMU readings in one compiled graph,
    forward and backward."""
    c, t = _curve_args(gen)
    c = c[0, :3]

    def f(c, t):  # kept small: compilation time grows with the levels and the order
        jet = curves.bspline_derivatives(c, t, order=2, degree=1, check=False)
        body = curves.kinematics(*jet, frame="body")
        return torch.cat((*jet, *body, *curves.imu(*jet)), -1)

    torch._dynamo.reset()
    compiled = torch.compile(f, backend="aot_eager", fullgraph=True)
    out, grads = _grads(compiled, (c, t))
    ref, ref_grads = _grads(f, (c, t))
    assert (out - ref).abs().max() <= 1e-12
    for g, r in zip(grads, ref_grads, strict=True):
        assert (g - r).abs().max() <= 1e-10


def test_compile_default_checks_skipped_outside_times_nan(gen):
    """docs/api_contract.md: the default arguments compile with ``fullgraph=True`` (the
    value checks that need a host sync are skipped under compile) and times outside the
    domain give NaN there, never a silent extrapolation; the times inside match eager."""
    c, _ = _curve_args(gen)
    c = c[:, :2]
    t = torch.tensor([0.0, 0.5, 1.0, 1.5], dtype=F64)
    torch._dynamo.reset()
    out = torch.compile(curves.bezier, backend="aot_eager", fullgraph=True)(c, t)
    assert torch.isnan(out[:, 3]).all()
    assert (out[:, :3] - curves.bezier(c, t[:3])).abs().max() <= 1e-14


def test_compile_nn_layer(gen):
    """A layer's forward and backward (through the unit-dual-quaternion parametrization).
    Degree 1 (one level: the curves' levels under compile are ``tests/test_compile.py``'s)."""
    module = dqnn.BSpline(unit_dq((2, 4), gen), degree=1, check=False)
    t = torch.linspace(0, 1, 7, dtype=F64)
    torch._dynamo.reset()
    compiled = torch.compile(module, backend="aot_eager", fullgraph=True)
    raw = module.parametrizations.ctrl.original
    out = compiled(t)
    out.sum().backward()
    grad = raw.grad.clone()
    raw.grad = None
    ref = module(t)
    ref.sum().backward()
    assert out.shape == (2, 7, 8)
    assert (out - ref).abs().max() <= 1e-14
    assert (grad - raw.grad).abs().max() <= 1e-12


def _cxx():
    return any(shutil.which(c) for c in ("g++", "c++", "clang++"))


@pytest.mark.skipif(not _cxx(), reason="no C++ compiler for the inductor CPU backend")
# PyTorch's own inductor modules use torch.jit.script_method on import (not torch_dq).
@pytest.mark.filterwarnings("ignore:`torch.jit.script_method` is deprecated:DeprecationWarning")
def test_compile_inductor_sclerp(gen):
    """The default backend (inductor, C++ on CPU): sclerp forward and backward."""
    a, b, t = _data(gen)[:3]
    torch._dynamo.reset()
    compiled = torch.compile(dq.sclerp, fullgraph=True)
    out, grads = _grads(compiled, (a, b, t))
    ref, ref_grads = _grads(dq.sclerp, (a, b, t))
    assert (out - ref).abs().max() <= 1e-13
    for g, r in zip(grads, ref_grads, strict=True):
        assert (g - r).abs().max() <= 1e-11


# ----------------------------------------------------------------------------- torch.func

def _registry_args(o, gen, n=3):
    return sample_args(o, (n,), gen)


@pytest.mark.parametrize("o", OPS, ids=IDS)
def test_vmap_matches_batched_call(o, gen):
    """vmap over the batch of every registry row (curves: over the control polygons, the
    times shared) equals the batched call."""
    f = flat(o)
    args = _registry_args(o, gen)
    for got, want in zip(torch.func.vmap(f)(*args), f(*args), strict=True):
        assert got.dtype == want.dtype
        if want.dtype == torch.bool:
            assert torch.equal(got, want)
        else:
            assert (got - want).abs().max() <= 1e-15 * want.abs().max().clamp(min=1)


def test_vmap_nested_and_over_t(gen):
    a, b, t = _data(gen)[:3]
    out = torch.func.vmap(lambda s: dq.sclerp(a, b, s))(t[:, None].expand(5, 5))
    assert (out - dq.sclerp(a, b, t[:, None])).abs().max() <= 1e-15
    nested = torch.func.vmap(torch.func.vmap(dq.sclerp))(a[None], b[None], t[None])
    assert (nested[0] - dq.sclerp(a, b, t)).abs().max() <= 1e-15


def test_vmap_curves_value_checks(gen):
    """The value checks on ``t`` run when ``t`` is shared; mapped over ``t`` they are
    data-dependent and refused: use ``check=False`` (documented)."""
    c, t = _curve_args(gen)
    out = torch.func.vmap(curves.bezier, in_dims=(0, None))(c, t)  # the readable scheme
    assert (out - curves.bezier(c, t)).abs().max() <= 1e-14
    with pytest.raises(RuntimeError, match=r"curves\.bezier: .* pass check=False"):
        torch.func.vmap(curves.bezier)(c, t.expand(2, 6))
    out = torch.func.vmap(lambda c, t: curves.bezier(c, t, check=False))(c, t.expand(2, 6))
    assert (out - curves.bezier(c, t)).abs().max() <= 1e-14


@pytest.mark.parametrize("o", DIFFERENTIABLE, ids=DIFF_IDS)
def test_jacrev_and_jacfwd_match_eager_jacobian(o, gen):
    """torch.func's reverse and forward Jacobians (the plain-op path) equal the eager
    Jacobian of the default path (fused kernels where the row has one)."""
    f = flat(o)
    args = _registry_args(o, gen, n=1)  # small Jacobians
    argnums = tuple(range(len(args)))
    rev = torch.func.jacrev(f, argnums=argnums)(*args)
    fwd = torch.func.jacfwd(f, argnums=argnums)(*args)
    ref = torch.autograd.functional.jacobian(f, tuple(args))
    for r_out, w_out, e_out in zip(rev, fwd, ref, strict=True):
        for r, w, e in zip(r_out, w_out, e_out, strict=True):
            scale = e.abs().max().clamp(min=1)
            assert torch.isfinite(r).all()
            assert (r - e).abs().max() <= 1e-12 * scale
            assert (w - e).abs().max() <= 1e-12 * scale


@pytest.mark.parametrize("o", DIFFERENTIABLE, ids=DIFF_IDS)
def test_vectorized_jacobian_and_hessian(o, gen):
    """``torch.autograd.functional.jacobian`` / ``hessian`` with ``vectorize=True`` (the
    backward under ``vmap``, after the forward took the fused path) equal the loops of
    ``vectorize=False``. The Hessian on one batch element: its loop runs a double backward
    per input entry (the rows' independence is the Jacobian's, on two)."""
    f = flat(o)
    args = tuple(_registry_args(o, gen, n=2))
    for vec, loop in zip(torch.autograd.functional.jacobian(f, args, vectorize=True),
                         torch.autograd.functional.jacobian(f, args), strict=True):
        for v, e in zip(vec, loop, strict=True):
            assert torch.isfinite(e).all() and (v - e).abs().max() <= 1e-12 * e.abs().max()

    def scalar(*xs):
        return sum((torch.sin(y) ** 2).sum() for y in f(*xs))

    args = tuple(_registry_args(o, gen, n=1))
    vec = torch.autograd.functional.hessian(scalar, args, vectorize=True)
    loop = torch.autograd.functional.hessian(scalar, args)
    for v_row, e_row in zip(vec, loop, strict=True):
        for v, e in zip(v_row, e_row, strict=True):
            assert (v - e).abs().max() <= 1e-12 * e.abs().max().clamp(min=1), o.id


@pytest.mark.parametrize("o", DIFFERENTIABLE, ids=DIFF_IDS)
def test_jvp_matches_finite_differences(o, gen):
    """Forward-mode AD (``torch.func.jvp``) against central differences."""
    f = flat(o)
    args = _registry_args(o, gen)
    tangents = [torch.randn(x.shape, generator=gen, dtype=F64) for x in args]
    out, tangent = torch.func.jvp(f, tuple(args), tuple(tangents))
    h = 1e-6
    plus = f(*(x + h * v for x, v in zip(args, tangents, strict=True)))
    minus = f(*(x - h * v for x, v in zip(args, tangents, strict=True)))
    for o_, t_, p, m, e in zip(out, tangent, plus, minus, f(*args), strict=True):
        assert (o_ - e).abs().max() <= 1e-15 * e.abs().max().clamp(min=1)
        fd = (p - m) / (2 * h)
        assert ((t_ - fd).abs() / t_.abs().clamp(min=1)).max() < 1e-7, o.id


# ----------------------------------------------------------------------------- CUDA

@CUDA
@pytest.mark.parametrize("o", OPS, ids=IDS)
def test_cuda_matches_cpu(o, gen):
    f = flat(o)
    args = _registry_args(o, gen)
    out, grads = _grads(f, [x.cuda() for x in args])
    ref, ref_grads = _grads(f, args)
    assert (out.cpu() - ref).abs().max() <= 1e-13 * ref.abs().max().clamp(min=1)
    for g, r in zip(grads, ref_grads, strict=True):
        assert g.device.type == "cuda"
        assert (g.cpu() - r).abs().max() <= 1e-11 * r.abs().max().clamp(min=1)


@CUDA
def test_cuda_compile_and_half(gen):
    a, b, t = (x.cuda() for x in _data(gen)[:3])
    torch._dynamo.reset()
    out = torch.compile(dq.sclerp, backend="aot_eager", fullgraph=True)(a, b, t)
    assert (out - dq.sclerp(a, b, t)).abs().max() <= 1e-14
    for dtype in (torch.float16, torch.bfloat16):
        h = dq.sclerp(a.to(dtype), b.to(dtype), t.to(dtype))
        assert h.dtype == dtype and h.device.type == "cuda"


# ----------------------------------------------------------------------------- determinism

@pytest.mark.parametrize("deterministic", [False, True], ids=["default", "deterministic"])
def test_bitwise_deterministic(deterministic, gen):
    previous = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(deterministic)
    try:
        for o in OPS:
            args = _registry_args(o, gen, n=2)
            out1, g1 = _grads(flat(o), args)
            out2, g2 = _grads(flat(o), args)
            assert torch.equal(out1, out2), o.id
            assert all(torch.equal(x, y) for x, y in zip(g1, g2, strict=True)), o.id
    finally:
        torch.use_deterministic_algorithms(previous)


def test_chunking_is_bitwise_invisible(gen):
    """Eager sclerp evaluates large batches in chunks: no bit changes, values or grads."""
    n = layout.CHUNK + 1000
    a, b = unit_dq((n,), gen), unit_dq((n,), gen)
    t = torch.rand(n, generator=gen, dtype=F64)
    out, grads = _grads(dq.sclerp, (a, b, t))
    out2, grads2 = _grads(dq.sclerp, (a, b, t))
    assert torch.equal(out, out2) and all(map(torch.equal, grads, grads2))
    out = out.view(n, 8)
    tail = slice(n - 1000, n)  # the last chunk alone, as one small batch
    small = dq.sclerp(a[tail], b[tail], t[tail])
    w = torch.linspace(-1, 1, out.numel(), dtype=F64).view(out.shape)[tail]
    xs = [x[tail].clone().requires_grad_() for x in (a, b, t)]
    small_grads = torch.autograd.grad((w * dq.sclerp(*xs)).sum(), xs)
    assert torch.equal(small, out[tail])
    for g, s in zip(grads, small_grads, strict=True):
        assert torch.equal(g[tail], s)

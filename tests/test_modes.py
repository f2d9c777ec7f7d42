"""Every PyTorch execution mode on the hot paths: torch.compile, torch.func (vmap, jacrev,
jacfwd, jvp), CUDA, and run-to-run determinism.

Status (each line is asserted below):

- ``torch.compile(fullgraph=True)``: sclerp, angle, bezier/bspline with ``check=False``
  and a ``torch_dq.nn`` layer compile without graph breaks, forward and backward, and
  match eager (backend ``aot_eager`` here to stay fast; one inductor test). The plain
  algebra (``mul``, ``exp``, ``log``, ...) has no custom op and no branch on values.
  The value checks of ``check=True`` read values on the host and break the graph.
- ``torch.func.vmap`` / ``jacrev`` / ``jacfwd`` / ``jvp``: supported (the custom autograd
  ops define vmap rules and a forward-mode rule); ``jacrev`` and ``jacfwd`` agree with the
  eager Jacobian, ``jvp`` with central differences. bezier/bspline need ``check=False``
  under ``vmap`` (the checks are data-dependent).
- ``torch.jit`` (deprecated by PyTorch, which prints a DeprecationWarning for it) is not
  tested: use ``torch.compile`` or ``torch.export``.
- The time derivatives, kinematics and IMU readings of ``torch_dq.curves`` compile with
  ``fullgraph=True`` too (plain ops, no custom op), forward and backward.
- CUDA: same results as on the CPU (skipped without a GPU).
- Determinism: the same inputs give bitwise equal outputs and gradients run to run, with
  ``torch.use_deterministic_algorithms(True)`` as well, and the eager chunking of large
  batches does not change a single bit.
"""

import functools
import shutil

import pytest
import torch
from strategies import unit_dq

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq import nn as dqnn
from torch_dq._kernels import layout

F64 = torch.float64
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _data(gen):
    a, b = unit_dq((5,), gen), unit_dq((5,), gen)
    t = torch.rand(5, generator=gen, dtype=F64) * 1.4 - 0.2
    ctrl = unit_dq((2, 5), gen)
    times = torch.linspace(0, 1, 6, dtype=F64)
    xi = torch.randn(5, 6, generator=gen, dtype=F64)
    return a, b, t, ctrl, times, xi


# name -> (function of tensors returning a tensor, indices into _data's tuple)
FNS = {
    "sclerp": (dq.sclerp, (0, 1, 2)),
    "sclerp_long": (lambda a, b, t: dq.sclerp(a, b, t, shortest=False), (0, 1, 2)),
    "angle": (lambda a, b: torch.stack(tuple(dq.angle(a, b)), -1), (0, 1)),
    "bezier": (lambda c, t: curves.bezier(c, t, check=False), (3, 4)),
    "bspline": (lambda c, t: curves.bspline(c, t, check=False), (3, 4)),
    "mul": (dq.mul, (0, 1)),
    "exp": (dq.exp, (5,)),
    "log": (dq.log, (0,)),
    "dlb": (lambda a, b: dq.dlb(torch.tensor([0.3, 0.7], dtype=F64), torch.stack((a, b), -2)),
            (0, 1)),
}


def _args(name, gen):
    data = _data(gen)
    return [data[i] for i in FNS[name][1]]


# Compiled functions, kept small (compilation time grows with the unrolled levels).
COMPILED = {
    "sclerp": (dq.sclerp, lambda d: (d[0], d[1], d[2])),
    "angle": (FNS["angle"][0], lambda d: (d[0], d[1])),
    "bezier": (FNS["bezier"][0], lambda d: (d[3][:, :3], d[4])),
    "bspline": (lambda c, t: curves.bspline(c, t, degree=2, check=False),
                lambda d: (d[3][:, :4], d[4])),
}


def _grads(f, args):
    xs = [x.clone().requires_grad_() for x in args]
    out = f(*xs)
    w = torch.linspace(-1, 1, out.numel(), dtype=out.dtype).view(out.shape)
    return out.detach(), torch.autograd.grad((w * out).sum(), xs)


# ----------------------------------------------------------------------------- torch.compile

@pytest.mark.parametrize("name", COMPILED)
def test_compile_fullgraph_forward_backward(name, gen):
    f, pick = COMPILED[name]
    args = pick(_data(gen))
    torch._dynamo.reset()
    compiled = torch.compile(f, backend="aot_eager", fullgraph=True)
    out, grads = _grads(compiled, args)
    ref, ref_grads = _grads(f, args)
    assert (out - ref).abs().max() <= 1e-14
    for g, r in zip(grads, ref_grads, strict=True):
        assert (g - r).abs().max() <= 1e-12


@pytest.mark.parametrize("grad", [False, True], ids=["inference", "grad"])
@pytest.mark.parametrize("name", ["bezier", "bspline"])
def test_compile_curves_partial_check_false(name, grad, gen):
    """Issue 14: ``torch.compile(partial(curves.bspline, check=False), fullgraph=True)``
    compiles without graph breaks in inference and with gradients, and matches eager."""
    c, t = _args(name, gen)
    c = c[:, :4]
    f = functools.partial(getattr(curves, name), check=False)
    torch._dynamo.reset()
    compiled = torch.compile(f, backend="aot_eager", fullgraph=True)
    with torch.set_grad_enabled(grad):
        cc = c.clone().requires_grad_(grad)
        out, ref = compiled(cc, t), f(c, t)
    assert (out - ref).abs().max() <= 1e-14
    if grad:
        (g,) = torch.autograd.grad((out * ref).sum(), cc)
        cr = c.clone().requires_grad_()
        (r,) = torch.autograd.grad((f(cr, t) * ref).sum(), cr)
        assert (g - r).abs().max() <= 1e-12


def test_compile_derivatives_kinematics_imu(gen):
    """Time derivatives, world/body kinematics and IMU readings in one compiled graph,
    forward and backward."""
    c, t = _args("bspline", gen)
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


def test_compile_with_value_checks_breaks_the_graph(gen):
    """Documented: ``check=True`` reads values on the host, so fullgraph fails; the
    default (graph breaks allowed) still compiles and matches."""
    c, t = _args("bezier", gen)
    c = c[:, :2]
    torch._dynamo.reset()
    with pytest.raises(Exception, match=r"(?i)graph break|tolist|data-dependent|Unsupported"):
        torch.compile(curves.bezier, backend="aot_eager", fullgraph=True)(c, t)
    torch._dynamo.reset()
    out = torch.compile(curves.bezier, backend="aot_eager")(c, t)
    assert (out - curves.bezier(c, t)).abs().max() <= 1e-14


def test_compile_nn_layer(gen):
    """A layer's forward and backward (through the unit-dual-quaternion parametrization)."""
    module = dqnn.BSpline(unit_dq((2, 4), gen), degree=2, check=False)
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
    a, b, t = _args("sclerp", gen)
    torch._dynamo.reset()
    compiled = torch.compile(dq.sclerp, fullgraph=True)
    out, grads = _grads(compiled, (a, b, t))
    ref, ref_grads = _grads(dq.sclerp, (a, b, t))
    assert (out - ref).abs().max() <= 1e-13
    for g, r in zip(grads, ref_grads, strict=True):
        assert (g - r).abs().max() <= 1e-11


# ----------------------------------------------------------------------------- torch.func

@pytest.mark.parametrize("name", FNS)
def test_vmap_matches_batched_call(name, gen):
    f = FNS[name][0]
    args = _args(name, gen)
    curve = name in ("bezier", "bspline")
    in_dims = (0, None) if curve else 0  # curves: map over the curves, share the times
    out = torch.func.vmap(f, in_dims=in_dims)(*args)
    assert (out - f(*args)).abs().max() <= 1e-15
    if name == "sclerp":  # map over t only, and nested maps
        a, b, t = args
        out = torch.func.vmap(lambda s: dq.sclerp(a, b, s))(t[:, None].expand(5, 5))
        assert (out - dq.sclerp(a, b, t[:, None])).abs().max() <= 1e-15
        nested = torch.func.vmap(torch.func.vmap(dq.sclerp))(a[None], b[None], t[None])
        assert (nested[0] - f(*args)).abs().max() <= 1e-15


def test_vmap_curves_value_checks(gen):
    """The value checks on ``t`` run when ``t`` is shared; mapped over ``t`` they are
    data-dependent and refused: use ``check=False`` (documented)."""
    c, t = _args("bezier", gen)
    out = torch.func.vmap(curves.bezier, in_dims=(0, None))(c, t)  # the readable scheme
    assert (out - curves.bezier(c, t)).abs().max() <= 1e-14
    with pytest.raises(RuntimeError, match=r"curves\.bezier: .* pass check=False"):
        torch.func.vmap(curves.bezier)(c, t.expand(2, 6))
    out = torch.func.vmap(lambda c, t: curves.bezier(c, t, check=False))(c, t.expand(2, 6))
    assert (out - curves.bezier(c, t)).abs().max() <= 1e-14


@pytest.mark.parametrize("name", FNS)
def test_jacrev_and_jacfwd_match_eager_jacobian(name, gen):
    f = FNS[name][0]
    args = [x[:2] for x in _args(name, gen)]  # small Jacobians
    argnums = tuple(range(len(args)))
    rev = torch.func.jacrev(f, argnums=argnums)(*args)
    fwd = torch.func.jacfwd(f, argnums=argnums)(*args)
    ref = torch.autograd.functional.jacobian(f, tuple(args))
    for r, w, e in zip(rev, fwd, ref, strict=True):
        assert torch.isfinite(r).all()
        assert (r - e).abs().max() <= 1e-12
        assert (w - e).abs().max() <= 1e-12


@pytest.mark.parametrize("name", FNS)
def test_jvp_matches_finite_differences(name, gen):
    f = FNS[name][0]
    args = _args(name, gen)
    tangents = [torch.randn(x.shape, generator=gen, dtype=F64) for x in args]
    if name in ("bezier", "bspline"):  # keep the times inside [0, 1]
        args[1] = args[1] * 0.8 + 0.1
    out, tangent = torch.func.jvp(f, tuple(args), tuple(tangents))
    h = 1e-6
    plus = f(*(x + h * v for x, v in zip(args, tangents, strict=True)))
    minus = f(*(x - h * v for x, v in zip(args, tangents, strict=True)))
    assert (out - f(*args)).abs().max() <= 1e-15
    assert ((tangent - (plus - minus) / (2 * h)).abs() / tangent.abs().clamp(min=1)).max() < 1e-7


# ----------------------------------------------------------------------------- CUDA

@CUDA
@pytest.mark.parametrize("name", FNS)
def test_cuda_matches_cpu(name, gen):
    f = FNS[name][0]
    args = _args(name, gen)
    if name == "dlb":
        f = lambda a, b: dq.dlb(torch.tensor([0.3, 0.7], dtype=F64, device=a.device),  # noqa: E731
                                torch.stack((a, b), -2))
    out, grads = _grads(f, [x.cuda() for x in args])
    ref, ref_grads = _grads(f, args)
    assert out.device.type == "cuda"
    assert (out.cpu() - ref).abs().max() <= 1e-13
    for g, r in zip(grads, ref_grads, strict=True):
        assert (g.cpu() - r).abs().max() <= 1e-11


@CUDA
def test_cuda_compile_and_half(gen):
    a, b, t = (x.cuda() for x in _args("sclerp", gen))
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
        for name, (f, _) in FNS.items():
            args = _args(name, gen)
            out1, g1 = _grads(f, args)
            out2, g2 = _grads(f, args)
            assert torch.equal(out1, out2), name
            assert all(torch.equal(x, y) for x, y in zip(g1, g2, strict=True)), name
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
    tail = slice(n - 1000, n)  # the last chunk alone, as one small batch
    small, small_grads = _grads(dq.sclerp, (a[tail], b[tail], t[tail]))
    w = torch.linspace(-1, 1, out.numel(), dtype=F64).view(out.shape)[tail]
    xs = [x[tail].clone().requires_grad_() for x in (a, b, t)]
    small_grads = torch.autograd.grad((w * dq.sclerp(*xs)).sum(), xs)
    assert torch.equal(small, out[tail])
    for g, s in zip(grads, small_grads, strict=True):
        assert torch.equal(g[tail], s)

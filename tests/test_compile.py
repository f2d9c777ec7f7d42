"""torch.compile: the fused kernels trace as one graph, with and without gradients, and a
change in the number of samples does not recompile.

The compiled functions run on the ``aot_eager`` backend (dynamo + AOTAutograd, the graphs
inductor would receive, without its slow code generation; dynamo's own ``eager`` backend for
inference, where there is no backward to trace) and are compared with eager
evaluation; ``CompileCounterWithBackend`` counts the frames dynamo compiled: with
``fullgraph=True`` (no graph break allowed), one frame per grad mode across the sizes means
no recompilation.
"""

import functools

import pytest
import torch
from strategies import unit_dq
from torch._dynamo.testing import CompileCounterWithBackend

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq.nn import BSpline

SIZES = (5, 9)  # the second size would recompile if the sample axis were specialised


@pytest.fixture(autouse=True)
def _fresh_dynamo():
    torch._dynamo.reset()
    yield
    torch._dynamo.reset()


def _compiled(fn, backend="aot_eager"):
    counter = CompileCounterWithBackend(backend)
    return torch.compile(fn, fullgraph=True, backend=counter), counter


def _weighted_sum(x):
    """A loss whose gradient differs per element (a plain sum would hide index mix-ups)."""
    return (x * torch.linspace(-1.0, 2.0, x.numel(), dtype=x.dtype).view(x.shape)).sum()


def _value_and_grads(fn, inputs, wrt):
    leaves = [x.clone().requires_grad_(i in wrt) for i, x in enumerate(inputs)]
    out = fn(*leaves)
    grads = torch.autograd.grad(_weighted_sum(out), [leaves[i] for i in wrt])
    return out.detach(), grads


def _check(fn, make_inputs, wrt, n_dynamic=1):
    """Compiled equals eager (values and gradients) at every size, from one graph.

    ``make_inputs(n)`` returns the inputs with ``n`` samples; the leading axis (the
    samples) of the first ``n_dynamic`` ones is marked dynamic.
    """
    infer, infer_count = _compiled(fn, "eager")  # no backward to trace: dynamo alone
    train, train_count = _compiled(fn)
    for n in SIZES:
        inputs = make_inputs(n)
        for x in inputs[:n_dynamic]:
            torch._dynamo.mark_dynamic(x, 0)
        with torch.no_grad():
            assert torch.allclose(infer(*inputs), fn(*inputs), rtol=0, atol=1e-14)
        out, grads = _value_and_grads(train, inputs, wrt)
        ref, ref_grads = _value_and_grads(fn, inputs, wrt)
        assert torch.allclose(out, ref, rtol=0, atol=1e-14)
        for g, r in zip(grads, ref_grads, strict=True):
            assert torch.allclose(g, r, rtol=0, atol=1e-12)
    # fullgraph=True: no graph break; one frame each at both sizes: no recompilation
    assert (infer_count.frame_count, train_count.frame_count) == (1, 1)


def _times(gen, n):
    return torch.rand(n, generator=gen, dtype=torch.float64)


def test_sclerp_compiles_as_one_graph(gen):
    """Times in [-0.2, 1.2]: interpolation and extrapolation."""
    _check(dq.sclerp, lambda n: (unit_dq((n,), gen), unit_dq((n,), gen),
                                 1.4 * _times(gen, n) - 0.2), wrt=(0, 1, 2), n_dynamic=3)


@pytest.mark.parametrize("curve", ["bezier", "bspline", "split"])
def test_curve_compiles_as_one_graph(gen, curve):
    """``partial(curves.bezier / bspline, check=False)`` with a batch of two control
    polygons: gradients with respect to the control points and the times (every level's
    alpha); ``split``: the B-spline's split form (plain ops on component rows). Degree 2
    (two levels, the second combining the first's results; three B-spline spans): the
    traced graph, and the time to trace it with symbolic sizes, grows with the levels."""
    ctrl = unit_dq((2, 3), gen) if curve == "bezier" else unit_dq((2, 5), gen)
    fn = {"bezier": functools.partial(curves.bezier, check=False),
          "bspline": functools.partial(curves.bspline, degree=2, check=False),
          "split": functools.partial(curves.bspline, degree=2, check=False, form="split")}[curve]
    _check(lambda t, c: fn(c, t), lambda n: (_times(gen, n), ctrl), wrt=(0, 1))


@pytest.mark.parametrize("form", ["de_boor", "split"])
def test_bspline_derivatives_compile_as_one_graph(gen, form):
    """The pose, velocity and acceleration (truncated Taylor arithmetic) in one dynamo graph
    per grad mode at both sizes. Dynamo's own ``eager`` backend: AOTAutograd takes ~60 s on
    this graph; the kernels' backward tracing is covered by the tests above. Degree 2, as
    above."""
    ctrl = unit_dq((5,), gen)
    derivatives = functools.partial(curves.bspline_derivatives, order=2, degree=2,
                                    check=False, form=form)

    def fn(t, c):
        return torch.stack(derivatives(c, t))
    infer, infer_count = _compiled(fn, "eager")
    train, train_count = _compiled(fn, "eager")
    for n in SIZES:
        t = _times(gen, n)
        torch._dynamo.mark_dynamic(t, 0)
        with torch.no_grad():
            assert torch.allclose(infer(t, ctrl), fn(t, ctrl), rtol=0, atol=1e-13)
        out, (grad,) = _value_and_grads(train, (t, ctrl), wrt=(1,))
        ref, (ref_grad,) = _value_and_grads(fn, (t, ctrl), wrt=(1,))
        assert torch.allclose(out, ref, rtol=0, atol=1e-13)
        assert torch.allclose(grad, ref_grad, rtol=0, atol=1e-11)
    assert (infer_count.frame_count, train_count.frame_count) == (1, 1)


def test_compile_with_default_arguments(gen):
    """torch.compile(module, fullgraph=True) failed in 0.2 on the default check=True (a
    data-dependent branch); now the host-sync check is skipped under compile (outside
    times give NaN) and the graph equals eager inside the domain. Values only, so under
    ``no_grad`` (the layer's backward under compile: ``tests/test_modes.py``), on the
    ``aot_eager`` backend: the graph break was dynamo's; inductor's C++ code generation,
    ~20 s here, is tested on sclerp in ``tests/test_modes.py``."""
    torch._dynamo.reset()
    ctrl = dq.exp(0.4 * torch.randn(6, 6, generator=gen, dtype=torch.float64))
    knots = 5.0 + 2.0 * curves.clamped_uniform_knots(6, 3, dtype=torch.float64)
    module = BSpline(ctrl, knots=knots)
    t = torch.tensor([5.0, 5.5, 7.0, 9.0], dtype=torch.float64)
    with torch.no_grad():
        out = torch.compile(module, fullgraph=True, backend="aot_eager")(t)
    torch.testing.assert_close(out[:3], module(t[:3]), rtol=0, atol=1e-12)
    assert torch.isnan(out[3]).all()

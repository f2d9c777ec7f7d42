"""Dual numbers: values against torch.func.jvp, identities, arithmetic, autograd, singular
points, the custom sin/cos op under vmap/jvp/compile, and argument validation."""

import copy
import math
import pickle

import pytest
import torch
from conftest import TOL

from torch_dq import dual
from torch_dq.dual import Dual

F64 = torch.float64
# Max error of a dual function against torch.func.jvp of its real counterpart, relative to
# max(1, |reference|) elementwise. The formulas are torch's own forward-mode formulas: on CPU
# the results are bitwise equal (measured error 0); the bound leaves room for other devices.
JVP_TOL = 1e-14


def _uniform(shape, lo, hi, gen, dtype=F64):
    return (lo + (hi - lo) * torch.rand(shape, generator=gen, dtype=F64)).to(dtype)


def _rand_dual(shape, gen, lo=-2.0, hi=2.0, dtype=F64):
    return Dual(_uniform(shape, lo, hi, gen, dtype), torch.randn(shape, generator=gen,
                                                                 dtype=F64).to(dtype))


def _away_from_zero(shape, gen):
    sign = torch.where(torch.rand(shape, generator=gen) < 0.5, -1.0, 1.0).to(F64)
    return sign * _uniform(shape, 0.2, 3.0, gen)


def _rel_err(got, ref):
    return float(((got - ref).abs() / ref.abs().clamp_min(1.0)).max()) if got.numel() else 0.0


def _assert_dual_close(x, real, dual_part, tol, what=""):
    assert isinstance(x, Dual) and x.real.shape == x.dual.shape == dual_part.shape, what
    err_r = float((x.real - real).abs().max()) if x.real.numel() else 0.0
    err_d = float((x.dual - dual_part).abs().max()) if x.dual.numel() else 0.0
    assert err_r < tol and err_d < tol, f"{what}: errors real {err_r:.2e}, dual {err_d:.2e}"


# -- every function against torch.func.jvp ------------------------------------------------

# name -> (dual function, real counterpart, sampler of the real part in the domain)
UNARY = {
    "sin": (dual.sin, torch.sin, lambda s, g: _uniform(s, -4.0, 4.0, g)),
    "cos": (dual.cos, torch.cos, lambda s, g: _uniform(s, -4.0, 4.0, g)),
    "tan": (dual.tan, torch.tan, lambda s, g: _uniform(s, -1.4, 1.4, g)),
    "acos": (dual.acos, torch.acos, lambda s, g: _uniform(s, -0.99, 0.99, g)),
    "sqrt": (dual.sqrt, torch.sqrt, lambda s, g: _uniform(s, 0.05, 4.0, g)),
    "exp": (dual.exp, torch.exp, lambda s, g: _uniform(s, -3.0, 3.0, g)),
    "log": (dual.log, torch.log, lambda s, g: _uniform(s, 0.05, 4.0, g)),
    "inv": (dual.inv, torch.reciprocal, _away_from_zero),
    "apply(sinh)": (lambda x: dual.apply(torch.sinh, torch.cosh, x), torch.sinh,
                    lambda s, g: _uniform(s, -2.0, 2.0, g)),
}
BINARY = {
    "mul": (dual.mul, torch.mul, lambda s, g: _uniform(s, -2.0, 2.0, g)),
    "div": (dual.div, torch.div, _away_from_zero),
    "atan2": (dual.atan2, torch.atan2, _away_from_zero),
}


@pytest.mark.parametrize("name", list(UNARY))
def test_unary_matches_jvp(name, batch_shape, gen):
    fn, ref, sample = UNARY[name]
    shape = (*batch_shape, 50)
    a, b = sample(shape, gen), torch.randn(shape, generator=gen, dtype=F64)
    real, tangent = torch.func.jvp(ref, (a,), (b,))
    out = fn(Dual(a, b))
    assert isinstance(out, Dual) and out.shape == shape and out.dtype == F64
    err = max(_rel_err(out.real, real), _rel_err(out.dual, tangent))
    assert err < JVP_TOL, f"{name}: max error {err:.2e} >= {JVP_TOL:.0e} against jvp"


@pytest.mark.parametrize("name", list(BINARY))
def test_binary_matches_jvp(name, gen):
    fn, ref, sample = BINARY[name]
    a, c = sample((3, 1, 40), gen), sample((5, 40), gen)
    b, d = torch.randn(a.shape, generator=gen, dtype=F64), torch.randn(c.shape, generator=gen,
                                                                       dtype=F64)
    real, tangent = torch.func.jvp(ref, (a, c), (b, d))
    out = fn(Dual(a, b), Dual(c, d))
    assert out.shape == (3, 5, 40)
    err = max(_rel_err(out.real, real), _rel_err(out.dual, tangent))
    assert err < JVP_TOL, f"{name}: max error {err:.2e} >= {JVP_TOL:.0e} against jvp"
    # Mixed with a plain tensor (dual part 0) on either side.
    for x, y, tx, ty in ((Dual(a, b), c, b, torch.zeros_like(c)),
                         (a, Dual(c, d), torch.zeros_like(a), d)):
        real, tangent = torch.func.jvp(ref, (a, c), (tx, ty))
        out = fn(x, y)
        err = max(_rel_err(out.real, real), _rel_err(out.dual, tangent))
        assert err < JVP_TOL, f"{name} with a tensor: max error {err:.2e} against jvp"


def test_sincos_matches_jvp(gen):
    a, b = _uniform((100,), -4.0, 4.0, gen), torch.randn(100, generator=gen, dtype=F64)
    s, c = dual.sincos(Dual(a, b))
    for out, ref in ((s, torch.sin), (c, torch.cos)):
        real, tangent = torch.func.jvp(ref, (a,), (b,))
        err = max(_rel_err(out.real, real), _rel_err(out.dual, tangent))
        assert err < JVP_TOL, f"sincos: max error {err:.2e} against jvp"


# -- identities in dual arithmetic ----------------------------------------------------------


def test_paper_sin_cos_formulas(dtype, device, batch_shape, gen):
    """Paper 2.2: cos(a + eps b) = cos a - eps b sin a, sin(a + eps b) = sin a + eps b cos a."""
    a = _uniform(batch_shape, -4.0, 4.0, gen, dtype).to(device)
    b = torch.randn(batch_shape, generator=gen, dtype=F64).to(dtype).to(device)
    x = Dual(a, b)
    _assert_dual_close(dual.cos(x), torch.cos(a), -b * torch.sin(a), TOL[dtype], "cos")
    _assert_dual_close(dual.sin(x), torch.sin(a), b * torch.cos(a), TOL[dtype], "sin")


def test_pythagoras_and_tan(dtype, batch_shape, gen):
    x = _rand_dual((*batch_shape, 30), gen, -1.4, 1.4, dtype)
    s, c = dual.sin(x), dual.cos(x)
    one = s * s + c * c
    _assert_dual_close(one, 1.0, torch.zeros_like(x.dual), 4 * TOL[dtype], "sin^2 + cos^2")
    t, q = dual.tan(x), s / c
    # tan' = 1 / cos^2 reaches ~ 36 on [-1.4, 1.4]: relative comparison.
    assert _rel_err(t.real, q.real) < 30 * TOL[dtype]
    assert _rel_err(t.dual, q.dual) < 60 * TOL[dtype]


@pytest.mark.parametrize(
    ("name", "lo", "hi", "compose"),
    [
        ("acos(cos x)", 0.3, math.pi - 0.3, lambda x: dual.acos(dual.cos(x))),
        ("exp(log x)", 0.1, 4.0, lambda x: dual.exp(dual.log(x))),
        ("log(exp x)", -3.0, 3.0, lambda x: dual.log(dual.exp(x))),
        ("sqrt(x) sqrt(x)", 0.1, 4.0, lambda x: dual.sqrt(x) * dual.sqrt(x)),
        ("atan2(sin x, cos x)", -3.1, 3.1, lambda x: dual.atan2(dual.sin(x), dual.cos(x))),
        ("inv(inv x)", 0.2, 3.0, lambda x: dual.inv(dual.inv(x))),
        ("x / x * x", 0.2, 3.0, lambda x: x / x * x),
    ],
)
def test_round_trips(name, lo, hi, compose, dtype, gen):
    x = _rand_dual((200,), gen, lo, hi, dtype)
    y = compose(x)
    err = max(float((y.real - x.real).abs().max()), float((y.dual - x.dual).abs().max()))
    assert err < 20 * TOL[dtype], f"{name}: max error {err:.2e}"


def test_inverse_times_x_is_one(dtype, gen):
    x = Dual(_away_from_zero((200,), gen).to(dtype), torch.randn(200, generator=gen).to(dtype))
    for y in (dual.inv(x) * x, x * dual.inv(x), 1.0 / x * x, dual.div(x, x)):
        _assert_dual_close(y, 1.0, torch.zeros_like(x.dual), 4 * TOL[dtype], "x^-1 x")


def test_paper_inverse_formula(gen):
    """Paper 2.2: (a + eps b)^-1 = (a - eps b) / a^2."""
    x = Dual(_away_from_zero((50,), gen), torch.randn(50, generator=gen, dtype=F64))
    y = dual.conj(x) / (x.real * x.real)
    _assert_dual_close(dual.inv(x), y.real, y.dual, 1e-12, "inverse")


# -- arithmetic ------------------------------------------------------------------------------


def test_arithmetic_against_hand_formulas(dtype, gen):
    a, b, c, d = (torch.randn(20, generator=gen, dtype=F64).to(dtype) for _ in range(4))
    c = c.abs() + 0.5
    x, y = Dual(a, b), Dual(c, d)
    tol = 4 * TOL[dtype]
    _assert_dual_close(x + y, a + c, b + d, tol, "+")
    _assert_dual_close(x - y, a - c, b - d, tol, "-")
    _assert_dual_close(x * y, a * c, a * d + b * c, tol, "*")
    _assert_dual_close(x / y, a / c, (b * c - a * d) / c**2, tol, "/")
    for z, real, dual_part in ((-x, -a, -b), (x.conj(), a, -b), (dual.conj(x), a, -b)):
        assert torch.equal(z.real, real) and torch.equal(z.dual, dual_part)
    _assert_dual_close(dual.mul(x, y), a * c, a * d + b * c, tol, "mul")
    _assert_dual_close(dual.div(x, y), a / c, (b * c - a * d) / c**2, tol, "div")
    # x conj(x) = a^2 (the paper's inverse formula).
    _assert_dual_close(x * x.conj(), a * a, torch.zeros_like(b), tol, "x conj(x)")


def test_mixing_with_numbers_and_tensors(gen):
    a, b = torch.randn(6, generator=gen, dtype=F64), torch.randn(6, generator=gen, dtype=F64)
    t = torch.rand(6, generator=gen, dtype=F64) + 0.5
    x = Dual(a, b)
    cases = {
        "x + 2": (x + 2.0, a + 2, b),
        "2 + x": (2.0 + x, a + 2, b),
        "x - 2": (x - 2, a - 2, b),
        "2 - x": (2 - x, 2 - a, -b),
        "x * 3": (x * 3.0, 3 * a, 3 * b),
        "3 * x": (3 * x, 3 * a, 3 * b),
        "x / 4": (x / 4.0, a / 4, b / 4),
        "4 / x": (4.0 / x, 4 / a, -4 * b / a**2),
        "x + t": (x + t, a + t, b),
        "t + x": (t + x, a + t, b),
        "x - t": (x - t, a - t, b),
        "t - x": (t - x, t - a, -b),
        "x * t": (x * t, a * t, b * t),
        "t * x": (t * x, a * t, b * t),
        "x / t": (x / t, a / t, b / t),
        "t / x": (t / x, t / a, -t * b / a**2),
        "mul(x, t)": (dual.mul(x, t), a * t, b * t),
        "mul(2, x)": (dual.mul(2.0, x), 2 * a, 2 * b),
        "div(t, x)": (dual.div(t, x), t / a, -t * b / a**2),
        "div(x, 2)": (dual.div(x, 2.0), a / 2, b / 2),
        "atan2(x, 1)": (dual.atan2(x, 1.0), torch.atan2(a, torch.ones_like(a)), b / (1 + a**2)),
    }
    for name, (y, real, dual_part) in cases.items():
        assert isinstance(y, Dual), name
        torch.testing.assert_close(y.real, real, rtol=1e-14, atol=1e-14, msg=name)
        torch.testing.assert_close(y.dual, dual_part, rtol=1e-14, atol=1e-14, msg=name)


def test_broadcasting(gen):
    x = _rand_dual((3, 1), gen)
    y = _rand_dual((4,), gen)
    t = torch.rand(4, generator=gen, dtype=F64) + 0.5
    for z in (x + y, x - y, x * y, x / y, dual.mul(x, y), dual.div(x, y), dual.atan2(x, y),
              x + t, t * x, t / x, x / t, dual.mul(x, t), dual.atan2(t, x)):
        assert z.shape == (3, 4) and z.real.shape == z.dual.shape == (3, 4)
    z = x * y
    torch.testing.assert_close(z.dual, x.real * y.dual + x.dual * y.real)


def test_construction_and_attributes(gen):
    r = torch.randn(3, 1, generator=gen, dtype=F64)
    x = Dual(r, torch.ones(4, dtype=F64))
    assert x.shape == (3, 4) and x.real.shape == x.dual.shape == (3, 4)
    assert x.dtype == F64 and x.device == r.device and x.ndim == 2
    real, dual_part = x
    assert real is x.real and dual_part is x.dual
    y = x[1:, 2]
    assert y.shape == (2,)
    torch.testing.assert_close(y.real, r[1:, 0])
    # Python numbers take the other part's dtype, or torch's default if both are numbers.
    assert Dual(r, 2.0).dual.dtype == F64 and Dual(2.0, r).real.dtype == F64
    assert Dual(1.0, 2.0).dtype == torch.get_default_dtype()
    assert float(Dual(r).dual.abs().max()) == 0.0 and Dual(r).shape == r.shape
    assert x.to(torch.float32).dtype == torch.float32
    assert x.to("cpu").device.type == "cpu"
    assert "Dual(real=" in repr(x)
    with pytest.raises(AttributeError, match="immutable"):
        x.real = r
    z = pickle.loads(pickle.dumps(x))
    torch.testing.assert_close(z.dual, x.dual)
    assert copy.deepcopy(x).shape == x.shape
    rg = r.clone().requires_grad_()
    assert not Dual(rg, 1.0).detach().real.requires_grad


@pytest.mark.parametrize("low", [torch.float16, torch.bfloat16])
def test_dtype_and_device_follow_inputs(low, device):
    x = Dual(torch.tensor([0.5, 0.0, 2.0], device=device).to(low), 1.0)
    for f in (dual.sin, dual.cos, dual.tan, dual.acos, dual.sqrt, dual.exp, dual.log,
              dual.inv, lambda x: dual.atan2(x, x), lambda x: x * x / (x + 1.0) - 2.0):
        out = f(x)
        assert out.real.dtype == out.dual.dtype == low
        assert out.real.device == out.dual.device == x.device
    d = dual.sqrt(x).dual.float()
    assert float(d[1]) == math.inf and abs(float(d[0]) - 0.5**0.5) < 1e-2


def test_inputs_not_modified(gen):
    a, b = torch.randn(5, generator=gen, dtype=F64), torch.randn(5, generator=gen, dtype=F64)
    a0, b0 = a.clone(), b.clone()
    x = Dual(a, b)
    for f in (dual.sin, dual.cos, dual.tan, dual.acos, dual.sqrt, dual.exp, dual.log,
              dual.inv, dual.conj, lambda x: -x, lambda x: x * x / x - x + 1.0,
              lambda x: dual.atan2(x, x)):
        f(x)
    assert torch.equal(a, a0) and torch.equal(b, b0)


def test_no_comparison_overloads(gen):
    x = _rand_dual((3,), gen)
    assert x == x and x != Dual(x.real, x.dual)  # identity, as for any object
    assert hash(x) == hash(x)


# -- autograd ---------------------------------------------------------------------------------


def _unary_grad_inputs(name, gen):
    _, _, sample = UNARY[name]
    a = sample((4,), gen).requires_grad_()
    b = torch.randn(4, generator=gen, dtype=F64).requires_grad_()
    return a, b


@pytest.mark.parametrize("name", list(UNARY))
def test_gradcheck_unary(name, gen):
    fn = UNARY[name][0]
    a, b = _unary_grad_inputs(name, gen)
    f = lambda a, b: tuple(fn(Dual(a, b)))  # noqa: E731
    assert torch.autograd.gradcheck(f, (a, b))
    assert torch.autograd.gradgradcheck(f, (a, b))


@pytest.mark.parametrize("name", list(BINARY))
def test_gradcheck_binary(name, gen):
    fn, _, sample = BINARY[name]
    a, c = sample((2, 1), gen).requires_grad_(), sample((3,), gen).requires_grad_()
    b = torch.randn(2, 1, generator=gen, dtype=F64).requires_grad_()
    d = torch.randn(3, generator=gen, dtype=F64).requires_grad_()
    f = lambda a, b, c, d: tuple(fn(Dual(a, b), Dual(c, d)))  # noqa: E731
    assert torch.autograd.gradcheck(f, (a, b, c, d))
    assert torch.autograd.gradgradcheck(f, (a, b, c, d))


def test_gradcheck_operators(gen):
    a, b, c, d = (torch.randn(3, generator=gen, dtype=F64).requires_grad_() for _ in range(4))
    with torch.no_grad():
        c.abs_().add_(0.5)

    def f(a, b, c, d):
        x, y = Dual(a, b), Dual(c, d)
        return tuple((x + y) * (x - 2.0) / y - x.conj() * 3.0 + 1.0 / y)

    assert torch.autograd.gradcheck(f, (a, b, c, d))
    assert torch.autograd.gradgradcheck(f, (a, b, c, d))


def test_sincos_custom_function_autograd(gen):
    a = _uniform((5,), -4.0, 4.0, gen).requires_grad_()
    b = torch.randn(5, generator=gen, dtype=F64).requires_grad_()
    f = lambda a, b: tuple(t for d in dual.sincos(Dual(a, b)) for t in d)  # noqa: E731
    assert torch.autograd.gradcheck(f, (a, b), check_forward_ad=True, check_batched_grad=True,
                                    check_batched_forward_grad=True)
    assert torch.autograd.gradgradcheck(f, (a, b), check_fwd_over_rev=True)
    # The backward saves only the inputs a and b (sin and cos are recomputed).
    saved = []
    with torch.autograd.graph.saved_tensors_hooks(lambda t: saved.append(t) or t, lambda t: t):
        s, c = dual.sincos(Dual(a, b))
    assert len(saved) == 2 and saved[0] is a and saved[1] is b
    assert s.real.grad_fn is c.dual.grad_fn  # one node computes both


def test_sincos_vmap_and_jvp(gen):
    a = _uniform((4, 3), -4.0, 4.0, gen)
    b = torch.randn(4, 3, generator=gen, dtype=F64)
    x = Dual(a, b)
    # vmap over the Dual pytree and over plain tensors.
    s = torch.func.vmap(dual.sin)(x)
    assert isinstance(s, Dual)
    torch.testing.assert_close(s.dual, b * torch.cos(a), rtol=0, atol=1e-15)
    c = torch.func.vmap(lambda a, b: dual.cos(Dual(a, b)).dual, in_dims=(1, 1))(a, b)
    torch.testing.assert_close(c, (-b * torch.sin(a)).T, rtol=0, atol=1e-15)
    # jvp: tangent along the real part gives the derivative of each part.
    ta, tb = torch.randn(4, 3, generator=gen, dtype=F64), torch.randn(4, 3, generator=gen,
                                                                      dtype=F64)
    (s, c), (ts, tc) = torch.func.jvp(dual.sincos, (x,), (Dual(ta, tb),))
    torch.testing.assert_close(ts.real, torch.cos(a) * ta, rtol=0, atol=1e-15)
    torch.testing.assert_close(ts.dual, torch.cos(a) * tb - b * torch.sin(a) * ta, rtol=0,
                               atol=1e-14)
    torch.testing.assert_close(tc.dual, -torch.sin(a) * tb - b * torch.cos(a) * ta, rtol=0,
                               atol=1e-14)
    # jacrev / jacfwd / hessian through the custom op.
    h = torch.func.hessian(lambda a: dual.sin(Dual(a, b[0])).dual.sum())(a[0])
    torch.testing.assert_close(h, torch.diag(-b[0] * torch.cos(a[0])), rtol=0, atol=1e-14)


def test_sincos_second_order_in_every_mode(gen):
    """Nested forward mode, forward-over-reverse and double backward through the dual
    sine and cosine: the second derivatives of ``(a, b) -> (sin a, b cos a, cos a, -b sin a)``
    against central differences of the numpy formulas (0.1 returned zeros for ``jvp`` of
    ``jvp``)."""
    import numpy as np

    def ref(z):  # numpy: the four parts at z = (a, b), contracted with w
        a, b = z
        return float(w @ np.array([np.sin(a), b * np.cos(a), np.cos(a), -b * np.sin(a)]))

    def f(z):
        s, c = dual.sincos(Dual(z[0], z[1]))
        return torch.stack((s.real, s.dual, c.real, c.dual)) @ torch.from_numpy(w)

    h = 1e-4
    for a0, b0 in ((0.0, 0.0), (0.7, -1.3), (math.pi / 2, 2.0), (-2.5, 0.4)):
        w = torch.randn(4, generator=gen, dtype=F64).numpy()
        z0 = np.array([a0, b0])
        fd = np.array([[(ref(z0 + h * (e_i + e_j)) - ref(z0 + h * (e_i - e_j))
                         - ref(z0 - h * (e_i - e_j)) + ref(z0 - h * (e_i + e_j))) / (4 * h * h)
                        for e_j in np.eye(2)] for e_i in np.eye(2)])
        z = torch.tensor([a0, b0], dtype=F64)
        for hess in (torch.func.hessian(f)(z), torch.func.jacfwd(torch.func.jacrev(f))(z),
                     torch.autograd.functional.hessian(f, z)):
            assert np.abs(hess.numpy() - fd).max() < 1e-7
        v = torch.randn(2, generator=gen, dtype=F64)
        nested = torch.func.jvp(lambda y, v=v: torch.func.jvp(f, (y,), (v,))[1], (z,), (v,))[1]
        assert abs(nested.item() - v.numpy() @ fd @ v.numpy()) < 1e-7


def test_sin_under_torch_compile(gen):
    torch._dynamo.reset()

    def f(a, b):
        x = Dual(a, b)
        y = dual.sin(x) * dual.cos(x) + 2.0 * x + dual.sqrt(x * x + 1.0) / (x * x + 2.0)
        return y.real.sum() + (y.dual * y.dual).sum()

    compiled = torch.compile(f, fullgraph=True, backend="aot_eager")
    a = _uniform((6,), -3.0, 3.0, gen).requires_grad_()
    b = torch.randn(6, generator=gen, dtype=F64).requires_grad_()
    expected, got = f(a, b), compiled(a, b)
    torch.testing.assert_close(got, expected, rtol=1e-14, atol=0)
    g_exp = torch.autograd.grad(expected, (a, b))
    g_got = torch.autograd.grad(got, (a, b))
    for ge, gg in zip(g_exp, g_got, strict=True):
        torch.testing.assert_close(gg, ge, rtol=1e-13, atol=1e-14)


# -- singular points ---------------------------------------------------------------------------

# name -> (function of (real, dual) tensors, singular real parts, sign of the derivative's limit)
SINGULAR = {
    "acos": (lambda a, b: dual.acos(Dual(a, b)), (1.0, -1.0), -1.0),
    "sqrt": (lambda a, b: dual.sqrt(Dual(a, b)), (0.0,), 1.0),
    "log": (lambda a, b: dual.log(Dual(a, b)), (0.0,), 1.0),
    "inv": (lambda a, b: dual.inv(Dual(a, b)), (0.0,), -1.0),
    "div(1, x)": (lambda a, b: dual.div(1.0, Dual(a, b)), (0.0,), -1.0),
    "div(2 + eps 0, x)": (lambda a, b: Dual(2.0 + 0 * a, 0.0) / Dual(a, b), (0.0,), -1.0),
}


@pytest.mark.parametrize("name", list(SINGULAR))
def test_singular_zero_dual_is_exact_zero_with_finite_grads(name, dtype, device):
    fn, points, _ = SINGULAR[name]
    a = torch.tensor(points, dtype=dtype, device=device, requires_grad=True)
    b = torch.zeros_like(a, requires_grad=True)
    out = fn(a, b)
    assert torch.equal(out.dual, torch.zeros_like(a)), f"{name}: dual part {out.dual}"
    out.dual.sum().backward()
    assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all(), \
        f"{name}: grads {a.grad}, {b.grad}"


@pytest.mark.parametrize("name", list(SINGULAR))
def test_singular_nonzero_dual_is_signed_inf(name):
    fn, points, sign = SINGULAR[name]
    a = torch.tensor(points, dtype=F64).repeat_interleave(3)
    b = torch.tensor([1.0, -2.0, math.nan] * len(points), dtype=F64)
    d = fn(a, b).dual
    expected = sign * torch.tensor([math.inf, -math.inf, math.nan] * len(points), dtype=F64)
    torch.testing.assert_close(d, expected, equal_nan=True, msg=f"{name}: dual part {d}")


@pytest.mark.parametrize("name", list(SINGULAR))
def test_regular_zero_dual_keeps_exact_gradient(name):
    """The guard must not touch regular points: d(dual)/d(b) = f'(a) even where b == 0."""
    fn, _, _ = SINGULAR[name]
    a = torch.tensor([0.5, 0.25], dtype=F64)
    b = torch.zeros(2, dtype=F64, requires_grad=True)
    fn(a, b).dual.sum().backward()
    _, expected = torch.func.jvp(lambda a: fn(a, torch.zeros_like(a)).real, (a,),
                                 (torch.ones_like(a),))
    torch.testing.assert_close(b.grad, expected, rtol=1e-15, atol=0)


def test_atan2_at_origin():
    zeros = torch.zeros(5, dtype=F64, requires_grad=True)
    yd = torch.tensor([0.0, 1.0, -1.0, 0.0, 0.0], dtype=F64, requires_grad=True)
    xd = torch.tensor([0.0, 0.0, 0.0, 1.0, -1.0], dtype=F64, requires_grad=True)
    y, x = Dual(zeros, yd), Dual(zeros * 1.0, xd)
    out = dual.atan2(y, x)
    # The angle jumps from atan2(0, 0) = 0 to atan2(yd, xd) along the dual direction.
    inf = math.inf
    assert torch.equal(out.dual, torch.tensor([0.0, inf, -inf, 0.0, inf], dtype=F64))
    assert torch.equal(out.real, torch.zeros(5, dtype=F64))
    # Zero dual parts: exact zero and finite gradients of the dual part.
    ya = torch.zeros(1, dtype=F64, requires_grad=True)
    xa = torch.zeros(1, dtype=F64, requires_grad=True)
    b = torch.zeros(1, dtype=F64, requires_grad=True)
    d = torch.zeros(1, dtype=F64, requires_grad=True)
    out = dual.atan2(Dual(ya, b), Dual(xa, d))
    assert torch.equal(out.dual, torch.zeros(1, dtype=F64))
    (out.real + out.dual).sum().backward()
    for g in (ya.grad, xa.grad, b.grad, d.grad):
        assert torch.isfinite(g).all()
    nan = dual.atan2(Dual(torch.zeros(1, dtype=F64), math.nan), Dual(torch.zeros(1, dtype=F64)))
    assert torch.isnan(nan.dual).all()


def test_div_by_zero_real_parts():
    inf = math.inf
    # (a + eps b) / (0 + eps d): b / (+0) = +inf; -a d / 0 = -sign(a d) inf.
    x = Dual(torch.tensor([1.0, 1.0, 1.0, -1.0]), torch.tensor([0.0, 1.0, 0.0, 0.0]))
    y = Dual(torch.zeros(4), torch.tensor([0.0, 0.0, 1.0, 1.0]))
    out = x / y
    assert torch.equal(out.real, torch.tensor([inf, inf, inf, -inf]))
    assert torch.equal(out.dual, torch.tensor([0.0, inf, -inf, inf]))
    # Dividing a real number by a real zero stays real.
    z = Dual(torch.tensor([2.0]), 0.0) / torch.zeros(1)
    assert torch.equal(z.real, torch.tensor([inf])) and torch.equal(z.dual, torch.zeros(1))


def test_acos_outside_domain_is_nan():
    out = dual.acos(Dual(torch.tensor([1.5, -2.0]), 1.0))
    assert torch.isnan(out.real).all() and torch.isnan(out.dual).all()


def test_nan_propagates_only_to_its_element():
    a = torch.tensor([0.5, math.nan, 0.25], dtype=F64)
    x = Dual(a, 1.0)
    for f in (dual.sin, dual.cos, dual.tan, dual.acos, dual.sqrt, dual.exp, dual.log,
              dual.inv, lambda x: dual.atan2(x, x), lambda x: x / x):
        out = f(x)
        assert torch.isnan(out.real[1]) and torch.isnan(out.dual[1])
        assert torch.isfinite(out.real[[0, 2]]).all() and torch.isfinite(out.dual[[0, 2]]).all()


# -- argument validation -------------------------------------------------------------------


def test_bad_construction():
    f64 = torch.ones(3, dtype=F64)
    with pytest.raises(TypeError, match=r"Dual: .*floating-point tensor for real"):
        Dual(torch.ones(3, dtype=torch.int64), f64)
    with pytest.raises(TypeError, match=r"Dual: .*floating-point tensor for dual"):
        Dual(f64, torch.ones(3, dtype=torch.int32))
    with pytest.raises(TypeError, match=r"dual has dtype torch\.float32 but real has"):
        Dual(f64, torch.ones(3))
    with pytest.raises(ValueError, match=r"real \(3,\), dual \(4,\)"):
        Dual(f64, torch.ones(4, dtype=F64))
    with pytest.raises(TypeError, match="for real, got list"):
        Dual([1.0], f64)
    with pytest.raises(TypeError, match="for dual, got str"):
        Dual(f64, "0")
    with pytest.raises(TypeError, match="for dual, got bool"):
        Dual(f64, True)
    with pytest.raises(TypeError, match="floating-point tensor for real"):
        Dual(f64, 0.0).to(torch.int64)


@pytest.mark.parametrize("fn", [dual.sin, dual.cos, dual.sincos, dual.tan, dual.acos,
                                dual.sqrt, dual.exp, dual.log, dual.inv, dual.conj])
def test_unary_rejects_non_dual(fn):
    with pytest.raises(TypeError, match=r"dual\.\w+: expected a Dual for x, got Tensor"):
        fn(torch.ones(3))
    with pytest.raises(TypeError, match="expected a Dual for x, got float"):
        fn(1.0)


@pytest.mark.parametrize(("fn", "names"), [(dual.mul, ("a", "b")), (dual.div, ("a", "b")),
                                           (dual.atan2, ("y", "x"))])
def test_binary_validation(fn, names):
    x = Dual(torch.ones(3), 1.0)
    first, second = names
    with pytest.raises(TypeError, match=f"for {second}, got str"):
        fn(x, "1")
    with pytest.raises(TypeError, match=f"for {first}, got list"):
        fn([1.0], x)
    with pytest.raises(TypeError, match=f"floating-point tensor for {second}"):
        fn(x, torch.ones(3, dtype=torch.int64))
    with pytest.raises(TypeError, match=f"{second} has dtype torch.float64"):
        fn(x, torch.ones(3, dtype=F64))
    with pytest.raises(ValueError, match=rf"{first} \(3,\), {second} \(4,\)"):
        fn(x, Dual(torch.ones(4), 0.0))
    with pytest.raises(TypeError, match="got two numbers"):
        fn(1.0, 2.0)


def test_operator_validation():
    x = Dual(torch.ones(3), 1.0)
    with pytest.raises(TypeError, match="unsupported operand"):
        x + "a"
    with pytest.raises(TypeError):
        [1.0] * x
    with pytest.raises(TypeError, match=r"Dual.__mul__: .*floating-point tensor for other"):
        x * torch.ones(3, dtype=torch.int64)
    with pytest.raises(TypeError, match=r"other has dtype torch\.float64"):
        x / torch.ones(3, dtype=F64)
    with pytest.raises(ValueError, match=r"self \(3,\), other \(2,\)"):
        x - Dual(torch.ones(2), 0.0)
    with pytest.raises(ValueError, match=r"Dual.__radd__|Dual.__add__"):
        torch.ones(2) + x


def test_apply_validation():
    x = Dual(torch.ones(3), 1.0)
    with pytest.raises(TypeError, match=r"dual\.apply: expected a callable for df"):
        dual.apply(torch.sin, 2.0, x)
    with pytest.raises(TypeError, match=r"dual\.apply: expected a Dual for x"):
        dual.apply(torch.sin, torch.cos, torch.ones(3))

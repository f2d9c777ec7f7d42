"""The fused kernels against the readable references (roma's ``slerp`` / ``slerp_fast``).

Every public function backed by a custom autograd op runs it in eager reverse mode and its
readable plain-op reference under ``torch.func`` transforms and forward-mode AD
(``torch_dq._dispatch.fused_path``). Here both are run on the same inputs, random and
degenerate (equal and opposite rotations, pure translations, relative rotations of 0,
1e-9, 1e-6, 1e-3 rad, half turns, translations up to 1e3), and compared:

- sclerp (eq. 11): ``_kernels.sclerp.sclerp`` against ``dualquat._eq11``;
- quaternion slerp (the real part of eq. 11, shortest path): ``_kernels.slerp.slerp``
  against ``_kernels.slerp.plain`` (the same forward to the bit, chunked; the analytic
  backward against autograd of the plain ops). The independent references (scipy, a numpy
  formula, finite differences) are in ``test_quat.py``;
- the dual angle (eqs. 4-5): ``_kernels.dual_angle.dual_angle`` against
  ``dualquat._eqs4_5``, and the public ``angle`` with and without ``torch.func``;
- dual sine and cosine: ``_kernels.sincos.SinCos`` against ``dual._sincos``;
- the fused De Casteljau / De Boor pyramid: ``curves.bezier`` / ``curves.bspline`` against
  themselves under ``torch.func.vmap`` (the readable level loops) and against a De Casteljau
  loop of ``dualquat.sclerp`` written here.

Bounds (float64), relative to the scale ``s = max(1, |a|, |b|)`` of the inputs' components
(translations up to 1e3 make the dual parts that large): values within 32 eps s; gradients
(a random cotangent) within 256 eps s max(1, |grad|); Hessian-vector products through the
fused double backward within 1e-10 relative. float32 kernels against the float64
reference: within 1e-6 s with the shortest path, 8e-6 s with ``shortest=False`` away from
opposite real parts (``q0 . q1 > -0.99``: the path's conditioning is 1 / sin(theta)), ties
(orthogonal real parts, where float32 and float64 may pick different equally short paths)
excluded.
"""

import math

import pytest
import torch
from references import hamilton
from strategies import adversarial_dqs, screw, unit_dq

import torch_dq.dual as D
import torch_dq.dualquat as dq
from torch_dq import _taylor, curves
from torch_dq._kernels import dual_angle as angle_kernel
from torch_dq._kernels import jet_pyramid, jet_sclerp, layout
from torch_dq._kernels import sclerp as sclerp_kernel
from torch_dq._kernels import slerp as slerp_kernel
from torch_dq._kernels.sincos import SinCos
from torch_dq.dual import Dual

EPS = torch.finfo(torch.float64).eps
T_VALUES = (0.0, 1.0, 0.5, -0.5, 1.5)


def degenerate_pairs(gen):
    """``(a, b, t, scale)``: random pairs, screw families at the degenerate angles, every pair
    of adversarial poses, equal and sign-flipped pairs; ``t`` cycles through ``T_VALUES``."""
    pairs = [(unit_dq((300,), gen), unit_dq((300,), gen))]
    for theta in (0.0, 1e-9, 1e-6, 1e-3, 0.5, math.pi / 2, math.pi - 1e-6, math.pi):
        for d in (0.0, 1.0, 100.0):
            axis, moment, th, dd = screw((40,), gen, theta, d, moment_scale=10.0)
            a = unit_dq((40,), gen, scale=10.0)
            pairs.append((a, dq.mul(a, dq.from_screw(axis, moment, th, dd))))
    adv = adversarial_dqs()
    i, j = torch.meshgrid(torch.arange(len(adv)), torch.arange(len(adv)), indexing="ij")
    pairs.append((adv[i.reshape(-1)], adv[j.reshape(-1)]))
    a = unit_dq((100,), gen, scale=3.0)
    pairs += [(a, a), (a, -a), (a, dq.from_rt(a[:, :4], torch.randn(100, 3, generator=gen,
                                                                     dtype=torch.float64)))]
    a, b = (torch.cat(x) for x in zip(*pairs, strict=True))
    t = torch.tensor(T_VALUES, dtype=torch.float64).repeat(len(a) // len(T_VALUES) + 1)[:len(a)]
    t = t[torch.randperm(len(a), generator=gen)]
    scale = torch.maximum(a.abs().amax(-1), b.abs().amax(-1)).clamp(min=1.0)
    return a, b, t, scale


@pytest.fixture(scope="module")
def pairs():
    return degenerate_pairs(torch.Generator().manual_seed(12))


def usable(a, b, shortest):
    """Pairs on which the function is defined: every pair with the shortest path; away from
    opposite real parts (undefined) without it."""
    c = (a[:, :4] * b[:, :4]).sum(-1)
    return torch.ones_like(c, dtype=torch.bool) if shortest else c > -0.99


def hvp_fused(f, args, w, v):
    """Hessian-vector product of ``<w, f(args)>`` by double backward (the fused ops)."""
    xs = [x.clone().requires_grad_() for x in args]
    gs = torch.autograd.grad((f(*xs) * w).sum(), xs, create_graph=True)
    return torch.autograd.grad(sum((g * u).sum() for g, u in zip(gs, v, strict=True)), xs)


def hvp_readable(f, args, w, v):
    """The same by forward-over-reverse under ``torch.func`` (the readable references)."""
    def grad(*xs):
        return torch.func.grad(lambda *ys: (f(*ys) * w).sum(), argnums=tuple(range(len(xs))))(*xs)

    return torch.func.jvp(grad, tuple(args), tuple(v))[1]


def rel(x, y):
    """Max ``|x - y|`` relative to ``max(1, |y|)`` over all entries."""
    return ((x - y).abs() / y.abs().amax().clamp(min=1.0)).max().item()


# ----------------------------------------------------------------------------- sclerp

@pytest.mark.parametrize("shortest", [True, False])
def test_sclerp_kernel_values_float64(pairs, shortest):
    a, b, t, s = (x[usable(*pairs[:2], shortest)] for x in pairs)
    fused = sclerp_kernel.sclerp(a, b, t, shortest)
    ref = dq._eq11(a, b, t, shortest)
    err = ((fused - ref).abs().amax(-1) / s).max().item()
    assert err <= 32 * EPS, err  # measured 16 eps


@pytest.mark.parametrize("shortest", [True, False])
def test_sclerp_kernel_values_float32(pairs, shortest):
    a, b, t, s = (x[usable(*pairs[:2], shortest)] for x in pairs)
    c = (a[:, :4] * b[:, :4]).sum(-1)
    keep = c.abs() > 1e-3  # no ties: float32 may pick the other equally short path
    a, b, t, s = a[keep], b[keep], t[keep], s[keep]
    ref = dq._eq11(a, b, t, shortest)
    fused = sclerp_kernel.sclerp(a.float(), b.float(), t.float(), shortest).double()
    readable = dq._eq11(a.float(), b.float(), t.float(), shortest).double()
    bound = 1e-6 if shortest else 8e-6  # measured 5.2e-7 and 5.0e-6
    assert ((fused - ref).abs().amax(-1) / s).max() <= bound
    assert ((fused - readable).abs().amax(-1) / s).max() <= bound  # measured 2.8e-7, 8e-7


@pytest.mark.parametrize("shortest", [True, False])
def test_sclerp_kernel_gradients(pairs, shortest):
    a, b, t, s = (x[usable(*pairs[:2], shortest)] for x in pairs)
    w = torch.randn(a.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    xs = [x.clone().requires_grad_() for x in (a, b, t)]
    fused = torch.autograd.grad((sclerp_kernel.sclerp(*xs, shortest) * w).sum(), xs)
    _, vjp = torch.func.vjp(lambda *ys: dq._eq11(*ys, shortest), a, b, t)
    for g, r in zip(fused, vjp(w), strict=True):
        g, r = g.reshape(len(s), -1), r.reshape(len(s), -1)
        err = (g - r).abs().amax(-1) / (s * r.abs().amax(-1).clamp(min=1.0))
        assert err.max() <= 256 * EPS, err.max()  # measured 113 eps (t = -0.5, c = 0.94)


@pytest.mark.parametrize("theta", [0.0, 1e-9, 1e-3, 0.7])
@pytest.mark.parametrize("t", [0.0, 0.3, 1.0])
def test_sclerp_kernel_second_order(gen, theta, t):
    """Double backward through the fused op equals forward-over-reverse of eq. 11."""
    axis, moment, th, d = screw((6,), gen, theta, 2.0)
    a = unit_dq((6,), gen)
    b = dq.mul(a, dq.from_screw(axis, moment, th, d))
    tt = torch.full((6,), t, dtype=torch.float64)
    w = torch.randn(6, 8, generator=gen, dtype=torch.float64)
    v = [torch.randn(x.shape, generator=gen, dtype=torch.float64) for x in (a, b, tt)]
    for shortest in (True, False):
        def f(x, y, z, shortest=shortest):
            return dq.sclerp(x, y, z, shortest=shortest)

        for h, r in zip(hvp_fused(f, (a, b, tt), w, v), hvp_readable(f, (a, b, tt), w, v),
                        strict=True):
            assert rel(h, r) < 1e-10


def test_sclerp_public_under_and_outside_vmap(pairs):
    a, b, t, s = pairs
    fused = dq.sclerp(a, b, t)
    readable = torch.func.vmap(dq.sclerp)(a, b, t)
    assert ((fused - readable).abs().amax(-1) / s).max() <= 32 * EPS


# ----------------------------------------------------------------------------- quaternion slerp

def slerp_pairs(gen, n_random=300):
    """``(q0, q1)``: random pairs, pairs at relative angles from 0 to pi (both signs of
    ``q1``: equal, opposite, across the weights' series switch, half turns with a dot of
    exactly 0), all float64."""
    q0 = unit_quat_rows(n_random, gen)
    pairs = [(q0, unit_quat_rows(n_random, gen))]
    for angle in (0.0, 1e-9, 1e-6, 1e-3, 0.3, 0.55, 0.6, 1.0, math.pi / 2, 2.0, math.pi - 1e-6,
                  math.pi):
        a = unit_quat_rows(20, gen)
        axis = torch.randn(20, 3, generator=gen, dtype=torch.float64)
        axis = axis / axis.norm(dim=-1, keepdim=True)
        rel = torch.cat((torch.full((20, 1), math.cos(angle / 2), dtype=torch.float64),
                         math.sin(angle / 2) * axis), -1)
        b = hamilton(a, rel)
        pairs += [(a, b), (a, -b)]
    e = torch.eye(4, dtype=torch.float64)
    pairs.append((e[[0, 1, 2, 3, 0]], e[[1, 0, 3, 2, 0]]))  # dots of exactly 0, and equal
    return tuple(torch.cat(x) for x in zip(*pairs, strict=True))


def unit_quat_rows(n, gen):
    q = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    return q / q.norm(dim=-1, keepdim=True)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("common_t", [False, True])
def test_slerp_kernel_forward_is_the_plain_formula(gen, monkeypatch, dtype, common_t):
    """Same bits as the plain ops (which ``quat.slerp`` runs under ``torch.func``), over
    several chunks (all-series, mixed and closed-form ones), with one ``t`` for all pairs
    and with one per pair."""
    monkeypatch.setattr(layout, "CHUNK", 128)
    q0, q1 = (x.to(dtype) for x in slerp_pairs(gen))
    n = q0.shape[0]
    t = (torch.tensor([0.3], dtype=dtype) if common_t else
         torch.tensor(T_VALUES, dtype=dtype).repeat(n // len(T_VALUES) + 1)[:n])
    fused = slerp_kernel.slerp(q0, q1, t)
    assert torch.equal(fused, slerp_kernel.plain(q0, q1, t.expand(n)))
    assert torch.equal(fused, slerp_kernel.plain(q0, q1, t.expand(n), host_branch=True))


@pytest.mark.parametrize("common_t", [False, True])
def test_slerp_kernel_gradients(gen, monkeypatch, common_t):
    """The analytic backward against reverse-mode autograd of the plain ops (over several
    chunks: a common ``t`` sums its gradient over them)."""
    monkeypatch.setattr(layout, "CHUNK", 128)
    q0, q1 = slerp_pairs(gen)
    n = q0.shape[0]
    t = (torch.tensor([0.7], dtype=torch.float64) if common_t else
         torch.tensor(T_VALUES, dtype=torch.float64).repeat(n // len(T_VALUES) + 1)[:n])
    w = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    xs = [x.clone().requires_grad_() for x in (q0, q1, t)]
    fused = torch.autograd.grad((slerp_kernel.slerp(*xs) * w).sum(), xs)
    _, vjp = torch.func.vjp(lambda a, b, s: slerp_kernel.plain(a, b, s.expand(n)), q0, q1, t)
    for g, r in zip(fused, vjp(w), strict=True):
        assert g.shape == r.shape
        assert rel(g, r) <= 64 * EPS, rel(g, r)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-3, 0.7, math.pi - 1e-6, math.pi])
@pytest.mark.parametrize("t", [0.0, 0.3, 1.0, 1.5])
def test_slerp_kernel_second_order(gen, angle, t):
    """Double backward through the analytic backward equals forward-over-reverse of the
    plain ops, at and near equal (``angle = 0``) and opposite (``angle = pi``: ``q1`` is
    ``-q0`` up to the rotation by ``2 pi - angle``) quaternions."""
    q0 = unit_quat_rows(6, gen)
    axis = torch.randn(6, 3, generator=gen, dtype=torch.float64)
    rel_q = torch.cat((torch.full((6, 1), math.cos(angle / 2), dtype=torch.float64),
                       math.sin(angle / 2) * axis / axis.norm(dim=-1, keepdim=True)), -1)
    q1 = hamilton(q0, rel_q)
    tt = torch.full((6,), t, dtype=torch.float64)
    w = torch.randn(6, 4, generator=gen, dtype=torch.float64)
    v = [torch.randn(x.shape, generator=gen, dtype=torch.float64) for x in (q0, q1, tt)]
    for h, r in zip(hvp_fused(slerp_kernel.slerp, (q0, q1, tt), w, v),
                    hvp_readable(slerp_kernel.plain, (q0, q1, tt), w, v), strict=True):
        assert rel(h, r) < 1e-10


def test_slerp_kernel_keeps_non_finite_input_in_its_pair(gen):
    q0, q1 = unit_quat_rows(16, gen), unit_quat_rows(16, gen)
    t = torch.full((16,), 0.3, dtype=torch.float64)
    for bad in (math.nan, math.inf, -math.inf):
        a, b = q0.clone(), q1.clone()
        a[range(4), range(4)] = bad  # each component of q0 in turn
        b[range(4, 8), range(4)] = bad  # each component of q1 in turn
        xs = [x.clone().requires_grad_() for x in (a, b, t)]
        out = slerp_kernel.slerp(*xs)
        assert not torch.isfinite(out[:8]).all(-1).any()
        assert torch.equal(out[8:], slerp_kernel.slerp(q0[8:], q1[8:], t[8:]))
        grads = torch.autograd.grad(out[8:].sum(), xs)
        clean = [x[8:].clone().requires_grad_() for x in (q0, q1, t)]
        ref = torch.autograd.grad(slerp_kernel.slerp(*clean).sum(), clean)
        assert all(torch.equal(g[8:], r) for g, r in zip(grads, ref, strict=True))


@pytest.mark.parametrize("common_t", [False, True])
def test_slerp_compiles_as_one_graph(gen, common_t):
    """``torch.compile(quat.slerp, fullgraph=True)`` traces the fused op (``aot_eager``
    backend): values and gradients as eager, at two sizes, without recompiling."""
    from torch._dynamo.testing import CompileCounterWithBackend

    from torch_dq import quat
    torch._dynamo.reset()
    counter = CompileCounterWithBackend("aot_eager")
    compiled = torch.compile(quat.slerp, fullgraph=True, backend=counter)
    frames = []
    for n in (5, 9):
        q0, q1 = slerp_pairs(gen, n_random=n)
        q0, q1 = q0[:n], q1[:n]
        t = torch.tensor(0.4, dtype=torch.float64) if common_t else torch.rand(
            n, generator=gen, dtype=torch.float64)
        w = torch.randn(n, 4, generator=gen, dtype=torch.float64)
        outs = []
        for f in (compiled, quat.slerp):
            xs = [x.clone().requires_grad_() for x in (q0, q1, t)]
            for x in xs[:2] if common_t else xs:
                torch._dynamo.mark_dynamic(x, 0)
            y = f(*xs)
            outs.append((y, *torch.autograd.grad((y * w).sum(), xs)))
        for x, r in zip(*outs, strict=True):
            assert torch.allclose(x, r, rtol=0, atol=1e-14)
        frames.append(counter.frame_count)
    # no recompilation at the second size (a 0-d t restarts the first analysis once, as
    # for sclerp: dynamo counts that frame twice)
    assert frames[0] == frames[1] <= (2 if common_t else 1)
    torch._dynamo.reset()


# ----------------------------------------------------------------------------- dual angle

def test_dual_angle_kernel_values(pairs):
    a, b, _, s = pairs
    fused = angle_kernel.dual_angle(a, b)
    theta, theta_hat, degenerate = dq._eqs4_5(a, b)
    assert torch.equal(fused.degenerate, degenerate)
    assert degenerate.any() and (~degenerate).any()
    assert (fused.theta - theta).abs().max() <= 4 * EPS
    assert torch.equal(fused.theta_hat[degenerate], torch.zeros_like(theta_hat[degenerate]))
    ok = ~degenerate
    err = (fused.theta_hat[ok] - theta_hat[ok]).abs() / (s[ok] * theta_hat[ok].abs().clamp(min=1))
    assert err.max() <= 8 * EPS


def test_dual_angle_kernel_float32(pairs):
    a, b, _, s = pairs
    ref = angle_kernel.dual_angle(a, b)
    fused = angle_kernel.dual_angle(a.float(), b.float())
    readable = dq._eqs4_5(a.float(), b.float())
    assert torch.equal(fused.degenerate, readable[2])
    assert (fused.theta - readable[0]).abs().max() <= 4 * torch.finfo(torch.float32).eps
    # theta from the rounded inputs: 2 atan2(|R - P|, |R + P|) is well conditioned
    assert (fused.theta.double() - ref.theta).abs().max() < 1e-6
    # theta_hat where sin(theta) > 0.1 (elsewhere its conditioning is 1 / sin(theta))
    ok = (torch.sin(ref.theta) > 0.1) & ~fused.degenerate
    err = (fused.theta_hat.double() - ref.theta_hat).abs() / s
    assert err[ok].max() < 1e-5


def test_dual_angle_public_gradients_and_second_order(pairs):
    a, b, _, _ = pairs
    gen = torch.Generator().manual_seed(4)
    w = torch.randn(2, len(a), generator=gen, dtype=torch.float64)

    def f(x, y):
        ang = dq.angle(x, y)
        return torch.stack((ang.real, ang.dual))

    fused = f(a, b)
    assert rel(fused, torch.func.vmap(f, out_dims=1)(a, b)) <= 8 * EPS
    xs = [x.clone().requires_grad_() for x in (a, b)]
    g_fused = torch.autograd.grad((f(*xs) * w).sum(), xs)
    _, vjp = torch.func.vjp(f, a, b)
    for g, r in zip(g_fused, vjp(w), strict=True):
        assert rel(g, r) <= 64 * EPS
    # second order away from the kinks (theta = 0 or pi) and the eq. 6 branch
    sin_theta = torch.sin(fused[0])
    keep = sin_theta > 1e-2
    a, b, w = a[keep][:200], b[keep][:200], w[:, keep][:, :200]
    v = [torch.randn(x.shape, generator=gen, dtype=torch.float64) for x in (a, b)]
    for h, r in zip(hvp_fused(f, (a, b), w, v), hvp_readable(f, (a, b), w, v), strict=True):
        assert rel(h, r) < 1e-10


# ----------------------------------------------------------------------------- dual sin / cos

def test_sincos_op_against_plain_ops(gen):
    x = torch.randn(50, generator=gen, dtype=torch.float64) * 4
    y = torch.randn(50, generator=gen, dtype=torch.float64)
    fused = SinCos.apply(x, y)
    plain = D._sincos(x, y)
    for f, p in zip(fused, plain, strict=True):
        assert torch.equal(f, p)
    w = torch.randn(4, 50, generator=gen, dtype=torch.float64)
    v = [torch.randn(50, generator=gen, dtype=torch.float64) for _ in range(2)]

    def through(op):
        return lambda a, b: torch.stack(op(a, b))

    for h, r in zip(hvp_fused(through(SinCos.apply), (x, y), w, v),
                    hvp_readable(through(D._sincos), (x, y), w, v), strict=True):
        assert rel(h, r) <= 8 * EPS
    # the public functions pick the op outside transforms and the plain ops inside
    s_fused, c_fused = D.sincos(Dual(x, y))
    s_vmap, c_vmap = torch.func.vmap(D.sincos)(Dual(x, y))
    for f, p in zip((*s_fused, *c_fused), (*s_vmap, *c_vmap), strict=True):
        assert torch.equal(f, p)


# ----------------------------------------------------------------------------- curve pyramid

def de_casteljau(ctrl, s):
    """De Casteljau with the public sclerp, written here: ``ctrl (n, 8)``, ``s (T,)``."""
    q = [ctrl[i].expand(len(s), 8) for i in range(len(ctrl))]
    while len(q) > 1:
        q = [dq.sclerp(q[i], q[i + 1], s) for i in range(len(q) - 1)]
    return q[0]


def up_to_sign(x, ref):
    sign = torch.where((x[..., :4] * ref[..., :4]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    return (x - sign * ref).abs().max().item()


def curve_ctrl(gen, n):
    """Control points: random, then a repeated pose, a pure translation and a 1e-9 turn."""
    ctrl = unit_dq((3, n), gen, scale=2.0)
    ctrl[1, 2] = ctrl[1, 1]
    ctrl[1, 3] = dq.from_rt(ctrl[1, 1, :4], torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64))
    axis, moment, th, d = screw((), gen, 1e-9, 0.5)
    ctrl[2, 1] = dq.mul(ctrl[2, 0], dq.from_screw(axis, moment, th, d))
    return ctrl


def test_bezier_pyramid_against_loops(gen):
    ctrl = curve_ctrl(gen, 5)
    t = torch.tensor([0.0, 0.1, 0.5, 0.77, 1.0], dtype=torch.float64)
    fused = curves.bezier(ctrl, t)
    readable = torch.func.vmap(lambda c: curves.bezier(c, t, check=False))(ctrl)
    assert up_to_sign(fused, readable) < 1e-13
    for k in range(3):
        assert up_to_sign(fused[k], de_casteljau(ctrl[k], t)) < 1e-13


def test_bspline_pyramid_against_readable(gen):
    ctrl = curve_ctrl(gen, 7)
    t = torch.linspace(0, 1, 23, dtype=torch.float64)
    for degree in (1, 2, 3):
        fused = curves.bspline(ctrl, t, degree=degree)
        readable = torch.func.vmap(lambda c, p=degree: curves.bspline(c, t, p, check=False))(ctrl)
        assert up_to_sign(fused, readable) < 1e-13


@pytest.mark.parametrize("name", ["bezier", "bspline"])
def test_pyramid_gradients_first_and_second_order(gen, name):
    ctrl = curve_ctrl(gen, 5)
    t = torch.tensor([0.0, 0.3, 0.5, 1.0], dtype=torch.float64)

    def f(c, t):
        return curves.bezier(c, t, check=False) if name == "bezier" else curves.bspline(
            c, t, degree=3, check=False)

    w = torch.randn(3, 4, 8, generator=gen, dtype=torch.float64)
    xs = [x.clone().requires_grad_() for x in (ctrl, t)]
    fused = torch.autograd.grad((f(*xs) * w).sum(), xs)
    _, vjp = torch.func.vjp(f, ctrl, t)
    for g, r in zip(fused, vjp(w), strict=True):
        assert rel(g, r) < 1e-12
    v = [torch.randn(x.shape, generator=gen, dtype=torch.float64) for x in (ctrl, t)]
    fused_hvp = hvp_fused(f, (ctrl, t), w, v)
    for h, r in zip(fused_hvp, hvp_readable(f, (ctrl, t), w, v), strict=True):
        assert rel(h, r) < 1e-10
    # nested forward mode (0 for the custom op in 0.1): v^T H v by jvp of jvp
    def inner(c, t):
        return torch.func.jvp(lambda c, t: (f(c, t) * w).sum(), (c, t), tuple(v))[1]

    nested = torch.func.jvp(inner, (ctrl, t), tuple(v))[1]
    quadratic = sum((h * u).sum() for h, u in zip(fused_hvp, v, strict=True))
    assert abs(nested - quadratic) < 1e-10 * max(1.0, abs(quadratic.item()))


# ----------------------------------------------------------------------------- jets of the scheme

def jet_ctrl(gen, n):
    """Control polygons ``(4, n, 8)`` for the jets: :func:`curve_ctrl`'s (random, a repeated
    pose, a pure translation, a 1e-9 turn) and one of screw steps of 1e-6 rad, a sign-flipped
    repeat and a step of pi - 1e-3 rad (float64)."""
    ctrl = torch.cat((curve_ctrl(gen, n), unit_dq((1, n), gen, scale=2.0)))
    steps = [1e-6, 0.0, math.pi - 1e-3] + [0.4] * (n - 4)
    for i, theta in enumerate(steps, start=1):
        axis, moment, th, d = screw((), gen, theta, 0.3)
        ctrl[3, i] = dq.mul(ctrl[3, i - 1], dq.from_screw(axis, moment, th, d))
    ctrl[3, 2] = -ctrl[3, 1]  # the step of 0: the same pose, other sign
    return ctrl


@pytest.mark.parametrize("name,degree", [("bezier", 4), ("bspline", 1), ("bspline", 2),
                                         ("bspline", 3), ("bspline", 5)])
@pytest.mark.parametrize("order", [1, 2, 3])
def test_jet_pyramid_backward_is_the_plain_jets_vjp(gen, monkeypatch, name, degree, order):
    """The written-out backward of the scheme on jets (:mod:`torch_dq._kernels.jet_pyramid`)
    gives the cotangents of autograd through the plain jets (``torch.func.vjp``, which takes
    them), at equal, sign-flipped, nearly equal and nearly opposite neighbours."""
    levels = []
    monkeypatch.setattr(jet_pyramid, "_level_vjp",
                        lambda p, qb, f=jet_pyramid._level_vjp: levels.append(1) or f(p, qb))
    ctrl = jet_ctrl(gen, degree + 3)
    t = torch.cat((torch.linspace(0, 1, 37, dtype=torch.float64),
                   torch.rand(20, generator=gen, dtype=torch.float64)))

    def f(c):
        if name == "bezier":
            return curves.bezier_derivatives(c, t, order=order, check=False)
        return curves.bspline_derivatives(c, t, order=order, degree=degree, check=False)

    w = [torch.randn(4, len(t), 8, generator=gen, dtype=torch.float64) for _ in range(order + 1)]
    c = ctrl.clone().requires_grad_()
    (fused,) = torch.autograd.grad(f(c), c, w)
    assert levels  # the written-out backward ran
    _, vjp = torch.func.vjp(f, ctrl)
    assert rel(fused, vjp(tuple(w))[0]) < 1e-11


def test_jet_pyramid_gradcheck_and_double_backward(gen):
    """Finite differences of the order-2 jets at degenerate neighbours (first order: the
    written-out backward), and their second derivatives (the plain jets' VJP, differentiable
    again), in float64; a batched Jacobian (``vmap`` of the backward) as well."""
    ctrl = jet_ctrl(gen, 5)[[1, 3]]  # a repeated pose, a translation; the steps
    t = torch.tensor([0.05, 0.52, 0.95], dtype=torch.float64)

    def f(c):
        return curves.bspline_derivatives(c, t, order=2, check=False)

    c = ctrl.requires_grad_()
    assert torch.autograd.gradcheck(f, (c,))
    assert torch.autograd.gradgradcheck(f, (c,), fast_mode=True)
    jac = torch.autograd.functional.jacobian(lambda c: f(c)[2], ctrl, vectorize=True)
    ref = torch.func.jacrev(lambda c: f(c)[2])(ctrl.detach())
    assert rel(jac, ref) < 1e-11


@pytest.mark.parametrize("form", ["de_boor", "cumulative"])
def test_written_backwards_save_through_autograd(gen, form):
    """The written-out backwards of the time derivatives keep their intermediates with
    ``save_for_backward`` (freed after the backward, seen by saved-tensor hooks such as
    checkpointing and ``save_on_cpu``), not as attributes of their context: the hooks see
    several times the outputs' bytes (before: 1.5x and 2.6x, the gathers' indices), and the
    backward still gives the same gradient when the hooks move them to another tensor."""
    ctrl = unit_dq((12,), gen)
    t = torch.linspace(0.0, 1.0, 3000, dtype=torch.float64)
    knots = None
    if form == "cumulative":
        knots = torch.arange(16, dtype=torch.float64)
        t = 3.0 + 8.99 * t
    packed = []

    def pack(x):
        packed.append(x.numel() * x.element_size())
        return x.clone()

    grads = []
    for hooks in (False, True):
        c = ctrl.clone().requires_grad_()
        with (torch.autograd.graph.saved_tensors_hooks(pack, lambda x: x) if hooks
              else torch.autograd.graph.saved_tensors_hooks(lambda x: x, lambda x: x)):
            xs = curves.bspline_derivatives(c, t, order=2, knots=knots, form=form)
        grads.append(torch.autograd.grad(sum((x * x).sum() for x in xs), c)[0])
    out = sum(x.numel() * x.element_size() for x in xs)
    assert sum(packed) >= 5 * out
    assert torch.equal(grads[0], grads[1])


def test_weight_jets_backward_is_the_plain_vjp(gen):
    """``jet_sclerp.weights`` on jets of ``c`` (its backward written out through the jets of
    ``G`` and ``H = dG/dy``) against autograd through the Taylor recurrences, over both
    branches and the switch between them, orders 1-3; gradcheck (finite differences) and
    gradgradcheck (the plain VJP) on one element of each branch (a second one of the same
    branch took the same path at twice the finite-difference cost)."""
    n = 4000
    y = torch.cat((10 ** torch.empty(n // 2, dtype=torch.float64).uniform_(-12, -0.2,
                                                                            generator=gen),
                   torch.rand(n // 2, generator=gen, dtype=torch.float64)))
    alpha = torch.rand(n, generator=gen, dtype=torch.float64) * 1.4 - 0.2
    for order in (1, 2, 3):
        c = [1.0 - y] + [0.05 * torch.randn(n, generator=gen, dtype=torch.float64)
                         for _ in range(order)]
        a = [alpha, torch.full_like(alpha, 0.7)] + [None] * (order - 1)
        s = _taylor._stack(zip(_taylor._rsub(1.0, a), a, strict=True))
        cs = [x.clone().requires_grad_() for x in c]
        F, G = jet_sclerp.weights(cs, s)
        assert type(F[0].grad_fn).__name__ == "_WeightJetsBackward"
        w = [torch.randn(x.shape, generator=gen, dtype=torch.float64) for x in F + G]
        fused = torch.autograd.grad(F + G, cs, w)
        F2, G2, _ = _taylor.weight_parts(cs, s, with_H=False)
        plain = torch.autograd.grad(F2 + G2, cs, w)
        for x, r in zip(fused, plain, strict=True):
            assert rel(x, r) < 1e-11
        # the smallest y (the series; alpha < 0 there) and one of the second half (closed)
        pick = torch.cat((torch.topk(y, 1, largest=False).indices, torch.tensor([2000])))
        few = [x[pick].detach().clone().requires_grad_() for x in c]
        s_few = [None if x is None else x[:, pick] for x in s]

        def g(*cs, s_few=s_few):
            F, G = jet_sclerp.weights(list(cs), s_few)
            return tuple(F + G)

        assert torch.autograd.gradcheck(g, tuple(few))
        assert torch.autograd.gradgradcheck(g, tuple(few))


# ----------------------------------------------------------------------------- non-finite input

def test_kernels_and_references_agree_on_non_finite_input(gen):
    """A NaN or an infinity in any component: the fused ops and the references give
    non-finite results in the same entries, and never a finite number where an input
    component is not finite."""
    a, b = unit_dq((2, 16), gen), unit_dq((2, 16), gen)
    for bad in (math.nan, math.inf, -math.inf):
        a2, b2 = a.clone(), b.clone()
        a2[0, range(8), range(8)] = bad  # each component of a in turn
        b2[1, range(8, 16), range(8)] = bad  # each component of b in turn
        a2, b2 = a2.reshape(-1, 8), b2.reshape(-1, 8)
        t = torch.full((32,), 0.3, dtype=torch.float64)
        for shortest in (True, False):
            fused = sclerp_kernel.sclerp(a2, b2, t, shortest)
            ref = dq._eq11(a2, b2, t, shortest)
            assert torch.equal(torch.isfinite(fused), torch.isfinite(ref))
            hit = torch.cat((torch.arange(8), 16 + torch.arange(8, 16)))
            assert not torch.isfinite(fused[hit]).all(-1).any()
        fused = dq.angle(a2, b2)
        readable = torch.func.vmap(dq.angle)(a2, b2)
        for f, r in zip(fused, readable, strict=True):
            assert torch.equal(torch.isfinite(f), torch.isfinite(r))
        assert not (torch.isfinite(fused.real[hit]) & torch.isfinite(fused.dual[hit])).any()


def test_index_add_compiled_is_the_scatter():
    """``_autograd.index_add`` (an opaque op when compiled on CPU, so that inductor does not
    lower the sums onto a few rows to atomic adds) gives ``Tensor.index_add``'s sums, eager
    and under ``torch.compile(fullgraph=True)``, along either dim and with repeated indices."""
    from torch_dq._autograd import index_add

    gen = torch.Generator().manual_seed(0)
    x = torch.randn(8, 5, generator=gen, dtype=torch.float64)
    src = torch.randn(8, 400, generator=gen, dtype=torch.float64)
    idx = torch.randint(0, 5, (400,), generator=gen)
    ref = torch.zeros_like(x)
    for k in range(400):
        ref[:, idx[k]] += src[:, k]
    ref += x

    def f(x, src):  # the second with a strided x
        return index_add(x, 1, idx, src), index_add(x.T, 0, idx, src.T)

    compiled = torch.compile(f, fullgraph=True)
    with torch.no_grad():  # as in a backward: the opaque op (with grad, the plain scatter)
        results = (f(x, src), compiled(x, src))
    for a, b in results:
        assert float((a - ref).abs().max()) <= 1e-12
        assert float((b - ref.T).abs().max()) <= 1e-12
    torch.library.opcheck(torch.ops.torch_dq.index_add.default, (x.T, 0, idx, src.T))

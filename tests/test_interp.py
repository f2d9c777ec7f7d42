"""Dual angle (eqs. 4-7), screw interpolation (eq. 11) and dual-quaternion linear blending."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from pytransform3d.trajectories import dual_quaternions_sclerp
from strategies import screw, unit_dq

import torch_dq
import torch_dq.dual as D
import torch_dq.dualquat as dq

T_VALUES = (0.0, 1.0, 0.5, -0.5, 1.5)


def up_to_sign(x, ref):
    """Max abs difference between ``x`` and ``ref`` after aligning each row's sign."""
    sign = torch.where((x * ref).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(x.dtype)
    return (x - sign * ref).abs().max().item()


def screw_pairs(gen, n, theta, d, moment_scale=1.0):
    """``(a, b, exact(t))``: ``b = a * screw`` and the exact interpolant ``a * screw(t)``."""
    a = unit_dq((n,), gen)
    axis, moment, th, dd = screw((n,), gen, theta, d, moment_scale)
    b = dq.mul(a, dq.from_screw(axis, moment, th, dd))
    return a, b, lambda t: dq.mul(a, dq.from_screw(axis, moment, t * th, t * dd))


# ----------------------------------------------------------------------------- sclerp values

def test_sclerp_matches_pytransform3d(gen):
    a, b = unit_dq((500,), gen), unit_dq((500,), gen)
    t = torch.rand(500, generator=gen, dtype=torch.float64)
    out = dq.sclerp(a, b, t)
    # pytransform3d interpolates towards b as given: hand it the sign-aligned b.
    b_near = torch.where((a[:, :4] * b[:, :4]).sum(-1, keepdim=True) < 0, -b, b)
    ref = torch.from_numpy(dual_quaternions_sclerp(a.numpy(), b_near.numpy(), t.numpy()))
    assert up_to_sign(out, ref) < 5e-15


def test_sclerp_equals_screw_power_through_exp_log(gen):
    a, b = unit_dq((300,), gen), unit_dq((300,), gen)
    for t in T_VALUES:
        rel = dq.mul(dq.conj(a), b)
        ref = dq.mul(a, dq.exp(t * dq.log(rel)))
        assert up_to_sign(dq.sclerp(a, b, t), ref) < 1e-13


@pytest.mark.parametrize("theta", [2.0, 1e-2, 1e-4, 1e-7, 1e-10, 0.0])
@pytest.mark.parametrize("t", T_VALUES)
def test_sclerp_exact_on_screw_families(gen, theta, t):
    """Tiny relative rotations with large translations and lever arms: exact to rounding."""
    a, b, exact = screw_pairs(gen, 200, theta, d=10.0, moment_scale=10.0)
    err = up_to_sign(dq.sclerp(a, b, t), exact(t))
    assert err < 3e-14 * 10  # translations of size ~10 (relative error ~3e-15)


def test_sclerp_degenerate_families(gen):
    a = unit_dq((50,), gen)
    # identical poses
    for t in T_VALUES:
        assert up_to_sign(dq.sclerp(a, a, t), a) < 1e-15
    # q versus -q: same pose, the shortest path is constant
    for t in T_VALUES:
        assert up_to_sign(dq.sclerp(a, -a, t), a) < 1e-15
    # pure translation (same rotation): translation interpolates linearly
    q, ta = dq.to_rt(a)
    tb = ta + torch.randn(ta.shape, generator=gen, dtype=torch.float64) * 5
    for t in T_VALUES:
        ref = dq.from_rt(q, (1 - t) * ta + t * tb)
        assert up_to_sign(dq.sclerp(a, dq.from_rt(q, tb), t), ref) < 1e-14
    # 180 degrees relative rotation: real parts orthogonal, both turning directions are
    # shortest (b = a screw(l, m, pi, d) = -a screw(-l, -m, pi, -d)); either is exact.
    a2 = unit_dq((50,), gen)
    axis, moment, th, d = screw((50,), gen, math.pi, 3.0, moment_scale=2.0)
    b2 = dq.mul(a2, dq.from_screw(axis, moment, th, d))
    for t in T_VALUES:
        out = dq.sclerp(a2, b2, t)
        ways = [dq.mul(a2, dq.from_screw(s * axis, s * moment, t * th, s * t * d)) for s in (1, -1)]
        err = torch.stack([(out - w).abs().max(-1).values for w in ways]).min(0).values
        assert err.max() < 1e-13


def test_sclerp_endpoints_and_unit_output(gen, batch_shape):
    a, b = unit_dq(batch_shape, gen), unit_dq(batch_shape, gen)
    b_near = torch.where((a[..., :4] * b[..., :4]).sum(-1, keepdim=True) < 0, -b, b)
    assert torch.equal(dq.sclerp(a, b, 0.0), a)
    assert (dq.sclerp(a, b, 1.0) - b_near).abs().max() < 1e-15
    t = torch.linspace(-0.5, 1.5, 9, dtype=torch.float64).reshape(9, *([1] * len(batch_shape)))
    out = dq.sclerp(a, b, t)
    assert out.shape == (9, *batch_shape, 8)
    assert dq.is_unit(out, atol=1e-14).all()


def test_sclerp_constant_screw_speed(gen):
    """Equal steps in t are equal dual angles (constant screw speed, the geodesic property)."""
    a, b = unit_dq((20,), gen), unit_dq((20,), gen)
    t = torch.linspace(0, 1, 11, dtype=torch.float64)[:, None]
    path = dq.sclerp(a, b, t)
    steps = dq.angle(path[:-1], path[1:])
    full = dq.angle(a, torch.where((a[:, :4] * b[:, :4]).sum(-1, keepdim=True) < 0, -b, b))
    assert (steps.real - full.real / 10).abs().max() < 1e-13
    assert (steps.dual - full.dual / 10).abs().max() < 1e-12


def test_sclerp_shortest_false_follows_given_sign(gen):
    a, b = unit_dq((100,), gen), unit_dq((100,), gen)
    b = torch.where((a[:, :4] * b[:, :4]).sum(-1, keepdim=True) > 0, -b, b)  # long way round
    for t in (0.25, 0.5, 1.5):
        ref = dq.mul(a, dq.exp(t * dq.log(dq.mul(dq.conj(a), b))))  # log takes the short way
        long = dq.sclerp(a, b, t, shortest=False)
        assert dq.is_unit(long).all()
        # the long path is a different motion from the short one...
        assert up_to_sign(long, ref) > 1e-3
    # ...and it ends at b itself (not -b)
    assert (dq.sclerp(a, b, 1.0, shortest=False) - b).abs().max() < 1e-14


def test_sclerp_broadcasts_t_against_batch(gen):
    a, b = unit_dq((4, 1), gen), unit_dq((1, 3), gen)
    t = torch.rand(4, 3, generator=gen, dtype=torch.float64)
    out = dq.sclerp(a, b, t)
    assert out.shape == (4, 3, 8)
    assert (out[2, 1] - dq.sclerp(a[2, 0], b[0, 1], t[2, 1])).abs().max() < 1e-15


def test_sclerp_float32_accuracy(gen):
    """float32 against float64 over 1e5 random + near-degenerate pairs (unit translations)."""
    n = 50_000
    a, b = unit_dq((n,), gen), unit_dq((n,), gen)
    a2, b2, _ = screw_pairs(gen, n, 1e-3, d=1.0)
    a, b = torch.cat((a, a2)), torch.cat((b, b2))
    t = torch.rand(2 * n, generator=gen, dtype=torch.float64)
    ref = dq.sclerp(a, b, t)
    out = dq.sclerp(a.float(), b.float(), t.float())
    err = (out.double() - ref).abs().max().item()
    assert err < 2e-6, err


def test_sclerp_half_precision_computes_in_float32(gen):
    a, b = unit_dq((64,), gen), unit_dq((64,), gen)
    for dtype, tol in ((torch.float16, 4e-3), (torch.bfloat16, 3e-2)):
        out = dq.sclerp(a.to(dtype), b.to(dtype), 0.3)
        assert out.dtype == dtype
        ref = dq.sclerp(a.to(dtype).double(), b.to(dtype).double(), 0.3)
        assert (out.double() - ref).abs().max() < tol


# ----------------------------------------------------------------------------- sclerp gradients

def test_sclerp_gradcheck_generic(gen):
    a = unit_dq((4,), gen).requires_grad_()
    b = unit_dq((4,), gen).requires_grad_()
    t = (torch.rand(4, generator=gen, dtype=torch.float64) * 2 - 0.5).requires_grad_()
    for shortest in (True, False):
        def f(a, b, t, shortest=shortest):
            return dq.sclerp(a, b, t, shortest)
        assert torch.autograd.gradcheck(f, (a, b, t))
        assert torch.autograd.gradgradcheck(f, (a, b, t))
        assert torch.autograd.gradcheck(f, (a, b, t), check_forward_ad=True,
                                        check_backward_ad=False, check_undefined_grad=False)


@pytest.mark.parametrize("theta", [1e-4, 1e-7, 0.0])
@pytest.mark.parametrize("t", [0.0, 0.5, 1.0])
def test_sclerp_gradients_at_degenerate_points(gen, theta, t):
    """Finite and equal to central finite differences at tiny and zero relative rotations."""
    a, b, _ = screw_pairs(gen, 3, theta, d=2.0)
    tt = torch.full((3,), t, dtype=torch.float64)
    inputs = (a.requires_grad_(), b.requires_grad_(), tt.requires_grad_())
    assert torch.autograd.gradcheck(dq.sclerp, inputs, atol=1e-7, rtol=1e-6)


def test_sclerp_gradients_finite_for_equal_and_opposite_poses(gen):
    a = unit_dq((5,), gen)
    for b in (a.clone(), -a.clone()):
        for t in (0.0, 0.5, 1.0):
            aa, bb = a.clone().requires_grad_(), b.requires_grad_()
            tt = torch.tensor(t, dtype=torch.float64, requires_grad=True)
            dq.sclerp(aa, bb, tt).sum().backward()
            for g in (aa.grad, bb.grad, tt.grad):
                assert torch.isfinite(g).all()
            bb.grad = None


@given(
    rot=st.sampled_from([0.0, 1e-12, 1e-8, 1e-4, 0.5, math.pi / 2, math.pi - 1e-6, math.pi]),
    d=st.sampled_from([0.0, 1e-9, 1.0, 1e3]),
    t=st.floats(-1.0, 2.0),
    flip=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_sclerp_fuzz_no_nan(rot, d, t, flip, seed):
    gen = torch.Generator().manual_seed(seed)
    a, b, _ = screw_pairs(gen, 2, rot, d)
    b = -b if flip else b
    a.requires_grad_()
    b.requires_grad_()
    tt = torch.tensor(t, dtype=torch.float64, requires_grad=True)
    out = dq.sclerp(a, b, tt)
    assert torch.isfinite(out).all()
    out.sum().backward()
    assert all(torch.isfinite(g).all() for g in (a.grad, b.grad, tt.grad))


# ----------------------------------------------------------------------------- execution modes

def test_sclerp_vmap_jvp_and_compile(gen):
    a, b = unit_dq((6,), gen), unit_dq((6,), gen)
    t = torch.rand(6, generator=gen, dtype=torch.float64)
    ref = dq.sclerp(a, b, t)
    assert (torch.func.vmap(dq.sclerp)(a, b, t) - ref).abs().max() < 1e-15
    ones = torch.ones_like(t)
    _, tangent = torch.func.jvp(lambda t: dq.sclerp(a, b, t), (t,), (ones,))
    h = 1e-6
    fd = (dq.sclerp(a, b, t + h) - dq.sclerp(a, b, t - h)) / (2 * h)
    assert (tangent - fd).abs().max() < 1e-8
    compiled = torch.compile(dq.sclerp, backend="aot_eager", fullgraph=True)
    aa = a.clone().requires_grad_()
    out = compiled(aa, b, t)
    assert (out - ref).abs().max() < 1e-15
    out.sum().backward()
    aa2 = a.clone().requires_grad_()
    dq.sclerp(aa2, b, t).sum().backward()
    assert (aa.grad - aa2.grad).abs().max() < 1e-14


# ----------------------------------------------------------------------------- dual angle

def test_angle_of_screw_is_half_screw(gen):
    """From the identity, the dual angle of a screw (theta, d) is (theta + eps d) / 2 (eq. 2)."""
    axis, moment, th, d = screw((100,), gen, 1.0, 0.0)
    th = torch.rand(100, generator=gen, dtype=torch.float64) * 3
    d = torch.randn(100, generator=gen, dtype=torch.float64) * 4
    x = dq.from_screw(axis, moment, th, d)
    ang = dq.angle(dq.identity((100,), dtype=torch.float64), x)
    assert (ang.real - th / 2).abs().max() < 1e-15
    assert (ang.dual - d / 2).abs().max() < 1e-13
    # it is invariant under a common left motion
    g = unit_dq((100,), gen)
    ang2 = dq.angle(dq.mul(g, dq.identity((100,), dtype=torch.float64)), dq.mul(g, x))
    assert (ang2.real - ang.real).abs().max() < 1e-14
    assert (ang2.dual - ang.dual).abs().max() < 1e-12


def test_angle_satisfies_eq7_cos_equals_dot(gen):
    a, b = unit_dq((500,), gen), unit_dq((500,), gen)
    ang, dot = dq.angle(a, b), dq.dot(a, b)
    c = D.cos(ang)
    assert (c.real - dot.real).abs().max() < 1e-15
    assert (c.dual - dot.dual).abs().max() < 1e-14
    assert ((ang.real >= 0) & (ang.real <= math.pi)).all()
    # no sign flip: theta(a, -b) = pi - theta(a, b)
    assert (dq.angle(a, -b).real - (math.pi - ang.real)).abs().max() < 1e-14


def test_angle_real_part_accurate_at_tiny_angles(gen):
    a, b, _ = screw_pairs(gen, 50, 2e-9, d=1.0)
    # rounding of the inputs themselves bounds the error (acos(q0 . q1) would be off by ~1e-8)
    assert (dq.angle(a, b).real - 1e-9).abs().max() < 2e-16


def test_angle_degenerate_branch_eq6(gen):
    q = torch.randn(40, 4, generator=gen, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    t0 = torch.randn(40, 3, generator=gen, dtype=torch.float64)
    t1 = torch.randn(40, 3, generator=gen, dtype=torch.float64)
    axis = q[:, 1:] / q[:, 1:].norm(dim=-1, keepdim=True)
    expected = ((t1 - t0) * axis).sum(-1).abs()
    for sign in (1.0, -1.0):  # equal and opposite rotation quaternions
        ang = dq.angle(dq.from_rt(q, t0), dq.from_rt(sign * q, t1))
        assert (ang.dual - expected).abs().max() < 1e-14
        assert (ang.real - (0.0 if sign > 0 else math.pi)).abs().max() < 1e-15
    # identity rotations: the full distance
    ident = torch.zeros(40, 4, dtype=torch.float64)
    ident[:, 0] = 1
    ang = dq.angle(dq.from_rt(ident, t0), dq.from_rt(ident, t1))
    assert (ang.dual - (t1 - t0).norm(dim=-1)).abs().max() < 1e-14


def test_angle_gradients(gen):
    a = unit_dq((4,), gen).requires_grad_()
    b = unit_dq((4,), gen).requires_grad_()

    def f(a, b):
        ang = dq.angle(a, b)
        return ang.real, ang.dual

    assert torch.autograd.gradcheck(f, (a, b))
    assert torch.autograd.gradgradcheck(f, (a, b))
    # degenerate points: finite gradients (zero subgradient of the kink of theta)
    for b2 in (a.detach().clone(), -a.detach().clone(),
               dq.from_rt(a.detach()[:, :4], torch.ones(4, 3, dtype=torch.float64))):
        a2, b2 = a.detach().clone().requires_grad_(), b2.requires_grad_()
        real, dual = f(a2, b2)
        (real + dual).sum().backward()
        assert torch.isfinite(a2.grad).all() and torch.isfinite(b2.grad).all()


def test_top_level_reexports():
    assert torch_dq.dual_angle is dq.angle
    assert torch_dq.sclerp is dq.sclerp
    assert torch_dq.Dual is D.Dual


# ----------------------------------------------------------------------------- DLB

def test_dlb_numpy_reference_and_properties(gen):
    xs = unit_dq((30, 4), gen)
    w = torch.rand(30, 4, generator=gen, dtype=torch.float64)
    out = dq.dlb(w, xs)
    # numpy reference: sign-align, weighted sum, divide by real norm, remove r.d component
    x = xs.numpy().copy()
    x *= np.where((x[..., :4] * x[..., :1, :4]).sum(-1, keepdims=True) < 0, -1.0, 1.0)
    s = (w.numpy()[..., None] * x).sum(-2)
    n = np.linalg.norm(s[:, :4], axis=-1, keepdims=True)
    r, d = s[:, :4] / n, s[:, 4:] / n
    ref = np.concatenate((r, d - r * (r * d).sum(-1, keepdims=True)), -1)
    assert np.abs(out.numpy() - ref).max() < 1e-15
    assert dq.is_unit(out).all()
    # sign of any input and the scale of the weights do not matter
    flipped = xs.clone()
    flipped[:, 2] *= -1
    assert (dq.dlb(3 * w, flipped) - out).abs().max() < 1e-14
    # one-hot weights return that input (sign-aligned with xs[0])
    onehot = torch.zeros_like(w)
    onehot[:, 1] = 1
    assert up_to_sign(dq.dlb(onehot, xs), xs[:, 1]) < 1e-15
    assert torch.autograd.gradcheck(dq.dlb, (w[:2].clone().requires_grad_(),
                                             xs[:2].clone().requires_grad_()))


def test_dlb_agrees_with_sclerp_for_a_common_pure_translation(gen):
    a = unit_dq((10,), gen)
    q, ta = dq.to_rt(a)
    b = dq.from_rt(q, ta + 1.0)
    t = 0.3
    w = torch.tensor([1 - t, t], dtype=torch.float64).expand(10, 2)
    assert up_to_sign(dq.dlb(w, torch.stack((a, b), -2)), dq.sclerp(a, b, t)) < 1e-14


# ----------------------------------------------------------------------------- bad input

@pytest.mark.parametrize(
    ("call", "kind", "match"),
    [
        (lambda: dq.sclerp(torch.zeros(3, 7), torch.zeros(3, 8), 0.5), ValueError, "for a"),
        (lambda: dq.sclerp(torch.zeros(3, 8), torch.zeros(2, 8), 0.5), ValueError, "broadcast"),
        (lambda: dq.sclerp(torch.zeros(8), torch.zeros(8), torch.zeros(2, dtype=torch.int64)),
         TypeError, "t"),
        (lambda: dq.sclerp(torch.zeros(8, dtype=torch.int32), torch.zeros(8), 0.5), TypeError,
         "for a"),
        (lambda: dq.sclerp(torch.zeros(8), torch.zeros(8, dtype=torch.float64), 0.5), TypeError,
         "dtype"),
        (lambda: dq.angle(torch.zeros(8), torch.zeros(4)), ValueError, "for b"),
        (lambda: dq.dlb(torch.ones(3), torch.zeros(2, 8)), ValueError, "same K"),
        (lambda: dq.dlb(torch.ones(2), torch.zeros(2, 7)), ValueError, "xs"),
    ],
)
def test_bad_input(call, kind, match):
    with pytest.raises(kind, match=match):
        call()


# ----------------------------------------------------------------------------- eager chunking

def test_chunked_evaluation_matches_one_chunk(gen, monkeypatch):
    """Values and gradients do not depend on the eager chunking (boundaries at odd sizes)."""
    import torch_dq.curves as curves
    from torch_dq._kernels import layout

    a, b = unit_dq((50,), gen), unit_dq((50,), gen)
    ctrl = unit_dq((2, 6), gen)
    t = torch.rand(50, generator=gen, dtype=torch.float64)

    def run():
        leaves = [x.clone().requires_grad_() for x in (a, b, t, ctrl)]
        aa, bb, tt, cc = leaves
        outs = [dq.sclerp(aa, bb, tt), curves.bspline(cc, tt), curves.bezier(cc, tt)]
        loss = sum((o * torch.linspace(-1, 1, o.numel(), dtype=o.dtype).view(o.shape)).sum()
                   for o in outs)
        return [*outs, *torch.autograd.grad(loss, leaves)]

    whole = run()
    monkeypatch.setattr(layout, "CHUNK", 7)
    monkeypatch.setattr(layout, "PYRAMID_CHUNK", 11)
    chunked = run()
    for x, y in zip(whole[:3], chunked[:3], strict=True):  # values: bit-identical
        assert torch.equal(x, y)
    for x, y in zip(whole[3:], chunked[3:], strict=True):  # gradients: summation order only
        assert (x - y).abs().max() < 1e-13

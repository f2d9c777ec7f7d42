"""Dual angle (eqs. 4-7), screw interpolation (eq. 11) and dual-quaternion linear blending,
against independent references: pytransform3d (``dual_quaternion_sclerp``, screw
parameters), scipy's matrix ``expm`` / ``logm`` of 4x4 transforms, mpmath at 40 digits and
numpy formulas written here (the paper's eq. 2 for screws, products of dual quaternions).

Second order (issue 14): Hessians (``torch.func.hessian``, ``jacfwd(jacrev)``, double
backward) and nested forward mode (``jvp`` of ``jvp``) of sclerp and of the dual angle, at
and near the degenerate points (equal rotations, pure translations, relative rotations of
1e-9 and 1e-3 rad, t = 0 and 1), against central differences of the references. The inputs
are parametrized on the manifold, ``q = (q0 + dq) / |q0 + dq|`` and ``t = t0 + dt`` (a test
harness in plain ops, written here), so only the functions under test are compared.
"""

import math

import mpmath
import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch
from hypothesis import given
from hypothesis import strategies as st
from pytransform3d.trajectories import dual_quaternions_sclerp
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation
from strategies import unit_dq, unit_quat

import torch_dq
import torch_dq.dual as D
import torch_dq.dualquat as dq

T_VALUES = (0.0, 1.0, 0.5, -0.5, 1.5)


def up_to_sign(x, ref):
    """Max abs difference between ``x`` and ``ref`` after aligning each row's sign."""
    x, ref = torch.as_tensor(x), torch.as_tensor(ref)
    sign = torch.where((x * ref).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(x.dtype)
    return (x - sign * ref).abs().max().item()


# ----------------------------------------------------------------------------- numpy references

def np_qmul(a, b):
    """Hamilton product of ``(..., 4)`` numpy quaternions ``(w, x, y, z)``."""
    aw, av, bw, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return np.concatenate((aw * bw - (av * bv).sum(-1, keepdims=True),
                           aw * bv + bw * av + np.cross(av, bv)), -1)


def np_dqmul(a, b):
    return np.concatenate((np_qmul(a[..., :4], b[..., :4]),
                           np_qmul(a[..., :4], b[..., 4:]) + np_qmul(a[..., 4:], b[..., :4])), -1)


def np_screw(axis, point, theta, d):
    r"""The paper's eq. 2: :math:`\cos\frac{\bar\theta}{2} + \sin\frac{\bar\theta}{2}\bar l`
    with :math:`\bar\theta = \theta + \epsilon d`, :math:`\bar l = l + \epsilon\, p \times l`."""
    m = np.cross(point, axis)
    c, s = np.cos(theta / 2)[..., None], np.sin(theta / 2)[..., None]
    d = np.asarray(d)[..., None]
    return np.concatenate((c, s * axis, -(d / 2) * s, s * m + (d / 2) * c * axis), -1)


def np_pose(q, t):
    """``(q, 0.5 (0, t) q)`` for numpy unit quaternions and translations."""
    t0 = np.concatenate((np.zeros_like(t[..., :1]), t), -1)
    return np.concatenate((q, 0.5 * np_qmul(t0, q)), -1)


def matrices(x):
    """``(N, 8)`` dual quaternions -> ``(N, 4, 4)`` transforms (pytransform3d)."""
    return np.stack([pt.transform_from_dual_quaternion(v) for v in np.asarray(x)])


def screw_pairs(gen, n, theta, d, moment_scale=1.0):
    """``(a, b, exact(t))`` with ``b = a * screw(theta, d)`` and the exact interpolant
    ``a * screw(t theta, t d)``, built with the numpy formulas above."""
    a = unit_dq((n,), gen).numpy()
    axis = torch.randn(n, 3, generator=gen, dtype=torch.float64).numpy()
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    point = torch.randn(n, 3, generator=gen, dtype=torch.float64).numpy() * moment_scale
    th, dd = np.full(n, float(theta)), np.full(n, float(d))

    def exact(t):
        return torch.from_numpy(np_dqmul(a, np_screw(axis, point, t * th, t * dd)))

    return torch.from_numpy(a), exact(1.0), exact


# ----------------------------------------------------------------------------- sclerp values

def test_sclerp_matches_pytransform3d(gen):
    a, b = unit_dq((500,), gen), unit_dq((500,), gen)
    t = torch.rand(500, generator=gen, dtype=torch.float64)
    out = dq.sclerp(a, b, t)
    # pytransform3d interpolates towards b as given: hand it the sign-aligned b.
    b_near = torch.where((a[:, :4] * b[:, :4]).sum(-1, keepdim=True) < 0, -b, b)
    ref = torch.from_numpy(dual_quaternions_sclerp(a.numpy(), b_near.numpy(), t.numpy()))
    assert up_to_sign(out, ref) < 5e-15


def test_sclerp_equals_matrix_power(gen):
    """``T_a expm(t logm(T_a^-1 T_b))`` (scipy), extrapolation included (measured 1.2e-13:
    scipy's logm loses digits near half turns)."""
    a, b = unit_dq((100,), gen), unit_dq((100,), gen)
    Ta, Tb = matrices(a), matrices(b)
    logs = [logm(np.linalg.solve(x, y)).real for x, y in zip(Ta, Tb, strict=True)]
    for t in T_VALUES:
        ref = np.stack([x @ expm(t * lg) for x, lg in zip(Ta, logs, strict=True)])
        assert np.abs(matrices(dq.sclerp(a, b, t)) - ref).max() < 5e-13


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("t", [-2.0, -0.5, 1.5, 2.0, 3.0])
def test_sclerp_extrapolates_across_the_series_switch(gen, dtype, t):
    """Relative rotations swept through the series/closed-form switch of the weights, where
    the switch point moves with ``s^2`` when extrapolating (a regression: a guard that did
    not move with it gave non-unit results, e.g. 0.1 rad at t = 1.5)."""
    for theta in np.geomspace(1e-4, 1.0, 60):
        a, b, exact = screw_pairs(gen, 8, float(theta), d=1.0)
        out = dq.sclerp(a.to(dtype), b.to(dtype), t).double()
        tol = 1e-13 if dtype == torch.float64 else 3e-6 * abs(t)
        assert up_to_sign(out, exact(t)) < tol, theta


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
    # pure translation (same rotation): the translation interpolates linearly
    q = a[:, :4].numpy()
    ta = torch.randn(50, 3, generator=gen, dtype=torch.float64).numpy()
    tb = ta + torch.randn(50, 3, generator=gen, dtype=torch.float64).numpy() * 5
    a, b = torch.from_numpy(np_pose(q, ta)), torch.from_numpy(np_pose(q, tb))
    for t in T_VALUES:
        assert up_to_sign(dq.sclerp(a, b, t), np_pose(q, (1 - t) * ta + t * tb)) < 1e-14
    # 180 degrees relative rotation: real parts orthogonal, both turning directions are
    # shortest (screw(l, p, pi, d) and screw(-l, p, pi, -d) are the same motion); either is
    # exact.
    a2, b2, _ = screw_pairs(gen, 50, math.pi, 3.0, moment_scale=2.0)
    a2n = a2.numpy()
    conj = np.array([1, -1, -1, -1, 1, -1, -1, -1])
    rel = np_dqmul(a2n * conj, b2.numpy())  # (0, l) + eps (-d / 2, m): a half-turn screw
    for t in T_VALUES:
        out = dq.sclerp(a2, b2, t).numpy()
        ways = []
        for sign in (1.0, -1.0):  # rel and -rel: the same motion, turning either way
            l, m, d = sign * rel[:, 1:4], sign * rel[:, 5:], -2 * sign * rel[:, 4]
            point = np.cross(l, m)  # the axis point nearest the origin
            ways.append(np_dqmul(a2n, np_screw(l, point, np.full(50, t * math.pi), t * d)))
        err = np.minimum(*(np.abs(out - w).max(-1) for w in ways))
        assert err.max() < 1e-13


def test_sclerp_endpoints_and_unit_output(gen, batch_shape):
    a, b = unit_dq(batch_shape, gen), unit_dq(batch_shape, gen)
    b_near = torch.where((a[..., :4] * b[..., :4]).sum(-1, keepdim=True) < 0, -b, b)
    assert torch.equal(dq.sclerp(a, b, 0.0), a)
    assert (dq.sclerp(a, b, 1.0) - b_near).abs().max() < 1e-15
    t = torch.linspace(-0.5, 1.5, 9, dtype=torch.float64).reshape(9, *([1] * len(batch_shape)))
    out = dq.sclerp(a, b, t)
    assert out.shape == (9, *batch_shape, 8)
    r, d = out[..., :4], out[..., 4:]
    assert ((r * r).sum(-1) - 1).abs().max() < 1e-14 and (r * d).sum(-1).abs().max() < 1e-14


def test_sclerp_constant_screw_speed(gen):
    """Equal steps in t are equal screw motions (the geodesic property): the screw
    parameters (pytransform3d) of each step ``x_i^-1 x_{i+1}`` are a tenth of the whole."""
    a, b = unit_dq((20,), gen), unit_dq((20,), gen)
    t = torch.linspace(0, 1, 11, dtype=torch.float64)[:, None]
    path = dq.sclerp(a, b, t).numpy()
    conj = np.array([1, -1, -1, -1, 1, -1, -1, -1])
    whole = np_dqmul(a.numpy() * conj, path[-1])
    for k in range(20):
        _, s_w, h_w, th_w = pt.screw_parameters_from_dual_quaternion(whole[k])
        for i in range(10):
            step = np_dqmul(path[i, k] * conj, path[i + 1, k])
            _, s, h, th = pt.screw_parameters_from_dual_quaternion(step)
            assert abs(th - th_w / 10) < 1e-13
            assert abs(h * th - h_w * th_w / 10) < 1e-12  # translation along the axis
            assert np.abs(s - s_w).max() < 1e-10


def long_way(a, b, t):
    """``a (a^-1 b)^t`` turning the long way (``shortest=False`` with ``a . b < 0``): the
    relative screw (pytransform3d's short one: ``l, p, theta, d``) followed as
    ``(2 pi - theta)`` about ``-l`` with ``d`` along ``l``, through scipy's ``expm``."""
    conj = np.array([1, -1, -1, -1, 1, -1, -1, -1])
    p, l, h, theta = pt.screw_parameters_from_dual_quaternion(np_dqmul(a * conj, b))
    u, phi, d = -l, 2 * math.pi - theta, h * theta
    omega, v = phi * u, -phi * np.cross(u, p) + d * l
    S = np.zeros((4, 4))
    S[:3, :3] = [[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]]
    S[:3, 3] = v
    return pt.transform_from_dual_quaternion(a) @ expm(t * S)


def test_sclerp_shortest_false_follows_given_sign(gen):
    a, b = unit_dq((30,), gen), unit_dq((30,), gen)
    b = torch.where((a[:, :4] * b[:, :4]).sum(-1, keepdim=True) > 0, -b, b)  # long way round
    for t in (0.25, 0.5, 1.0, 1.5):
        long = dq.sclerp(a, b, t, shortest=False)
        ref = np.stack([long_way(x, y, t) for x, y in zip(a.numpy(), b.numpy(), strict=True)])
        assert np.abs(matrices(long) - ref).max() < 1e-12
        if t != 1.0:  # a different motion from the short path
            assert np.abs(matrices(dq.sclerp(a, b, t)) - ref).max() > 1e-3
    # ...and it ends at b itself (not -b)
    assert (dq.sclerp(a, b, 1.0, shortest=False) - b).abs().max() < 1e-14


def test_sclerp_opposite_real_parts_without_shortest_is_nan(gen):
    """Exactly opposite real parts have no unique path: NaN (0.1 returned finite values up
    to 1e16), only in those elements; nearly opposite ones (1e-6 rad) stay finite."""
    a = unit_dq((200,), gen)
    for t in (0.0, 0.3, 1.0, torch.rand(200, generator=gen, dtype=torch.float64)):
        assert torch.isnan(dq.sclerp(a, -a, t, shortest=False)).all()
        assert up_to_sign(dq.sclerp(a, -a, t), a) < 1e-15  # shortest: the pose itself
    a, b, _ = screw_pairs(gen, 50, 1e-6, 1.0)
    b = torch.cat((-b, -a[:1]))  # near-opposite, then one exactly opposite in the batch
    out = dq.sclerp(torch.cat((a, a[:1])), b, 0.5, shortest=False)
    assert torch.isfinite(out[:-1]).all() and torch.isnan(out[-1]).all()
    assert out.dtype == a.dtype
    for dtype in (torch.float32, torch.float16):
        assert torch.isnan(dq.sclerp(a.to(dtype), -a.to(dtype), 0.5, shortest=False)).all()


@pytest.mark.parametrize("flag", ["no", 1, 0, None, np.bool_(True)])
def test_sclerp_shortest_takes_bools_only(flag):
    x = dq.identity((2,), dtype=torch.float64)
    with pytest.raises(TypeError, match=r"^dualquat\.sclerp: expected shortest to be a bool"):
        dq.sclerp(x, x, 0.5, shortest=flag)


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

def test_sclerp_vmap_and_jvp(gen):
    """Under torch.compile: ``tests/test_compile.py`` (two sizes, both grad modes)."""
    a, b = unit_dq((6,), gen), unit_dq((6,), gen)
    t = torch.rand(6, generator=gen, dtype=torch.float64)
    ref = dq.sclerp(a, b, t)
    assert (torch.func.vmap(dq.sclerp)(a, b, t) - ref).abs().max() < 1e-15
    ones = torch.ones_like(t)
    _, tangent = torch.func.jvp(lambda t: dq.sclerp(a, b, t), (t,), (ones,))
    h = 1e-6
    fd = (dq.sclerp(a, b, t + h) - dq.sclerp(a, b, t - h)) / (2 * h)
    assert (tangent - fd).abs().max() < 1e-8


# ----------------------------------------------------------------------------- second order

def t_qmul(a, b):
    """Hamilton product in plain torch ops (test harness)."""
    aw, av, bw, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return torch.cat((aw * bw - (av * bv).sum(-1, keepdim=True),
                      aw * bv + bw * av + torch.linalg.cross(av, bv, dim=-1)), -1)


def t_pose(q, t):
    return torch.cat((q, 0.5 * t_qmul(torch.cat((torch.zeros_like(t[..., :1]), t), -1), q)), -1)


def t_transform(x):
    """``[R | t]`` (3, 4) of a unit dual quaternion, in plain torch ops (test harness)."""
    r, d = x[..., :4], x[..., 4:]
    w, v = r[..., :1], r[..., 1:]
    eye = torch.eye(3, dtype=x.dtype)
    vx = torch.stack([torch.linalg.cross(v.expand(3, 3), eye, dim=-1)[i] for i in range(3)])
    R = eye + 2 * w * vx.T + 2 * vx.T @ vx.T  # Rodrigues in quaternion form
    t = 2 * t_qmul(d, r * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=x.dtype))[..., 1:]
    return torch.cat((R, t[:, None]), -1)


def chart_torch(base, z):
    """Poses near the base: ``q = (q0 + dq) / |q0 + dq|``, ``t = t0 + dt`` (7 numbers each)."""
    out = []
    for k, (q, t) in enumerate(base):
        qz = q + z[7 * k:7 * k + 4]
        out.append(t_pose(qz / qz.norm(), t + z[7 * k + 4:7 * k + 7]))
    return out


def chart_numpy(base, z):
    out = []
    for k, (q, t) in enumerate(base):
        qz = q.numpy() + z[7 * k:7 * k + 4]
        out.append((qz / np.linalg.norm(qz), t.numpy() + z[7 * k + 4:7 * k + 7]))
    return out


def np_transform(q, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q[[1, 2, 3, 0]]).as_matrix()
    T[:3, 3] = t
    return T


def directions(gen, n):
    """Pairs ``(u, v)`` of directions in ``R^n``: four random pairs, and the last coordinate
    (sclerp's ``t``) with itself and with a random direction."""
    r = torch.randn(10, n, generator=gen, dtype=torch.float64).numpy()
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    last = np.eye(n)[-1]
    return [(r[2 * k], r[2 * k + 1]) for k in range(4)] + [(last, last), (last, r[8])]


def fd_second(f, u, v, h):
    """Central difference of the second derivative of ``f`` at 0 along ``u`` and ``v``."""
    return (f(h * (u + v)) - f(h * (u - v)) - f(h * (v - u)) + f(-h * (u + v))) / (4 * h * h)


def second_derivatives(f, z, pairs):
    """``u^T H v`` for each pair: from ``torch.func.hessian`` (= ``jacfwd(jacrev)``), from
    double backward (``torch.autograd.functional.hessian``: the fused ops) and from nested
    forward mode (``jvp`` of ``jvp``, 0 for every custom op in 0.1)."""
    H = {"hessian": torch.func.hessian(f)(z).numpy(),
         "double backward": torch.autograd.functional.hessian(f, z).numpy()}
    out = {mode: np.array([u @ M @ v for u, v in pairs]) for mode, M in H.items()}

    def nested(u, v):
        inner = lambda y: torch.func.jvp(f, (y,), (u,))[1]  # noqa: E731
        return torch.func.jvp(inner, (z,), (v,))[1].item()

    out["jvp of jvp"] = np.array([nested(torch.from_numpy(u), torch.from_numpy(v))
                                  for u, v in pairs])
    return out


def screw_base(gen, theta, d):
    """``a`` and ``b = a * screw(theta, d)`` as (quaternion, translation) pairs."""
    a, b, _ = screw_pairs(gen, 1, theta, d)
    return [(x[0, :4], torch.from_numpy(pt.pq_from_dual_quaternion(x[0].numpy())[:3]))
            for x in (a, b)]


@pytest.mark.parametrize(("theta", "t0"), [(0.0, 0.3), (0.0, 1.0), (1e-9, 0.0), (1e-3, 0.3),
                                           (1e-3, 1.0), (0.8, 0.0), (0.8, 0.3)])
def test_sclerp_second_order_against_matrix_power(gen, theta, t0):
    """Second derivatives of ``<W, [R | t](sclerp(a, b, t))>`` over ``(a, b, t)`` (15
    coordinates) in every mode, along random direction pairs, against central differences
    of ``T_a expm(t log(T_a^-1 T_b))`` (scipy's ``expm``, pytransform3d's closed-form log:
    scipy's ``logm``, equal to 1e-14, took 60 ms a call). Sclerp is analytic in its inputs at equal
    rotations (theta = 0, pure translations), so they exist there too. Measured agreement
    ~1e-8 (the differences' own error)."""
    base = screw_base(gen, theta, 1.5)
    W = torch.randn(3, 4, generator=gen, dtype=torch.float64)

    def f(z):
        a, b = chart_torch(base, z)
        return (W * t_transform(dq.sclerp(a, b, t0 + z[14]))).sum()

    def ref(z):
        (qa, ta), (qb, tb) = chart_numpy(base, z)
        Ta, Tb = np_transform(qa, ta), np_transform(qb, tb)
        T = Ta @ expm((t0 + z[14]) * pt.transform_log_from_transform(np.linalg.solve(Ta, Tb)))
        return float((W.numpy() * T[:3]).sum())

    pairs = directions(gen, 15)
    fd = np.array([fd_second(ref, u, v, 1e-4) for u, v in pairs])
    z = torch.zeros(15, dtype=torch.float64)
    for mode, d2 in second_derivatives(f, z, pairs).items():
        err = np.abs(d2 - fd).max() / max(1.0, np.abs(fd).max())
        assert err < 1e-6, (mode, err)


def angle_reference(base_q_sign):
    """``(theta, theta_hat)`` of two poses from their relative transform (scipy): half the
    relative rotation angle (pi minus it for opposite signs) and half the translation along
    the relative screw axis (negated for opposite signs, eq. 7 with no sign flip)."""
    def ref(poses):
        (qa, ta), (qb, tb) = poses
        T = np.linalg.solve(np_transform(qa, ta), np_transform(qb, tb))
        rotvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
        phi = np.linalg.norm(rotvec)
        half_d = 0.5 * T[:3, 3] @ rotvec / phi
        return (phi / 2, half_d) if base_q_sign > 0 else (math.pi - phi / 2, -half_d)

    return ref


def eq6_reference(poses):
    """Eq. 6 literally: ``|d_1 - d_0|`` with ``d_i = h_i theta_i`` the translation of pose i
    along its own screw axis (pytransform3d's screw parameters); ``|t_1 - t_0|`` for the
    identity rotation."""
    (qa, ta), (qb, tb) = poses
    if np.abs(qa[1:]).max() == 0 and np.abs(qb[1:]).max() == 0:
        return np.linalg.norm(tb - ta)
    d = [h * th for _, _, h, th in (pt.screw_parameters_from_dual_quaternion(np_pose(q, t))
                                    for q, t in ((qa, ta), (qb, tb)))]
    return abs(d[1] - d[0])


@pytest.mark.parametrize(("theta", "sign"), [(1e-3, 1), (0.8, 1), (2.5, 1), (1e-3, -1),
                                             (0.8, -1)])
def test_angle_second_order_against_relative_screw(gen, theta, sign):
    """Second derivatives of ``w0 theta + w1 theta_hat`` over both poses (14 coordinates)
    in every mode along random direction pairs, against central differences of the
    relative screw (scipy), in eq. 5's branch: relative rotations of 1e-3 and more
    (opposite signs: theta near pi). The dual part
    varies on the scale of the relative rotation there, hence the small steps."""
    base = screw_base(gen, theta, 1.5)
    base[1] = (sign * base[1][0], base[1][1])
    w = torch.randn(2, generator=gen, dtype=torch.float64)
    reference = angle_reference(sign)

    def f(z):
        ang = dq.angle(*chart_torch(base, z))
        return w[0] * ang.real + w[1] * ang.dual

    def ref(z):
        theta_ref, hat_ref = reference(chart_numpy(base, z))
        return float(w[0] * theta_ref + w[1] * hat_ref)

    pairs = directions(gen, 14)
    fd = np.array([fd_second(ref, u, v, min(1e-4, theta * 1e-3)) for u, v in pairs])
    z = torch.zeros(14, dtype=torch.float64)
    for mode, d2 in second_derivatives(f, z, pairs).items():
        err = np.abs(d2 - fd).max() / max(1.0, np.abs(fd).max())
        assert err < 1e-5, (mode, err)


@pytest.mark.parametrize("case", ["equal", "1e-9", "opposite sign", "identity"])
def test_angle_second_order_eq6_branch(gen, case):
    """Eq. 6's branch (equal rotations to working precision): second derivatives of
    ``theta_hat`` in every mode against central differences of the literal eq. 6
    (pytransform3d's screw parameters of each pose), smooth where the distance is not 0."""
    translation = np.array([0.0] * 4 + [1.0] * 3 + [0.0] * 4 + [1.0] * 3)
    theta = 1e-9 if case == "1e-9" else 0.0
    base = screw_base(gen, theta, 0.0)
    if case == "identity":
        base = [(torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64), t) for _, t in base]
    q = base[0][0]
    along = q[1:] / q[1:].norm() if case != "identity" else torch.zeros(3, dtype=q.dtype)
    offset = 1.2 * along + torch.tensor([0.3, -0.7, 1.1], dtype=torch.float64)
    base[1] = (base[1][0], base[1][1] + offset)
    sign = -1.0 if case == "opposite sign" else 1.0
    torch_base = [base[0], (sign * base[1][0], base[1][1])]

    def f(z):
        return dq.angle(*chart_torch(torch_base, z)).dual

    assert dq.angle(*chart_torch(torch_base, torch.zeros(14, dtype=torch.float64))).dual > 0.1
    pairs = directions(gen, 14)
    if case == "identity":  # rotation directions leave the identity (and the branch)
        pairs = [(u * translation, v * translation) for u, v in pairs]
    fd = np.array([fd_second(lambda z: eq6_reference(chart_numpy(torch_base, z)), u, v, 1e-4)
                   for u, v in pairs])
    z = torch.zeros(14, dtype=torch.float64)
    for mode, d2 in second_derivatives(f, z, pairs).items():
        err = np.abs(d2 - fd).max() / max(1.0, np.abs(fd).max())
        assert err < 1e-6, (mode, err)


# ----------------------------------------------------------------------------- dual angle

def test_angle_of_screw_is_half_screw(gen):
    """From the identity, the dual angle of a screw (theta, d) is (theta + eps d) / 2 (eq. 2):
    screws built by pytransform3d from random lines, angles and pitches."""
    n = 100
    axis = torch.randn(n, 3, generator=gen, dtype=torch.float64).numpy()
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    point = torch.randn(n, 3, generator=gen, dtype=torch.float64).numpy()
    th = torch.rand(n, generator=gen, dtype=torch.float64).numpy() * 3 + 1e-3
    d = torch.randn(n, generator=gen, dtype=torch.float64).numpy() * 4
    x = torch.from_numpy(np.stack([pt.dual_quaternion_from_screw_parameters(p, s, dd / t, t)
                                   for p, s, dd, t in zip(point, axis, d, th, strict=True)]))
    ang = dq.angle(dq.identity((n,), dtype=torch.float64), x)
    assert np.abs(ang.real.numpy() - th / 2).max() < 1e-15
    assert np.abs(ang.dual.numpy() - d / 2).max() < 1e-13
    # it is invariant under a common left motion (numpy product)
    g = unit_dq((n,), gen).numpy()
    ang2 = dq.angle(torch.from_numpy(g), torch.from_numpy(np_dqmul(g, x.numpy())))
    assert (ang2.real - ang.real).abs().max() < 1e-14
    assert (ang2.dual - ang.dual).abs().max() < 1e-12


def test_angle_against_mpmath_and_eq7(gen):
    """Eqs. 4, 5 at 40 digits on the inputs as given (mpmath), and eq. 7 in numpy:
    cos(theta) = P . R and -theta_hat sin(theta) = P . S + R . Q (eq. 1)."""
    a, b = unit_dq((300,), gen), unit_dq((300,), gen)
    near = screw_pairs(gen, 20, 1e-5, 1.0)[:2]
    a, b = torch.cat((a, near[0], near[0])), torch.cat((b, near[1], -near[1]))
    ang = dq.angle(a, b)
    with mpmath.workdps(40):
        for k in range(len(a)):
            P, Q, R, S = (list(map(mpmath.mpf, v)) for v in (a[k, :4].tolist(), a[k, 4:].tolist(),
                                                             b[k, :4].tolist(), b[k, 4:].tolist()))
            c = mpmath.fsum(p * r for p, r in zip(P, R, strict=True))
            delta = mpmath.fsum(p * s for p, s in zip(P, S, strict=True)) + mpmath.fsum(
                r * q for r, q in zip(R, Q, strict=True))
            norms = mpmath.sqrt(mpmath.fsum(p * p for p in P) * mpmath.fsum(r * r for r in R))
            theta = mpmath.acos(c / norms)  # the angle of the 4-vectors as given
            assert abs(ang.real[k].item() - float(theta)) < 4e-16 * (1 + float(theta))
            # delta's rounding (relative to the dual parts' size) over sin(theta)
            scale = max(1.0, a[k].abs().max().item(), b[k].abs().max().item())
            tol = 8e-16 * scale / float(mpmath.sin(theta)) ** 2
            assert abs(ang.dual[k].item() - float(-delta / mpmath.sin(theta))) < tol
    P, Q, R, S = a[:, :4].numpy(), a[:, 4:].numpy(), b[:, :4].numpy(), b[:, 4:].numpy()
    theta, theta_hat = ang.real.numpy(), ang.dual.numpy()
    assert np.abs(np.cos(theta) - (P * R).sum(-1)).max() < 1e-15
    assert np.abs(-theta_hat * np.sin(theta) - (P * S).sum(-1) - (R * Q).sum(-1)).max() < 1e-14
    assert ((theta >= 0) & (theta <= math.pi)).all()
    # no sign flip: theta(a, -b) = pi - theta(a, b), theta_hat(a, -b) = -theta_hat(a, b)
    flipped = dq.angle(a, -b)
    assert np.abs(flipped.real.numpy() - (math.pi - theta)).max() < 1e-14
    assert np.abs(flipped.dual.numpy() + theta_hat).max() < 1e-12


def test_angle_real_part_accurate_at_tiny_angles(gen):
    a, b, _ = screw_pairs(gen, 50, 2e-9, d=1.0)
    # rounding of the inputs themselves bounds the error (acos(q0 . q1) would be off by ~1e-8)
    assert (dq.angle(a, b).real - 1e-9).abs().max() < 2e-16


def test_angle_degenerate_branch_eq6(gen):
    """Equal and opposite rotation quaternions: eq. 6, |d1 - d0| with d_i the translation
    along each pose's own screw axis, from pytransform3d's screw parameters (d = h theta);
    the identity: |t1 - t0|. Also the factor 2 between eq. 6 and eq. 5's limit."""
    q = unit_quat((40,), gen).numpy()
    t0 = torch.randn(40, 3, generator=gen, dtype=torch.float64).numpy()
    t1 = torch.randn(40, 3, generator=gen, dtype=torch.float64).numpy()
    expected = np.array([abs(eq6_reference(((qi, x), (qi, y)))) for qi, x, y in zip(q, t0, t1,
                                                                                strict=True)])
    for sign in (1.0, -1.0):  # equal and opposite rotation quaternions
        ang = dq.angle(torch.from_numpy(np_pose(q, t0)), torch.from_numpy(np_pose(sign * q, t1)))
        assert np.abs(ang.dual.numpy() - expected).max() < 1e-13
        assert np.abs(ang.real.numpy() - (0.0 if sign > 0 else math.pi)).max() < 1e-15
    ident = np.tile([1.0, 0.0, 0.0, 0.0], (40, 1))
    ang = dq.angle(torch.from_numpy(np_pose(ident, t0)), torch.from_numpy(np_pose(ident, t1)))
    assert np.abs(ang.dual.numpy() - np.linalg.norm(t1 - t0, axis=-1)).max() < 1e-14
    # eq. 5 just outside the branch: half the (signed) axial distance (documented jump)
    a, b, _ = screw_pairs(gen, 20, 1e-4, 3.0)
    assert np.abs(dq.angle(a, b).dual.numpy() - 1.5).max() < 1e-9
    a, b, _ = screw_pairs(gen, 20, 1e-12, 3.0)  # eq. 6: each pose's own axis, not the screw's
    expected = [eq6_reference(((x[:4], pt.pq_from_dual_quaternion(x)[:3]),
                               (y[:4], pt.pq_from_dual_quaternion(y)[:3])))
                for x, y in zip(a.numpy(), b.numpy(), strict=True)]
    assert np.abs(dq.angle(a, b).dual.numpy() - expected).max() < 1e-9
    # a screw about the poses' own rotation axis: eq. 5 -> d / 2, eq. 6 = d (the factor 2)
    n = np.array([0.0, 0.6, 0.8])
    a = np_pose(np.concatenate(([math.cos(0.4)], math.sin(0.4) * n)), np.array([1.0, 2, -1]))
    for theta, expected in ((1e-4, 1.5), (1e-12, 3.0)):
        b = np_dqmul(a, np_screw(n, np.array([0.3, -1.0, 2.0]), np.array(theta), 3.0))
        assert abs(dq.angle(torch.from_numpy(a), torch.from_numpy(b)).dual.item() - expected) < 1e-9


def test_angle_gradients(gen):
    a = unit_dq((4,), gen).requires_grad_()
    b = unit_dq((4,), gen).requires_grad_()

    def f(a, b):
        ang = dq.angle(a, b)
        return ang.real, ang.dual

    assert torch.autograd.gradcheck(f, (a, b))
    assert torch.autograd.gradgradcheck(f, (a, b))
    assert torch.autograd.gradcheck(f, (a, b), check_forward_ad=True, check_backward_ad=False,
                                    check_undefined_grad=False)
    # degenerate points: finite gradients (zero subgradient of the kink of theta)
    for b2 in (a.detach().clone(), -a.detach().clone(),
               dq.from_rt(a.detach()[:, :4], torch.ones(4, 3, dtype=torch.float64))):
        a2, b2 = a.detach().clone().requires_grad_(), b2.requires_grad_()
        real, dual = f(a2, b2)
        (real + dual).sum().backward()
        assert torch.isfinite(a2.grad).all() and torch.isfinite(b2.grad).all()


def test_angle_compiles_without_graph_breaks(gen):
    """``torch.compile(fullgraph=True)`` runs the fused op, with and without gradients (with
    respect to both arguments, of a loss weighing each output differently)."""
    a, b = unit_dq((6,), gen), unit_dq((6,), gen)
    b[0] = a[0]  # the eq. 6 branch too

    def f(a, b):
        ang = dq.angle(a, b)
        return torch.stack((ang.real, ang.dual))

    compiled = torch.compile(f, fullgraph=True, backend="aot_eager")
    with torch.no_grad():
        assert torch.equal(compiled(a, b), f(a, b))
    w = torch.linspace(-1.0, 2.0, 12, dtype=a.dtype).view(2, 6)
    grads = []
    for fn in (compiled, f):
        aa, bb = a.clone().requires_grad_(), b.clone().requires_grad_()
        out = fn(aa, bb)
        grads.append((out.detach(), *torch.autograd.grad((w * out).sum(), (aa, bb))))
    assert (grads[0][0] - grads[1][0]).abs().max() <= 1e-14
    for g, r in zip(grads[0][1:], grads[1][1:], strict=True):
        assert (g - r).abs().max() < 1e-14


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

"""torch_dq.curves: De Casteljau / De Boor with sclerp against independent references.

References: numpy slerp De Casteljau (Shoemake) and De Boor for rotations, the Bernstein
formula and scipy's BSpline for translations, and a 4x4-matrix screw interpolation
``Ta expm(s logm(Ta^-1 Tb))`` (pytransform3d's exponential coordinates) for general poses.
"""

import math

import numpy as np
import pytest
import torch
from references import casteljau_np, deboor_np, sclerp_mat
from scipy.interpolate import BSpline
from strategies import unit_quat

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq._core import align_chain
from torch_dq._fused_curves import span_points
from torch_dq.curves import bezier, bspline, clamped_uniform_knots, screw_axis, twists, velocity

F64 = torch.float64


# ----------------------------------------------------------------------------- samplers

def poses(shape, gen, dtype=F64, scale=1.0):
    """Random unit dual quaternions with random signs and translations ~ N(0, scale)."""
    q = unit_quat(shape, gen)
    t = scale * torch.randn((*shape, 3), generator=gen, dtype=F64)
    return dq.from_rt(q, t).to(dtype)


def align(x, ref):
    """``x`` with the sign of the representative nearest to ``ref``."""
    s = torch.where((x[..., :4] * ref[..., :4]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    return x * s.to(x.dtype)


def tol(dtype):
    return 1e-11 if dtype == F64 else 2e-5


def max_err(a, b):
    return float((a - b).detach().abs().max())


# ----------------------------------------------------------------------------- numpy references

def slerp_np(q0, q1, s):
    """Quaternion slerp along the shorter arc (sign of q1 aligned with q0)."""
    if np.dot(q0, q1) < 0:
        q1 = -q1
    c = min(1.0, float(np.dot(q0, q1)))
    theta = math.acos(c)
    if theta < 1e-12:
        q = (1 - s) * q0 + s * q1
        return q / np.linalg.norm(q)
    return (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)


def bernstein_np(points, s):
    n = len(points) - 1
    return sum(math.comb(n, i) * s**i * (1 - s) ** (n - i) * points[i] for i in range(n + 1))


KNOT_CASES = ["clamped-uniform", "clamped-nonuniform", "repeated-interior-2",
              "repeated-interior-3", "unclamped"]


def knots_for(case, n, p):
    """(n + p + 1,) float64 knots: clamped (uniform, random interior, an interior knot of
    multiplicity 2 or min(3, p)) or unclamped strictly increasing."""
    rng = np.random.default_rng(7)
    if case == "clamped-uniform":
        return clamped_uniform_knots(n, p, dtype=F64)
    if case == "unclamped":
        return torch.from_numpy(np.cumsum(rng.uniform(0.2, 1.0, n + p + 1)) - 3.0)
    interior = np.sort(rng.uniform(0.05, 0.95, n - p - 1))
    if case == "repeated-interior-2":
        interior[2] = interior[1]
    elif case == "repeated-interior-3":
        interior[1:1 + min(3, p)] = interior[1]
    return torch.from_numpy(np.concatenate((np.zeros(p + 1), interior, np.ones(p + 1))))


def sample_domain(knots, p, n, count):
    """Times over the domain including its ends and every interior knot."""
    lo, hi = float(knots[p]), float(knots[n])
    inner = [float(k) for k in knots[p:n + 1]]
    return torch.tensor(sorted(set(np.linspace(lo, hi, count).tolist() + inner)), dtype=F64)


# ----------------------------------------------------------------------------- endpoints

def test_bezier_endpoints(dtype, device, batch_shape, gen):
    ctrl = poses((*batch_shape, 5), gen, dtype).to(device)
    x = bezier(ctrl, torch.tensor([0.0, 1.0], dtype=dtype, device=device))
    assert x.shape == (*batch_shape, 2, 8) and x.dtype == dtype and x.device == device
    assert max_err(x[..., 0, :], ctrl[..., 0, :]) <= tol(dtype)
    assert max_err(align(x[..., 1, :], ctrl[..., -1, :]), ctrl[..., -1, :]) <= tol(dtype)


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_bspline_clamped_endpoints(dtype, device, batch_shape, gen, degree):
    ctrl = poses((*batch_shape, 7), gen, dtype).to(device)
    x = bspline(ctrl, torch.tensor([0.0, 1.0], dtype=dtype, device=device), degree=degree)
    assert x.shape == (*batch_shape, 2, 8) and x.device == device
    assert max_err(align(x[..., 0, :], ctrl[..., 0, :]), ctrl[..., 0, :]) <= tol(dtype)
    assert max_err(align(x[..., 1, :], ctrl[..., -1, :]), ctrl[..., -1, :]) <= tol(dtype)


def test_bezier_two_points_is_sclerp(gen):
    ctrl = poses((4, 2), gen, scale=3.0)
    t = torch.linspace(0, 1, 11, dtype=F64)
    ref = dq.sclerp(ctrl[:, None, 0], ctrl[:, None, 1], t)
    assert max_err(bezier(ctrl, t), ref) <= 1e-14


def test_bspline_degree1_is_piecewise_sclerp(gen):
    n = 6
    ctrl = poses((n,), gen, scale=2.0)
    knots = torch.tensor([0.0, 0.0, 0.1, 0.4, 0.45, 0.8, 1.0, 1.0], dtype=F64)
    t = sample_domain(knots, 1, n, 41)
    x = bspline(ctrl, t, degree=1, knots=knots)
    i = torch.clamp(torch.searchsorted(knots, t, right=True) - 1, 1, n - 1)
    s = (t - knots[i]) / (knots[i + 1] - knots[i])
    ref = dq.sclerp(ctrl[i - 1], ctrl[i], s)
    assert max_err(align(x, ref), ref) <= 1e-14  # bspline sign-aligns the polygon first
    # bspline with n = degree + 1 and clamped knots is the Bezier curve
    assert max_err(bspline(ctrl[:4], t, degree=3), bezier(ctrl[:4], t)) <= 1e-12


# ----------------------------------------------------------------------------- rotation-only

def test_rotation_only_bezier_is_shoemake(gen):
    q = unit_quat((6,), gen)  # random signs: exercises the shortest-arc choice
    ctrl = dq.from_rt(q, torch.zeros(6, 3, dtype=F64))
    t = torch.linspace(0, 1, 23, dtype=F64)
    x = bezier(ctrl, t)
    ref = np.stack([casteljau_np(q.numpy(), s, slerp_np) for s in t.tolist()])
    assert max_err(x[:, :4], torch.from_numpy(ref)) <= 1e-13
    assert float(x[:, 4:].abs().max()) <= 1e-15


@pytest.mark.parametrize("knot_case", KNOT_CASES)
def test_rotation_only_bspline_is_quaternion_deboor(gen, knot_case):
    n, p = 8, 3
    q = unit_quat((n,), gen)
    ctrl = dq.from_rt(q, torch.zeros(n, 3, dtype=F64))
    knots = knots_for(knot_case, n, p)
    t = sample_domain(knots, p, n, 29)
    x = bspline(ctrl, t, degree=p, knots=None if knot_case == "clamped-uniform" else knots)
    kn = knots.tolist()
    ref = torch.from_numpy(np.stack([deboor_np(q.numpy(), kn, p, s, slerp_np)
                                     for s in t.tolist()]))
    assert max_err(align(x[:, :4], ref), ref) <= 1e-13
    assert float(x[:, 4:].abs().max()) <= 1e-15


# ----------------------------------------------------------------------------- translation-only

def test_translation_only_bezier_is_bernstein(gen):
    p = 3.0 * torch.randn(7, 3, generator=gen, dtype=F64)
    ctrl = dq.from_rt(dq.identity((7,), dtype=F64)[:, :4], p)
    t = torch.linspace(0, 1, 31, dtype=F64)
    q, trans = dq.to_rt(bezier(ctrl, t))
    ref = np.stack([bernstein_np(p.numpy(), s) for s in t.tolist()])
    assert max_err(trans, torch.from_numpy(ref)) <= 1e-13
    assert max_err(q, dq.identity((31,), dtype=F64)[:, :4]) == 0


@pytest.mark.parametrize("knot_case", KNOT_CASES)
@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_translation_only_bspline_is_scipy(gen, knot_case, degree):
    n = 9
    p = 3.0 * torch.randn(n, 3, generator=gen, dtype=F64)
    ctrl = dq.from_rt(dq.identity((n,), dtype=F64)[:, :4], p)
    knots = knots_for(knot_case, n, degree)
    t = sample_domain(knots, degree, n, 37)
    _, trans = dq.to_rt(bspline(ctrl, t, degree=degree, knots=knots))
    # scipy is right-continuous inside and takes the left limit at the domain's right end.
    ref = BSpline(knots.numpy(), p.numpy(), degree)(t.numpy())
    assert max_err(trans, torch.from_numpy(ref)) <= 1e-12


# ----------------------------------------------------------------------------- general poses

def test_bezier_general_poses_matrix_reference(gen):
    ctrl = poses((5,), gen, scale=2.0)
    t = torch.linspace(0, 1, 9, dtype=F64)
    mats = dq.to_matrix(ctrl).numpy()
    ref = np.stack([casteljau_np(mats, s, sclerp_mat) for s in t.tolist()])
    assert max_err(dq.to_matrix(bezier(ctrl, t)), torch.from_numpy(ref)) <= 1e-11


@pytest.mark.parametrize("knot_case", ["clamped-nonuniform", "repeated-interior-2", "unclamped"])
def test_bspline_general_poses_matrix_reference(gen, knot_case):
    n, p = 8, 3
    ctrl = poses((n,), gen, scale=2.0)
    knots = knots_for(knot_case, n, p)
    t = sample_domain(knots, p, n, 13)
    mats = dq.to_matrix(ctrl).numpy()
    ref = np.stack([deboor_np(mats, knots.tolist(), p, s, sclerp_mat) for s in t.tolist()])
    x = bspline(ctrl, t, degree=p, knots=knots)
    assert max_err(dq.to_matrix(x), torch.from_numpy(ref)) <= 1e-11


# ----------------------------------------------------------------------------- structure

@pytest.mark.parametrize("knot_case", ["clamped-uniform", "repeated-interior-2", "unclamped"])
def test_bspline_local_control(gen, knot_case):
    n, p = 8, 3
    ctrl = poses((n,), gen)
    knots = knots_for(knot_case, n, p)
    t = sample_domain(knots, p, n, 201)
    x = bspline(ctrl, t, knots=knots)
    for i in range(n):
        moved = ctrl.clone()
        moved[i] = poses((), gen)
        y = bspline(moved, t, knots=knots)
        support = (t >= knots[i]) & (t < knots[i + p + 1])
        if i == n - 1:
            support |= t == knots[n]  # the right end belongs to the last span
        changed = (dq.to_matrix(x) - dq.to_matrix(y)).abs().amax((-1, -2)) > 1e-12
        assert not bool((changed & ~support).any()), i
        assert bool(changed[support].any()), i


def test_bspline_knot_affine_invariance(gen):
    n, p = 9, 3
    ctrl = poses((2, n), gen, scale=2.0)
    knots = torch.tensor([0, 0, 0, 0, 0.15, 0.3, 0.3, 0.7, 0.75, 1, 1, 1, 1.2], dtype=F64)
    t = sample_domain(knots, p, n, 25)
    x = bspline(ctrl, t, knots=knots)
    y = bspline(ctrl, 2.0 * t + 5.0, knots=2.0 * knots + 5.0)
    assert max_err(x, y) <= 1e-12


@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_output_is_unit(dtype, device, gen, kind):
    ctrl = poses((3, 10), gen, dtype, scale=10.0).to(device)
    t = torch.linspace(0, 1, 500, dtype=dtype, device=device)
    x = bezier(ctrl, t) if kind == "bezier" else bspline(ctrl, t, degree=4)
    assert bool(dq.is_unit(x, atol=1e-12 if dtype == F64 else 1e-5).all())


@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_identical_and_antipodal_controls(gen, kind):
    x0 = poses((), gen, scale=2.0)
    ctrl = torch.stack((x0, -x0, x0, x0, -x0, -x0)).requires_grad_()
    t = torch.linspace(0, 1, 17, dtype=F64).requires_grad_()
    x = bezier(ctrl, t) if kind == "bezier" else bspline(ctrl, t)
    assert max_err(align(x, x0), x0.expand_as(x)) <= 1e-14
    (x * torch.randn(x.shape, generator=gen, dtype=F64)).sum().backward()
    assert bool(torch.isfinite(ctrl.grad).all()) and bool(torch.isfinite(t.grad).all())
    # sign-invariance: -x and x control points give the same motion
    other = torch.stack((x0,) * 6)
    y = bezier(other, t) if kind == "bezier" else bspline(other, t)
    assert max_err(align(x, y), y) <= 1e-14


@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_output_sign_is_continuous(gen, kind):
    # random signs and large rotations between neighbours: no sign jump at the knots
    ctrl = poses((10, 10), gen, scale=2.0)
    t = torch.linspace(0, 1, 401, dtype=F64)
    x = bezier(ctrl, t) if kind == "bezier" else bspline(ctrl, t)
    assert bool(((x[..., 1:, :4] * x[..., :-1, :4]).sum(-1) > 0).all())
    assert max_err(x[..., 0, :], ctrl[..., 0, :]) <= 1e-13  # sign of ctrl[0] kept


def test_nan_stays_local(gen):
    ctrl = poses((8,), gen)
    t = torch.tensor([0.1, float("nan"), 0.7], dtype=F64)
    for x in (bezier(ctrl, t), bspline(ctrl, t)):
        assert bool(torch.isnan(x[1]).all())
        assert bool(torch.isfinite(x[[0, 2]]).all())
    # a NaN control point poisons its support only: [knots[2], knots[6]) = [0, 0.6)
    ctrl[2] = float("nan")
    t = torch.linspace(0, 1, 101, dtype=F64)
    nan_rows = torch.isnan(bspline(ctrl, t)).any(-1)
    assert torch.equal(nan_rows, t < 0.6 - 1e-12)


# ----------------------------------------------------------------------------- fused vs readable

def readable_bspline(ctrl, t, degree=3, knots=None):
    """The readable De Boor loop of torch_dq.curves (the reference of the fused op)."""
    batch, dom, rel, _ = curves._prepare_bspline("test", ctrl, t, degree, knots, True, False,
                                                 "de_boor")
    c, r = align_chain(ctrl), dom.span(rel)
    alphas = [a for a, _ in dom.de_boor_levels(rel, r, ctrl.dtype)]
    return curves._de_boor(span_points(c, r, dom.degree, batch), alphas)


def degenerate_polygons(gen, dtype):
    """Control polygons at the degenerate points of eq. 11: identical and antipodal
    neighbours, pure translations, rotations about one axis, tiny rotations with large
    translations, half turns between neighbours, and random poses."""
    x0 = poses((), gen, scale=2.0)
    shift = dq.from_rt(torch.tensor([1.0, 0, 0, 0], dtype=F64), torch.tensor([0.3, -1, 2],
                                                                             dtype=F64))
    z = torch.zeros(6, 3, dtype=F64)
    angles = torch.linspace(0, 2.5, 6, dtype=F64)
    about_z = torch.stack((torch.cos(angles), 0 * angles, 0 * angles, torch.sin(angles)), -1)
    tiny = dq.exp(torch.cat((1e-9 * torch.randn(6, 3, generator=gen, dtype=F64),
                             50 * torch.randn(6, 3, generator=gen, dtype=F64)), -1))
    half = dq.from_rt(torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1],
                                    [0, 1, 0, 0], [1.0, 0, 0, 0]], dtype=F64), z)
    cases = {
        "identical-antipodal": torch.stack((x0, -x0, x0, x0, -x0, x0)),
        "translations": torch.stack([dq.mul(x0, shift)] * 3 + [x0] * 3),
        "pure-translation": dq.from_rt(dq.identity((6,), dtype=F64)[:, :4],
                                       torch.randn(6, 3, generator=gen, dtype=F64)),
        "one-axis": dq.from_rt(about_z, torch.randn(6, 3, generator=gen, dtype=F64)),
        "tiny-rotations": tiny,
        "half-turns": half,
        "random": poses((6,), gen, scale=3.0),
    }
    return {k: v.to(dtype) for k, v in cases.items()}


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
def test_fused_matches_readable(gen, dtype):
    """The fused op behind bezier/bspline against the readable level loops, values and
    gradients: float64 to rounding, float32 within 2e-6 (relative to the largest entry;
    measured: values bitwise equal, gradients 9e-16 and 3e-7)."""
    t = torch.linspace(0, 1, 41, dtype=dtype)
    knots = torch.tensor([0, 0, 0, 0, 0.3, 0.35, 1, 1, 1, 1], dtype=dtype)
    tol = 1e-13 if dtype == F64 else 2e-6
    for name, ctrl in degenerate_polygons(gen, dtype).items():
        w = torch.randn(41, 8, generator=gen, dtype=F64).to(dtype)
        for fused, readable in (
                (lambda c: bezier(c, t), lambda c: curves._de_casteljau(c, t)),
                (lambda c: bspline(c, t, knots=knots),
                 lambda c: readable_bspline(c, t, knots=knots))):
            c1, c2 = ctrl.clone().requires_grad_(), ctrl.clone().requires_grad_()
            x, y = fused(c1), readable(c2)
            scale = max(1.0, float(y.detach().abs().max()))
            assert max_err(x, y) <= tol * scale, name
            (g1,) = torch.autograd.grad((w * x).sum(), c1)
            (g2,) = torch.autograd.grad((w * y).sum(), c2)
            assert bool(torch.isfinite(g1).all()), name
            assert max_err(g1, g2) <= tol * max(1.0, float(g2.abs().max())), name


# ----------------------------------------------------------------------------- autograd

def test_gradcheck_bezier(gen):
    ctrl = poses((4,), gen).requires_grad_()
    t = torch.tensor([0.05, 0.4, 0.93], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c, s: bezier(c, s, check=False), (ctrl, t))


def test_gradcheck_bspline(gen):
    ctrl = poses((6,), gen).requires_grad_()
    knots = torch.tensor([0, 0, 0, 0.2, 0.45, 0.7, 1, 1, 1], dtype=F64, requires_grad=True)
    t = torch.tensor([0.05, 0.3, 0.5, 0.93], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda c, s, k: bspline(c, s, degree=2, knots=k, check=False), (ctrl, t, knots))


def test_gradgradcheck_bspline(gen):
    ctrl = poses((4,), gen).requires_grad_()
    t = torch.tensor([0.3, 0.8], dtype=F64, requires_grad=True)
    assert torch.autograd.gradgradcheck(lambda c, s: bspline(c, s, degree=2), (ctrl, t))


# ----------------------------------------------------------------------------- velocity, twists

def skew_vec(S):
    return torch.stack((S[..., 2, 1], S[..., 0, 2], S[..., 1, 0]), -1)


@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_twists_match_matrix_finite_differences(gen, kind):
    ctrl = poses((7,), gen, scale=2.0)
    knots = torch.tensor([0, 0, 0, 0, 0.2, 0.55, 0.6, 1, 1, 1, 1], dtype=F64)
    f = (lambda s: bezier(ctrl, s)) if kind == "bezier" else (
        lambda s: bspline(ctrl, s, knots=knots))
    t = torch.tensor([0.01, 0.3, 0.5, 0.7, 0.99], dtype=F64)
    x, dx = velocity(f, t)
    assert max_err(x, f(t)) <= 1e-14  # readable scheme under jvp, fused op outside
    h = 1e-4  # fourth-order central differences
    T = dq.to_matrix(x)
    M = [dq.to_matrix(f(t + k * h)) for k in (-2, -1, 1, 2)]
    dT = (M[0] - 8 * M[1] + 8 * M[2] - M[3]) / (12 * h)
    R, p = T[..., :3, :3], T[..., :3, 3]
    body, spatial = twists(x, dx, "body"), twists(x, dx, frame="spatial")
    # dR/dt = R [w_b]x, dp/dt = R v_b
    w_b, v_b = skew_vec(R.mT @ dT[..., :3, :3]), (R.mT @ dT[..., :3, 3:])[..., 0]
    assert max_err(body, torch.cat((w_b, v_b), -1)) <= 1e-8
    # w_s = R w_b, v_s = dp/dt - w_s x p
    w_s = skew_vec(dT[..., :3, :3] @ R.mT)
    v_s = dT[..., :3, 3] - torch.linalg.cross(w_s, p, dim=-1)
    assert max_err(spatial, torch.cat((w_s, v_s), -1)) <= 1e-8
    assert max_err((R @ body[..., :3, None])[..., 0], spatial[..., :3]) <= 1e-12
    # (x, dx) and (-x, -dx) give the same twists
    assert max_err(twists(-x, -dx), body) == 0


def test_velocity_at_knots_and_ends_is_finite(gen):
    ctrl = poses((6,), gen)
    t = clamped_uniform_knots(6, 3, dtype=F64)[3:7]
    _, dx = velocity(lambda s: bspline(ctrl, s), t)
    assert bool(torch.isfinite(dx).all())
    # jvp equals the derivative of the span containing t; continuous at simple cubic knots
    h = 1e-6
    fd = (bspline(ctrl, t[1:3] + h) - bspline(ctrl, t[1:3] - h)) / (2 * h)
    assert max_err(dx[1:3], fd) <= 1e-6


def test_constant_screw_axis(gen):
    # Two-point Bezier = sclerp = constant spatial twist of b a^-1: fixed axis and pitch.
    a, b = poses((2,), gen, scale=2.0)
    x, dx = velocity(lambda s: bezier(torch.stack((a, b)), s), torch.linspace(0, 1, 7, dtype=F64))
    xi = twists(x, dx, "spatial")
    direction, moment, pitch = screw_axis(xi[..., :3], xi[..., 3:])
    l, m, theta, d = dq.to_screw(dq.mul(b, dq.conj(a)))
    s = torch.sign((direction * l).sum(-1, keepdim=True))
    assert max_err(s * direction, l.expand_as(direction)) <= 1e-12
    assert max_err(s * moment, m.expand_as(moment)) <= 1e-12
    assert max_err(pitch, (d / theta).expand_as(pitch)) <= 1e-12


def test_screw_axis_properties(dtype, gen):
    omega = torch.randn(50, 3, generator=gen, dtype=F64).to(dtype)
    v = 3.0 * torch.randn(50, 3, generator=gen, dtype=F64).to(dtype)
    direction, moment, pitch = screw_axis(omega, v)
    point = torch.linalg.cross(direction, moment, dim=-1)
    tol_ = 1e-12 if dtype == F64 else 1e-4
    assert max_err(direction.norm(dim=-1), torch.ones(50, dtype=dtype)) <= tol_
    assert float((direction * moment).sum(-1).abs().max()) <= tol_
    # points on the axis slide along it: v + omega x c = pitch omega
    lhs = v + torch.linalg.cross(omega, point, dim=-1)
    assert max_err(lhs, pitch[:, None] * omega) <= tol_ * 10
    # pure translation and rest
    z = torch.zeros(3, dtype=dtype)
    d0, m0, h0 = screw_axis(z, torch.tensor([0.0, 3.0, 4.0], dtype=dtype))
    assert max_err(d0, torch.tensor([0.0, 0.6, 0.8], dtype=dtype)) <= tol_
    assert float(m0.abs().max()) == 0 and math.isinf(float(h0))
    assert all(bool(torch.isnan(u).all()) for u in screw_axis(z, z))


def test_screw_axis_gradients_finite(gen):
    omega = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [0, 0, 0]], dtype=F64,
                         requires_grad=True)
    v = torch.tensor([[1.0, 2.0, 0.5], [0.3, 0.0, 1.0], [0, 0, 0]], dtype=F64,
                     requires_grad=True)
    direction, moment, pitch = screw_axis(omega, v)
    (direction[:2].sum() + moment[:2].sum() + pitch[1:2].sum()).backward()
    assert bool(torch.isfinite(omega.grad).all()) and bool(torch.isfinite(v.grad).all())


# ----------------------------------------------------------------------------- shapes, dtypes

@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_batch_broadcasting(gen, kind):
    n, T = 5, 7
    ctrl = poses((3, 1, n), gen)
    f = bezier if kind == "bezier" else bspline
    t1 = torch.rand(T, generator=gen, dtype=F64)
    t2 = torch.rand(2, T, generator=gen, dtype=F64)
    x1, x2 = f(ctrl, t1), f(ctrl, t2)
    assert x1.shape == (3, 1, T, 8) and x2.shape == (3, 2, T, 8)
    for i in range(3):
        assert max_err(x1[i, 0], f(ctrl[i, 0], t1)) <= 1e-15
        for j in range(2):
            assert max_err(x2[i, j], f(ctrl[i, 0], t2[j])) <= 1e-15
    # gradient flows back to the un-broadcast shapes
    ctrl.requires_grad_()
    f(ctrl, t2).sum().backward()
    assert ctrl.grad.shape == ctrl.shape and bool(torch.isfinite(ctrl.grad).all())


@pytest.mark.parametrize("low", [torch.float16, torch.bfloat16])
def test_low_precision_dtypes(gen, low):
    ctrl = poses((5,), gen)
    t = torch.linspace(0, 1, 9, dtype=F64)
    for f in (bezier, bspline):
        x = f(ctrl.to(low), t.to(low))
        assert x.dtype == low
        ref = f(ctrl.to(low).double(), t.to(low).double())
        assert max_err(align(x.double(), ref), ref) <= 2e-2


def test_check_false_matches(gen):
    ctrl = poses((6,), gen)
    t = torch.rand(10, generator=gen, dtype=F64)
    assert torch.equal(bspline(ctrl, t), bspline(ctrl, t, check=False))
    assert torch.equal(bezier(ctrl, t), bezier(ctrl, t, check=False))


def test_domain_ends_with_rounding(gen):
    ctrl = poses((6,), gen)
    eps = torch.finfo(F64).eps
    t = torch.tensor([-eps, 1.0 + 2 * eps], dtype=F64)  # a few ulps outside: accepted
    assert bool(torch.isfinite(bspline(ctrl, t)).all())
    assert bool(torch.isfinite(bezier(ctrl, t)).all())


def test_clamped_uniform_knots():
    k = clamped_uniform_knots(7, 3, dtype=F64)
    assert k.tolist() == [0, 0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1, 1]
    assert clamped_uniform_knots(4, 3).dtype == torch.get_default_dtype()
    assert clamped_uniform_knots(2, 1, dtype=torch.float32).tolist() == [0, 0, 1, 1]


# ----------------------------------------------------------------------------- bad input

def _bad_cases():
    g = torch.Generator().manual_seed(0)
    c = poses((5,), g)
    t = torch.linspace(0, 1, 4, dtype=F64)
    k = clamped_uniform_knots(5, 3, dtype=F64)
    return [
        ("bezier ctrl last dim", lambda: bezier(c[..., :7], t), ValueError, r"bezier.*ctrl"),
        ("bezier one point", lambda: bezier(c[:1], t), ValueError, r"bezier.*ctrl.*n >= 2"),
        ("bezier ctrl 1-D", lambda: bezier(c[0], t), ValueError, r"bezier.*ctrl"),
        ("bezier t 0-d", lambda: bezier(c, t[0]), ValueError, r"bezier.*t"),
        ("bezier t outside", lambda: bezier(c, t + 0.1), ValueError, r"bezier.*t.*\[0, 1\]"),
        ("bezier t inf", lambda: bezier(c, t * math.inf), ValueError, r"bezier.*t.*domain"),
        ("bezier int ctrl", lambda: bezier(c.long(), t), TypeError, r"bezier.*ctrl"),
        ("bezier int t", lambda: bezier(c, t.long()), TypeError, r"bezier.*t"),
        ("bezier not tensor", lambda: bezier(c, [0.5]), TypeError, r"bezier.*t"),
        ("bezier batch", lambda: bezier(c.expand(3, 5, 8), t.expand(2, 4)), ValueError,
         r"bezier.*batch.*ctrl.*t"),
        ("bspline ctrl last dim", lambda: bspline(c[..., :4], t), ValueError, r"bspline.*ctrl"),
        ("bspline degree 0", lambda: bspline(c, t, degree=0), ValueError, r"bspline.*degree"),
        ("bspline degree float", lambda: bspline(c, t, degree=2.0), ValueError,
         r"bspline.*degree"),
        ("bspline degree bool", lambda: bspline(c, t, degree=True), ValueError,
         r"bspline.*degree"),
        ("bspline degree >= n", lambda: bspline(c, t, degree=5), ValueError,
         r"bspline.*degree.*n = 5"),
        ("bspline knot count", lambda: bspline(c, t, knots=k[:-1]), ValueError,
         r"bspline.*knots.*9"),
        ("bspline knots 2-D", lambda: bspline(c, t, knots=k[None, :-1]), ValueError,
         r"^curves\.bspline: expected \(\.\.\., n \+ degree \+ 1\) = \(\.\.\., 9\) knots"),
        ("bspline knot rows", lambda: bspline(c.expand(2, 5, 8), t, knots=k.expand(3, 9)),
         ValueError,
         r"^curves\.bspline: batch shapes do not broadcast: .*knots \(3,\)"),
        ("bspline knots decreasing", lambda: bspline(c, t, knots=k.flip(0)), ValueError,
         r"bspline.*knots.*non-decreasing"),
        ("bspline knots nan", lambda: bspline(c, t, knots=k * math.nan), ValueError,
         r"bspline.*knots.*finite"),
        ("bspline empty domain", lambda: bspline(c, t * 0, knots=k * 0), ValueError,
         r"bspline.*knots.*domain"),
        ("bspline t outside", lambda: bspline(c, t * 2 - 0.5, knots=k), ValueError,
         r"bspline.*t.*domain"),
        ("bspline t outside default", lambda: bspline(c, t + 1e-6), ValueError,
         r"bspline.*t.*domain"),
        ("bspline knots int", lambda: bspline(c, t, knots=k.long()), TypeError,
         r"bspline.*knots"),
        ("knots degree", lambda: clamped_uniform_knots(5, 0), ValueError,
         r"clamped_uniform_knots.*degree"),
        ("knots n_ctrl", lambda: clamped_uniform_knots(3, 3), ValueError,
         r"clamped_uniform_knots.*n_ctrl"),
        ("knots dtype", lambda: clamped_uniform_knots(5, 3, dtype=torch.int64), TypeError,
         r"clamped_uniform_knots.*dtype"),
        ("velocity fn", lambda: velocity(3, t), TypeError, r"velocity.*fn"),
        ("velocity t", lambda: velocity(lambda s: s, [0.5]), TypeError, r"velocity.*t"),
        ("twists shape", lambda: twists(c, c[..., :6]), ValueError, r"twists.*dx"),
        ("twists frame", lambda: twists(c, c, frame="world"), ValueError, r"twists.*frame"),
        ("twists batch", lambda: twists(c, c[:3]), ValueError, r"twists.*batch"),
        ("screw_axis shape", lambda: screw_axis(c[..., :3], c[..., :4]), ValueError,
         r"screw_axis.*v"),
        ("screw_axis dtype", lambda: screw_axis(c[..., :3], c[..., :3].float()), TypeError,
         r"screw_axis.*v"),
    ]


@pytest.mark.parametrize("case", _bad_cases(), ids=lambda c: c[0])
def test_bad_input(case):
    _, call, error, pattern = case
    with pytest.raises(error, match=pattern):
        call()


def test_module_exports():
    assert set(curves.__all__) == {"bezier", "bspline", "clamped_uniform_knots", "screw_axis",
                                   "twists", "velocity", "bezier_derivatives",
                                   "bspline_derivatives", "kinematics", "imu"}

"""Continuous time: the caller's time units, wide time dtypes, exact time derivatives,
kinematics and IMU readings of ``torch_dq.curves``.

Independent references, written here in numpy: De Casteljau and De Boor on 4x4 rigid
transforms with the screw interpolation ``Ta exp(s log(Ta^-1 Tb))`` (pytransform3d's
exponential coordinates, i.e. the matrix logarithm and exponential of se(3)), their
time derivatives by a 9-point polynomial fit (finite differences of order 8), and the
kinematic quantities from rotation matrices (``w = vee(dR R^T)``, ``a = d2p/dt2``).
"""

import math

import numpy as np
import pytest
import torch
from pytransform3d import rotations as pr
from pytransform3d import transformations as pt
from references import casteljau_np, deboor_np, sclerp_mat
from strategies import raises_exactly, unit_quat

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq.curves import (
    bezier,
    bezier_derivatives,
    bspline,
    bspline_derivatives,
    clamped_uniform_knots,
    imu,
    kinematics,
)

F64 = torch.float64


def poses(shape, gen, dtype=F64, scale=1.0):
    """Random unit dual quaternions with random signs and translations ~ N(0, scale)."""
    q = unit_quat(shape, gen)
    t = scale * torch.randn((*shape, 3), generator=gen, dtype=F64)
    return dq.from_rt(q, t).to(dtype)


def near(shape, gen, spread=0.6, scale=1.0):
    """A chain of poses each a moderate screw motion away from the previous one (so that
    the curves stay far from half turns between neighbours)."""
    xi = torch.randn((*shape, 6), generator=gen, dtype=F64)
    xi[..., :3] *= spread
    xi[..., 3:] *= scale
    steps = dq.exp(xi)
    out = [poses(shape[:-1], gen)]
    for k in range(1, shape[-1]):
        out.append(dq.mul(out[-1], steps[..., k, :]))
    return torch.stack(out, -2)


def max_err(a, b):
    return float((a - b).detach().abs().max())


# ----------------------------------------------------------------------------- numpy references

def dq_of(T, ref):
    """The unit dual quaternion of a 4x4 transform (pytransform3d), sign-aligned with ref."""
    x = pt.dual_quaternion_from_transform(T)
    return x if np.dot(x[:4], ref[:4]) >= 0 else -x


STENCIL = np.arange(-4, 5)


def fd_derivatives(f, t, h, order=3):
    """Derivatives 0..order of a vector function at t from a degree-8 polynomial through
    f(t + k h), k = -4..4 (errors O(h^(9-k)) plus rounding / h^k)."""
    vals = np.stack([f(t + k * h) for k in STENCIL])
    V = np.vander(STENCIL * h, 9, increasing=True)
    coef = np.linalg.solve(V, vals.reshape(9, -1)).reshape(vals.shape)
    return [math.factorial(k) * coef[k] for k in range(order + 1)]


def vee(S):
    """Axial vector of the antisymmetric part of a 3x3 matrix."""
    return 0.5 * np.array([S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]])


def kinematics_mat(f, t, h, g):
    """World and body velocities/accelerations and IMU readings from matrices T(t)."""
    T0, T1, T2 = fd_derivatives(lambda s: f(s).ravel(), t, h, 2)
    T0, T1, T2 = (M.reshape(4, 4) for M in (T0, T1, T2))
    R, dR, ddR = T0[:3, :3], T1[:3, :3], T2[:3, :3]
    w = vee(dR @ R.T)  # dR = [w]x R
    alpha = vee(ddR @ R.T)  # d/dt of vee(dR R^T); dR dR^T is symmetric
    v, a = T1[:3, 3], T2[:3, 3]
    world = np.stack([w, v, alpha, a])
    return world, world @ R, (R.T @ w, R.T @ (a - g))  # rows @ R = R^T rows


# ----------------------------------------------------------------------------- derivatives

def _check_against_reference(jet, ref_fn, t, h, scale):
    x = jet[0].numpy()
    for k, tk in enumerate(t.tolist()):
        ref = fd_derivatives(lambda s, k=k: dq_of(ref_fn(s), x[k]), tk, h, len(jet) - 1)
        for m in range(len(jet)):
            err = np.abs(jet[m][k].numpy() - ref[m]).max()
            assert err <= 2e-6 * scale ** m * max(1.0, np.abs(ref[m]).max()), (k, m, err)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_bezier_derivatives_match_reference(gen, order):
    ctrl = near((5,), gen)
    t0, t1 = 3.0, 5.5  # seconds: d/dt includes the factor 1 / (t1 - t0)
    t = torch.tensor([3.3, 4.1, 5.2], dtype=F64)
    jet = bezier_derivatives(ctrl, t, order=order, domain=(t0, t1))
    assert len(jet) == order + 1 and all(x.shape == (3, 8) and x.dtype == F64 for x in jet)
    mats = list(dq.to_matrix(ctrl).numpy())
    _check_against_reference(jet, lambda s: casteljau_np(mats, (s - t0) / (t1 - t0), sclerp_mat), t,
                             2e-3, 1.0)


@pytest.mark.parametrize("order", [1, 2, 3])
@pytest.mark.parametrize("degree", [2, 3])
def test_bspline_derivatives_match_reference_nonuniform(gen, order, degree):
    n = 7
    ctrl = near((n,), gen)
    inner = [10.4, 10.55, 11.3, 11.9][:n - degree - 1]
    knots = torch.tensor([10.0] * (degree + 1) + inner + [12.5] * (degree + 1), dtype=F64)
    t = torch.tensor([10.2, 10.48, 11.0, 12.3], dtype=F64)  # inside spans, off the knots
    jet = bspline_derivatives(ctrl, t, order=order, degree=degree, knots=knots)
    mats, kn = list(dq.to_matrix(ctrl).numpy()), knots.tolist()
    _check_against_reference(jet, lambda s: deboor_np(mats, kn, degree, s, sclerp_mat), t,
                             4e-3, 1.0)


def test_derivatives_order0_and_poses_match_the_curves(gen):
    ctrl = poses((2, 6), gen, scale=2.0)
    t = torch.linspace(0, 1, 9, dtype=F64)
    (x,) = bspline_derivatives(ctrl, t, order=0)
    assert max_err(x, bspline(ctrl, t)) <= 1e-14
    x, dx = bezier_derivatives(ctrl, t, order=1)
    assert max_err(x, bezier(ctrl, t)) <= 1e-14
    # tangent to the unit dual quaternions: x* dx is pure (zero scalar parts)
    prod = dq.mul(dq.conj(x), dx)
    assert float(prod[..., [0, 4]].abs().max()) <= 1e-12


def test_derivatives_scale_with_the_time_unit(gen):
    """The same curve over [0, 1] and over [0, 1000] ms: d^k x / dt^k scales by 1e-3^k."""
    ctrl = poses((6,), gen)
    t = torch.tensor([0.1, 0.45, 0.8], dtype=F64)
    a = bspline_derivatives(ctrl, t, order=3)
    b = bspline_derivatives(ctrl, 1000.0 * t, order=3,
                            knots=clamped_uniform_knots(6, 3, dtype=F64, domain=(0, 1000)))
    for k in range(4):
        assert max_err(b[k], a[k] * 1e-3**k) <= 1e-12 * max(1.0, float(a[k].abs().max()))


def test_nested_jvp_through_the_public_curve_matches(gen):
    """jvp of jvp of bspline (readable scheme under torch.func) is the second derivative."""
    ctrl = poses((6,), gen)
    knots = torch.tensor([0, 0, 0, 0, 0.3, 0.4, 1, 1, 1, 1], dtype=F64)
    t = torch.tensor([0.1, 0.35, 0.7], dtype=F64)
    ones = torch.ones_like(t)

    def x(s):
        return bspline(ctrl, s, knots=knots, check=False)

    def dx(s):
        return torch.func.jvp(x, (s,), (ones,))[1]

    ddx = torch.func.jvp(dx, (t,), (ones,))[1]
    jet = bspline_derivatives(ctrl, t, order=3, knots=knots)
    assert max_err(dx(t), jet[1]) <= 1e-12
    assert max_err(ddx, jet[2]) <= 1e-10
    assert float(jet[2].abs().max()) > 1.0  # not the silent zeros of a custom op
    # forward mode over the derivatives themselves: d/dt of x'' is x'''
    d3 = torch.func.jvp(lambda s: bspline_derivatives(ctrl, s, 2, knots=knots,
                                                      check=False)[2], (t,), (ones,))[1]
    assert max_err(d3, jet[3]) <= 1e-9


# ----------------------------------------------------------------------------- constant screw

def test_two_point_curve_is_a_constant_screw_motion(gen):
    a, b = poses((2,), gen, scale=2.0)
    t0, t1 = -2.0, 1.5
    t = torch.linspace(t0, t1, 7, dtype=F64)
    Ta, Tb = dq.to_matrix(a).numpy(), dq.to_matrix(b).numpy()
    xi = pt.exponential_coordinates_from_transform(np.linalg.inv(Ta) @ Tb) / (t1 - t0)
    w_b, v_b = xi[:3], xi[3:]  # body twist of Ta exp(s xi): constant
    for jet in (bezier_derivatives(torch.stack((a, b)), t, order=2, domain=(t0, t1)),
                bspline_derivatives(torch.stack((a, b)), t, degree=1,
                                    knots=torch.tensor([t0, t0, t1, t1], dtype=F64))):
        k = kinematics(*jet, frame="body")
        assert max_err(k.angular_velocity, torch.from_numpy(w_b).expand(7, 3)) <= 1e-12
        assert max_err(k.linear_velocity, torch.from_numpy(v_b).expand(7, 3)) <= 1e-12
        assert float(k.angular_acceleration.abs().max()) <= 1e-12
        wxv = torch.from_numpy(np.cross(w_b, v_b)).expand(7, 3)
        assert max_err(k.linear_acceleration, wxv) <= 1e-12


# ----------------------------------------------------------------------------- kinematics, imu

@pytest.mark.parametrize("kind", ["bezier", "bspline"])
def test_kinematics_and_imu_match_matrix_formulas(gen, kind):
    n = 6
    ctrl = near((n,), gen, scale=2.0)
    mats = list(dq.to_matrix(ctrl).numpy())
    t = torch.tensor([0.7, 1.6, 2.9], dtype=F64)
    g = torch.tensor([0.3, -0.2, -9.8], dtype=F64)
    if kind == "bezier":
        jet = bezier_derivatives(ctrl, t, domain=(0.5, 3.0))
        ref_fn = lambda s: casteljau_np(mats, (s - 0.5) / 2.5, sclerp_mat)  # noqa: E731
    else:
        knots = torch.tensor([0.5] * 4 + [1.2, 2.2] + [3.0] * 4, dtype=F64)
        jet = bspline_derivatives(ctrl, t, knots=knots)
        ref_fn = lambda s: deboor_np(mats, knots.tolist(), 3, s, sclerp_mat)  # noqa: E731
    world, body = kinematics(*jet), kinematics(*jet, frame="body")
    gyro, accel = imu(*jet, gravity=g)
    for k, tk in enumerate(t.tolist()):
        w_ref, b_ref, (gyro_ref, accel_ref) = kinematics_mat(ref_fn, tk, 1e-3, g.numpy())
        scale = max(1.0, np.abs(w_ref).max())
        for m in range(4):
            assert abs(world[m][k].numpy() - w_ref[m]).max() <= 1e-6 * scale, (k, m)
            assert abs(body[m][k].numpy() - b_ref[m]).max() <= 1e-6 * scale, (k, m)
        assert abs(gyro[k].numpy() - gyro_ref).max() <= 1e-6 * scale
        assert abs(accel[k].numpy() - accel_ref).max() <= 1e-6 * scale


def test_kinematics_named_fields_and_sign_invariance(gen):
    x, dx, ddx = bspline_derivatives(poses((5,), gen), torch.rand(4, generator=gen, dtype=F64))
    k = kinematics(x, dx, ddx)
    assert isinstance(k, curves.Kinematics) and k._fields == (
        "angular_velocity", "linear_velocity", "angular_acceleration", "linear_acceleration")
    assert all(v.shape == (4, 3) for v in k)
    assert max_err(torch.stack(tuple(kinematics(-x, -dx, -ddx))), torch.stack(tuple(k))) <= 1e-14
    k1 = kinematics(x, dx)
    assert k1.angular_acceleration is None and k1.linear_acceleration is None
    assert torch.equal(k1.linear_velocity, k.linear_velocity)
    # the body velocity is not the spatial twist's linear part, but R^T of the world one
    assert max_err(kinematics(x, dx, frame="body").linear_velocity,
                   curves.twists(x, dx, "body")[..., 3:]) <= 1e-12


def test_imu_at_rest_and_default_gravity():
    q = torch.tensor([math.cos(0.3), 0.0, math.sin(0.3), 0.0], dtype=F64)  # 0.6 rad about y
    x = dq.from_rt(q, torch.tensor([1.0, 2.0, 3.0], dtype=F64))
    z = torch.zeros(8, dtype=F64)
    gyro, accel = imu(x, z, z)
    R = pr.matrix_from_quaternion(q.numpy())
    assert max_err(gyro, torch.zeros(3, dtype=F64)) == 0
    assert max_err(accel, torch.from_numpy(R.T @ np.array([0.0, 0.0, 9.81]))) <= 1e-14
    # free fall reads zero
    _, accel = imu(x, z, z, gravity=torch.tensor([0.0, 0.0, -9.81], dtype=F64))
    fall = torch.cat((torch.zeros(4, dtype=F64), 0.5 * dq.mul(
        torch.cat((torch.tensor([0.0, 0, 0, -9.81], dtype=F64), z[:4])), x)[:4]))
    assert max_err(imu(x, z, fall)[1], torch.zeros(3, dtype=F64)) <= 1e-14
    # a gravity tensor of another floating dtype is a constant like the numbers: x's dtype
    g32 = torch.tensor([0.0, 0.0, -9.81])
    a, b = imu(x, z, z, gravity=g32)[1], imu(x, z, z, gravity=g32.double())[1]
    assert a.dtype == F64 and torch.equal(a, b)


# ----------------------------------------------------------------------------- wide time

def test_unix_seconds_float32_ctrl_float64_times(gen):
    """float32 control points, float64 UNIX timestamps (~1.7e9 s) and knots: the same
    curve and derivatives as in float64, to float32 rounding."""
    n, start = 12, 1.7e9 + 0.123
    ctrl64 = near((n,), gen)
    ctrl32 = ctrl64.float()
    knots = clamped_uniform_knots(n, 3, dtype=F64, domain=(start, start + 4.5))
    t = start + torch.tensor([0.0, 0.01, 1.337, 2.5001, 4.4999, 4.5], dtype=F64)
    ref = bspline_derivatives(ctrl32.double(), t, order=2, knots=knots)
    got = bspline_derivatives(ctrl32, t, order=2, knots=knots)
    assert all(x.dtype == torch.float32 for x in got)
    for k, (x, r) in enumerate(zip(got, ref, strict=True)):
        assert max_err(x.double(), r) <= 4e-6 * max(1.0, float(r.abs().max())), k
    assert max_err(bspline(ctrl32, t, knots=knots).double(), ref[0]) <= 4e-6
    # without wide time the samples would collapse: float32 resolves 128 s at 1.7e9
    assert len(set(t.float().tolist())) == 1
    # Bezier with a float64 domain
    dom = torch.tensor([start, start + 2.0], dtype=F64)
    tb = start + torch.tensor([0.25, 1.0, 1.999], dtype=F64)
    x = bezier(ctrl32[:4], tb, domain=dom)
    assert max_err(x.double(), bezier(ctrl32[:4].double(), tb - start, domain=(0.0, 2.0))) <= 4e-6


def test_narrower_times_are_promoted(gen):
    ctrl = poses((5,), gen)
    t = torch.tensor([0.25, 0.5], dtype=torch.float32)
    x = bspline(ctrl, t, knots=clamped_uniform_knots(5, 3, dtype=torch.float32))
    assert x.dtype == F64
    assert max_err(x, bspline(ctrl, t.double())) <= 1e-15
    assert bezier(ctrl, t).dtype == F64


def test_grad_reaches_float64_times_of_float32_curves(gen):
    ctrl = poses((5,), gen).float().requires_grad_()
    t = torch.tensor([100.25, 100.5], dtype=F64, requires_grad=True)
    knots = clamped_uniform_knots(5, 3, dtype=F64, domain=(100.0, 101.0))
    x, dx = bspline_derivatives(ctrl, t, order=1, knots=knots)
    (x * dx.detach()).sum().backward()  # d/dt sum |x|^2 / 2 along dx: sum |dx|^2 per time
    assert t.grad.dtype == F64 and ctrl.grad.dtype == torch.float32
    assert max_err(t.grad, (dx.double() ** 2).sum(-1)) <= 1e-4 * float(t.grad.abs().max())


# ----------------------------------------------------------------------------- smoothness at knots

def test_smoothness_at_interior_knots(gen):
    """The sclerp De Boor curve is C^1 at simple interior knots, not C^2 (documented): each
    level is a screw interpolation, not an affine combination. Pure translations keep the
    Euclidean C^(p-1). A derivative is continuous when its jump between ``knot - eps`` and
    the knot shrinks like eps (100x from eps = 1e-6 to 1e-8), discontinuous when it stays."""
    n = 8

    def jumps(ctrl, p, eps):
        knots = clamped_uniform_knots(n, p, dtype=F64)
        inner = knots[p + 1:n]
        left = bspline_derivatives(ctrl, inner - eps, order=3, degree=p, knots=knots)
        right = bspline_derivatives(ctrl, inner, order=3, degree=p, knots=knots)
        return np.array([max_err(a, b) for a, b in zip(left, right, strict=True)])

    def continuous(ctrl, p):
        ratio = jumps(ctrl, p, 1e-8) / jumps(ctrl, p, 1e-6)
        assert np.all((ratio < 0.02) | (ratio > 0.5)), ratio  # clearly one or the other
        return (ratio < 0.02).tolist()

    generic = poses((n,), gen)
    for p in (2, 3, 4):
        assert continuous(generic, p) == [True, True, False, False]  # C^1, not C^2
    trans = dq.from_rt(dq.identity((n,), dtype=F64)[:, :4],
                       torch.randn(n, 3, generator=gen, dtype=F64))
    assert continuous(trans, 3) == [True, True, True, False]  # Euclidean cubic: C^2


# ----------------------------------------------------------------------------- autograd

def test_gradcheck_derivatives_wrt_ctrl_and_t(gen):
    ctrl = near((3,), gen).requires_grad_()
    t = torch.tensor([0.3, 0.8], dtype=F64, requires_grad=True)

    def f(c, s):
        return torch.cat(bezier_derivatives(c, s, order=2, domain=(0.0, 1.2), check=False), -1)

    assert torch.autograd.gradcheck(f, (ctrl, t))
    assert torch.autograd.gradgradcheck(f, (ctrl, t), fast_mode=True)
    domain = torch.tensor([-0.1, 1.2], dtype=F64, requires_grad=True)  # a tensor domain
    assert torch.autograd.gradcheck(lambda d: torch.cat(bezier_derivatives(
        ctrl.detach(), t.detach(), order=2, domain=d, check=False), -1), (domain,))
    c4 = near((4,), gen).requires_grad_()
    knots = torch.tensor([0, 0, 0, 0.45, 1, 1, 1], dtype=F64, requires_grad=True)

    def g(c, s, k):
        return torch.cat(bspline_derivatives(c, s, order=3, degree=2, knots=k, check=False), -1)

    assert torch.autograd.gradcheck(g, (c4, t, knots), fast_mode=True)
    assert torch.autograd.gradgradcheck(lambda c, s: g(c, s, knots.detach()), (c4, t),
                                        fast_mode=True)


def test_gradients_finite_at_degenerate_control_points(gen):
    """Equal, antipodal and pure-translation neighbours (the series branch of eq. 11)."""
    x0 = poses((), gen)
    shift = dq.from_rt(torch.tensor([1.0, 0, 0, 0], dtype=F64), torch.tensor([0.5, 0, 0],
                                                                             dtype=F64))
    ctrl = torch.stack((x0, -x0, x0, dq.mul(x0, shift), x0)).requires_grad_()
    t = torch.tensor([0.2, 0.5, 0.9], dtype=F64, requires_grad=True)
    jet = bspline_derivatives(ctrl, t, order=3)
    loss = sum((x * x).sum() for x in jet)
    gc, gt = torch.autograd.grad(loss, (ctrl, t), create_graph=True)
    assert bool(torch.isfinite(gc).all()) and bool(torch.isfinite(gt).all())
    (hc,) = torch.autograd.grad(gt.sum(), ctrl)
    assert bool(torch.isfinite(hc).all())
    assert torch.autograd.gradgradcheck(
        lambda c: bspline_derivatives(c, t.detach(), order=2, check=False)[2], (ctrl,),
        fast_mode=True)


def test_gradcheck_kinematics_and_imu(gen):
    x, dx, ddx = (v.detach().requires_grad_() for v in bspline_derivatives(
        poses((4,), gen), torch.tensor([0.2, 0.7], dtype=F64)))
    g = torch.tensor([0.0, 0.1, -9.8], dtype=F64, requires_grad=True)
    assert torch.autograd.gradgradcheck(lambda a, b, c: torch.cat(tuple(kinematics(
        a, b, c, frame="body")), -1), (x, dx, ddx))
    assert torch.autograd.gradcheck(lambda a, b, c, h: torch.cat(imu(a, b, c, h), -1),
                                    (x, dx, ddx, g))


# ----------------------------------------------------------------------------- broadcasting

SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


@pytest.mark.parametrize("tshape", SHAPES, ids=lambda s: "t" + "x".join(map(str, s)))
@pytest.mark.parametrize("cshape", SHAPES, ids=lambda s: "c" + "x".join(map(str, s)))
def test_derivatives_broadcast_ctrl_against_t(gen, cshape, tshape):
    batch = torch.broadcast_shapes(cshape, tshape)  # every pair of SHAPES broadcasts
    ctrl = poses((*cshape, 4), gen)
    t = torch.rand((*tshape, 3), generator=gen, dtype=F64)
    for fn in (lambda c, s: bezier_derivatives(c, s, order=1),
               lambda c, s: bspline_derivatives(c, s, order=1, degree=2)):
        x, dx = fn(ctrl, t)
        assert x.shape == dx.shape == (*batch, 3, 8)
        ce, te = ctrl.expand(*batch, 4, 8), t.expand(*batch, 3)
        for i in np.ndindex(*batch):
            xi, dxi = fn(ce[i], te[i])
            assert max_err(x[i], xi) <= 1e-14 and max_err(dx[i], dxi) <= 1e-13


@pytest.mark.parametrize("shapes", [((), (5,), (2, 5)), ((3, 1, 5), (5,), ()),
                                    ((1,), (2, 5), (3, 1, 5))], ids=str)
def test_kinematics_and_imu_broadcast(gen, shapes):
    xs = [poses(s, gen) for s in shapes]
    batch = torch.broadcast_shapes(*shapes)
    k = kinematics(*xs, frame="body")
    gyro, accel = imu(*xs, gravity=torch.randn(5, 3, generator=gen, dtype=F64)[0])
    assert all(v.shape == (*batch, 3) for v in (*k, gyro, accel))
    ex = [x.expand(*batch, 8) for x in xs]
    for i in np.ndindex(*batch):
        ki = kinematics(*(x[i] for x in ex), frame="body")
        assert max_err(torch.stack(tuple(k))[(slice(None), *i)], torch.stack(tuple(ki))) <= 1e-15


# ----------------------------------------------------------------------------- bad input

def _bad_cases():
    g = torch.Generator().manual_seed(0)
    c = poses((5,), g)
    t = torch.linspace(0, 1, 4, dtype=F64)
    x = c[:2]
    unix = clamped_uniform_knots(5, 3, dtype=F64, domain=(1.7e9, 1.7e9 + 60))
    return [
        ("order 4", lambda: bspline_derivatives(c, t, order=4), ValueError,
         r"^curves\.bspline_derivatives: order must be an int in 0\.\.3, got 4$"),
        ("order float", lambda: bezier_derivatives(c, t, order=1.0), ValueError,
         r"^curves\.bezier_derivatives: order must be an int"),
        ("order bool", lambda: bezier_derivatives(c, t, order=True), ValueError,
         r"order must be an int"),
        ("domain reversed", lambda: bezier(c, t, domain=(1.0, 0.0)), ValueError,
         r"^curves\.bezier: domain must be two finite times t0 < t1"),
        ("domain nan", lambda: bezier(c, t, domain=(0.0, math.nan)), ValueError,
         r"domain must be two finite times"),
        ("domain three", lambda: bezier(c, t, domain=(0.0, 1.0, 2.0)), ValueError,
         r"^curves\.bezier: expected domain to be \(t0, t1\)"),
        ("domain str", lambda: bezier_derivatives(c, t, domain="0,1"), ValueError,
         r"expected domain to be \(t0, t1\)"),
        ("domain tensor shape", lambda: bezier(c, t, domain=torch.zeros(3, dtype=F64)),
         ValueError, r"^curves\.bezier: expected a \(2,\) tensor for domain"),
        ("domain tensor empty", lambda: bezier(c, t, domain=torch.ones(2, dtype=F64)),
         ValueError, r"^curves\.bezier: domain must be two finite times t0 < t1"),
        ("domain int tensor", lambda: bezier(c, t, domain=torch.tensor([0, 1])), TypeError,
         r"^curves\.bezier: expected a floating-point tensor for domain"),
        ("t outside domain", lambda: bezier(c, t + 5, domain=(0.0, 2.0)), ValueError,
         r"^curves\.bezier: t must lie in the domain \[0, 2\], got values in \[5, 6\]; "
         r"evaluate inside it, cover it by domain=\(t0, t1\), or pass "
         r"extrapolate=True to continue the end spans$"),
        ("t all inf", lambda: bezier(c, t * math.inf + 1), ValueError,
         r"^curves\.bezier: t must lie in the domain \[0, 1\], but t contains NaN/inf only "
         r"\(4 values\)"),
        ("t some inf", lambda: bspline(c, torch.tensor([0.5, math.inf, -1.0], dtype=F64)),
         ValueError, r"got values in \[-1, 0\.5\] and t contains NaN/inf \(1 values\); "
                     r"evaluate inside it, pass knots that cover it"),
        ("t unix outside", lambda: bspline_derivatives(c, 1.7e9 + 61 + t, knots=unix),
         ValueError, r"domain \[1700000000, 1700000060\], got values in \[1700000061, "
                     r"1700000062\]; evaluate inside it, pass knots that cover it, or pass "
                     r"extrapolate=True to continue the end spans$"),
        ("t normalized for unix knots", lambda: bspline(c, t, knots=unix), ValueError,
         r"t must lie in the domain \[1700000000, 1700000060\]"),
        ("knots device", lambda: bspline(c, t, knots=unix.to("meta")), TypeError,
         r"^curves\.bspline: knots is on meta but ctrl is on cpu$"),
        ("check str", lambda: bspline(c, t, check="no"), TypeError,
         r"^curves\.bspline: expected check to be a bool"),
        ("knots domain", lambda: clamped_uniform_knots(5, 3, domain=(1.0, 1.0)), ValueError,
         r"^curves\.clamped_uniform_knots: domain must be two finite times t0 < t1"),
        ("knots domain str", lambda: clamped_uniform_knots(5, 3, domain="ab"), ValueError,
         r"^curves\.clamped_uniform_knots: expected domain to be \(t0, t1\)"),
        ("kinematics frame", lambda: kinematics(x, x, frame="spatial"), ValueError,
         r"^curves\.kinematics: frame must be 'world' or 'body', got 'spatial'$"),
        ("kinematics frame none", lambda: kinematics(x, x, frame=None), ValueError,
         r"^curves\.kinematics: frame must be 'world' or 'body', got None$"),
        ("kinematics dx shape", lambda: kinematics(x, x[..., :6]), ValueError,
         r"^curves\.kinematics: expected a \(\.\.\., 8\) tensor for dx, got shape \(2, 6\)$"),
        ("kinematics ddx batch", lambda: kinematics(x, x, c[:3]), ValueError,
         r"^curves\.kinematics: batch shapes do not broadcast: x \(2,\), dx \(2,\), ddx \(3,\)$"),
        ("kinematics dtype", lambda: kinematics(x, x.float()), TypeError,
         r"^curves\.kinematics: dx has dtype torch\.float32 but x has dtype torch\.float64$"),
        ("kinematics list", lambda: kinematics(x, x.tolist()), TypeError,
         r"^curves\.kinematics: expected a torch\.Tensor for dx, got list$"),
        ("imu ddx missing", lambda: imu(x, x, None), TypeError,
         r"^curves\.imu: expected a torch\.Tensor for ddx, got NoneType$"),
        ("imu gravity 2", lambda: imu(x, x, x, gravity=(0.0, -9.8)), ValueError,
         r"^curves\.imu: expected gravity to be three real numbers or a \(\.\.\., 3\) tensor"),
        ("imu gravity str", lambda: imu(x, x, x, gravity="down"), ValueError,
         r"expected gravity to be three real numbers"),
        ("imu gravity shape", lambda: imu(x, x, x, gravity=torch.zeros(4, dtype=F64)),
         ValueError, r"^curves\.imu: expected a \(\.\.\., 3\) tensor for gravity, got shape"),
        ("imu gravity integer", lambda: imu(x, x, x, gravity=torch.tensor([0, 0, -10])),
         TypeError, r"^curves\.imu: expected a floating-point tensor for gravity, got dtype "
         r"torch\.int64$"),
        ("imu gravity batch", lambda: imu(x, x, x, gravity=torch.zeros(3, 3, dtype=F64)),
         ValueError, r"^curves\.imu: batch shapes do not broadcast"),
    ]


@pytest.mark.parametrize("case", _bad_cases(), ids=lambda c: c[0])
def test_bad_input(case):
    _, call, error, pattern = case
    raises_exactly(call, error, pattern)


# ----------------------------------------------------------------------------- series branch

def _jvp_derivatives(f, t, order):
    """Derivatives 0..order of f at t by nested torch.func.jvp (readable eq. 11 inside)."""
    ones = torch.ones_like(t)
    fs = [f]
    for _ in range(order):
        fs.append(lambda s, g=fs[-1]: torch.func.jvp(g, (s,), (ones,))[1])
    return [g(t) for g in fs]


@pytest.mark.parametrize("half_angle", [0.0, 1e-9, 1e-4, 0.01, 0.019, 0.021, 0.05, 0.3, 1.2])
def test_jets_match_nested_forward_mode_across_the_series_switch(gen, half_angle):
    """Relative rotations on both sides of the switch between the series and the closed
    forms of the jets (y = 1 - cos(half angle) ~ 0.02 at order 3 in float64), with large
    translations: the jets against nested forward mode through the readable eq. 11."""
    n = 5
    axis = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=F64), dim=-1)
    xi = torch.cat((2 * half_angle * axis, 3.0 * torch.randn(n, 3, generator=gen, dtype=F64)), -1)
    ctrl = dq.exp(xi)
    for k in range(1, n):  # a chain: each pose a small screw motion away from the previous
        ctrl[k] = dq.mul(ctrl[k - 1], dq.exp(xi[k]))
    knots = torch.tensor([0, 0, 0, 0, 0.4, 1, 1, 1, 1], dtype=F64)
    t = torch.tensor([0.1, 0.55, 0.9], dtype=F64)
    jet = bspline_derivatives(ctrl, t, order=3, knots=knots)
    ref = _jvp_derivatives(lambda s: bspline(ctrl, s, knots=knots, check=False), t, 3)
    for k in range(4):
        scale = max(1.0, float(ref[k].abs().max()))
        assert max_err(jet[k], ref[k]) <= 1e-9 * scale, (k, max_err(jet[k], ref[k]), scale)


def test_float32_derivatives_accuracy(gen):
    """float32 jets against float64 on the same (rounded) inputs, relative to the largest
    derivative of each order; measured maxima 2e-7 (poses) to 4e-7 (third derivatives)."""
    ctrl = near((20, 6), gen).float()
    t = torch.rand(20, 16, generator=gen, dtype=torch.float32)
    got = bspline_derivatives(ctrl, t, order=3)
    ref = bspline_derivatives(ctrl.double(), t.double(), order=3)
    for k in range(4):
        err = max_err(got[k].double(), ref[k]) / max(1.0, float(ref[k].abs().max()))
        assert err <= 1e-6, (k, err)


@pytest.mark.parametrize("gap", [1e-2, 1e-3, 1e-4])
def test_rounding_of_accelerations_near_a_short_knot_span(gap):
    """Issue 22: the De Boor form's linear acceleration loses accuracy as eps / gap^2 near a
    short knot span (angular as eps / gap); the bound stated in bspline_derivatives holds,
    and the cumulative form does not amplify rounding. float32 control points against the
    float64 evaluation of the same (rounded) control points."""
    g = torch.Generator().manual_seed(1)
    ctrl = dq.exp(torch.randn(9, 6, dtype=F64, generator=g) * 0.5).float()
    size = float(dq.to_rt(ctrl.double())[1].norm(dim=-1).max())
    knots = torch.tensor([0, 0, 0, 0, 1, 2, 2 + gap, 3, 4, 5, 5, 5, 5], dtype=F64)
    t = torch.cat((2 + gap * torch.tensor([0.1, 0.5, 0.9], dtype=F64),
                   torch.tensor([1.5, 2.5], dtype=F64)))
    eps = torch.finfo(torch.float32).eps
    for form in ("de_boor", "cumulative"):
        k32 = kinematics(*bspline_derivatives(ctrl, t, 2, knots=knots, form=form))
        k64 = kinematics(*bspline_derivatives(ctrl.double(), t, 2, knots=knots, form=form))
        lin = (k32.linear_acceleration.double() - k64.linear_acceleration).norm(dim=-1).max()
        ang = (k32.angular_acceleration.double() - k64.angular_acceleration).norm(dim=-1).max()
        if form == "de_boor":
            assert lin <= 10 * eps * size / gap**2 and ang <= 4 * eps / gap
        else:
            scale = float(k64.linear_acceleration.norm(dim=-1).max())
            assert lin <= 100 * eps * scale and ang <= 100 * eps * scale

"""torch_dq.nn: the unit-dual-quaternion parametrization, the Bezier / BSpline layers in the
caller's time (domains, knots, wide float64 timestamps, deprecated 0.1 time API), their
derivatives / kinematics / IMU methods, the least-squares construction from poses, fitting
(fit and plain torch.optim loops), a network predicting control points, state_dict / dtype
moves, and DistributedDataParallel. Fitting on real trajectories: tests/test_fitting.py.

Reference trajectory for the fitting tests: a screw motion about the z-parallel axis through
(0.5, 0, 0) (1.5 rad and 0.6 length units per time unit) composed with a slow rotation about
x (0.4 rad per time unit), over times [0, 2]; translations are of unit scale.
"""

import functools
import math
import os
import sys
import warnings

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline as ScipyBSpline
from strategies import unit_dq
from torch.nn.utils import parametrize

import torch_dq
import torch_dq.dualquat as dq
from torch_dq import curves, quat
from torch_dq.losses import pose_loss, rotation_angle, translation_error
from torch_dq.nn import Bezier, BSpline, FitHistory, UnitDualQuaternion, fit

F32, F64 = torch.float32, torch.float64
DEG = 180.0 / math.pi


# ----------------------------------------------------------------------------- helpers

def truth(s):
    """The reference trajectory at times ``s`` (any shape), float64."""
    s = s.to(F64)
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=F64).expand(*s.shape, 3)
    moment = torch.linalg.cross(torch.tensor([0.5, 0.0, 0.0], dtype=F64),
                                torch.tensor([0.0, 0.0, 1.0], dtype=F64)).expand(*s.shape, 3)
    screw = dq.from_screw(axis, moment, 1.5 * s, 0.6 * s)
    roll = quat.from_rotvec(0.4 * s[..., None] * torch.tensor([1.0, 0.0, 0.0], dtype=F64))
    return dq.mul(screw, dq.from_rt(roll, torch.zeros(*s.shape, 3, dtype=F64)))


def noisy(x, gen, rot_deg=1.0, trans=0.01):
    """Right-multiply by random small motions (per-axis std ``rot_deg`` and ``trans``)."""
    n = x.shape[:-1]
    xi = torch.cat((torch.randn(*n, 3, generator=gen, dtype=F64) * math.radians(rot_deg),
                    torch.randn(*n, 3, generator=gen, dtype=F64) * trans), -1)
    return dq.mul(x, dq.exp(xi))


def errors(x, ref):
    """(max rotation error in degrees, max translation error) between two pose tensors."""
    x, ref = x.detach().to(F64), ref.detach().to(F64)
    return (float(rotation_angle(x, ref).max()) * DEG, float(translation_error(x, ref).max()))


def knots_on(n, degree, t0, t1, dtype=F64):
    """Clamped uniform knots over [t0, t1] (the caller's time)."""
    return t0 + (t1 - t0) * curves.clamped_uniform_knots(n, degree, dtype=dtype)


def held_out(module, gen, count=200):
    """Errors of ``module`` against the truth at random times in [0, 2] (its own time)."""
    s = torch.rand(count, generator=gen, dtype=F64) * 2.0
    with torch.no_grad():
        x = module(s)
    return errors(x, truth(s)), float(pose_loss(x.to(F64), truth(s)))


def is_unit(x):
    return bool(dq.is_unit(x.detach()).all())


# ----------------------------------------------------------------------------- parametrization

def test_parametrization_projects_and_is_idempotent(gen):
    p = UnitDualQuaternion()
    raw = torch.randn(4, 3, 8, generator=gen, dtype=F64)
    x = p(raw)
    assert x.shape == raw.shape and is_unit(x)
    torch.testing.assert_close(p(x), x, rtol=0, atol=1e-15)
    torch.testing.assert_close(p(p.right_inverse(x)), x, rtol=0, atol=1e-15)
    torch.testing.assert_close(p(3.0 * raw), x, rtol=0, atol=1e-15)  # scale-free
    # the translation of the raw tensor is kept (normalize removes only the non-rigid part)
    t_raw = 2 * quat.mul(raw[..., 4:], quat.conj(raw[..., :4]))[..., 1:] / (
        raw[..., :4] ** 2).sum(-1, keepdim=True)
    torch.testing.assert_close(dq.to_rt(x)[1], t_raw, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\).*for X"):
        p(torch.zeros(3, 7))
    with pytest.raises(ValueError, match=r"right_inverse.*for X"):
        p.right_inverse(torch.zeros(3, 4))


def test_parametrization_on_a_linear_weight(gen):
    layer = torch.nn.Linear(8, 5, dtype=F64)  # weight (5, 8): five dual quaternions
    parametrize.register_parametrization(layer, "weight", UnitDualQuaternion())
    assert is_unit(layer.weight) and layer.weight.shape == (5, 8)
    assert layer(torch.randn(2, 8, generator=gen, dtype=F64)).shape == (2, 5)
    new = unit_dq((5,), gen, scale=2.0)
    layer.weight = new  # assignment through right_inverse
    torch.testing.assert_close(layer.weight, new, rtol=0, atol=1e-15)
    layer.weight = -4.0 * new  # non-unit values are projected (sign kept)
    torch.testing.assert_close(layer.weight, -new, rtol=0, atol=1e-15)
    opt = torch.optim.SGD(layer.parameters(), lr=0.5)
    layer(torch.randn(2, 8, generator=gen, dtype=F64)).square().sum().backward()
    opt.step()
    assert is_unit(layer.weight)
    assert not torch.allclose(layer.weight, -new)


def test_parametrization_rejects_non_8_parameters():
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\)"):
        parametrize.register_parametrization(torch.nn.Linear(7, 3), "weight",
                                             UnitDualQuaternion())


# ----------------------------------------------------------------------------- layers

def test_layers_match_the_functional_curves(dtype, device, gen):
    ctrl = unit_dq((3, 6), gen, scale=2.0, dtype=dtype).to(device)
    t = torch.linspace(0, 1, 9, dtype=dtype, device=device)
    spline = BSpline(ctrl, degree=3).to(device)
    bez = Bezier(ctrl[0, :4])
    assert spline.n_ctrl == 6 and bez.n_ctrl == 4
    x = spline(t)
    assert x.shape == (3, 9, 8) and x.dtype == dtype and x.device == device
    torch.testing.assert_close(x, curves.bspline(ctrl, t, degree=3))  # up to the projection
    torch.testing.assert_close(bez(t), curves.bezier(ctrl[0, :4], t))
    assert spline(t[None].expand(2, 1, 9)).shape == (2, 3, 9, 8)  # batched times broadcast
    assert spline.knots.device == device and spline.knots.dtype == F64
    assert spline.domain == (0.0, 1.0) and bez.domain == (0.0, 1.0)


def test_control_points_are_projected_and_assignable(gen):
    raw = torch.randn(5, 8, generator=gen, dtype=F64)
    spline = BSpline(raw, degree=2)
    assert is_unit(spline.control_points)
    torch.testing.assert_close(spline.control_points, dq.normalize(raw))
    new = unit_dq((5,), gen)
    spline.ctrl = new
    torch.testing.assert_close(spline.control_points, new, rtol=0, atol=1e-15)
    spline.control_points = 2.0 * new
    torch.testing.assert_close(spline.control_points, new, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"control_points of shape \(5, 8\)"):
        spline.control_points = unit_dq((6,), gen)


def test_forward_with_predicted_control_points(gen):
    spline = BSpline(dq.identity((6,), dtype=F64), degree=3)
    raw = torch.randn(4, 6, 8, generator=gen, dtype=F64) + dq.identity(dtype=F64)
    t = torch.linspace(0, 1, 7, dtype=F64)
    x = spline(t, ctrl=raw)
    assert x.shape == (4, 7, 8)
    torch.testing.assert_close(x, curves.bspline(dq.normalize(raw), t))
    torch.testing.assert_close(Bezier(raw[0, :3])(t), Bezier(dq.identity((3,), dtype=F64))(
        t, ctrl=raw[0, :3]))
    with pytest.raises(ValueError, match=r"\(\.\.\., 6, 8\) tensor for ctrl"):
        spline(t, ctrl=raw[:, :5])
    with pytest.raises(ValueError, match=r"for ctrl"):
        spline(t, ctrl=raw[..., :7])


def test_extra_repr():
    spline = BSpline(dq.identity((2, 7), dtype=F64), degree=2, knots=knots_on(7, 2, 1.0, 3.5))
    r = repr(spline)
    for part in ("n_ctrl=7", "degree=2", "batch_shape=(2,)", "domain=(1.0, 3.5)",
                 "dtype=torch.float64", "UnitDualQuaternion"):
        assert part in r
    assert "n_ctrl=3" in repr(Bezier(dq.identity((3,)))) and "degree" not in Bezier(
        dq.identity((3,))).extra_repr()


def test_custom_knots_are_the_callers_time():
    """Knots in seconds: module(t) is curves.bspline at the same t and knots; a shift of the
    knots and the times by 1e9 s changes nothing (float64)."""
    knots = torch.tensor([0.0, 0, 0, 1, 2, 4, 4, 4], dtype=F64) + 10.0  # domain [10, 14]
    ctrl = unit_dq((5,), torch.Generator().manual_seed(4), dtype=F64)
    spline = BSpline(ctrl, degree=2, knots=knots)
    assert spline.domain == (10.0, 14.0)
    torch.testing.assert_close(spline.knots, knots, rtol=0, atol=0)
    t = torch.tensor([10.0, 10.5, 11.0, 12.875, 14.0], dtype=F64)  # exact after + 1e9
    torch.testing.assert_close(spline(t), curves.bspline(ctrl, t, degree=2, knots=knots),
                               rtol=0, atol=1e-13)
    far = BSpline(ctrl, degree=2, knots=knots + 1e9)
    torch.testing.assert_close(far(t + 1e9), spline(t), rtol=0, atol=1e-12)
    bez = Bezier(ctrl[:3], domain=(10.0, 14.0))
    torch.testing.assert_close(bez(t), curves.bezier(ctrl[:3], (t - 10.0) / 4.0), rtol=0,
                               atol=1e-13)


def test_times_outside_the_domain_name_it():
    spline = BSpline(dq.identity((5,), dtype=F64), knots=knots_on(5, 3, 1.7e9, 1.7e9 + 30))
    with pytest.raises(ValueError, match=r"domain \[1700000000, 1700000030\].*"
                                         r"got values in \[0, 1\].*extrapolate=True"):
        spline(torch.tensor([0.0, 1.0], dtype=F64))
    with pytest.raises(ValueError, match=r"nn.Bezier.forward: t must lie in the module's time "
                                         r"domain \[2, 3\]"):
        Bezier(dq.identity((3,)), domain=(2.0, 3.0))(torch.tensor([3.5]))
    with pytest.raises(ValueError, match=r"derivatives.*domain"):
        spline.derivatives(torch.tensor([1.7e9 + 31], dtype=F64))
    unchecked = BSpline(dq.identity((5,)), check=False)  # no sync, no check
    assert unchecked(torch.tensor([1.5])).shape == (1, 8)


def test_deprecated_time_api_keeps_working():
    """0.1 code: time_range= maps the domain onto (t0, t1), normalize_time is now the
    identity on the module's time, time_range reads the domain; all warn."""
    with pytest.warns(DeprecationWarning, match="time_range"):
        old = BSpline(dq.identity((5,), dtype=F64), degree=2, time_range=(10.0, 12.0))
    assert old.domain == (10.0, 12.0)
    with pytest.warns(DeprecationWarning, match="normalize_time"):
        u = old.normalize_time(torch.tensor([10.0, 11.0, 12.0], dtype=F64))
    torch.testing.assert_close(u, torch.tensor([10.0, 11.0, 12.0], dtype=F64))
    assert old(u).shape == (3, 8)
    with pytest.warns(DeprecationWarning, match="time_range"):
        torch.testing.assert_close(old.time_range, torch.tensor([10.0, 12.0], dtype=F64))
    with pytest.warns(DeprecationWarning, match="time_range"):
        assert Bezier(dq.identity((3,)), time_range=(1.0, 2.0)).domain == (1.0, 2.0)


@pytest.mark.parametrize("cls", [BSpline, Bezier])
def test_loading_a_0_1_state_dict(cls, gen):
    """A 0.1 checkpoint (knots on [0, 1] and a time_range buffer (3, 7)) loads with a
    DeprecationWarning into a module on [3, 7] that is the old one at the old raw times."""
    raw = unit_dq((5,), gen).float()
    old = {"parametrizations.ctrl.original": raw, "time_range": torch.tensor([3.0, 7.0])}
    if cls is BSpline:
        old["knots"] = curves.clamped_uniform_knots(5, 2)
    module = cls(dq.identity((5,)), **({"degree": 2} if cls is BSpline else {}))
    with pytest.warns(DeprecationWarning, match="0.1 state_dict"):
        module.load_state_dict(old)
    assert module.domain == (3.0, 7.0)
    t = torch.tensor([3.0, 4.5, 7.0])
    u = (t - 3.0) / 4.0
    ref = curves.bspline(raw, u, degree=2) if cls is BSpline else curves.bezier(raw, u)
    torch.testing.assert_close(module(t), ref, rtol=0, atol=2e-6)


def test_float32_module_with_unix_times_matches_float64():
    """from_poses on float64 UNIX seconds (~1.7e9): the float32 module (and after .float() of
    a float64 one) agrees with the float64 module to float32 rounding at those times; in
    0.1 the times collapsed onto a handful of float32 values."""
    s = torch.linspace(0.0, 2.0, 50, dtype=F64)
    times = 1.7e9 + s
    q, t = dq.to_rt(truth(s))
    ref = BSpline.from_poses(q, t, times, n_ctrl=8)
    f32 = BSpline.from_poses(q.float(), t.float(), times, n_ctrl=8)
    assert ref.domain == f32.domain == (float(times[0]), float(times[-1]))
    cast = BSpline.from_poses(q, t, times, n_ctrl=8).float()  # .float() keeps the origin
    assert cast.domain == ref.domain
    tq = 1.7e9 + torch.rand(300, generator=torch.Generator().manual_seed(2), dtype=F64) * 2
    with torch.no_grad():
        x64 = ref(tq)
        for module in (f32, cast):
            x32 = module(tq)
            assert x32.dtype == F32
            rot, trans = errors(x32, x64)
            assert rot < 2e-4 and trans < 2e-6, (rot, trans)  # float32 rounding, unit scale
    # the fit itself: float32 start vs float64 start (the same algorithm in each dtype)
    rot, trans = errors(f32.control_points, ref.control_points)
    assert rot < 1e-3 and trans < 1e-5
    # 0.1's failure: distinct float64 times must give distinct poses
    assert torch.unique(f32(times).detach(), dim=0).shape[0] == 50
    # exact derivatives per second at UNIX times, float32 (measured 1.6e-6, 1.7e-5)
    with torch.no_grad():
        k64, k32 = ref.kinematics(tq), f32.kinematics(tq)
    torch.testing.assert_close(k32.linear_velocity.double(), k64.linear_velocity, rtol=0,
                               atol=1e-5)
    torch.testing.assert_close(k32.linear_acceleration.double(), k64.linear_acceleration,
                               rtol=0, atol=1e-4)


def test_state_dict_and_dtype_moves_keep_the_time_origin(gen):
    times = 1.3e9 + torch.linspace(0.0, 2.0, 30, dtype=F64)
    q, t = dq.to_rt(truth(times - times[0]))
    src = BSpline.from_poses(q.float(), t.float(), times, n_ctrl=6)
    state = src.state_dict()
    assert state["_extra_state"] == {"origin": float(times[0]), "degree": 3, "form": "de_boor"}
    assert state["_knots"].dtype == F32 and float(state["_knots"][-1]) == pytest.approx(2.0)
    dst = BSpline(dq.identity((6,)))
    dst.load_state_dict(state)
    assert dst.domain == src.domain
    assert torch.equal(dst(times), src(times))
    for dtype in (F64, F32, torch.float16, F64):
        src.to(dtype)
        assert src.domain == (float(times[0]), float(times[-1]))
    bez = Bezier(dq.identity((3,), dtype=F64), domain=(1.3e9, 1.3e9 + 2))
    other = Bezier(dq.identity((3,), dtype=F64))
    other.load_state_dict(bez.float().state_dict())
    assert other.domain == (1.3e9, 1.3e9 + 2)
    with pytest.raises(ValueError, match="extra state"):
        other.set_extra_state({"origin": "x"})


# ----------------------------------------------------------------------------- kinematics

def _screw_reference(x0, xi, t, tau):
    """Closed-form positions of x0 exp((t - tau) xi) and their central differences."""
    h = 1e-4

    def pos(s):
        return dq.to_rt(dq.mul(x0, dq.exp((s - tau)[:, None] * xi)))[1]

    p0, pp, pm = pos(t), pos(t + h), pos(t - h)
    R = quat.to_matrix(dq.to_rt(dq.mul(x0, dq.exp((t - tau)[:, None] * xi)))[0])
    return R, (pp - pm) / (2 * h), (pp - 2 * p0 + pm) / h**2


@pytest.mark.parametrize("cls", [Bezier, BSpline])
def test_kinematics_and_imu_of_a_constant_screw_in_seconds(cls):
    """Control points on x0 exp(s xi) over the domain [10, 14] s give the constant screw
    motion: body angular velocity xi[:3] rad/s, world velocity and acceleration of the
    origin from central differences of the closed form; the IMU reads R^T w and R^T (a - g)."""
    xi = torch.tensor([0.3, -0.2, 0.5, 1.0, 0.4, -0.3], dtype=F64)
    x0 = dq.from_rt(quat.normalize(torch.tensor([0.9, 0.1, 0.3, -0.2], dtype=F64)),
                    torch.tensor([3.0, -1.0, 2.0], dtype=F64))
    n = 2 if cls is Bezier else 6
    grev = 10.0 + 4.0 * (torch.arange(n, dtype=F64) / (n - 1) if cls is Bezier else
                         knots_on(n, 3, 0.0, 1.0)[1:n + 3].unfold(0, 3, 1).mean(-1))
    ctrl = dq.mul(x0, dq.exp((grev - 10.0)[:, None] * xi))
    module = (Bezier(ctrl, domain=(10.0, 14.0)) if cls is Bezier else
              BSpline(ctrl, knots=knots_on(n, 3, 10.0, 14.0)))
    t = torch.tensor([10.0, 10.7, 12.0, 13.3, 14.0], dtype=F64)
    R, v_ref, a_ref = _screw_reference(x0, xi, t, 10.0)
    k = module.kinematics(t)
    w_ref = (R @ xi[:3, None])[..., 0]
    torch.testing.assert_close(k.angular_velocity, w_ref, rtol=0, atol=1e-10)
    torch.testing.assert_close(k.linear_velocity, v_ref, rtol=0, atol=1e-7)
    torch.testing.assert_close(k.angular_acceleration, torch.zeros_like(w_ref), rtol=0,
                               atol=1e-10)
    torch.testing.assert_close(k.linear_acceleration, a_ref, rtol=0, atol=1e-6)
    body = module.kinematics(t, frame="body")
    torch.testing.assert_close(body.angular_velocity, xi[:3].expand(5, 3), rtol=0, atol=1e-10)
    gyro, accel = module.imu(t, gravity=(0.0, 0.0, -9.81))
    g = torch.tensor([0.0, 0.0, -9.81], dtype=F64)
    torch.testing.assert_close(gyro, xi[:3].expand(5, 3), rtol=0, atol=1e-10)
    torch.testing.assert_close(accel, (R.mT @ (a_ref - g)[..., None])[..., 0], rtol=0,
                               atol=1e-6)
    x, _ = module.derivatives(t, order=1)
    torch.testing.assert_close(x, module(t), rtol=0, atol=1e-14)


def test_derivative_methods_take_predicted_control_points(gen):
    spline = BSpline(dq.identity((6,), dtype=F64), knots=knots_on(6, 3, 5.0, 7.0))
    raw = torch.randn(3, 6, 8, generator=gen, dtype=F64) * 0.2 + dq.identity(dtype=F64)
    t = torch.tensor([5.0, 5.5, 6.9], dtype=F64)
    ref = curves.bspline_derivatives(dq.normalize(raw), t - 5.0, order=3,
                                     knots=knots_on(6, 3, 0.0, 2.0))
    got = spline.derivatives(t, order=3, ctrl=raw)
    assert len(got) == 4 and got[3].shape == (3, 3, 8)
    for a, b in zip(got, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
    k = spline.kinematics(t, ctrl=raw)
    assert k.linear_acceleration.shape == (3, 3, 3)
    gyro, accel = spline.imu(t, ctrl=raw)
    assert gyro.shape == accel.shape == (3, 3, 3)
    with pytest.raises(ValueError, match=r"order must be an int in 0\.\.3"):
        spline.derivatives(t, order=4)
    with pytest.raises(ValueError, match=r"\(\.\.\., 6, 8\) tensor for ctrl"):
        spline.kinematics(t, ctrl=raw[:, :5])


def test_kinematics_twice_differentiable_in_the_control_points(gen):
    """First derivatives by gradcheck; second: the Hessian-vector product of a scalar of
    the kinematics (double backward) against central differences of its gradient."""
    spline = BSpline(dq.identity((4,), dtype=F64), knots=knots_on(4, 3, 1.0, 2.0))
    raw = torch.randn(4, 8, generator=gen, dtype=F64) * 0.3 + dq.identity(dtype=F64)
    t = torch.tensor([1.2, 1.75], dtype=F64)
    weights = torch.randn(2, 6, generator=gen, dtype=F64)

    def f(c):
        k = spline.kinematics(t, ctrl=c)
        return torch.cat((k.angular_velocity, k.linear_acceleration), -1)

    assert torch.autograd.gradcheck(f, (raw.clone().requires_grad_(),))

    def grad(c, create_graph=False):
        c = c if c.requires_grad else c.clone().requires_grad_()
        return torch.autograd.grad((weights * f(c)).sum(), c, create_graph=create_graph)[0]

    v = torch.randn(4, 8, generator=gen, dtype=F64)
    c = raw.clone().requires_grad_()
    hvp = torch.autograd.grad((grad(c, True) * v).sum(), c)[0]
    h = 1e-5
    fd = (grad(raw + h * v) - grad(raw - h * v)) / (2 * h)
    torch.testing.assert_close(hvp, fd, rtol=1e-6, atol=1e-7)
    assert float(hvp.abs().max()) > 1e-3  # not silently zero


# ----------------------------------------------------------------------------- least-squares init

@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_bspline_basis_matches_scipy(p):
    """BSpline.basis (local Cox-de Boor) against scipy's design matrix, repeated knot."""
    n = 9
    rng = np.random.default_rng(p)
    interior = np.sort(rng.uniform(0.05, 0.95, n - p - 1))
    interior[2] = interior[1]  # a repeated interior knot
    knots = torch.from_numpy(np.concatenate((np.zeros(p + 1), interior, np.ones(p + 1))))
    u = torch.from_numpy(np.concatenate((np.linspace(0, 1, 41), interior)))
    first, values = BSpline(dq.identity((n,), dtype=F64), degree=p, knots=5.0 + knots).basis(
        5.0 + u)
    dense = torch.zeros(len(u), n, dtype=F64)
    dense.scatter_(1, first[:, None] + torch.arange(p + 1), values)
    ref = ScipyBSpline.design_matrix(u.numpy(), knots.numpy(), p).toarray()
    np.testing.assert_allclose(dense.numpy(), ref, atol=1e-13)
    torch.testing.assert_close(values.sum(-1), torch.ones(len(u), dtype=F64))


def test_bernstein_basis():
    u = torch.linspace(0, 1, 11, dtype=F64)
    first, B = Bezier(dq.identity((5,)), domain=(3.0, 5.0)).basis(3.0 + 2.0 * u)
    ref = [[math.comb(4, i) * s**i * (1 - s) ** (4 - i) for i in range(5)] for s in u.tolist()]
    torch.testing.assert_close(B, torch.tensor(ref, dtype=F64))
    assert not first.any()


def test_from_poses_noise_free_is_close(dtype):
    """Least-squares init on 60 noise-free samples, 8 control points: < 0.15 deg and
    < 0.003 length units at held-out times (measured: 0.061 deg, 0.0014)."""
    gen = torch.Generator().manual_seed(3)
    times = torch.linspace(0, 2, 60, dtype=F64)
    x = truth(times)
    q, t = dq.to_rt(x)
    spline = BSpline.from_poses(q.to(dtype), t.to(dtype), times.to(dtype), n_ctrl=8)
    assert spline.control_points.dtype == dtype and is_unit(spline.control_points)
    assert spline.domain == (0.0, 2.0)
    (rot, trans), _ = held_out(spline, gen)
    assert rot < 0.15 and trans < 0.003, (rot, trans)
    # rotation matrices, homogeneous matrices and dual quaternions give the same fit
    R = quat.to_matrix(q).to(dtype)
    for other in (BSpline.from_poses(R, t.to(dtype), times.to(dtype), n_ctrl=8),
                  BSpline.from_matrices(dq.to_matrix(x).to(dtype), times.to(dtype), n_ctrl=8),
                  BSpline.from_dualquats(-x.to(dtype), times.to(dtype), n_ctrl=8)):
        u = torch.linspace(0, 2, 17, dtype=dtype)
        rot2, trans2 = errors(other(u), spline(u))
        assert rot2 < 1e-3 and trans2 < 1e-5
    # a Bezier curve of degree 5 (measured: 0.24 deg, 0.0055)
    bez = Bezier.from_poses(q.to(dtype), t.to(dtype), times.to(dtype), n_ctrl=6)
    (rot, trans), _ = held_out(bez, gen)
    assert rot < 0.5 and trans < 0.01, (rot, trans)


@pytest.mark.parametrize("turns", [0.75, 1.4])
def test_from_poses_constant_screw_is_exact_beyond_a_half_turn(turns, gen):
    """Relative rotations up to 1.4 pi either side of the middle sample: the twists are
    unwrapped, so a constant screw motion is reproduced exactly (random sample signs).
    (At 1.5 turns the 6 exact B-spline control points hold two neighbours exactly a half
    turn apart, where the shortest path of every interpolation is undefined.)"""
    s = torch.linspace(-1.0, 1.0, 41, dtype=F64)
    xi = torch.tensor([0.2, 0.3, 1.0, 0.5, -0.2, 0.4], dtype=F64)
    xi[:3] *= turns * math.pi / xi[:3].norm()
    start = dq.from_rt(quat.normalize(torch.tensor([0.3, 1.0, 0, 0], dtype=F64)),
                       torch.tensor([1.0, 2.0, 3.0], dtype=F64))
    x = dq.mul(start, dq.exp(s[:, None] * xi))
    x = x * torch.where(torch.rand(41, generator=gen) < 0.5, -1.0, 1.0).to(F64)[:, None]
    with warnings.catch_warnings(record=True) as caught:  # 1.4 turns: 2.2 rad per knot span
        warnings.simplefilter("always")
        spline = BSpline.from_dualquats(x, s, n_ctrl=6)
    assert [str(w.message).startswith("nn.BSpline.from_dualquats: the poses turn at up to")
            for w in caught] == ([True] if turns > 1 else [])
    for module in (spline, Bezier.from_dualquats(x, s, n_ctrl=6)):
        rot, trans = errors(module(s), x)
        assert rot < 1e-9 and trans < 1e-9


def test_from_poses_batched(gen):
    times = torch.linspace(0, 2, 30, dtype=F64)
    x = torch.stack((truth(times), noisy(truth(times), gen, 5.0, 0.1)))
    q, t = dq.to_rt(x)
    both = BSpline.from_poses(q, t, times, n_ctrl=7, degree=2)
    assert both.control_points.shape == (2, 7, 8) and both.degree == 2
    for b in range(2):
        one = BSpline.from_poses(q[b], t[b], times, n_ctrl=7, degree=2)
        torch.testing.assert_close(both.control_points[b], one.control_points)


# ----------------------------------------------------------------------------- fitting

@pytest.mark.parametrize("optimizer", ["adam", "lm"])
def test_fit_from_identity_recovers_the_trajectory(optimizer):
    """Adam (at most 250 steps) or Levenberg-Marquardt (5 steps) from all-identity control
    points on 60 noisy samples (noise 1 deg and 0.01 per axis), 8 control points, float32:
    the held-out pose loss drops by >= 100x (measured 3.9 -> 1.9e-4), the training loss by
    >= 1000x (4.09 -> 1.1e-3), and at 200 held-out times the curve is within 3 deg and 0.03
    length units of the noise-free truth (measured max 1.01 deg and 0.011 with either; 171
    deg and 1.55 at the start)."""
    gen = torch.Generator().manual_seed(1)
    times = torch.linspace(0, 2, 60, dtype=F64)
    samples = noisy(truth(times), gen).float()
    spline = BSpline(dq.identity((8,)), degree=3, knots=knots_on(8, 3, 0.0, 2.0))
    (rot0, trans0), loss0 = held_out(spline, torch.Generator().manual_seed(9))
    kwargs = dict(optimizer="adam", lr=3e-2) if optimizer == "adam" else dict(optimizer="lm")
    history = fit(spline, times.float(), samples, steps=250, verbose=False, **kwargs)
    (rot1, trans1), loss1 = held_out(spline, torch.Generator().manual_seed(9))
    assert isinstance(history, FitHistory) and history.steps == len(history.loss) <= 250
    assert history.final_loss <= 1e-3 * history.loss[0]
    assert loss1 <= loss0 / 100.0, (loss0, loss1)
    assert rot0 > 90 and trans0 > 1.0
    assert rot1 < 3.0 and trans1 < 0.03, (rot1, trans1)
    assert is_unit(spline.control_points)


@pytest.mark.parametrize("optimizer", ["adam", "sgd", "lbfgs"])
def test_control_points_unit_after_every_step(optimizer, gen):
    times = torch.linspace(0, 2, 40, dtype=F64)
    target = noisy(truth(times), gen, 3.0, 0.05).float()
    spline = BSpline(unit_dq((6,), gen).float(), degree=3, knots=knots_on(6, 3, 0.0, 2.0))
    u = times.float()
    make = {"adam": lambda p: torch.optim.Adam(p, lr=0.05),
            "sgd": lambda p: torch.optim.SGD(p, lr=0.05, momentum=0.9),
            "lbfgs": lambda p: torch.optim.LBFGS(p, line_search_fn="strong_wolfe")}[optimizer]
    opt = make(spline.parameters())
    losses = []

    def closure():
        opt.zero_grad()
        loss = pose_loss(spline(u), target)
        loss.backward()
        return loss

    for _ in range(5 if optimizer == "lbfgs" else 15):
        losses.append(float(opt.step(closure).detach()))
        assert is_unit(spline.control_points)
    assert losses[-1] < losses[0]
    if optimizer == "adam":  # the raw tensor has left the manifold; the projection has not
        assert not is_unit(spline.parametrizations.ctrl.original)


def test_fit_equals_a_plain_torch_optim_loop(gen):
    times = torch.linspace(0, 2, 30, dtype=F64)
    target = noisy(truth(times), gen, 2.0, 0.02)
    init = BSpline.from_poses(*dq.to_rt(truth(times[::6])), times[::6], n_ctrl=4, degree=2)
    a, b = (BSpline(init.control_points.detach(), degree=2, knots=knots_on(4, 2, 0.0, 2.0))
            for _ in range(2))
    history = fit(a, times, target, optimizer="adam", lr=0.02, steps=20, tol=0.0,
                  verbose=False)
    opt = torch.optim.Adam(b.parameters(), lr=0.02)
    plain = []
    for _ in range(20):
        opt.zero_grad()
        loss = pose_loss(b(times), target)
        loss.backward()
        opt.step()
        plain.append(loss.item())
    np.testing.assert_allclose(history.loss, plain, rtol=1e-12, atol=0)
    assert history.loss[-1] < history.loss[0] and not history.converged
    torch.testing.assert_close(a.control_points, b.control_points, rtol=0, atol=1e-14)


@pytest.mark.parametrize("kind", ["lbfgs", "sgd", "factory", "class", "instance", "matrices"])
def test_fit_optimizer_choices(kind, gen):
    """Each optimizer choice fits data that a curve of the module's family contains (the
    known optimum, loss 0) from a perturbed start: LBFGS reaches it, the 20 first-order
    steps at least halve the distance to it."""
    times = torch.linspace(0, 2, 30, dtype=F64)
    coarse = torch.linspace(0, 2, 4, dtype=F64)
    exact = BSpline.from_dualquats(truth(coarse), coarse, n_ctrl=3, degree=2)
    with torch.no_grad():
        target = exact(times)
    moved = dq.mul(exact.control_points.detach(),
                   dq.exp(0.05 * torch.randn(3, 6, generator=gen, dtype=F64)))
    spline = BSpline(moved, degree=2, knots=exact.knots)

    def distance():
        with torch.no_grad():
            x = spline(times)
            return (float(rotation_angle(x, target).max()),
                    float(translation_error(x, target).max()))

    before = distance()
    kwargs = {"lbfgs": dict(optimizer="lbfgs", steps=5),
              "sgd": dict(optimizer="SGD", lr=0.05, steps=20),
              "factory": dict(optimizer=lambda p: torch.optim.AdamW(p, lr=1e-2), steps=20),
              "class": dict(optimizer=torch.optim.Rprop, steps=20),  # default lr 1e-2
              "instance": dict(optimizer=torch.optim.Adam(spline.parameters(), lr=1e-2),
                               steps=20),
              "matrices": dict(optimizer="adam", steps=20)}[kind]
    poses = dq.to_matrix(target) if kind == "matrices" else target
    history = fit(spline, times, poses, verbose=False, **kwargs)
    # LBFGS may stop before its steps when its own tests hold, and says so (issue 22)
    assert history.steps == len(history.loss) == kwargs["steps"] or (
        kind == "lbfgs" and "LBFGS made no progress" in history.reason)
    assert history.seconds > 0 and is_unit(spline.control_points)
    if kind == "lbfgs":
        assert history.final_loss < 1e-8
    else:
        after = distance()
        assert after[0] <= 0.5 * before[0] and after[1] <= 0.5 * before[1], (before, after)


def test_fit_early_stopping(gen):
    """The stopping test ends the loop (converged, with the reason); LBFGS from an exact
    start makes no progress and says so instead of claiming convergence (issue 22)."""
    times = torch.linspace(0, 2, 30, dtype=F64)
    spline = BSpline.from_dualquats(truth(times), times, n_ctrl=6)
    history = fit(spline, times, truth(times), optimizer="lbfgs", steps=100, tol=1e-3,
                  window=2, verbose=False)
    assert not history.converged and "LBFGS made no progress" in history.reason
    history = fit(spline, times, truth(times), optimizer="adam", steps=100, tol=0.5,
                  window=2, verbose=False)
    assert history.converged and history.steps < 100 and "tol" in history.reason


def test_fit_progress_bar(monkeypatch, capsys, gen):
    times = torch.linspace(0, 1, 10, dtype=F64)
    spline = BSpline(dq.identity((4,), dtype=F64))
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    for optimizer, name in (("adam", "torch_dq.fit"), ("lm", "torch_dq.estimate")):
        fit(spline, times, truth(times), optimizer, steps=3, verbose=True)
        assert name in capsys.readouterr().err  # fit's LM is estimate with one Poses term
    fit(spline, times, truth(times), steps=3, verbose=False)
    assert capsys.readouterr().err == ""
    monkeypatch.setitem(sys.modules, "tqdm", None)  # tqdm not installed: no bar, no error
    monkeypatch.setitem(sys.modules, "tqdm.auto", None)
    history = fit(spline, times, truth(times), "adam", steps=3, verbose=True)
    assert history.steps == 3 and capsys.readouterr().err == ""


# ----------------------------------------------------------------------------- a network

def test_mlp_predicts_bspline_control_points_end_to_end(gen):
    """A small MLP maps a condition (angle rate, pitch) to the 6 control points of a cubic
    B-spline; trained end to end, the loss drops and every weight gets a gradient."""
    torch.manual_seed(0)
    n, B = 6, 8
    spline = BSpline(dq.identity((n,), dtype=F64))
    net = torch.nn.Sequential(torch.nn.Linear(2, 32), torch.nn.Tanh(),
                              torch.nn.Linear(32, n * 8)).double()
    cond = torch.rand(B, 2, generator=gen, dtype=F64) * 2.0 - 1.0
    zeros = torch.zeros(B, 2, dtype=F64)
    xi = torch.cat((zeros, cond[:, :1], cond[:, 1:], zeros), -1)  # screw about z
    t = torch.linspace(0, 1, 25, dtype=F64)
    target = dq.exp(t[:, None] * xi[:, None, :])  # (B, 25, 8)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    losses = []
    for step in range(60):
        opt.zero_grad()
        raw = net(cond).view(B, n, 8) + dq.identity(dtype=F64)
        loss = pose_loss(spline(t, ctrl=raw), target)
        loss.backward()
        if step == 0:
            for name, p in net.named_parameters():
                assert p.grad is not None and torch.isfinite(p.grad).all(), name
                assert float(p.grad.abs().max()) > 0, name
            assert spline.parametrizations.ctrl.original.grad is None
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.1 * losses[0], (losses[0], losses[-1])


# ----------------------------------------------------------------------------- state and dtype

@pytest.mark.parametrize("cls", [BSpline, Bezier])
def test_state_dict_round_trip(cls, gen):
    kw = {"degree": 2} if cls is BSpline else {}
    span = {"knots": knots_on(5, 2, 3.0, 7.0)} if cls is BSpline else {"domain": (3.0, 7.0)}
    src = cls(unit_dq((2, 5), gen, scale=2.0), **span, **kw)
    with torch.no_grad():  # a raw tensor off the manifold, as after training
        src.parametrizations.ctrl.original.mul_(1.7).add_(0.01)
    state = src.state_dict()
    assert set(state) >= {"_extra_state", "parametrizations.ctrl.original"}
    dst = cls(dq.identity((2, 5), dtype=F64), **kw)
    dst.load_state_dict(state)
    t = 3.0 + 4.0 * torch.rand(11, dtype=F64)
    assert torch.equal(dst(t), src(t))
    assert dst.domain == src.domain == (3.0, 7.0)
    if cls is BSpline:
        assert "_knots" in state and torch.equal(dst.knots, src.knots)


def test_to_float64_and_back(gen):
    spline = BSpline.from_poses(*dq.to_rt(truth(torch.linspace(0, 2, 20)).float()),
                                torch.linspace(0, 2, 20), n_ctrl=5)
    t32 = torch.linspace(0, 2, 13)
    x32 = spline(t32)
    spline.to(F64)
    assert spline.control_points.dtype == F64
    assert spline._knots.dtype == F64 and spline.domain == (0.0, 2.0)
    x64 = spline(t32.double())
    assert x64.dtype == F64 and is_unit(x64)
    torch.testing.assert_close(x64.float(), x32, rtol=0, atol=1e-5)
    assert spline.to(F32)(t32).dtype == F32


# ----------------------------------------------------------------------------- bad input

def test_bad_constructor_arguments(gen):
    with pytest.raises(ValueError, match="ctrl with n >= 2"):
        Bezier(dq.identity((1,)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\) tensor for ctrl"):
        BSpline(torch.zeros(5, 7))
    with pytest.raises(TypeError, match="floating"):
        BSpline(torch.zeros(5, 8, dtype=torch.int64))
    with pytest.raises(ValueError, match="degree must be < the number of control points"):
        BSpline(dq.identity((3,)), degree=3)
    with pytest.raises(ValueError, match="degree must be an int >= 1"):
        BSpline(dq.identity((3,)), degree=0)
    with pytest.raises(ValueError, match="knots tensor of n \\+ degree \\+ 1 = 9"):
        BSpline(dq.identity((5,)), knots=torch.linspace(0, 1, 8))
    with pytest.raises(ValueError, match="knots must be non-decreasing"):
        BSpline(dq.identity((5,)), knots=torch.linspace(1, 0, 9))
    with pytest.raises(ValueError, match=r"^nn\.Bezier: domain must be two finite times "
                                         r"t0 < t1, got \(2\.0, 1\.0\)$"):
        Bezier(dq.identity((5,)), domain=(2.0, 1.0))
    with pytest.raises(ValueError, match=r"^nn\.Bezier: expected domain to be \(t0, t1\)"):
        Bezier(dq.identity((5,)), domain=(0.0, 1.0, 2.0))
    with pytest.raises(ValueError, match="domain"), pytest.warns(DeprecationWarning):
        Bezier(dq.identity((5,)), time_range=(0.0, math.inf))
    with pytest.raises(ValueError, match="time_range"), pytest.warns(DeprecationWarning):
        BSpline(dq.identity((5,)), time_range=(2.0, 1.0))
    with pytest.raises(TypeError, match="check must be a bool"):
        BSpline(dq.identity((5,)), check="no")


def test_bad_from_poses_arguments():
    times = torch.linspace(0, 2, 20, dtype=F64)
    q, t = dq.to_rt(truth(times))
    with pytest.raises(ValueError, match="n_ctrl must be an int > degree = 3"):
        BSpline.from_poses(q, t, times, n_ctrl=3)
    with pytest.raises(ValueError, match="n_ctrl must be an int >= 2"):
        Bezier.from_poses(q, t, times, n_ctrl=1)
    with pytest.raises(ValueError, match="degree must be an int >= 1"):
        BSpline.from_poses(q, t, times, degree=0)
    with pytest.raises(ValueError, match="times must be strictly increasing"):
        BSpline.from_poses(q, t, times.flip(0))
    with pytest.raises(ValueError, match="times must be strictly increasing"):
        BSpline.from_poses(q, t, torch.cat((times[:10], times[9:-1])))
    with pytest.raises(ValueError, match=r"times must hold one time per pose: expected shape "
                                         r"\(20,\) for the N = 20 poses, got shape \(19,\)"):
        BSpline.from_poses(q, t, times[:-1])
    with pytest.raises(ValueError, match=r"at least 2 timestamped poses are needed, got N = 1"):
        BSpline.from_dualquats(truth(times[:1]), times[:1], n_ctrl=2, degree=1)
    with pytest.raises(ValueError, match=r"one time per pose: expected shape \(\.\.\., 20\) "
                                         r"for the N = 20 poses, got shape \(20, 1\)"):
        BSpline.from_poses(q, t, times[:, None])  # (B, N) times: a row per trajectory
    with pytest.raises(ValueError, match=r"an \(N,\) or \(\.\.\., N\) tensor for times, got "
                                         r"shape \(\)"):
        BSpline.from_poses(q, t, times[0])
    with pytest.raises(ValueError, match=r"underdetermined: n_ctrl = 21.*N = 20"):
        BSpline.from_poses(q, t, times, n_ctrl=21)
    with pytest.raises(ValueError, match="rotations"):
        BSpline.from_poses(q[:, :3], t, times)
    with pytest.raises(ValueError, match="same number N of poses"):
        BSpline.from_poses(q, t[:-1], times)
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\).*for T"):
        BSpline.from_matrices(torch.zeros(20, 3, 4, dtype=F64), times)
    with pytest.raises(TypeError, match="dtype"):
        BSpline.from_poses(q, t.float(), times)
    with pytest.raises(ValueError, match="poses must be finite"):
        BSpline.from_poses(torch.zeros_like(q), t, times)


def test_bad_fit_arguments():
    times = torch.linspace(0, 2, 10, dtype=F64)
    poses = truth(times)
    spline = BSpline(dq.identity((4,), dtype=F64), knots=knots_on(4, 3, 0.0, 2.0))
    with pytest.raises(ValueError, match="optimizer must be 'auto', 'lm', 'adam', 'sgd'"):
        fit(spline, times, poses, optimizer="rmsprop")
    with pytest.raises(ValueError, match="optimizer must be"):
        fit(spline, times, poses, optimizer=3)
    with pytest.raises(ValueError, match="lr applies to named optimizers only"):
        fit(spline, times, poses, optimizer=torch.optim.Adam, lr=0.1)
    with pytest.raises(ValueError, match="lr must be a real number > 0"):
        fit(spline, times, poses, lr=-1.0)
    with pytest.raises(TypeError, match=r"factory must return a torch\.optim\.Optimizer"):
        fit(spline, times, poses, optimizer=lambda p: None)
    with pytest.raises(ValueError, match="steps must be an int >= 1"):
        fit(spline, times, poses, steps=0)
    with pytest.raises(ValueError, match="tol must be"):
        fit(spline, times, poses, tol=-1.0)
    with pytest.raises(ValueError, match="window must be"):
        fit(spline, times, poses, window=0)
    with pytest.raises(ValueError, match="times must be strictly increasing"):
        fit(spline, times.flip(0), poses)
    with pytest.raises(ValueError, match=r"one time per pose: expected shape \(10,\)"):
        fit(spline, times[:-1], poses)
    with pytest.raises(ValueError, match="for poses"):
        fit(spline, times, poses[:, :7])
    with pytest.raises(TypeError, match="module"):
        fit(lambda t: t, times, poses)
    with pytest.raises(TypeError, match="loss"):
        fit(spline, times, poses, loss="l2")


def test_top_level_exports():
    assert torch_dq.nn.BSpline is BSpline and torch_dq.losses.pose_loss is pose_loss
    assert {"nn", "losses"} <= set(torch_dq.__all__)
    loss = functools.partial(pose_loss, trans_weight=4.0)  # the documented weighting idiom
    x = dq.identity((3,))
    assert float(loss(x, x)) == 0.0


# ----------------------------------------------------------------------------- DDP

def _ddp_model(rank):
    """Rank-dependent initial control points: DDP must broadcast rank 0's."""
    gen = torch.Generator().manual_seed(100 + rank)
    return BSpline(unit_dq((6,), gen), degree=3, knots=knots_on(6, 3, 0.0, 2.0, F32))


def _ddp_data(rank):
    gen = torch.Generator().manual_seed(200 + rank)
    times = torch.linspace(0, 2, 16, dtype=F64)
    return times, noisy(truth(times), gen, 5.0, 0.1)


def _ddp_worker(rank, world, init_file, out_dir):
    import datetime

    import torch.distributed as dist
    from torch.nn.parallel import DistributedDataParallel

    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank,
                            world_size=world, timeout=datetime.timedelta(seconds=60))
    try:
        model = _ddp_model(rank)
        ddp = DistributedDataParallel(model)
        u, target = _ddp_data(rank)
        pose_loss(ddp(u), target).backward()
        grad = model.parametrizations.ctrl.original.grad.clone()
        torch.optim.SGD(ddp.parameters(), lr=0.1).step()
        torch.save({"grad": grad, "ctrl": model.control_points.detach().clone()},
                   os.path.join(out_dir, f"rank{rank}.pt"))
    finally:
        dist.destroy_process_group()


def test_distributed_data_parallel(tmp_path):
    dist = pytest.importorskip("torch.distributed")
    if not dist.is_available() or not dist.is_gloo_available():
        pytest.skip("torch.distributed with the gloo backend is not available")
    import torch.multiprocessing as mp

    world = 2
    mp.spawn(_ddp_worker, args=(world, str(tmp_path / "init"), str(tmp_path)), nprocs=world,
             join=True)
    out = [torch.load(tmp_path / f"rank{r}.pt") for r in range(world)]
    assert torch.equal(out[0]["grad"], out[1]["grad"])  # identical across ranks
    assert torch.equal(out[0]["ctrl"], out[1]["ctrl"]) and is_unit(out[0]["ctrl"])
    # ... and the average of the single-process gradients from rank 0's parameters
    grads = []
    for r in range(world):
        model = _ddp_model(0)
        u, target = _ddp_data(r)
        pose_loss(model(u), target).backward()
        grads.append(model.parametrizations.ctrl.original.grad)
    torch.testing.assert_close(out[0]["grad"], sum(grads) / world, rtol=1e-12, atol=1e-14)

"""torch_dq.fitting.Reprojections against OpenCV, finite differences and a simulated rig.

The motion is closed-form: the body rotation R(t) = R_n Rz(a1 sin w1 t) Ry(a2 sin w2 t)
Rx(a3 sin w3 t) and position p(t) = sums of sines, with the body angular rate written out
by hand (for R = R_n Rz(z) Ry(y) Rx(x): w_body = Rx^T Ry^T z' e_z + Rx^T y' e_y + x' e_x)
and the acceleration differentiated by hand. A camera mounted at e on the body looks at a
planar grid (the world is the target's frame); pixels come from cv2.projectPoints of the
points in camera axes at t' = t + dt + l v (a rolling shutter: v the row, solved by fixed
point), with seeded noise.
"""

import math

import cv2
import numpy as np
import pytest
import torch
from pytransform3d.transformations import transform_from_dual_quaternion
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.camera import Camera
from torch_dq.fitting import Accel, Free, Gyro, Reprojections, estimate
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._problem import Problem
from torch_dq.nn import BSpline

F64 = torch.float64
RADTAN = np.array([460.0, 458.0, 376.0, 240.0, -0.28, 0.07, 2e-4, 2e-5])
E_ROT = Rotation.from_euler("xyz", [0.1, -0.15, 1.4])  # camera axes in body axes
E_T = np.array([0.05, -0.02, 0.01])
R_N = (Rotation.from_euler("z", 0.3) * E_ROT.inv())  # body orientation: camera ~ forward
AMP, W = (0.25, 0.2, 0.15), (1.3, 1.7, 2.1)
G = np.array([0.0, 0.0, -9.81])


def make_camera(model="pinhole-radtan", params=RADTAN):
    return Camera(model, torch.as_tensor(params, dtype=F64), (752, 480))


# ----------------------------------------------------------------------------- the truth

def body(t):
    """numpy: body rotation (scipy), position, body angular rate, world acceleration."""
    t = np.atleast_1d(np.asarray(t, dtype=float))
    ang = [a * np.sin(w * t) for a, w in zip(AMP, W, strict=True)]
    dang = [a * w * np.cos(w * t) for a, w in zip(AMP, W, strict=True)]
    Rz, Ry, Rx = (Rotation.from_euler(ax, v[:, None]) for ax, v in zip("zyx", ang, strict=True))
    R = R_N * Rz * Ry * Rx
    ez, ey, ex = np.eye(3)[2], np.eye(3)[1], np.eye(3)[0]
    w = ((Rx.inv() * Ry.inv()).apply(np.outer(dang[0], ez)) + Rx.inv().apply(
        np.outer(dang[1], ey)) + np.outer(dang[2], ex))
    k = np.array([[0.12, 0.9], [0.1, 1.1], [0.08, 1.4]])  # amplitude, rate per axis
    base = np.array([0.15, 0.12, -0.75])
    p = base + np.stack([a * np.sin(f * t + i) for i, (a, f) in enumerate(k)], -1)
    acc = np.stack([-a * f * f * np.sin(f * t + i) for i, (a, f) in enumerate(k)], -1)
    return R, p, w, acc


def body_dq(t):
    R, p = body(t)[:2]
    return dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p))


def extrinsic_dq(rot=E_ROT, trans=E_T):
    return dq.from_rt(torch.from_numpy(rot.as_quat(scalar_first=True)), torch.as_tensor(
        trans, dtype=F64))


def grid_points(rows=5, cols=6, pitch=0.06):
    y, x = np.meshgrid(np.arange(rows) * pitch, np.arange(cols) * pitch, indexing="ij")
    return np.stack((x.ravel(), y.ravel(), np.zeros(rows * cols)), -1)


def project_cv(T_wc, points, params):
    """OpenCV pixels of world points for the camera posed at ``T_wc`` (4x4), and z."""
    T_cw = np.linalg.inv(T_wc)
    cam = points @ T_cw[:3, :3].T + T_cw[:3, 3]
    K = np.array([[params[0], 0, params[2]], [0, params[1], params[3]], [0, 0, 1.0]])
    dist = np.array([*params[4:8], 0.0]) if len(params) > 4 else np.zeros(5)
    rvec = cv2.Rodrigues(T_cw[:3, :3])[0]
    pix = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, T_cw[:3, 3], K, dist)[0]
    return pix.reshape(-1, 2), cam[:, 2]


def camera_pose(R, p, e_rot, e_t):
    T_wb = np.eye(4)
    T_wb[:3, :3], T_wb[:3, 3] = R.as_matrix(), p
    T_be = np.eye(4)
    T_be[:3, :3], T_be[:3, 3] = e_rot.as_matrix(), e_t
    return T_wb @ T_be


def project_np(R, p, points, params):
    """numpy radtan (OpenCV's plumb bob, k3 = 0) of world points for body poses ``(R, p)``
    (one per point), the camera at ``E`` on the body; returns pixels and depths."""
    R_c = R * E_ROT
    p_c = p + R.apply(E_T)
    x, y, z = R_c.inv().apply(points - p_c).T
    a, b = x / z, y / z
    r2 = a * a + b * b
    fu, fv, cu, cv, k1, k2, p1, p2 = params
    radial = 1 + k1 * r2 + k2 * r2 * r2
    ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    return np.stack((fu * ad + cu, fv * bd + cv), -1), z


def project_moving_cv(R, p, points, params):
    """cv2.projectPoints pixels of world points for body poses ``(R, p)`` (one per point),
    the camera at ``E`` on the body: the points moved into the camera by scipy/numpy."""
    cam = (R * E_ROT).inv().apply(points - p - R.apply(E_T))
    K = np.array([[params[0], 0, params[2]], [0, params[1], params[3]], [0, 0, 1.0]])
    pix = cv2.projectPoints(cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K,
                            np.array([*params[4:8], 0.0]))[0]
    return pix.reshape(-1, 2)


def simulate(frames, points, *, dt, line_delay, params=RADTAN, noise=0.0, seed=0):
    """Observations (times, points, pixels) of the grid at the frame times, OpenCV's pixels
    with the rolling shutter solved by fixed point (v = row of the point at t + dt + l v)."""
    rng = np.random.default_rng(seed)
    tf = np.repeat(np.asarray(frames, dtype=float), len(points))
    pts = np.tile(points, (len(frames), 1))
    v = np.full(len(tf), params[3])
    for _ in range(8):
        R, p = body(tf + dt + line_delay * v)[:2]
        pix = project_moving_cv(R, p, pts, params)
        v = pix[:, 1]
    pix = pix + noise * rng.standard_normal(pix.shape)
    return torch.from_numpy(tf), torch.from_numpy(pts), torch.from_numpy(pix)


def spline_of(t0, t1, spacing=0.1):
    t = torch.linspace(t0, t1, round((t1 - t0) * 100) + 1, dtype=F64)
    n = math.ceil((t1 - t0) / spacing) + 3
    return BSpline.from_dualquats(body_dq(t), t, n_ctrl=n, form="cumulative")


# ----------------------------------------------------------------------------- reference

def reference(traj, term, ctrl=None, *, e, target, params, dt, line_delay):
    """numpy/OpenCV residuals ``(N, 2)`` of ``term``'s data at the trajectory's poses."""
    t = term.times + dt + line_delay * term.pixels[..., 1]
    with torch.no_grad():
        x = traj(t, ctrl=ctrl).numpy()
    T_e = transform_from_dual_quaternion(e.numpy())
    T_t = transform_from_dual_quaternion(target.numpy())
    out = []
    for i in range(x.shape[0]):
        T_wc = np.linalg.inv(T_t) @ transform_from_dual_quaternion(x[i]) @ T_e
        out.append(project_cv(T_wc, term.points[i:i + 1].numpy(), params.numpy())[0][0])
    r = (np.stack(out) - term.pixels.numpy()) / term.sigma.numpy()
    return torch.from_numpy(r)


@pytest.fixture(scope="module")
def small():
    """A few observations of two frames, with every nuisance parameter present."""
    pts = grid_points(2, 3)
    times, points, pixels = simulate([0.5, 0.55], pts, dt=0.01, line_delay=3e-5, noise=0.5)
    traj = spline_of(0.0, 1.0)
    e = extrinsic_dq(E_ROT * Rotation.from_rotvec([0.02, -0.03, 0.05]), E_T + 0.02)
    target = dq.exp(torch.tensor([0.01, -0.02, 0.03, 0.01, 0.02, -0.01], dtype=F64))
    params = torch.from_numpy(RADTAN * 1.01)
    return traj, times, points, pixels, e, target, params


def test_residuals_match_opencv(small):
    traj, times, points, pixels, e, target, params = small
    term = Reprojections(times, points, pixels, camera=make_camera(params=params.numpy()),
                         sigma=(0.5, 0.4), extrinsic=e, target=target, time_offset=0.012,
                         line_delay=4e-5)
    ref = reference(traj, term, e=e, target=target, params=params, dt=0.012, line_delay=4e-5)
    R, p = body(times.numpy())[:2]  # the simulator's formula is OpenCV's
    T_wc = camera_pose(R[0], p[0], E_ROT, E_T)
    np.testing.assert_allclose(project_np(R[:1], p[:1], points[:1].numpy(), RADTAN)[0],
                               project_cv(T_wc, points[:1].numpy(), RADTAN)[0], atol=1e-9)
    r = term(traj)
    assert r.shape == (12, 2)
    torch.testing.assert_close(r, ref, atol=1e-8, rtol=0)
    # the robust cost is rho of the norms
    assert float(term.cost(traj).detach()) == pytest.approx(float((ref ** 2).sum()), rel=1e-10)


def _jacobians(traj, term):
    """The solver's Jacobians (exact, through the spans) at the terms' values."""
    ctrl = traj.control_points.detach()
    problem = Problem(traj, [term], ctrl.shape[:-2])
    values = _starts("test", problem, ctrl)
    w = problem.width(values)
    r, f0, Jc, Jn = problem.linearization._chained(0, problem.terms[0], ctrl, values, w)
    return ctrl, values, r, f0, Jc, Jn


def test_jacobians_match_finite_differences(small):
    """Every parameter's Jacobian against central differences of the OpenCV residual."""
    traj, times, points, pixels, e, target, params = small
    dt0, l0 = 0.012, 4e-5
    term = Reprojections(times, points, pixels, camera=make_camera(params=params.numpy()),
                         sigma=0.5, extrinsic=Free(e), target=Free(target),
                         intrinsics=True, time_offset=Free(dt0), line_delay=Free(l0),
                         max_line_delay=1e-3)
    ctrl, _, r, f0, Jc, Jn = _jacobians(traj, term)
    base = dict(e=e, target=target, params=params, dt=dt0, line_delay=l0)
    torch.testing.assert_close(r, reference(traj, term, **base), atol=1e-8, rtol=1e-9)
    h = 1e-6

    def fd(**moved):
        lo = reference(traj, term, **{**base, **{k: v(-h) for k, v in moved.items()}})
        hi = reference(traj, term, **{**base, **{k: v(h) for k, v in moved.items()}})
        return (hi - lo) / (2 * h)

    def unit(n, j):
        return torch.eye(n, dtype=F64)[j]

    for j in range(6):
        torch.testing.assert_close(Jn["extrinsic"][..., j], fd(
            e=lambda s, j=j: dq.mul(e, dq.exp(s * unit(6, j)))), atol=1e-5, rtol=1e-6)
        torch.testing.assert_close(Jn["target"][..., j], fd(
            target=lambda s, j=j: dq.mul(target, dq.exp(s * unit(6, j)))), atol=1e-5, rtol=1e-6)
    for j in range(8):
        torch.testing.assert_close(Jn["intrinsics"][..., j], fd(
            params=lambda s, j=j: params + s * unit(8, j)), atol=1e-5, rtol=1e-6)
    torch.testing.assert_close(Jn["time_offset"][..., 0], fd(dt=lambda s: dt0 + s),
                               atol=1e-4, rtol=1e-6)
    torch.testing.assert_close(Jn["line_delay"][..., 0], fd(line_delay=lambda s: l0 + s),
                               atol=1e-2, rtol=1e-6)
    assert float(Jn["line_delay"].abs().max()) > 1e3  # pixels per (s per row): it moves
    n, w = ctrl.shape[-2], Jc.shape[-2]
    for a in range(w):  # each window control point, each step axis
        for j in range(6):
            got = Jc[..., a, j]
            for k in torch.unique(f0 + a).tolist():
                if k >= n:
                    continue
                rows = (f0 + a) == k

                def step(s, k=k, j=j):
                    c = ctrl.clone()
                    c[k] = dq.mul(ctrl[k], dq.exp(s * unit(6, j)))
                    return c

                lo = reference(traj, term, step(-h), **base)
                hi = reference(traj, term, step(h), **base)
                torch.testing.assert_close(got[rows], ((hi - lo) / (2 * h))[rows], atol=1e-5,
                                           rtol=1e-6)


def test_shared_frame_times_take_the_distinct_time_path_exactly(small, monkeypatch):
    """Corners of one frame share its time (a global shutter): the solver evaluates the
    spans once per distinct time; its Jacobians equal the per-sample path's and central
    differences of the OpenCV residual (control points and the time offset)."""
    import torch_dq.fitting._linearize as problem_module

    traj, _, _, _, e, _, params = small
    dt0 = 0.012
    times, points, pixels = simulate([0.5, 0.55], grid_points(), dt=dt0, line_delay=0.0,
                                     noise=0.5)  # 30 corners per frame
    term = Reprojections(times, points, pixels, camera=make_camera(params=params.numpy()),
                         sigma=0.5, extrinsic=Free(e), intrinsics=True, time_offset=Free(dt0))
    calls = []
    distinct = problem_module._distinct_times

    def spy(*args):
        out = distinct(*args)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(problem_module, "_distinct_times", spy)
    ctrl, values, r, f0, Jc, Jn = _jacobians(traj, term)
    assert calls and all(calls)  # both the evaluation and the chain took it
    problem = Problem(traj, [term], ctrl.shape[:-2])
    cost_rows = problem_module.residuals(problem, 0, ctrl, values)  # the trial costs' path
    assert calls[-1]
    torch.testing.assert_close(cost_rows, r, atol=1e-13, rtol=0)
    monkeypatch.setattr(problem_module, "_distinct_times", lambda *args: None)
    _, _, r2, f02, Jc2, Jn2 = _jacobians(traj, term)
    # the span tables sum the samples' rows in another order: equal to rounding
    torch.testing.assert_close(r, r2, atol=1e-12, rtol=1e-13)
    torch.testing.assert_close(Jc, Jc2, atol=1e-9, rtol=1e-12)
    for name in Jn2:
        torch.testing.assert_close(Jn[name], Jn2[name], atol=1e-9, rtol=1e-12)
    identity = dq.exp(torch.zeros(6, dtype=F64))  # no target pose: the world frame
    h, base = 1e-6, dict(e=e, target=identity, params=params, dt=dt0, line_delay=0.0)
    fd = (reference(traj, term, **{**base, "dt": dt0 + h})
          - reference(traj, term, **{**base, "dt": dt0 - h})) / (2 * h)
    torch.testing.assert_close(Jn["time_offset"][..., 0], fd, atol=1e-4, rtol=1e-6)
    k, j = int(f0[0]) + 1, 2
    rows = (f0 + 1) == k

    def step(s):
        c = ctrl.clone()
        c[k] = dq.mul(ctrl[k], dq.exp(s * torch.eye(6, dtype=F64)[j]))
        return c

    fd = (reference(traj, term, step(h), **base) - reference(traj, term, step(-h), **base))
    torch.testing.assert_close(Jc[..., 1, j][rows], (fd / (2 * h))[rows], atol=1e-5,
                               rtol=1e-6)


# ----------------------------------------------------------------------------- recovery

def imu(times, seed):
    rng = np.random.default_rng(seed)
    R, _, w, acc = body(times)
    gyro = w + 0.005 * rng.standard_normal(w.shape)
    accel = R.inv().apply(acc - G) + 0.05 * rng.standard_normal(acc.shape)
    return torch.from_numpy(gyro), torch.from_numpy(accel)


def within(value, ref, std, k=4.0):
    value, ref, std = (np.asarray(torch.as_tensor(v, dtype=F64)) for v in (value, ref, std))
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    assert np.all(np.abs(value - ref) <= k * std), (value, ref, std, (value - ref) / std)


@pytest.fixture(scope="module")
def rig():
    """A rolling-shutter radtan camera at 20 Hz seeing a 5 x 6 grid for 3 s, an IMU at
    200 Hz; the camera's clock 12 ms behind, 30 us per row."""
    frames = np.arange(0.3, 2.8, 0.05)
    times, points, pixels = simulate(frames, grid_points(), dt=0.012, line_delay=3e-5,
                                     noise=0.3, seed=1)
    ti = torch.linspace(0.0, 3.1, 621, dtype=F64)
    gyro, accel = imu(ti.numpy(), 2)
    return times, points, pixels, ti, gyro, accel


def test_estimate_recovers_extrinsic_clock_line_delay_and_intrinsics(rig):
    times, points, pixels, ti, gyro, accel = rig
    e_true = extrinsic_dq()
    e0 = extrinsic_dq(E_ROT * Rotation.from_rotvec(np.radians(5.0) * np.array([0.6, 0.0, 0.8])),
                      E_T + np.array([0.03, -0.03, 0.0265]))  # 5 deg, 5 cm away
    start = RADTAN + np.array([4.0, -4.0, 3.0, -3.0, 0.03, -0.02, 0.0, 0.0])
    cam = Reprojections(times, points, pixels, camera=make_camera(params=start), sigma=0.3,
                        extrinsic=Free(e0), intrinsics=True, time_offset=True,
                        line_delay=True)
    terms = [cam, Gyro(ti, gyro, sigma=0.005), Accel(ti, accel, sigma=0.05,
                                                     gravity=torch.from_numpy(G))]
    traj = spline_of(0.0, 3.1)
    est = estimate(traj, terms, steps=30, verbose=False)
    assert bool(est.converged), est.reason
    d = dq.log(dq.mul(dq.conj(e_true), cam.extrinsic))  # truth^-1 estimate, chart e exp(d)
    within(d, torch.zeros(6), est.std(cam, "extrinsic"))
    within(cam.time_offset, 0.012, est.std(cam, "time_offset"))
    within(cam.line_delay, 3e-5, est.std(cam, "line_delay"))
    within(cam.intrinsics, torch.from_numpy(RADTAN), est.std(cam, "intrinsics"))
    assert est.std(cam, "intrinsics").shape == (8,) and est.std(cam, "line_delay").shape == ()
    chi2 = float(est.chi2[cam]) / float(est.dof[cam])
    assert 0.8 < chi2 < 1.2


def test_standard_deviations_match_a_monte_carlo_scatter():
    """30 draws of the pixel (0.3 px) and IMU noise on one rig (20 Hz rolling-shutter radtan
    camera, 5 x 6 grid, 2.1 s; IMU at 200 Hz), solved together as a batch: every draw's
    extrinsic, time offset, line delay and intrinsics within 4 standard deviations of the
    truth (started there: the recovery test above starts far), and each parameter's reported
    standard deviation (mean over the draws) over the draws' scatter in [0.6, 1.5]
    (measured 0.89 to 1.20; the sample standard deviation of 30 draws is itself uncertain
    by 13 %; 100 draws of the same rig, run once: 0.87 to 1.10, every |error| / std < 3.9)."""
    draws, t1 = 30, 2.1
    frames = np.arange(0.3, t1 - 0.25, 0.05)
    obs = [simulate(frames, grid_points(), dt=0.012, line_delay=3e-5, noise=0.3, seed=100 + s)
           for s in range(draws)]
    ti = torch.linspace(0.0, t1, round(t1 * 200) + 1, dtype=F64)
    times, points, pixels, gyro, accel = (torch.stack(x) for x in zip(
        *[o + imu(ti.numpy(), 200 + s) for s, o in enumerate(obs)], strict=True))
    spline = spline_of(0.0, t1)
    traj = BSpline(torch.stack([spline.control_points.detach()] * draws), knots=spline.knots,
                   form="cumulative")
    e_true = extrinsic_dq()
    cam = Reprojections(times, points, pixels, camera=make_camera(), sigma=0.3,
                        extrinsic=Free(e_true), intrinsics=True, time_offset=Free(0.012),
                        line_delay=Free(3e-5))
    ti = ti.expand(draws, -1)
    est = estimate(traj, [cam, Gyro(ti, gyro, sigma=0.005), Accel(
        ti, accel, sigma=0.05, gravity=torch.from_numpy(G))], steps=20, verbose=False)
    assert bool(est.converged.all()), est.reason
    errors = {"extrinsic": dq.log(dq.mul(dq.conj(e_true), cam.extrinsic)),
              "time_offset": cam.time_offset - 0.012, "line_delay": cam.line_delay - 3e-5,
              "intrinsics": cam.intrinsics - torch.from_numpy(RADTAN)}
    for name, err in errors.items():
        err, std = err.reshape(draws, -1).numpy(), est.std(cam, name).reshape(draws, -1).numpy()
        within(err, np.zeros_like(err), std)
        ratio = std.mean(0) / err.std(0, ddof=1)
        assert np.all((ratio > 0.6) & (ratio < 1.5)), (name, ratio)
    chi2 = est.chi2[cam] / est.dof[cam]
    assert bool(((chi2 > 0.9) & (chi2 < 1.1)).all()), chi2


# ----------------------------------------------------------------------------- invalid points

def test_points_behind_the_camera_are_excluded_and_counted():
    """Observations of points behind the camera: zero residual rows, finite gradients, and
    estimate counts them at the solution with a warning; the rest of the fit is unharmed."""
    frames = np.arange(0.3, 1.3, 0.05)
    times, points, pixels = simulate(frames, grid_points(), dt=0.0, line_delay=0.0,
                                     noise=0.3, seed=3)
    behind = torch.zeros(len(times), dtype=torch.bool)
    behind[::97] = True  # these points moved 3 m behind the target (the camera looks at +z)
    points = torch.where(behind[:, None], points + torch.tensor([0.0, 0.0, -3.0],
                                                                dtype=F64), points)
    traj = spline_of(0.3, 1.25)
    term = Reprojections(times, points, pixels, camera=make_camera(), sigma=0.3,
                         extrinsic=extrinsic_dq())
    r = term(traj)
    assert torch.isfinite(r).all() and bool((r[behind] == 0).all())
    assert bool((r[~behind].abs() > 0).all())
    ctrl = traj.control_points.detach().clone().requires_grad_()
    (g,) = torch.autograd.grad(term.cost(traj, ctrl), ctrl)
    assert torch.isfinite(g).all() and bool((g != 0).any())
    with pytest.warns(RuntimeWarning, match=r"7 observation\(s\) of Reprojections"):
        est = estimate(traj, [term], steps=10, verbose=False)
    assert int(term.invalid) == int(behind.sum()) == 7
    assert torch.isfinite(est.final_loss) and torch.isfinite(traj.control_points).all()
    assert float(est.chi2[term]) / (2 * int((~behind).sum())) < 1.3


# ----------------------------------------------------------------------------- arguments

def _obs():
    times, points, pixels = simulate([0.5, 0.55], grid_points(2, 3), dt=0.0, line_delay=0.0)
    return times, points, pixels


@pytest.mark.parametrize("kwargs, kind, match", [
    (dict(camera="pinhole"), TypeError, "camera"),
    (dict(sigma=None), ValueError, "sigma"),
    (dict(sigma=-1.0), ValueError, "sigma"),
    (dict(sigma=(1.0, 2.0, 3.0)), ValueError, "sigma"),
    (dict(line_delay=-1e-5), ValueError, "line_delay"),
    (dict(max_line_delay=0.0), ValueError, "max_line_delay"),
    (dict(intrinsics=torch.zeros(5, dtype=F64)), ValueError, "intrinsics"),
    (dict(extrinsic=torch.zeros(7, dtype=F64)), ValueError, "extrinsic"),
    (dict(target="yes"), ValueError, "target"),
    (dict(robust="tukey"), ValueError, "robust"),
    (dict(pixels=torch.zeros(12, 3, dtype=F64)), ValueError, "pixels"),
    (dict(points=torch.zeros(11, 3, dtype=F64)), ValueError, "points"),
    (dict(times=torch.zeros(11, dtype=F64)), ValueError, "times"),
    (dict(mask=torch.ones(12)), TypeError, "mask"),
])
def test_bad_arguments_raise_naming_them(kwargs, kind, match):
    times, points, pixels = _obs()
    args = dict(times=times, points=points, pixels=pixels, camera=make_camera(), sigma=0.3)
    args.update(kwargs)
    with pytest.raises(kind, match=match):
        Reprojections(args.pop("times"), args.pop("points"), args.pop("pixels"), **args)


def test_line_delay_started_outside_its_range_raises():
    times, points, pixels = _obs()
    term = Reprojections(times, points, pixels, camera=make_camera(), sigma=0.3,
                         line_delay=Free(2e-4), extrinsic=extrinsic_dq())
    with pytest.raises(ValueError, match="line_delay starts outside"):
        estimate(spline_of(0.0, 1.0), [term], verbose=False)


# ----------------------------------------------------------------------------- structure

def _imu_terms():
    ti = torch.linspace(0.0, 1.0, 201, dtype=F64)
    gyro, accel = imu(ti.numpy(), 0)
    return [Gyro(ti, gyro, sigma=0.005), Accel(ti, accel, sigma=0.05,
                                                 gravity=torch.from_numpy(G))]


@pytest.mark.parametrize("kwargs, imu, match", [
    (dict(extrinsic=True, target=True), False, "extrinsic and target are both estimated"),
    (dict(extrinsic=True, target=True), True, "extrinsic and target are both estimated"),
    (dict(extrinsic=True), False, "extrinsic is undetermined"),
    (dict(target=True), True, "target is undetermined"),
    (dict(intrinsics=True, extrinsic=extrinsic_dq()), False, "one view"),
    (dict(line_delay=True, extrinsic=extrinsic_dq()), False, "line_delay is undetermined"),
])
def test_undetermined_camera_parameters_raise(kwargs, imu, match):
    times, points, pixels = _obs()
    if "intrinsics" in kwargs:  # one frame
        times, points, pixels = times[:6], points[:6], pixels[:6]
    if "line_delay" in kwargs:  # every observation on one row
        pixels = pixels.clone()
        pixels[:, 1] = 240.0
    term = Reprojections(times, points, pixels, camera=make_camera(), sigma=0.3, **kwargs)
    with pytest.raises(ValueError, match=match):
        estimate(spline_of(0.0, 1.0), [term] + (_imu_terms() if imu else []), verbose=False)


def test_domain_check_widens_by_the_line_delay():
    """t + max_line_delay * v must stay inside the trajectory's domain."""
    times, points, pixels = simulate([0.9, 0.95], grid_points(2, 3), dt=0.0, line_delay=0.0)
    term = Reprojections(times, points, pixels, camera=make_camera(), sigma=0.3,
                         extrinsic=extrinsic_dq(), line_delay=True, max_line_delay=1e-3)
    lo, hi = term.time_reach()
    torch.testing.assert_close(hi, 1e-3 * pixels[:, 1])
    torch.testing.assert_close(lo, torch.zeros_like(lo))
    with pytest.raises(ValueError, match="line_delay"):
        estimate(spline_of(0.0, 1.0), [term], verbose=False)


# ----------------------------------------------------------------------------- batches

@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_batches_with_their_own_times_are_independent_problems():
    """Two camera-only problems with their own frame times, intrinsics estimated: the batch
    gives each element's own estimate."""
    obs = [simulate(np.arange(a, a + 0.8, 0.05), grid_points(), dt=0.0, line_delay=0.0,
                    noise=0.3, seed=s) for a, s in ((0.3, 5), (0.35, 6))]
    start = RADTAN + np.array([3.0, -3.0, 2.0, -2.0, 0.02, 0.0, 0.0, 0.0])
    alone = []
    for times, points, pixels in obs:
        term = Reprojections(times, points, pixels, camera=make_camera(params=start),
                             sigma=0.3, extrinsic=extrinsic_dq(), intrinsics=True)
        estimate(spline_of(0.3, 1.15), [term], steps=20, verbose=False)
        alone.append(term.intrinsics)
    times, points, pixels = (torch.stack(x) for x in zip(*obs, strict=True))
    traj = BSpline(torch.stack([spline_of(0.3, 1.15).control_points.detach()] * 2),
                   knots=spline_of(0.3, 1.15).knots, form="cumulative")
    term = Reprojections(times, points, pixels, camera=make_camera(params=start), sigma=0.3,
                         extrinsic=extrinsic_dq(), intrinsics=True)
    assert term(traj).shape == (2, len(obs[0][0]), 2)
    estimate(traj, [term], steps=20, verbose=False)
    assert term.intrinsics.shape == (2, 8)
    torch.testing.assert_close(term.intrinsics, torch.stack(alone), atol=1e-6, rtol=1e-8)


def test_line_delay_without_motion_warns():
    """A body at rest: the line delay moves no pixel (the warning says so)."""
    still = BSpline(torch.stack([body_dq(np.array([0.5]))[0]] * 12), knots=None,
                    form="cumulative")
    frames = torch.linspace(0.2, 0.8, 7, dtype=F64)
    pts = torch.from_numpy(np.tile(grid_points(), (7, 1)))
    R, p = body(np.full(len(pts), 0.5))[:2]
    pix = torch.from_numpy(project_np(R, p, pts.numpy(), RADTAN)[0])
    term = Reprojections(frames.repeat_interleave(30), pts, pix, camera=make_camera(),
                         sigma=0.3, extrinsic=extrinsic_dq(), line_delay=True)
    with pytest.warns(RuntimeWarning, match="line_delay is undetermined"):
        estimate(still, [term], steps=20, verbose=False)


# ----------------------------------------------------------------------------- options

def test_masked_observations_and_robust_kernel(small):
    """Masked observations (NaN data allowed) give zero rows; a Huber kernel's default scale
    is the chi quantile of 2 dimensions and down-weights an outlier."""
    traj, times, points, pixels, e, target, params = small
    pixels, points = pixels.clone(), points.clone()
    mask = torch.ones(len(times), dtype=torch.bool)
    mask[[1, 7]] = False
    pixels[1] = float("nan")
    points[7] = float("nan")
    cam = make_camera(params=params.numpy())
    term = Reprojections(times, points, pixels, camera=cam, sigma=0.5, extrinsic=e,
                         target=target, robust="huber", mask=mask)
    assert term.robust_k == pytest.approx(2.4477, abs=1e-4)
    r = term(traj)
    assert torch.isfinite(r).all() and bool((r[~mask] == 0).all())
    full = Reprojections(times[mask], points[mask], pixels[mask], camera=cam, sigma=0.5,
                         extrinsic=e, target=target)
    torch.testing.assert_close(r[mask], full(traj), atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match="finite"):
        Reprojections(times, points, pixels, camera=cam, sigma=0.5)


def test_float32_trajectory_and_gradcheck(small):
    """float32 residuals against float64 (measured: 7e-5 px), and gradcheck of the
    residuals in a control point (float64)."""
    traj, times, points, pixels, e, target, params = small
    term = Reprojections(times, points, pixels, camera=make_camera(params=params.numpy()),
                         sigma=1.0, extrinsic=e, target=target, time_offset=0.01,
                         line_delay=3e-5)
    r64 = term(traj).detach()
    ctrl32 = traj.control_points.detach().float()
    r32 = term(traj, ctrl32).detach()
    assert r32.dtype == torch.float32
    err = float((r32.double() - r64).abs().max())
    assert err < 5e-3, err
    ctrl = traj.control_points.detach()
    part = ctrl[6:7].clone().requires_grad_()  # a control point of the frames' spans

    def residual(c):
        return term(traj, torch.cat((ctrl[:6], c, ctrl[7:])))

    assert torch.autograd.gradcheck(residual, (part,), atol=1e-6, rtol=1e-5)

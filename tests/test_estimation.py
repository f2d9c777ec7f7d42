"""torch_dq.fitting.estimate and its terms, against an analytic motion.

The motion: R(t) = Rz(a t) Ry(b sin t), p(t) = (c t + d t^2, sin 2t, 0.5 cos t), with its
angular velocity, angular and linear accelerations written out by hand below (independent of
the library): for R = Rz(at) Ry(phi), phi = b sin t,
dR/dt = ([a e_z]x + [phi' Rz(at) e_y]x) R, so w = a e_z + phi' (-sin at, cos at, 0) and
alpha = phi'' (-sin at, cos at, 0) + phi' a (-cos at, -sin at, 0). Measurements are
synthesised from these formulas with seeded noise, biases, clock offsets and outliers.
"""

import math
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.fitting import (Accel, Free, Gyro, Poses, Positions, RelativePoses, estimate)
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64
A, B, C, D = 0.8, 0.5, 0.6, 0.1  # the motion's constants
G = np.array([0.0, 0.0, -9.81])


# ----------------------------------------------------------------------------- the truth

def truth(t):
    """numpy: rotation (scipy), position, world angular velocity, velocity, angular and
    linear acceleration at times t (N,)."""
    t = np.asarray(t, dtype=float)
    phi, dphi, ddphi = B * np.sin(t), B * np.cos(t), -B * np.sin(t)
    R = Rotation.from_euler("z", (A * t)[:, None]) * Rotation.from_euler("y", phi[:, None])
    p = np.stack((C * t + D * t**2, np.sin(2 * t), 0.5 * np.cos(t)), -1)
    v = np.stack((C + 2 * D * t, 2 * np.cos(2 * t), -0.5 * np.sin(t)), -1)
    acc = np.stack((2 * D + 0 * t, -4 * np.sin(2 * t), -0.5 * np.cos(t)), -1)
    ey = np.stack((-np.sin(A * t), np.cos(A * t), 0 * t), -1)
    dey = A * np.stack((-np.cos(A * t), -np.sin(A * t), 0 * t), -1)
    w = A * np.array([0.0, 0.0, 1.0]) + dphi[:, None] * ey
    alpha = ddphi[:, None] * ey + dphi[:, None] * dey
    return R, p, w, v, alpha, acc


def poses_of(t):
    R, p = truth(t)[:2]
    q = torch.from_numpy(R.as_quat(scalar_first=True))
    return dq.from_rt(q, torch.from_numpy(p))


def imu_of(t, bg=(0.0, 0.0, 0.0), ba=(0.0, 0.0, 0.0)):
    """Ideal gyroscope and accelerometer readings (body axes) with biases."""
    R, _, w, _, _, acc = truth(t)
    gyro = R.inv().apply(w) + np.asarray(bg)
    accel = R.inv().apply(acc - G) + np.asarray(ba)
    return torch.from_numpy(gyro), torch.from_numpy(accel)


def noisy_poses(x, gen, rot, trans):
    q, p = dq.to_rt(x)
    dq_ = quat.from_rotvec(rot * torch.randn(*q.shape[:-1], 3, generator=gen, dtype=F64))
    return dq.from_rt(quat.mul(q, dq_), p + trans * torch.randn(*p.shape, generator=gen,
                                                                 dtype=F64))


def grid(t0, t1, hz):
    return torch.linspace(t0, t1, int(round((t1 - t0) * hz)) + 1, dtype=F64)


def start_spline(t, x, spacing=0.2, form="de_boor"):
    n = math.ceil((float(t[-1]) - float(t[0])) / spacing) + 3
    return BSpline.from_dualquats(x, t, n_ctrl=n, form=form)


def randn(gen, *shape, scale=1.0):
    return scale * torch.randn(*shape, generator=gen, dtype=F64)


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(7)


def imu_problem(gen, *, offset=0.01, bg=(0.01, -0.02, 0.005), ba=(0.1, -0.05, 0.2),
                clock=None, gravity=9.81, duration=4.0, cam_hz=20, imu_hz=100):
    """Noisy camera poses and an IMU with biases and a clock offset (readings stamped t
    measure the motion at t + offset), a spline started from the poses."""
    tc = grid(0.0, duration, cam_hz)
    ti = grid(0.15, duration - 0.15, imu_hz)
    x = noisy_poses(poses_of(tc), gen, 0.002, 0.002)
    gy, ac = imu_of(ti.numpy() + offset, bg, ba)
    clock = Free() if clock is None else clock
    terms = [Poses(tc, x, rot_sigma=0.002, trans_sigma=0.002),
             Gyro(ti, gy + randn(gen, *gy.shape, scale=0.005), sigma=0.005, bias=True,
                  time_offset=clock),
             Accel(ti, ac + randn(gen, *ac.shape, scale=0.05), sigma=0.05, bias=True,
                   time_offset=clock, gravity=gravity)]
    return start_spline(tc, x, 0.1, "cumulative"), terms  # C2: accelerations continuous


def within(value, ref, std, k=4.0):
    value, ref, std = (np.asarray(torch.as_tensor(v, dtype=F64)) for v in (value, ref, std))
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    assert np.all(np.abs(value - ref) <= k * std), (value, ref, std)


# ----------------------------------------------------------------------------- kernels

@pytest.mark.parametrize("d", [1, 2, 3, 6])
def test_chi_quantile_matches_scipy(d):
    assert fitting.chi_quantile(d) == pytest.approx(chi.ppf(0.95, d), abs=1e-10)
    assert fitting.chi_quantile(d, 0.5) == pytest.approx(chi.ppf(0.5, d), abs=1e-10)


def test_default_robust_scale_is_the_chi_quantile():
    t = grid(0, 1, 10)
    assert Poses(t, poses_of(t), rot_sigma=1, trans_sigma=1, robust="huber").robust_k == \
        pytest.approx(3.5485, abs=1e-4)
    assert Positions(t, torch.zeros(11, 3, dtype=F64), sigma=1, robust="cauchy").robust_k == \
        pytest.approx(2.7955, abs=1e-4)


# ----------------------------------------------------------------------------- recovery

@pytest.mark.filterwarnings("ignore:fitting.estimate. Accel.time_offset is estimated on a")
def test_recovers_biases_clock_offset_and_gravity(gen):
    """Camera at 20 Hz, IMU at 100 Hz with both biases, a 10 ms offset shared by the gyro and
    accelerometer (one Free), gravity's direction estimated from its magnitude: every value
    within 4 reported standard deviations of the truth, chi2 near its dof."""
    spline, (cam, gyro, acc) = imu_problem(gen)
    est = estimate(spline, [cam, gyro, acc], verbose=False)
    assert bool(est.converged)
    within(gyro.bias, [0.01, -0.02, 0.005], est.std(gyro, "bias"))
    within(acc.bias, [0.1, -0.05, 0.2], est.std(acc, "bias"))
    within(gyro.time_offset, 0.01, est.std(gyro, "time_offset"))
    torch.testing.assert_close(acc.time_offset, gyro.time_offset)  # one shared parameter
    assert float(est.std(gyro, "time_offset")) < 2e-3
    within(acc.gravity, G, est.std(acc, "gravity") + 1e-9)
    assert float(acc.gravity.norm()) == pytest.approx(9.81)
    for term in (cam, gyro, acc):
        assert 0.8 < float(est.chi2[term]) / int(est.dof[term]) < 1.2
    assert est.cov().shape == (9, 9)  # 3 + 3 + 1 + 2 (gravity's chart)
    assert float(est.final_loss) <= float(est.loss[0])


def test_gyro_offset_start_from_cross_correlation(gen):
    """A 60 ms clock offset: the cross-correlation of the measured rates with those of the
    start spline (fit to noisy poses, its rates noisy) lands near it, and the estimate
    recovers it."""
    spline, (cam, gyro, _) = imu_problem(gen, offset=0.06)
    start = gyro.default_start("time_offset", spline, None, {})
    assert abs(float(start) - 0.06) < 0.02
    est = estimate(spline, [cam, gyro], verbose=False)
    within(gyro.time_offset, 0.06, est.std(gyro, "time_offset"))


def test_reported_stds_agree_with_monte_carlo_scatter():
    """40 seeds of one small problem (poses + a biased gyroscope), solved as one batch: the
    scatter of the estimated biases and of the pose at one time about the truth agrees with
    the reported standard deviations within 30 % (pooled over the axes)."""
    S = 40
    tc, ti = grid(0.0, 3.0, 10), grid(0.2, 2.8, 40)
    t_q = torch.tensor([1.55], dtype=F64)
    R_q, p_q = truth(t_q.numpy())[:2]
    bias = np.array([0.02, -0.01, 0.03])
    g = torch.Generator().manual_seed(100)
    x = noisy_poses(poses_of(tc).expand(S, -1, -1), g, 0.01, 0.01)
    gy = imu_of(ti.numpy(), bias)[0]
    gyro = Gyro(ti, gy + randn(g, S, *gy.shape, scale=0.01), sigma=0.01, bias=True)
    cam = Poses(tc, x, rot_sigma=0.01, trans_sigma=0.01)
    spline = start_spline(tc, x, 0.3)
    est = estimate(spline, [cam, gyro], prior=1e-6, verbose=False)
    assert bool(est.converged.all())
    q, p = dq.to_rt(spline(t_q))
    rot = R_q.inv() * Rotation.from_quat(q.detach().numpy()[:, 0], scalar_first=True)
    perr = np.concatenate((rot.as_rotvec(), p.detach().numpy()[:, 0] - p_q), -1)
    pairs = ((gyro.bias.numpy() - bias, est.std(gyro, "bias").numpy()),
             (perr, est.pose_std(t_q)[:, 0].numpy()))
    for e, s in pairs:
        ratio = np.sqrt((e**2).mean()) / np.sqrt((s**2).mean())
        assert 0.7 < ratio < 1.3, ratio


# ----------------------------------------------------------------------------- Jacobians

def test_gauss_newton_system_equals_dense_autograd(gen, monkeypatch):
    """Band, coupling and nuisance blocks and gradients of the Gauss-Newton system (exact
    per-span Jacobians) against J^T J and J^T r of torch.autograd.functional.jacobian through
    the layer's public path, every term and nuisance kind estimated."""
    from torch_dq.fitting._estimate import _starts
    from torch_dq.fitting._problem import Problem

    t = grid(0.0, 2.0, 5)
    ti = grid(0.3, 1.7, 5)
    x = noisy_poses(poses_of(t), gen, 0.01, 0.01)
    spline = start_spline(t, x, 0.4)
    e = dq.exp(torch.tensor([0.1, -0.2, 0.05, 0.02, 0.01, -0.03], dtype=F64))
    gy, ac = imu_of(ti.numpy())
    terms = [Poses(t, dq.mul(x, e), rot_sigma=0.01, trans_sigma=0.02, extrinsic=True),
             Positions(t[1:-1], dq.to_rt(x)[1][1:-1] + randn(gen, 9, 3, scale=0.01),
                       sigma=0.01,
                       lever_arm=True, time_offset=Free(0.01)),
             RelativePoses(t[:-2], t[2:], dq.mul(dq.conj(x[:-2]), x[2:]), rot_sigma=0.02,
                           trans_sigma=0.02),
             Gyro(ti, gy, sigma=0.01, bias=True, time_offset=0.02),
             Accel(ti, ac, sigma=0.1, bias=True, gravity=9.81)]
    ctrl = spline.control_points.detach()
    problem = Problem(spline, terms, ctrl.shape[:-2])
    values = _starts("fitting.estimate", problem, ctrl)
    values = [v + 0.01 if v.shape[-1:] != (8,) else v for v in values]
    w = problem.width(values)
    assert w == 5  # relative poses 0.4 s (a knot span) apart: one more control point
    sys_ = problem.system(ctrl, values, w)
    n, m = ctrl.shape[0], problem.m

    def residuals(dc, dn):
        c, v = problem.retract(ctrl, values, dc, dn)
        return torch.cat([term.evaluate(spline, c, problem.term_values(i, v)).reshape(-1)
                          for i, term in enumerate(terms)])

    zc, zn = torch.zeros(n, 6, dtype=F64), torch.zeros(m, dtype=F64)
    Jc, Jn = torch.autograd.functional.jacobian(residuals, (zc, zn), vectorize=True)
    J = torch.cat((Jc.reshape(-1, 6 * n), Jn), -1)
    H, r = J.T @ J, residuals(zc, zn)
    g = J.T @ r
    for k in range(n):
        for d in range(w):
            if k + d < n:
                torch.testing.assert_close(sys_.band[0, k, d],
                                           H[6 * k:6 * k + 6, 6 * (k + d):6 * (k + d) + 6],
                                           rtol=1e-7, atol=1e-7)
    assert H[:6 * n, :6 * n].reshape(n, 6, n, 6).abs().amax((1, 3)).triu(w).max() == 0
    torch.testing.assert_close(sys_.cn[0].reshape(6 * n, m), H[:6 * n, 6 * n:], rtol=1e-7,
                               atol=1e-7)
    torch.testing.assert_close(sys_.nn[0], H[6 * n:, 6 * n:], rtol=1e-7, atol=1e-7)
    torch.testing.assert_close(sys_.gc[0].reshape(-1), g[:6 * n], rtol=1e-7, atol=1e-7)
    torch.testing.assert_close(sys_.gn[0], g[6 * n:], rtol=1e-7, atol=1e-7)
    # large inputs take one reverse pass per residual component instead of k copies: equal
    monkeypatch.setattr("torch_dq.fitting._local._COPY_ELEMENTS", 0)
    separate = problem.system(ctrl, values, w)
    for a, b in ((separate.band, sys_.band), (separate.cn, sys_.cn), (separate.nn, sys_.nn),
                 (separate.gc, sys_.gc), (separate.gn, sys_.gn)):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------- robust, batch

@pytest.mark.parametrize("kernel", ["huber", "cauchy"])
def test_robust_kernels_resist_gross_outliers(gen, kernel):
    """5 % of the positions off by 2 m (noise 1 cm): the robust fits stay within a few
    noise levels of the truth, the squared loss is pulled away by tens of noise levels; the
    outliers get small weights."""
    t = grid(0.0, 4.0, 25)
    R, p = truth(t.numpy())[:2]
    q = torch.from_numpy(R.as_quat(scalar_first=True))
    meas = torch.from_numpy(p) + randn(gen, 101, 3, scale=0.01)
    bad = torch.zeros(101, dtype=torch.bool)
    bad[torch.randperm(101, generator=gen)[:5]] = True
    meas[bad] += torch.tensor([2.0, -1.0, 1.0], dtype=F64)
    rot = Poses(t, dq.from_rt(q, torch.from_numpy(p)), rot_sigma=0.001, trans_sigma=1e3)
    errors = {}
    for robust in (None, kernel):
        spline = start_spline(t, poses_of(t), 0.25)
        pos = Positions(t, meas, sigma=0.01, robust=robust)
        est = estimate(spline, [rot, pos], verbose=False)
        errors[robust] = float((dq.to_rt(spline(t))[1] - torch.from_numpy(p)).norm(dim=-1)
                               .detach().max())
        if robust:
            assert float(est.weights[pos][bad].max()) < 0.1
            assert float(est.weights[pos][~bad].min()) > 0.3
    assert errors[kernel] < 0.03 and errors[None] > 0.2, errors


@pytest.mark.filterwarnings("ignore:fitting.Estimate. chi2/dof far above 1:RuntimeWarning")
def test_batched_problems_equal_separate_ones(gen):
    """Two trajectories with their own times (B, N), a mask for unequal counts, their own
    biases: one batched estimate equals two separate ones."""
    t = torch.stack((grid(0.0, 3.0, 10), grid(0.0, 3.0, 10) ** 1.1 / 3.0**0.1))
    keep = torch.ones(2, 31, dtype=torch.bool)
    keep[1, 5::7] = False  # the second trajectory has 27 poses
    x = torch.stack([noisy_poses(poses_of(t[b]), gen, 0.01, 0.01) for b in range(2)])
    x[1, 5::7] = float("nan")  # masked: never read
    ti = grid(0.3, 2.7, 30)
    gy = torch.stack([imu_of(ti.numpy() + 0.3 * b, (0.01 * b, 0.02, 0.0))[0] for b in
                      range(2)]) + randn(gen, 2, 73, 3, scale=0.01)
    spline = BSpline.from_dualquats(torch.stack((x[0], x[0])), t[0], n_ctrl=13)
    one = [BSpline.from_dualquats(x[b][keep[b]], t[b][keep[b]], n_ctrl=13) for b in range(2)]
    with torch.no_grad():
        spline.control_points = torch.stack([o.control_points for o in one])
    cam = Poses(t, x, rot_sigma=0.01, trans_sigma=0.01, mask=keep)
    gyro = Gyro(ti, gy, sigma=0.01, bias=True)
    est = estimate(spline, [cam, gyro], verbose=False)
    with pytest.warns(RuntimeWarning, match=r"chi2/dof far above 1 \(Poses"):
        # the second trajectory's gyro reads the motion 0.3 s later than its poses
        assert est.loss.shape[1:] == (2,) and est.std(gyro, "bias").shape == (2, 3)
    for b in range(2):
        cam_b = Poses(t[b][keep[b]], x[b][keep[b]], rot_sigma=0.01, trans_sigma=0.01)
        gyro_b = Gyro(ti, gy[b], sigma=0.01, bias=True)
        est_b = estimate(one[b], [cam_b, gyro_b], verbose=False)
        torch.testing.assert_close(spline.control_points[b], one[b].control_points,
                                   rtol=0, atol=1e-7)
        torch.testing.assert_close(gyro.bias[b], gyro_b.bias, rtol=0, atol=1e-8)
        torch.testing.assert_close(est.std(gyro, "bias")[b], est_b.std(gyro_b, "bias"))
        torch.testing.assert_close(est.final_loss[b], est_b.final_loss)
        torch.testing.assert_close(est.pose_std(t[b, :5])[b], est_b.pose_std(t[b, :5]))


def test_per_trajectory_knots_equal_separate_estimates(gen):
    """Three trajectories on their own time ranges (per-trajectory knots and origins, from
    (B, N) times; one starts at t = 100 s), poses and a gyro with its own bias each, in the
    cumulative form: one batched estimate equals three separate ones (control points, bias,
    losses, standard deviations); a time outside its own trajectory's domain (inside
    another's) is refused, naming the trajectory."""
    ranges = [(0.0, 3.0), (1.0, 2.5), (100.0, 102.0)]
    t = torch.stack([torch.linspace(a, b, 31, dtype=F64) for a, b in ranges])
    ti = torch.stack([torch.linspace(a + 0.2, b - 0.2, 60, dtype=F64) for a, b in ranges])
    x = torch.stack([noisy_poses(poses_of(t[b] - t[b, 0]), gen, 0.01, 0.01)
                     for b in range(3)])
    gy = torch.stack([imu_of(ti[b].numpy() - float(t[b, 0]), (0.01 * b, 0.02, 0.0))[0]
                      for b in range(3)]) + randn(gen, 3, 60, 3, scale=0.01)
    spline = BSpline.from_dualquats(x, t, n_ctrl=9, form="cumulative")
    assert spline.time_model.knots.shape == (3, 13)  # a row of knots per trajectory
    one = [BSpline.from_dualquats(x[b], t[b], n_ctrl=9, form="cumulative") for b in range(3)]
    for b in range(3):
        torch.testing.assert_close(spline.control_points[b], one[b].control_points)
    gyro = Gyro(ti, gy, sigma=0.01, bias=True)
    est = estimate(spline, [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01), gyro],
                   verbose=False)
    assert est.steps >= 2 and bool(est.converged.all())
    for b in range(3):
        gyro_b = Gyro(ti[b], gy[b], sigma=0.01, bias=True)
        est_b = estimate(one[b], [Poses(t[b], x[b], rot_sigma=0.01, trans_sigma=0.01),
                                  gyro_b], verbose=False)
        torch.testing.assert_close(spline.control_points[b], one[b].control_points,
                                   rtol=0, atol=1e-6)
        torch.testing.assert_close(gyro.bias[b], gyro_b.bias, rtol=0, atol=1e-7)
        torch.testing.assert_close(est.final_loss[b], est_b.final_loss, rtol=1e-7, atol=0)
        torch.testing.assert_close(est.std(gyro, "bias")[b],
                                   est_b.std(gyro_b, "bias"), rtol=1e-5, atol=0)
        torch.testing.assert_close(est.kinematics_std(ti[:, 10:13])[b],
                                   est_b.kinematics_std(ti[b, 10:13]), rtol=1e-5, atol=0)
    bias = torch.tensor([[0.01 * b, 0.02, 0.0] for b in range(3)], dtype=F64)
    assert bool(((gyro.bias - bias).abs() < 5 * est.std(gyro, "bias")).all())
    late = t.clone()
    late[1, -1] = 2.9  # inside trajectory 0's domain, past trajectory 1's end
    with pytest.raises(ValueError, match=r"trajectory 1.*\[1\.0, 2\.5\]"):
        estimate(spline, [Poses(late, x, rot_sigma=0.01, trans_sigma=0.01)], verbose=False)


def test_imu_improves_velocity_over_poses_alone(gen):
    """Sparse noisy poses (5 Hz, 2 cm): the velocity of the fit with a 100 Hz IMU is closer
    to the analytic velocity than the poses-only fit, and its reported velocity standard
    deviations are smaller; both errors within a few reported standard deviations."""
    tc, ti = grid(0.0, 4.0, 5), grid(0.2, 3.8, 100)
    x = noisy_poses(poses_of(tc), gen, 0.02, 0.02)
    gy, ac = imu_of(ti.numpy())
    cam = Poses(tc, x, rot_sigma=0.02, trans_sigma=0.02)
    imu = [Gyro(ti, gy + randn(gen, *gy.shape, scale=0.01), sigma=0.01),
           Accel(ti, ac + randn(gen, *ac.shape, scale=0.05), sigma=0.05)]
    tq = grid(0.5, 3.5, 10)
    v_true = torch.from_numpy(truth(tq.numpy())[3])
    res = {}
    for name, terms in (("poses", [cam]), ("imu", [cam, *imu])):
        spline = start_spline(tc, x, 0.4, "cumulative")
        est = estimate(spline, terms, verbose=False)
        v = spline.kinematics(tq).linear_velocity.detach()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            std = est.kinematics_std(tq)[:, 3:6]
        chi = [str(w.message) for w in caught if "chi2/dof far above 1" in str(w.message)]
        assert len(chi) == (name == "imu"), chi  # 0.4 s knots underfit the IMU: Accel 3.3
        res[name] = (float((v - v_true).norm(dim=-1).mean()), float(std.mean()))
        assert float(((v - v_true).abs() / std).max()) < 5.0
    assert res["imu"][0] < 0.5 * res["poses"][0] and res["imu"][1] < 0.5 * res["poses"][1]


# ----------------------------------------------------------------------------- what cannot be known

def _small(gen):
    t = grid(0.0, 2.0, 10)
    ti = grid(0.2, 1.8, 20)
    x = poses_of(t)
    gy, ac = imu_of(ti.numpy())
    pos = dq.to_rt(x)[1]
    return t, ti, x, gy, ac, pos, start_spline(t, x, 0.4)


@pytest.mark.parametrize(("build", "match"), [
    (lambda t, ti, x, gy, ac, pos: [Poses(t, x, rot_sigma=1, trans_sigma=1, extrinsic=True)],
     "extrinsic is undetermined"),
    (lambda t, ti, x, gy, ac, pos: [Poses(t, x, rot_sigma=1, trans_sigma=1, extrinsic=True),
                                    Gyro(ti, gy, sigma=1)],
     "extrinsic's translation is undetermined: a Gyro"),
    (lambda t, ti, x, gy, ac, pos: [Poses(t, x, rot_sigma=1, trans_sigma=1, extrinsic=True),
                                    Gyro(ti, gy, sigma=1),
                                    Positions(t, pos, sigma=1, lever_arm=True)],
     "extrinsic's translation is undetermined: a Gyro"),
    (lambda t, ti, x, gy, ac, pos: [Poses(t, x, rot_sigma=1, trans_sigma=1, time_offset=True),
                                    Gyro(ti, gy, sigma=1, time_offset=True)],
     "every term's time_offset"),
    (lambda t, ti, x, gy, ac, pos: [Gyro(ti, gy, sigma=1), Accel(ti, ac, sigma=1)],
     "absolute pose"),
    (lambda t, ti, x, gy, ac, pos: [RelativePoses(t[:-1], t[1:], dq.mul(dq.conj(x[:-1]), x[1:]),
                                                  rot_sigma=1, trans_sigma=1)],
     "absolute pose"),
    (lambda t, ti, x, gy, ac, pos: [Positions(t, pos, sigma=1)], "rotation is undetermined"),
    (lambda t, ti, x, gy, ac, pos: [Positions(t, pos, sigma=1), Gyro(ti, gy, sigma=1)],
     "rotation is undetermined"),
    (lambda t, ti, x, gy, ac, pos: [Positions(t, pos, sigma=1, lever_arm=True)],
     "lever_arm is undetermined"),
    (lambda t, ti, x, gy, ac, pos: [Positions(t, pos, sigma=1),
                                    Accel(ti, ac, sigma=1, bias=True, gravity=9.81)],
     "accelerometer bias and the gravity direction"),
])
def test_structurally_undetermined_parameters_raise_before_solving(gen, build, match):
    *data, spline = _small(gen)
    before = spline.control_points.detach().clone()
    with pytest.raises(ValueError, match=match):
        estimate(spline, build(*data), verbose=False)
    assert torch.equal(spline.control_points.detach(), before)


def test_three_fixed_lever_arms_determine_rotation(gen):
    """Three markers at non-collinear lever arms fix the rotation: no error, and the fit
    recovers the analytic rotation."""
    t, _, x, *_ = _small(gen)
    q, p = dq.to_rt(x)
    arms = [torch.tensor(a, dtype=F64) for a in ((0, 0, 0), (0.5, 0, 0), (0, 0.5, 0))]
    terms = [Positions(t, p + quat.rotate(q, a), sigma=0.001, lever_arm=a) for a in arms]
    spline = start_spline(t, dq.from_rt(quat.identity((21,), dtype=F64), p), 0.4)
    estimate(spline, terms, prior=0.0, verbose=False)  # from identity rotations
    from torch_dq.losses import rotation_angle
    assert float(rotation_angle(spline(t), x).detach().max()) < 3e-3


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_unobservable_time_offset_gives_inf_and_a_warning(gen):
    """A constant rotation rate carries no information on a gyroscope's clock offset: its
    standard deviation is inf with a warning, never the prior's value."""
    t, ti = grid(0.0, 2.0, 10), grid(0.2, 1.8, 20)
    xi = torch.tensor([0.0, 0.0, 0.7, 0.3, 0.0, 0.0], dtype=F64)
    x = dq.exp(t[:, None] * xi)
    gyro = Gyro(ti, xi[:3].expand(33, 3), sigma=0.01, time_offset=Free(0.0))
    cam = Poses(t, x, rot_sigma=0.01, trans_sigma=0.01)
    est = estimate(start_spline(t, x, 0.4), [cam, gyro], steps=2, verbose=False)  # exact data
    with (pytest.warns(RuntimeWarning, match="chi2/dof far below 1"),  # chi2 ~ 0: true
          pytest.warns(RuntimeWarning, match="Gyro.time_offset")):
        assert math.isinf(float(est.std(gyro, "time_offset")))


def _lever_arm_estimate(t, x, marks, spacing):
    """Poses and Positions(lever_arm=Free()) on a spline of the given knot spacing."""
    pos = Positions(t, marks, sigma=0.002, lever_arm=Free())
    cam = Poses(t, x, rot_sigma=0.002, trans_sigma=0.002)
    return estimate(start_spline(t, x, spacing), [cam, pos], verbose=False), pos


def test_time_gap_leaves_nuisance_stds_finite(gen):
    """A 1 s gap over about seven knot spacings leaves control points without data: the
    poses that read them get inf with the gap warning only, while the lever arm keeps the
    std of the same data on knots that leave no control point undetermined."""
    t = grid(0.0, 4.0, 20)
    t = t[(t < 1.5) | (t > 2.5)]
    q, p = dq.to_rt(poses_of(t))
    arm = torch.tensor([0.1, -0.05, 0.2], dtype=F64)
    marks = p + quat.rotate(q, arm.expand(len(t), 3)) + randn(gen, len(t), 3, scale=0.002)
    x = noisy_poses(poses_of(t), gen, 0.002, 0.002)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est, pos = _lever_arm_estimate(t, x, marks, 0.15)
        std = est.std(pos, "lever_arm")
        pose = est.pose_std(torch.tensor([1.0, 1.3, 1.8, 2.0, 2.2, 2.7, 3.0], dtype=F64))
    messages = [str(w.message) for w in caught]
    assert messages and all("do not determine every control point" in m for m in messages)
    ref_est, ref_pos = _lever_arm_estimate(t, x, marks, 0.6)  # no warning (pytest: error)
    # 0.6 s knots underfit the marks: 1.67 with each term's own dof (1.7 under the share)
    with pytest.warns(RuntimeWarning, match=r"chi2/dof far above 1 \(Positions 1\.67"):
        ref = ref_est.std(ref_pos, "lever_arm")
    assert torch.isfinite(std).all() and torch.isfinite(ref).all()
    torch.testing.assert_close(std, ref, rtol=0.3, atol=0.0)
    within(pos.lever_arm, arm, std)
    assert torch.isinf(pose[2:5]).all()
    assert torch.isfinite(pose[[0, 1, 5, 6]]).all()


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_known_time_offset_prior_gives_its_std(gen):
    """The same offset with a Gaussian prior (a Free's prior_std): finite, the prior's."""
    t, ti = grid(0.0, 2.0, 10), grid(0.2, 1.8, 20)
    xi = torch.tensor([0.0, 0.0, 0.7, 0.3, 0.0, 0.0], dtype=F64)
    x = dq.exp(t[:, None] * xi)
    gyro = Gyro(ti, xi[:3].expand(33, 3), sigma=0.01, time_offset=Free(0.0, prior_std=0.02))
    cam = Poses(t, x, rot_sigma=0.01, trans_sigma=0.01)
    est = estimate(start_spline(t, x, 0.4), [cam, gyro], steps=2, verbose=False)
    with pytest.warns(RuntimeWarning, match="chi2/dof far below 1"):  # exact data: chi2 ~ 0
        assert float(est.std(gyro, "time_offset")) == pytest.approx(0.02, rel=1e-3)


# ----------------------------------------------------------------------------- bad input

def test_terms_validate_their_arguments():
    t = grid(0.0, 1.0, 10)
    x = poses_of(t)
    y = torch.zeros(11, 3, dtype=F64)
    with pytest.raises(ValueError, match="rot_sigma is required"):
        Poses(t, x, rot_sigma=None, trans_sigma=1.0)
    with pytest.raises(TypeError):
        Poses(t, x, 0.1, 0.1)  # sigmas are keyword-only
    with pytest.raises(ValueError, match="sigma must be positive"):
        Positions(t, y, sigma=-1.0)
    with pytest.raises(ValueError, match=r"\(3,\) tensor"):
        Gyro(t, y, sigma=torch.ones(2))
    with pytest.raises(ValueError, match="times of shape"):
        Gyro(t[:-1], y, sigma=1.0)
    with pytest.raises(ValueError, match="must be finite"):
        Gyro(t, y.index_fill(0, torch.tensor([3]), float("nan")), sigma=1.0)
    with pytest.raises(ValueError, match="non-decreasing"):
        Gyro(t.flip(0), y, sigma=1.0)
    with pytest.raises(ValueError, match="mask must have"):
        Gyro(t, y, sigma=1.0, mask=torch.ones(10, dtype=torch.bool))
    with pytest.raises(TypeError, match="mask must be a bool"):
        Gyro(t, y, sigma=1.0, mask=torch.ones(11))
    with pytest.raises(ValueError, match="robust must be"):
        Gyro(t, y, sigma=1.0, robust="tukey")
    with pytest.raises(ValueError, match="bias must be None"):
        Gyro(t, y, sigma=1.0, bias="yes")
    with pytest.raises(ValueError, match=r"bias of shape \(\.\.\., 3\)"):
        Gyro(t, y, sigma=1.0, bias=torch.zeros(2, dtype=F64))
    with pytest.raises(ValueError, match="unit dual quaternions"):
        Poses(t, x, rot_sigma=1, trans_sigma=1, extrinsic=2 * dq.identity(dtype=F64))
    with pytest.raises(TypeError, match="floating-point"):
        Positions(t, y.long(), sigma=1.0)
    ok = Gyro(t, y.index_fill(0, torch.tensor([3]), float("nan")), sigma=1.0,
              mask=torch.arange(11) != 3)  # a masked NaN is fine
    assert bool(ok.mask.sum() == 10)


@pytest.mark.parametrize("make", [
    lambda t, y: Gyro(t, y, sigma=1.0),
    lambda t, y: Accel(t, y, sigma=1.0),
    lambda t, y: Positions(t, y, sigma=1.0),
    lambda t, y: Poses(t, dq.identity((t.shape[0],), dtype=F64), rot_sigma=1, trans_sigma=1),
    lambda t, y: RelativePoses(t, t + 1e-3, dq.identity((t.shape[0],), dtype=F64), rot_sigma=1,
                               trans_sigma=1),
])
def test_float32_unix_times_are_refused(make):
    """10 s at 200 Hz stamped 1.7e9 + s: float32 rounds every stamp to one value (spacing
    128 s there); each term refuses it and names float64; the float64 times and float32
    times near zero are accepted."""
    t = 1.7e9 + grid(0.0, 10.0, 200)
    y = torch.zeros(t.shape[0], 3, dtype=F64)
    assert torch.unique(t.float()).numel() == 1  # the trap
    with pytest.raises(ValueError, match=r"torch.float32 cannot resolve these times.*"
                                         r"spacing at 1.7e\+09 is 128.*torch.float64"):
        make(t.float(), y)
    make(t, y)
    make((t - 1.7e9).float(), y)


def test_coarse_float32_times_are_refused_without_collapsing():
    """float32 times at 1e5 s over a 1 s span: distinct after rounding, but resolved to
    7.8e-3 s only (0.8 % of the span): refused."""
    t = (1e5 + grid(0.0, 1.0, 50)).float()
    assert torch.unique(t).numel() > 1
    with pytest.raises(ValueError, match="cannot resolve"):
        Gyro(t, torch.zeros(51, 3), sigma=1.0)


def test_messages_name_the_first_bad_sample():
    t = grid(0.0, 1.0, 10)
    y = torch.zeros(11, 3, dtype=F64)
    swapped = t.clone()
    swapped[[4, 5]] = swapped[[5, 4]]
    with pytest.raises(ValueError, match=r"times\[5\] = 0.4 is before an earlier one \(0.5, "
                                         r"sample 4\); sort"):
        Gyro(swapped, y, sigma=1.0)
    with pytest.raises(ValueError, match=r"times\[1, 5\] = 0.4 is before"):
        Gyro(torch.stack((t, swapped)), y.expand(2, 11, 3), sigma=1.0)
    with pytest.raises(ValueError, match="measurements must be finite: sample 6 is not"):
        Accel(t, y.index_fill(0, torch.tensor([6, 8]), float("inf")), sigma=1.0)
    with pytest.raises(ValueError, match="times must be finite: sample 2 is not"):
        Gyro(t.index_fill(0, torch.tensor([2]), float("nan")), y, sigma=1.0)
    assert Gyro(t, y, sigma=1.0, robust="Huber").robust == "huber"
    assert Positions(t, y, sigma=1.0, robust="CAUCHY").robust == "cauchy"


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_accel_with_a_c1_spline_warns_once(gen):
    """de Boor B-splines (degree >= 2) are only C1: an Accel term warns (once per estimate)
    and names form='cumulative'; the cumulative form and terms without Accel do not."""
    t, ti, x, gy, ac, _, spline = _small(gen)
    terms = [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01), Accel(ti, ac, sigma=0.1)]
    with pytest.warns(UserWarning, match="form='cumulative'") as record:
        estimate(spline, terms, steps=1, verbose=False)
    assert len([w for w in record if "only C1" in str(w.message)]) == 1
    estimate(start_spline(t, x, 0.4, "cumulative"), terms, steps=1, verbose=False)
    estimate(spline, [terms[0], Gyro(ti, gy, sigma=0.1)], steps=1, verbose=False)


@pytest.mark.filterwarnings("ignore:fitting.estimate. Accel.time_offset is estimated on a")
@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
@pytest.mark.filterwarnings("ignore:fitting.Estimate. chi2/dof far above 1:RuntimeWarning")
def test_estimate_repr_and_parameter_order(gen):
    """The summary names steps, reason, final loss and chi2/dof per term; ``parameters``
    lists cov's rows (a shared Free once): the gyro's time offset 1 and bias 3, then the
    accelerometer's bias 3 and gravity 2; cov's diagonal blocks match std() of each."""
    t, ti, x, gy, ac, _, _ = _small(gen)
    x = noisy_poses(x, gen, 0.01, 0.01)
    gy, ac = gy + randn(gen, *gy.shape, scale=0.01), ac + randn(gen, *ac.shape, scale=0.1)
    clock = Free(0.0)
    cam = Poses(t, x, rot_sigma=0.01, trans_sigma=0.01)
    gyro = Gyro(ti, gy, sigma=0.01, bias=True, time_offset=clock)
    acc = Accel(ti, ac, sigma=0.1, bias=True, time_offset=clock, gravity=9.81)
    est = estimate(start_spline(t, x, 0.4, "cumulative"), [cam, gyro, acc], steps=1,
                   verbose=False)
    text = repr(est)
    assert text.startswith("Estimate(steps=1, reason=") and "final_loss=" in text
    for term in (cam, gyro, acc):
        ratio = float(est.chi2[term]) / float(est.dof[term])
        assert f"{type(term).__name__}: {ratio:.3g}" in text
    assert est.parameters == [(gyro, "time_offset", 1), (gyro, "bias", 3), (acc, "bias", 3),
                              (acc, "gravity", 2)]
    C, start = est.cov(), 0
    for term, name, size in est.parameters:
        block = C[start:start + size, start:start + size].diagonal().sqrt()
        if name != "gravity":  # gravity's std is reported in world axes, cov in its chart
            torch.testing.assert_close(block, est.std(term, name).reshape(size))
        start += size
    assert start == C.shape[-1] == 9


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_verbose_prints_one_line_per_step_without_a_terminal(gen, capsys):
    t, _, x, *_, spline = _small(gen)
    est = estimate(spline, [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01)], steps=2, tol=0.0)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == est.steps >= 1
    assert lines[0].startswith("torch_dq.estimate: step 1: cost ") and "damping" in lines[0]


def test_term_constructors_have_their_class_docs():
    for cls in (Poses, Positions, RelativePoses, Gyro, Accel):
        assert cls.__init__.__doc__ == cls.__doc__ and "Args:" in cls.__doc__
    assert "Initialize internal Module state" not in fitting.Term.__init__.__doc__


def test_estimate_validates_domain_and_arguments(gen):
    t, ti, x, gy, *_ = _small(gen)
    spline = start_spline(t, x, 0.4)
    cam = Poses(t, x, rot_sigma=1, trans_sigma=1)
    with pytest.raises(ValueError, match="max_time_offset"):
        estimate(spline, [cam, Gyro(t, poses_of(t)[:, :3], sigma=1, time_offset=True)],
                 verbose=False)  # gyro at the ends, widened by 0.1 s
    with pytest.raises(ValueError, match=r"^fitting\.estimate: Poses times leave the trajectory's "
                                         r"domain .*drop those samples \(are the times in"):
        estimate(spline, [Poses(t - 1e3, x, rot_sigma=1, trans_sigma=1)], verbose=False)
    with pytest.raises(ValueError, match="steps must be"):
        estimate(spline, [cam], steps=-1)
    with pytest.raises(TypeError, match="curve layer"):
        estimate(torch.nn.Linear(2, 2), [cam])
    with pytest.raises(TypeError, match="non-empty list .*Accel, Reprojections\\)"):
        estimate(spline, [])


def test_bezier_trajectory_with_a_biased_gyro(gen):
    """A Bézier curve (every sample touches every control point: one dense band) with poses
    and a biased gyroscope: the bias within 4 reported standard deviations."""
    tc, ti = grid(0.0, 1.5, 20), grid(0.2, 1.3, 50)
    x = noisy_poses(poses_of(tc), gen, 0.002, 0.002)
    gy = imu_of(ti.numpy(), (0.03, -0.01, 0.02))[0] + randn(gen, 56, 3, scale=0.005)
    curve = Bezier.from_dualquats(x, tc, n_ctrl=7)
    gyro = Gyro(ti, gy, sigma=0.005, bias=True)
    est = estimate(curve, [Poses(tc, x, rot_sigma=0.002, trans_sigma=0.002), gyro],
                   verbose=False)
    within(gyro.bias, [0.03, -0.01, 0.02], est.std(gyro, "bias"))
    assert est.pose_std(tc[:3]).shape == (3, 6)


def test_time_offset_start_outside_its_bound_raises(gen):
    """A Free time offset started beyond ``max_time_offset`` contradicts its own bound: a
    ValueError naming both, before solving, the trajectory untouched."""
    spline, (cam, gyro, _) = imu_problem(gen, offset=0.0, clock=Free(0.5))
    before = spline.control_points.detach().clone()
    with pytest.raises(ValueError, match=r"Gyro's time_offset starts at 0\.5 s, outside its "
                                         r"max_time_offset=0\.1"):
        estimate(spline, [cam, gyro], verbose=False)
    assert torch.equal(spline.control_points.detach(), before)

"""fitting.estimate's standard deviations against a Monte-Carlo scatter (issue 31's 'done when').

The motion is written out by hand here, independent of the library: R(t) = Rz(psi) Ry(phi)
with psi = a t + c sin(w t) (a yaw rate that varies: under a constant one the centripetal
acceleration of a lever arm is constant in body axes, the same as an accelerometer bias, and
that pair is determined by the small wobble alone) and phi = b sin(t); for R = Rz(psi) Ry(phi),
dR/dt = ([psi' e_z]x + [phi' Rz(psi) e_y]x) R, so the world angular velocity is
psi' e_z + phi' (-sin psi, cos psi, 0). The position is a sum of sines with its second
derivative written out. Measurements: camera poses through an extrinsic, a gyroscope and an
accelerometer with biases and one clock offset, Gaussian noise of exactly the sigmas given.
A second case estimates gravity's direction (``Accel``, the ``Direction`` chart) and the
lever arm of a point whose positions are measured (``Positions``, e.g. a prism or an antenna),
next to camera poses and both biases.

The cubic B-splines with an IMU clock offset here warn (``fitting.estimate``: an Accel offset
on accelerations that are not C1 in time); on these knots they converge all the same.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.fitting import Accel, Free, Gyro, Poses, Positions, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
G = np.array([0.0, 0.0, -9.81])
E_TRUE = torch.tensor([0.1, -0.2, 0.05, 0.2, 0.1, -0.15], dtype=F64)
BG, BA = np.array([0.01, -0.02, 0.005]), np.array([0.1, -0.05, 0.2])
OFFSET = 0.01
AMP, FREQ = np.array([0.4, 0.5, 0.3]), np.array([1.3, 0.9, 1.7])


def motion(t):
    """numpy: rotation (scipy), position, world angular velocity, linear acceleration."""
    t = np.asarray(t, dtype=float)
    psi, dpsi = 1.2 * t + 0.6 * np.sin(1.5 * t), 1.2 + 0.9 * np.cos(1.5 * t)
    phi, dphi = 0.5 * np.sin(t), 0.5 * np.cos(t)
    R = Rotation.from_euler("z", psi[:, None]) * Rotation.from_euler("y", phi[:, None])
    w = dpsi[:, None] * np.array([0.0, 0.0, 1.0]) + dphi[:, None] * np.stack(
        (-np.sin(psi), np.cos(psi), 0 * t), -1)
    p = AMP * np.sin(FREQ * t[:, None])
    acc = -AMP * FREQ**2 * np.sin(FREQ * t[:, None])
    return R, p, w, acc


def _draws(S, gen, tc, ti, rot, trans, gyro, accel):
    """``S`` noisy copies: camera poses through ``exp(E_TRUE)``, gyroscope, accelerometer."""
    R, p, _, _ = motion(tc.numpy())
    x = dq.mul(dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p)),
               dq.exp(E_TRUE))
    q, pos = dq.to_rt(x.expand(S, -1, -1))
    noise = lambda s, *shape: s * torch.randn(*shape, generator=gen, dtype=F64)  # noqa: E731
    cam = dq.from_rt(quat.mul(q, quat.from_rotvec(noise(rot, *q.shape[:-1], 3))),
                     pos + noise(trans, *pos.shape))
    R, _, w, acc = motion(ti.numpy() + OFFSET)  # readings stamped t measure t + OFFSET
    gy = torch.from_numpy(R.inv().apply(w) + BG)
    ac = torch.from_numpy(R.inv().apply(acc - G) + BA)
    return cam, gy + noise(gyro, S, *gy.shape), ac + noise(accel, S, *ac.shape)


def ratios(S=50, seed=3, n_ctrl=33):
    """Scatter over ``S`` draws divided by the root-mean-square reported std, per
    coordinate: extrinsic (rotation, translation), gyro bias, accel bias, clock offset."""
    gen = torch.Generator().manual_seed(seed)
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = torch.linspace(0.15, 2.85, 271, dtype=F64)
    cam, gy, ac = _draws(S, gen, tc, ti, 0.002, 0.002, 0.005, 0.05)
    e = dq.exp(E_TRUE)
    start = dq.mul(e, dq.exp(torch.tensor([0.05, -0.05, 0.04, 0.06, -0.06, 0.05], dtype=F64)))
    spline = BSpline.from_dualquats(dq.mul(cam, dq.conj(start)), tc, n_ctrl=n_ctrl,
                                    form="cumulative")
    clock = Free(0.0)
    terms = [Poses(tc, cam, rot_sigma=0.002, trans_sigma=0.002, extrinsic=Free(start)),
             Gyro(ti, gy, sigma=0.005, bias=True, time_offset=clock),
             Accel(ti, ac, sigma=0.05, bias=True, time_offset=clock)]
    with pytest.warns(RuntimeWarning, match="Accel.time_offset is estimated on a degree-3"):
        est = estimate(spline, terms, verbose=False)
    assert bool(est.converged.all()), est.reason
    ext = dq.log(dq.mul(dq.conj(e), terms[0].extrinsic))
    checks = {"extrinsic": (ext, est.std(terms[0], "extrinsic")),
              "gyro bias": (terms[1].bias - torch.from_numpy(BG), est.std(terms[1], "bias")),
              "accel bias": (terms[2].bias - torch.from_numpy(BA), est.std(terms[2], "bias")),
              "time offset": ((terms[1].time_offset - OFFSET)[:, None],
                              est.std(terms[1], "time_offset")[:, None])}
    # the scatter about the draws' mean: the spline's model error at these knots is common
    # to every draw (a bias, not a scatter)
    return {k: err.std(0) / (std**2).mean(0).sqrt() for k, (err, std) in checks.items()}


@pytest.mark.slow
def test_nuisance_stds_match_a_monte_carlo_scatter():
    """50 draws solved as one batch from an extrinsic start 5 deg / 10 cm off: for every
    estimated nuisance coordinate the scatter over the draws divided by the reported
    standard deviation lies in [0.7, 1.4]."""
    for name, ratio in ratios().items():
        assert bool(((ratio > 0.7) & (ratio < 1.4)).all()), (name, ratio)


def _yaw_problem(wobble):
    """Poses (10 Hz) and a gyroscope 20 ms late (50 Hz) of a yaw psi = t + wobble sin(2 t):
    the rate's variation, 2 wobble rad/s^2, is all that determines the clock offset."""
    gen = torch.Generator().manual_seed(4)
    tc, ti = torch.linspace(0.0, 3.0, 31, dtype=F64), torch.linspace(0.3, 2.7, 121, dtype=F64)
    yaw = lambda t: t + wobble * torch.sin(2 * t)  # noqa: E731
    z = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    q = quat.from_rotvec(yaw(tc)[:, None] * z)
    x = dq.from_rt(q, 0.1 * torch.stack((tc, tc**2, 0 * tc), -1))
    rate = 1.0 + 2 * wobble * torch.cos(2 * (ti + 0.02))
    gy = rate[:, None] * z + 0.002 * torch.randn(len(ti), 3, generator=gen, dtype=F64)
    gyro = Gyro(ti, gy, sigma=0.002, time_offset=Free(0.0), max_time_offset=0.1)
    x = dq.mul(x, dq.exp(0.001 * torch.randn(len(tc), 6, generator=gen, dtype=F64)))
    spline = BSpline.from_dualquats(x, tc, n_ctrl=12, form="cumulative")
    est = estimate(spline, [Poses(tc, x, rot_sigma=0.001, trans_sigma=0.001), gyro],
                   verbose=False)
    return est, gyro


def test_an_unexcited_time_offset_warns_naming_it():
    """Issue 31: a time offset that the motion barely excites got a 3-4x overconfident std
    and no warning. A yaw rate varying by 2e-4 rad/s^2 (std of the offset well above a
    tenth of max_time_offset) warns naming Gyro.time_offset; 0.4 rad/s^2 does not, and its
    std is below a millisecond."""
    est, gyro = _yaw_problem(1e-4)
    with pytest.warns(RuntimeWarning, match=r"Gyro.time_offset is barely excited by the motion"):
        s = float(est.std(gyro, "time_offset"))
    assert s > 0.01
    est, gyro = _yaw_problem(0.2)
    s = float(est.std(gyro, "time_offset"))  # no warning: pytest makes it an error
    assert s < 1e-3 and abs(float(gyro.time_offset) - 0.02) < 4 * s


def test_starts_0_5_and_90_deg_apart_agree_within_a_tenth_of_a_std():
    """Issue 31's 'done when': one data set solved from three starts (a batch of three
    identical problems): the extrinsic at the truth, 5 deg / 10 cm off and 90 deg / 10 cm
    off, with the biases and the clock offset started apart too. Every estimated nuisance
    coordinate (extrinsic rotation and translation, both biases, the offset) agrees with
    the first start's within 0.1 of its standard deviation, and the truth is within 4."""
    gen = torch.Generator().manual_seed(8)
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = torch.linspace(0.15, 2.85, 271, dtype=F64)
    cam, gy, ac = (v.expand(3, *v.shape[1:]) for v in
                   _draws(1, gen, tc, ti, 0.002, 0.002, 0.005, 0.05))
    e = dq.exp(E_TRUE)
    axis = torch.tensor([1.0, 2.0, -1.0], dtype=F64) / 6**0.5
    trans = torch.tensor([0.06, -0.06, 0.05], dtype=F64)
    turns = [dq.exp(torch.cat((a * axis, b * trans))) for a, b in
             ((0.0, 0.0), (np.radians(5), 1.0), (np.radians(90), 1.0))]
    starts = torch.stack([dq.mul(e, t) for t in turns])
    spline = BSpline.from_dualquats(dq.mul(cam, dq.conj(starts[:, None])), tc, n_ctrl=33,
                                    form="cumulative")
    clock = Free(torch.tensor([0.0, 0.005, -0.005], dtype=F64))
    b0 = torch.tensor([[0.0] * 3, [0.02] * 3, [-0.02] * 3], dtype=F64)
    terms = [Poses(tc, cam, rot_sigma=0.002, trans_sigma=0.002, extrinsic=Free(starts)),
             Gyro(ti, gy, sigma=0.005, bias=Free(b0), time_offset=clock),
             Accel(ti, ac, sigma=0.05, bias=Free(10 * b0), time_offset=clock)]
    with pytest.warns(RuntimeWarning, match="Accel.time_offset is estimated on a degree-3"):
        est = estimate(spline, terms, verbose=False)
    assert bool(est.converged.all()), est.reason
    ext = dq.log(dq.mul(dq.conj(e), terms[0].extrinsic))
    found = {"extrinsic": (ext, est.std(terms[0], "extrinsic"), 0.0),
             "gyro bias": (terms[1].bias, est.std(terms[1], "bias"), torch.from_numpy(BG)),
             "accel bias": (terms[2].bias, est.std(terms[2], "bias"), torch.from_numpy(BA)),
             "time offset": (terms[1].time_offset, est.std(terms[1], "time_offset"), OFFSET)}
    for name, (value, std, truth) in found.items():
        assert bool(((value[1:] - value[0]).abs() < 0.1 * std[0]).all()), (
            name, (value[1:] - value[0]) / std[0])
        assert bool(((value[0] - truth).abs() < 4 * std[0]).all()), (name, value[0], truth)


# ----------------------------------------------------------------- gravity and a lever arm

LEVER = np.array([0.3, -0.2, 0.15])  # a measured point (prism, antenna) in body axes


def _lever_draws(S, gen, tc, ti):
    """``S`` noisy copies: camera poses of the body (2 mm, 2 mrad), positions of the point
    at ``LEVER`` (2 mm), gyroscope (5 mrad/s) and accelerometer (0.05 m/s^2) with biases."""
    R, p, _, _ = motion(tc.numpy())
    x = dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p))
    q, pos = dq.to_rt(x.expand(S, -1, -1))
    noise = lambda s, *shape: s * torch.randn(*shape, generator=gen, dtype=F64)  # noqa: E731
    cam = dq.from_rt(quat.mul(q, quat.from_rotvec(noise(0.002, *q.shape[:-1], 3))),
                     pos + noise(0.002, *pos.shape))
    point = torch.from_numpy(p + R.apply(LEVER))
    R, _, w, acc = motion(ti.numpy())
    gy = torch.from_numpy(R.inv().apply(w) + BG)
    ac = torch.from_numpy(R.inv().apply(acc - G) + BA)
    return (cam, point + noise(0.002, S, *point.shape), gy + noise(0.005, S, *gy.shape),
            ac + noise(0.05, S, *ac.shape))


def _lever_problem(data, tc, ti, lever, gravity, bias=None):
    """Poses, Positions with the lever arm estimated from ``lever``, Gyro and Accel with
    biases (from ``bias``, gyro's tenfold smaller) and gravity's direction from ``gravity``
    (its norm kept): the estimate and the terms."""
    cam, point, gy, ac = data
    spline = BSpline.from_dualquats(cam, tc, n_ctrl=33, form="cumulative")
    gb, ab = (True, True) if bias is None else (Free(0.1 * bias), Free(bias))
    terms = [Poses(tc, cam, rot_sigma=0.002, trans_sigma=0.002),
             Positions(tc, point, sigma=0.002, lever_arm=Free(lever)),
             Gyro(ti, gy, sigma=0.005, bias=gb),
             Accel(ti, ac, sigma=0.05, bias=ab, gravity=Free(gravity))]
    est = estimate(spline, terms, verbose=False)
    assert bool(est.converged.all()), est.reason
    return est, terms


def _lever_found(est, terms):
    """name: (value, std) of the lever arm, gravity's horizontal components (world x, y:
    its 2-d chart; the vertical one moves only to second order), both biases."""
    return {"lever arm": (terms[1].lever_arm, est.std(terms[1], "lever_arm")),
            "gravity x, y": (terms[3].gravity[..., :2], est.std(terms[3], "gravity")[..., :2]),
            "gyro bias": (terms[2].bias, est.std(terms[2], "bias")),
            "accel bias": (terms[3].bias, est.std(terms[3], "bias"))}


def gravity_lever_ratios(S=50, seed=3):
    """Scatter over ``S`` draws (one batch) over the root-mean-square reported std, per
    coordinate, started 5 deg (gravity) and 10 cm (lever arm) off."""
    gen = torch.Generator().manual_seed(seed)
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = torch.linspace(0.15, 2.85, 271, dtype=F64)
    g0 = quat.rotate(quat.from_rotvec(torch.tensor([0.06, -0.06, 0.0], dtype=F64)),
                     torch.from_numpy(G))
    lever0 = torch.from_numpy(LEVER) + torch.tensor([0.06, -0.06, 0.05], dtype=F64)
    est, terms = _lever_problem(_lever_draws(S, gen, tc, ti), tc, ti, lever0, g0)
    return {k: v.std(0) / (s**2).mean(0).sqrt() for k, (v, s) in _lever_found(est, terms).items()}


@pytest.mark.slow
def test_gravity_and_lever_arm_stds_match_a_monte_carlo_scatter():
    """Issue 31's 'done when' for gravity's direction and a Positions lever arm (and both
    biases beside them): 50 draws, the scatter over the reported std in [0.7, 1.4] for every
    coordinate (measured: lever arm 0.94 0.92 0.98, gravity 1.05 1.15, gyro bias 0.84 1.16
    0.96, accel bias 1.18 0.89 0.96)."""
    for name, ratio in gravity_lever_ratios().items():
        assert bool(((ratio > 0.7) & (ratio < 1.4)).all()), (name, ratio)


def test_gravity_and_lever_arm_from_starts_90_deg_and_10_cm_apart_agree():
    """One data set from three starts (a batch): gravity at the truth, 5 deg and 90 deg off
    (about a horizontal axis), the lever arm at the truth and 10 cm off either way, the
    biases apart. Every coordinate agrees with the first start's within 0.1 std (measured
    2e-4), the truth is within 4. The 90 deg start about this axis ended in the
    flipped-gravity local minimum (168.9 deg off, Accel chi2 60913 against 799) before
    Accel took the mean-reading direction where it explains the readings better."""
    gen = torch.Generator().manual_seed(8)
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = torch.linspace(0.15, 2.85, 271, dtype=F64)
    data = [v.expand(3, *v.shape[1:]) for v in _lever_draws(1, gen, tc, ti)]
    axis = torch.tensor([1.0, 2.0, 0.0], dtype=F64) / 5**0.5
    g0 = torch.stack([quat.rotate(quat.from_rotvec(np.radians(a) * axis), torch.from_numpy(G))
                      for a in (0.0, 5.0, 90.0)])
    shift = torch.tensor([0.0, 1.0, -1.0], dtype=F64)[:, None] * torch.tensor(
        [0.06, -0.06, 0.05], dtype=F64)  # 9.8 cm
    bias = torch.tensor([[0.0] * 3, [0.2] * 3, [-0.2] * 3], dtype=F64)
    est, terms = _lever_problem(data, tc, ti, torch.from_numpy(LEVER) + shift, g0, bias)
    truth = {"lever arm": LEVER, "gravity x, y": G[:2], "gyro bias": BG, "accel bias": BA}
    for name, (value, std) in _lever_found(est, terms).items():
        assert bool(((value[1:] - value[0]).abs() < 0.1 * std[0]).all()), (
            name, (value[1:] - value[0]) / std[0])
        assert bool(((value[0] - torch.from_numpy(truth[name])).abs() < 4 * std[0]).all()), (
            name, value[0])


def test_a_gravity_start_far_off_gives_way_to_the_mean_reading():
    """Accel's start values: a caller's gravity start 90 deg off is replaced by the
    mean-reading direction (within 3 deg of the truth here: the biases and accelerations
    tilt it), its norm kept; a start at the truth is kept as given; once estimated, the
    estimate is kept (a second estimate continues from it)."""
    gen = torch.Generator().manual_seed(8)
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = torch.linspace(0.15, 2.85, 271, dtype=F64)
    cam, _, _, ac = _lever_draws(1, gen, tc, ti)
    spline = BSpline.from_dualquats(cam, tc, n_ctrl=33, form="cumulative")
    truth = torch.from_numpy(G)
    far = torch.tensor([0.0, 9.0, 0.0], dtype=F64)  # 90 deg off, another norm
    for start, near in ((far, True), (truth, False)):
        accel = Accel(ti, ac, sigma=0.05, bias=True, gravity=Free(start))
        g = accel.values(spline)["gravity"].reshape(3)
        assert abs(float(g.norm()) - float(start.norm())) < 1e-12
        angle = np.degrees(float(torch.acos((g @ truth) / (g.norm() * truth.norm()))))
        assert (angle < 3.0) if near else torch.equal(g, start), (angle, g)
    accel.slots()["gravity"].free.value = far.clone()
    assert torch.equal(accel.values(spline)["gravity"].reshape(3), far)


# ----------------------------------------------------------------- clock offsets on knots
# not aligned with the samples

def _clock(side, gen, degree=3, steps=50):
    """Camera poses (20 Hz) stamped 4.3 ms early (they show the motion at t + 4.3 ms) and an
    IMU (100 Hz, from 0.013 s) on its own clock; knots every 0.037 s from 0.01 s before the
    first pose: no knot falls on a sample, neither period nor the offset is a multiple of the
    spacing. ``side``: the offset estimated on the camera's term or on the IMU's."""
    tc = torch.linspace(0.0, 3.0, 61, dtype=F64)
    ti = 0.013 + 0.01 * torch.arange(297, dtype=F64)
    R, p, _, _ = motion(tc.numpy() + 0.0043)
    x = dq.mul(dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p)),
               dq.exp(E_TRUE))
    q, pos = dq.to_rt(x)
    cam = dq.from_rt(quat.mul(q, quat.from_rotvec(0.002 * torch.randn(
        61, 3, generator=gen, dtype=F64))), pos + 0.002 * torch.randn(61, 3, generator=gen,
                                                                      dtype=F64))
    R, _, w, acc = motion(ti.numpy())
    gy = torch.from_numpy(R.inv().apply(w) + BG) + 0.005 * torch.randn(297, 3, generator=gen,
                                                                       dtype=F64)
    ac = torch.from_numpy(R.inv().apply(acc - G) + BA) + 0.05 * torch.randn(
        297, 3, generator=gen, dtype=F64)
    e = dq.exp(E_TRUE)
    qs, ps = dq.to_rt(dq.mul(cam, dq.conj(e)))
    spline = BSpline.from_poses(qs, ps, tc, form="cumulative", knot_spacing=0.037,
                                margin=0.02, degree=degree)
    cam_clock, imu_clock = (Free(0.0), None) if side == "camera" else (None, Free(0.0))
    terms = [Poses(tc, cam, rot_sigma=0.002, trans_sigma=0.002, extrinsic=Free(e),
                   time_offset=cam_clock, max_time_offset=0.02),
             Gyro(ti, gy, sigma=0.005, bias=True, time_offset=imu_clock,
                  max_time_offset=0.02),
             Accel(ti, ac, sigma=0.05, bias=True, time_offset=imu_clock,
                   max_time_offset=0.02)]
    est = estimate(spline, terms, steps=steps, verbose=False)
    term = terms[0] if side == "camera" else terms[1]
    std = float(est.std(term, "time_offset")) if steps else float("nan")  # steps=0: the start
    return est, float(term.time_offset), std



@pytest.fixture(scope="module")
def camera_side():
    """The camera-side solve on the cubic (once): estimate, offset, its std."""
    return _clock("camera", torch.Generator().manual_seed(9))


def test_camera_side_offset_on_misaligned_knots(camera_side):
    """Issue 31 (EuRoC-like): a camera clock 4.3 ms late, estimated on the camera's term on
    knots aligned with no sample: converged, within 4 std of the truth, std below 1 ms
    (measured 5.29 +- 0.94 ms)."""
    est, cam, s_cam = camera_side
    assert bool(est.converged), est.reason
    assert abs(cam - 0.0043) < 4 * s_cam and s_cam < 1e-3, (cam, s_cam)


def test_imu_side_offset_on_a_cubic_warns_naming_the_fix():
    """Issue 31: an IMU-side offset on knots not aligned with the samples ended at 31.95 +-
    0.017 ms for 4 ms with nothing warning; on this case's cubic the solve stopped at 'no
    damped step lowers the objective' 0.23 std short (a cubic's accelerations are only C0 in
    time: the Accel cost kinks in the offset as samples cross knots). estimate now warns,
    naming Accel.time_offset, the curve and the fix (degree >= 4)."""
    with pytest.warns(RuntimeWarning, match=r"Accel\.time_offset is estimated on a degree-3 "
                                            r"B-spline of form='cumulative'.*degree >= 4"):
        _clock("imu", torch.Generator().manual_seed(9), steps=0)


def test_imu_side_offset_on_misaligned_knots_converges_on_a_quartic(camera_side):
    """The same IMU-side offset on a quartic cumulative B-spline (accelerations C1 in time:
    the Accel cost is smooth in the offset), no warning: converged, -4.3 ms within 4 std,
    agreeing with the camera side's within 4 std of their difference (measured -6.11 +-
    0.78 ms against 5.29 +- 0.94 ms)."""
    est, imu, s_imu = _clock("imu", torch.Generator().manual_seed(9), degree=4)
    assert bool(est.converged), est.reason
    assert abs(imu + 0.0043) < 4 * s_imu and s_imu < 1e-3, (imu, s_imu)
    _, cam, s_cam = camera_side
    assert abs(cam + imu) < 4 * (s_cam**2 + s_imu**2) ** 0.5, (cam, imu, s_cam, s_imu)

"""``calibration.camera_imu`` as an outside suite would run it: synthetic rigs from analytic
motions (``_calib12_rig``: numpy / scipy / OpenCV, no torch_dq), default settings and no
guess, the results against the truth within a few of the returned standard deviations, and
Kalibr's conventions of ``to_kalibr()`` derived here from the truth."""

import numpy as np
import pytest
import torch
from _calib12_rig import DS, EQUI, HEIGHT, RADTAN, WIDTH, Cam, make_rig, rot
from scipy.spatial.transform import Rotation

from torch_dq import dualquat
from torch_dq.calibration import camera_imu
from torch_dq.camera import Camera

pytest.importorskip("cv2")

SIGMA_PX = 0.3
# Records of 4 s (the rig's default is 8 s): about two periods of every motion frequency
# (0.55-1.1 Hz), half the knots and corners, so half the time. The checks are in standard
# deviations (which grow by sqrt(2): the z-scores keep their law) and the RMS of 0.3 px
# noise over ~7000 corners (1 % of spread); measured at 4 s: |z| 2.9 at most, the RMS
# within 0.9 %, the Monte Carlo's ratios in [0.52, 1.78].
DURATION = 4.0


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


def run(rig, **kw):
    cams = [Camera(c.model, _t(c.params), (WIDTH, HEIGHT)) for c in rig.cams]
    obs = [tuple(map(_t, o)) for o in rig.observations]
    kw.setdefault("pixel_sigma", SIGMA_PX)
    return camera_imu(cams, obs, tuple(map(_t, rig.imu)), gyro_noise=rig.gyro_noise,
                      accel_noise=rig.accel_noise, **kw)


def errors(res, rig) -> tuple[np.ndarray, np.ndarray]:
    """(errors, stds) of every estimated value: per camera the extrinsic in the chart
    ``e exp(delta)`` (rotation vector of ``R_true^T R``, then ``R_true^T (t - t_true)``, both
    camera axes, to first order), the time offset and the line delay; then the biases and
    gravity (its two directions across the true vector)."""
    err, std = [], []
    for i, c in enumerate(rig.cams):
        M = dualquat.to_matrix(res.extrinsics[i]).numpy()
        err += [*Rotation.from_matrix(c.R_bc.T @ M[:3, :3]).as_rotvec(),
                *(c.R_bc.T @ (M[:3, 3] - c.t_bc)), float(res.time_offsets[i]) - c.dt]
        std += [*res.std["extrinsics"][i].numpy(), float(res.std["time_offsets"][i])]
        if c.line_delay:
            err.append(float(res.line_delays[i]) - c.line_delay)
            std.append(float(res.std["line_delays"][i]))
    err += [*(res.gyro_bias.numpy() - rig.gyro_bias), *(res.accel_bias.numpy() - rig.accel_bias)]
    std += [*res.std["gyro_bias"].numpy(), *res.std["accel_bias"].numpy()]
    g, sg = res.gravity.numpy(), res.std["gravity"].numpy()
    assert abs(np.linalg.norm(g) - np.linalg.norm(rig.gravity)) < 1e-9
    across = np.flatnonzero(rig.gravity == 0)  # along an axis: the others show its direction
    assert across.size == 2
    err += list((g - rig.gravity)[across])
    std += list(sg[across])
    return np.array(err), np.array(std)


def check(res, rig, zmax=4.0):
    err, std = errors(res, rig)
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    z = err / std
    assert np.abs(z).max() < zmax, np.round(z, 2)
    assert bool(res.estimate.converged), res.estimate.reason
    # the RMS of the pixel error's norm: sqrt(2) sigma for isotropic noise
    np.testing.assert_allclose(res.reprojection_rms.numpy(), np.sqrt(2) * SIGMA_PX, rtol=0.05)
    return z


def kalibr_conventions(res, rig):
    """``to_kalibr()`` against Kalibr's conventions written from the truth: ``p_cam =
    T_cam_imu p_imu``, ``p_cn = T_cn_cnm1 p_cnm1``, ``t_imu = t_cam + timeshift_cam_imu``."""
    chain = res.to_kalibr()
    for i, c in enumerate(rig.cams):
        T = np.array(chain[f"cam{i}"]["T_cam_imu"])
        p_imu = np.array([0.3, -0.2, 0.5])
        p_cam = c.R_bc.T @ (p_imu - c.t_bc)
        np.testing.assert_allclose(T[:3, :3] @ p_imu + T[:3, 3], p_cam, atol=5e-3)
        np.testing.assert_allclose(T[3], [0, 0, 0, 1])
        assert abs(chain[f"cam{i}"]["timeshift_cam_imu"] - c.dt) < 1e-3
        if i:
            prev = rig.cams[i - 1]
            R = c.R_bc.T @ prev.R_bc
            t = c.R_bc.T @ (prev.t_bc - c.t_bc)
            Tn = np.array(chain[f"cam{i}"]["T_cn_cnm1"])
            assert np.degrees(Rotation.from_matrix(Tn[:3, :3] @ R.T).magnitude()) < 0.1
            np.testing.assert_allclose(Tn[:3, 3], t, atol=3e-3)


CAM_TILTED = Cam("pinhole-radtan", RADTAN, rot("x", 90), np.array([0.1, 0.0, 0.02]), 0.012)


def test_one_camera_tilted_lever_arm():
    """A radtan camera tilted 90 degrees, 10 cm off the IMU, 12 ms late."""
    rig = make_rig([CAM_TILTED], seed=0, duration=DURATION)
    res = run(rig)
    check(res, rig)
    kalibr_conventions(res, rig)
    assert res.line_delays.tolist() == [0.0]


def test_two_cameras_own_offsets_default_sigma():
    """A radtan and a double-sphere camera with offsets of opposite signs, every setting
    at its default (``pixel_sigma`` 1 px against 0.3 px noise: the stds are larger, the
    values the same, and a warning says so)."""
    cams = [Cam("pinhole-radtan", RADTAN, rot("x", 90), np.array([0.1, 0.0, 0.02]), 0.008),
            Cam("double-sphere", DS, rot("x", 90) @ rot("y", 5), np.array([0.21, 0.0, 0.02]),
                -0.015)]
    rig = make_rig(cams, seed=1, duration=DURATION)
    with pytest.warns(RuntimeWarning, match="chi2/dof far below 1"):  # said, not hidden
        res = run(rig, pixel_sigma=1.0)
    err, std = errors(res, rig)
    assert np.abs(err / std).max() < 4
    np.testing.assert_allclose(res.reprojection_rms.numpy(), np.sqrt(2) * SIGMA_PX, rtol=0.05)
    kalibr_conventions(res, rig)


def test_equidistant_upside_down_early():
    """A fisheye (equidistant) camera rolled 90 degrees and pitched, 20 ms early."""
    cam = Cam("pinhole-equidistant", EQUI, rot("xz", [90, 90]), np.array([0.0, 0.1, -0.03]),
              -0.02)
    rig = make_rig([cam], seed=2, duration=DURATION)
    res = run(rig)
    check(res, rig)
    kalibr_conventions(res, rig)


def test_rolling_shutter_line_delay():
    """Each row at ``t + dt + line_delay * v`` (30 us per row: 14 ms per frame)."""
    cam = Cam("pinhole-radtan", RADTAN, rot("x", 90), np.array([0.1, 0.0, 0.02]), 0.005, 3e-5)
    rig = make_rig([cam], seed=4, duration=DURATION)
    res = run(rig, rolling_shutter=True)
    check(res, rig)
    assert abs(float(res.line_delays[0]) - 3e-5) < 1e-6
    assert res.to_kalibr()["cam0"]["line_delay"] == pytest.approx(3e-5, abs=1e-6)


def test_milliseconds_named_as_milliseconds():
    """IMU times in milliseconds: the error says milliseconds (it said nanoseconds, and
    to divide by 1e9)."""
    rig = make_rig([CAM_TILTED], seed=0, duration=3.0)
    t, g, a = rig.imu
    rig.imu = (t * 1e3, g, a)
    with pytest.raises(ValueError, match=r"imu times look like milliseconds.*1e\+03"):
        run(rig)


def test_gravity_magnitude_given():
    """A simulation with standard gravity 9.80665 (scipy.constants.g): given its magnitude,
    every value within 4 standard deviations (the default 9.81 put the accelerometer bias
    along gravity 6 of them off); a magnitude that is not positive is an error naming it."""
    rig = make_rig([CAM_TILTED], seed=0, duration=DURATION,
                   gravity=np.array([0.0, -9.80665, 0.0]))
    check(run(rig, gravity_magnitude=9.80665), rig)
    with pytest.raises(ValueError, match="gravity_magnitude"):
        run(rig, gravity_magnitude=-9.81)


@pytest.mark.slow
def test_std_honest_monte_carlo():
    """Over 6 noise draws the RMS error of each value is within a factor 2 of its reported
    standard deviation (6 draws: the RMS of 6 unit normals lies in [0.4, 1.7] with 99 %)."""
    errs, stds = [], []
    for seed in range(10, 16):
        rig = make_rig([CAM_TILTED], seed=seed, duration=DURATION)
        e, s = errors(run(rig), rig)
        errs.append(e)
        stds.append(s)
    ratio = np.sqrt(np.mean(np.square(errs), 0)) / np.mean(stds, 0)
    assert np.all(ratio < 2.0) and np.all(ratio > 0.35), np.round(ratio, 2)


@pytest.mark.parametrize("mix", [[[0, 1, 0], [1, 0, 0], [0, 0, 1]], np.diag([1, 1, -1])],
                         ids=["xy-swapped", "z-flipped"])
def test_left_handed_gyro_is_an_error(mix):
    """A gyroscope log with two columns swapped or one sign flipped (left-handed axes): no
    rotation maps the camera's rates onto it; an error saying so (it ran the estimate into
    a misfit of chi2/dof ~2000, a warning only)."""
    rig = make_rig([CAM_TILTED], seed=0, duration=4.0)
    t, g, a = rig.imu
    rig.imu = (t, g @ np.asarray(mix, float).T, a)
    with pytest.raises(ValueError, match=r"reflection, not a rotation.*left-handed"):
        run(rig)


def test_imu_log_covering_half_the_frames():
    """An IMU log that starts 2 s after the first frame and ends 2 s before the last (8 s
    of frames): calibrated from the overlap (the start correlated the frames outside the
    log too and stopped at "the IMU log is not this recording's", correlation 0.27)."""
    rig = make_rig([CAM_TILTED], seed=0)
    t, g, a = rig.imu
    inside = (t > t[0] + 2.0) & (t < t[-1] - 2.0)
    rig.imu = (t[inside], g[inside], a[inside])
    check(run(rig), rig)

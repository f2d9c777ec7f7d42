"""A new user's camera-IMU calibration from far starts (outside8), against an independent truth.

The truth (``tests/_outside8_rig.py``, numpy only): closed-form body motion, a camera 150 deg
and 0.3 m away from the IMU's axes, 30 ms of clock offset, gyroscope and accelerometer
biases, EuRoC's noise densities, 0.3 px corner noise. ``camera_imu`` takes no start: the
library's defaults (identity extrinsic, zero offset) are that far from the truth. Checked:
the generator against finite differences; convergence to the truth within a small fraction
of the reported standard deviations on nearly noise-free data; the honesty of those
standard deviations (RMS of error / std over noise seeds near 1); a rolling shutter's line
delay; the Kalibr camchain written and read back; argument errors.
"""

import math
import os
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torch_dq import calibration, dualquat
from torch_dq.camera import Camera

sys.path.insert(0, os.path.dirname(__file__))
import _outside8_rig as rig

R_BC = Rotation.from_rotvec(math.radians(150) * np.array([1.0, 2.0, -1.0]) / math.sqrt(6))
T_BC = np.array([0.2, -0.2, 0.1])  # 0.3 m from the IMU
OFFSET = 0.03
BG, BA = np.array([0.01, -0.02, 0.015]), np.array([0.1, -0.05, 0.08])
GYRO, ACCEL, PIXEL = 1.7e-4, 2.0e-3, 0.3  # EuRoC's ADIS16448 densities, corner noise (px)
RADTAN = np.array([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
                   1.76187114e-05])
EQUI = np.array([380.0, 380.0, 376.0, 240.0, 0.01, -0.005, 0.002, -0.001])
RES = (752, 480)
RIG = rig.Rig(R_BC.as_matrix(), T_BC)


def _calibrate(model, seed, *, line_delay=0.0, noise=1.0, duration=3.0):
    intr, proj = (RADTAN, rig.radtan) if model == "pinhole-radtan" else (EQUI, rig.equidistant)
    imu, obs = rig.simulate(RIG, intr, proj, RES, duration=duration, offset=OFFSET,
                            line_delay=line_delay, pixel_sigma=PIXEL * noise,
                            gyro_density=GYRO * noise, accel_density=ACCEL * noise, bg=BG,
                            ba=BA, seed=seed)
    cam = Camera(model, torch.tensor(intr), RES)
    res = calibration.camera_imu([cam], [tuple(torch.tensor(a) for a in obs)],
                                 tuple(torch.tensor(a) for a in imu), gyro_noise=GYRO,
                                 accel_noise=ACCEL, pixel_sigma=PIXEL,
                                 rolling_shutter=line_delay > 0)
    return res, len(obs[0])


def _z(res, line_delay=None):
    """(error, std) of every estimated value, errors in the result's own charts: the
    extrinsic's ``e exp(delta)`` (rotation, then translation in camera axes)."""
    E = dualquat.to_matrix(res.extrinsics[0]).numpy()
    d_rot = Rotation.from_matrix(E[:3, :3].T @ R_BC.as_matrix()).as_rotvec()
    d_pos = E[:3, :3].T @ (T_BC - E[:3, 3])
    err = [d_rot, d_pos, [float(res.time_offsets[0]) - OFFSET], res.gyro_bias.numpy() - BG,
           res.accel_bias.numpy() - BA]
    std = [res.std["extrinsics"][0].numpy(), [float(res.std["time_offsets"][0])],
           res.std["gyro_bias"].numpy(), res.std["accel_bias"].numpy()]
    if line_delay is not None:
        err.append([float(res.line_delays[0]) - line_delay])
        std.append([float(res.std["line_delays"][0])])
    return np.concatenate(err), np.concatenate(std)


def test_truth_generator_against_finite_differences():
    t, h = np.array([0.4, 1.3, 2.2]), 1e-5
    Rm, Rp = RIG.rotation(t - h), RIG.rotation(t + h)
    w = Rotation.from_matrix(np.einsum("tji,tjk->tik", Rm, Rp)).as_rotvec() / (2 * h)
    np.testing.assert_allclose(w, RIG.gyro(t), atol=1e-8)
    acc = (RIG.position(t + h) - 2 * RIG.position(t) + RIG.position(t - h)) / h ** 2
    np.testing.assert_allclose(acc, RIG.position(t, 2), atol=1e-4)
    R = RIG.rotation(t)
    np.testing.assert_allclose(np.einsum("tji,tjk->tik", R, R), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-14)


@pytest.fixture(scope="module")
def quiet_fit():
    """Nearly noise-free data (1 % of the stated noise), the stated noise passed: the
    residuals' chi2/dof is far below 1, which the estimate reports."""
    with pytest.warns(RuntimeWarning, match="chi2/dof far below 1"):
        return _calibrate("pinhole-radtan", 0, noise=0.01)


def test_far_start_converges_to_the_truth(quiet_fit):
    """150 deg, 0.3 m, 30 ms from the defaults: every value ends within a tenth of its
    reported standard deviation."""
    res, n = quiet_fit
    err, std = _z(res)
    assert n > 4000
    assert np.all(np.isfinite(std)) and np.all(std > 0)
    assert np.abs(err / std).max() < 0.1, (err / std).round(3)
    assert float(res.reprojection_rms[0]) < 0.02


def test_standard_deviations_are_honest():
    """RMS of error / std over 4 noise seeds and 13 values (52 draws): near 1 (the 95 %
    interval of a chi with 52 degrees of freedom over sqrt(52) is [0.81, 1.19]; wider
    bounds for the error of the std itself); no single value beyond 4 std."""
    z = np.concatenate([np.divide(*_z(_calibrate("pinhole-radtan", seed)[0]))
                        for seed in range(4)])
    assert np.abs(z).max() < 4.0, z.round(2)
    assert 0.7 < math.sqrt(float(np.mean(z ** 2))) < 1.35, z.round(2)


def test_rolling_shutter_equidistant_from_a_far_start():
    """A Kannala-Brandt camera with a 30 us/row rolling shutter: the line delay (started at
    0 by the library) and the rest within 4 std; the residual at the noise level."""
    delay = 3e-5
    res, _ = _calibrate("pinhole-equidistant", 1, line_delay=delay)
    err, std = _z(res, delay)
    assert np.abs(err / std).max() < 4.0, (err / std).round(2)
    assert float(res.std["line_delays"][0]) < 0.05 * delay
    assert abs(float(res.reprojection_rms[0]) - PIXEL * math.sqrt(2)) < 0.03


def test_camchain_imucam_round_trip(tmp_path, quiet_fit):
    yaml = pytest.importorskip("yaml")
    res, _ = quiet_fit
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(yaml.safe_dump(res.to_kalibr(["/cam0/image_raw"])))
    entry = yaml.safe_load(path.read_text())["cam0"]
    assert Camera.from_kalibr(entry) == res.cameras[0]
    T = np.array(entry["T_cam_imu"])  # Kalibr: p_cam = T_cam_imu p_imu
    E = dualquat.to_matrix(res.extrinsics[0]).numpy()
    np.testing.assert_allclose(T @ E, np.eye(4), atol=1e-14)
    np.testing.assert_allclose(np.linalg.inv(T)[:3, :3], R_BC.as_matrix(), atol=1e-5)  # 0.1 std
    assert entry["timeshift_cam_imu"] == float(res.time_offsets[0])
    assert abs(entry["timeshift_cam_imu"] - OFFSET) < 1e-5  # Kalibr's sign
    with pytest.raises(ValueError, match="rostopics"):
        res.to_kalibr(["/cam0", "/cam1"])


@pytest.fixture(scope="module")
def short_data():
    imu, obs = rig.simulate(RIG, RADTAN, rig.radtan, RES, duration=2.0, offset=OFFSET,
                            line_delay=0.0, pixel_sigma=PIXEL, gyro_density=GYRO,
                            accel_density=ACCEL, bg=BG, ba=BA, seed=3)
    cam = Camera("pinhole-radtan", torch.tensor(RADTAN), RES)
    return cam, tuple(torch.tensor(a) for a in obs), tuple(torch.tensor(a) for a in imu)


@pytest.mark.parametrize("value", [-1e-5, 0.0, math.nan, "1e-4"])
def test_max_line_delay_is_checked_and_named(short_data, value):
    cam, obs, imu = short_data
    with pytest.raises(ValueError, match="camera_imu: expected max_line_delay"):
        calibration.camera_imu([cam], [obs], imu, gyro_noise=GYRO, accel_noise=ACCEL,
                               rolling_shutter=True, max_line_delay=value)


def test_a_target_off_the_plane_is_refused(short_data):
    """The start is a homography of ``Z = 0``: points off it (here 1 cm) are refused as
    ``calibration.cameras`` refuses them, instead of a silently wrong start."""
    cam, (t, p, u), imu = short_data
    p = p.clone()
    p[::7, 2] = 0.01
    with pytest.raises(ValueError, match=r"camera_imu: expected a planar .*observations\[0\]"):
        calibration.camera_imu([cam], [(t, p, u)], imu, gyro_noise=GYRO, accel_noise=ACCEL)

"""A new user's IMU units checks from a start at rest (user12): a gyroscope in deg/s with an
identity start spline and poses (the start tells nothing of the rates: the measured poses do),
an accelerometer in milli-g. The truth is a numpy screw motion about z (body rate (0, 0, w))."""

import math
import warnings

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import curves, nn
from torch_dq.fitting import Accel, Gyro, Poses, estimate

F64 = torch.float64
W, RADIUS, T = 0.5, 1.0, 4.0


def _data():
    tc = np.linspace(0.0, T, 41)
    ti = np.linspace(0.05, T - 0.05, 200)
    half = 0.5 * W * tc
    q = np.stack((np.cos(half), 0 * half, 0 * half, np.sin(half)), -1)
    p = np.stack((RADIUS * np.cos(W * tc), RADIUS * np.sin(W * tc), 0.1 * tc), -1)
    poses = dq.from_rt(torch.tensor(q), torch.tensor(p))
    gyro = np.tile([0.0, 0.0, W], (len(ti), 1))  # R^T w, rotation about z
    # R^T (a - g): centripetal W^2 R toward the axis is (-W^2 R, 0, 0) in body axes
    accel = np.tile([-W * W * RADIUS, 0.0, 9.81], (len(ti), 1))
    return torch.tensor(tc), poses, torch.tensor(ti), torch.tensor(gyro), torch.tensor(accel)


def _identity_start(n=12):
    knots = curves.clamped_uniform_knots(n, 3, dtype=F64, domain=(0.0, T))
    return nn.BSpline(dq.identity((n,), dtype=F64), knots=knots, form="cumulative")


def _run(gyro_scale=1.0, accel_scale=1.0):
    tc, poses, ti, gyro, accel = _data()
    terms = [Poses(tc, poses, rot_sigma=1e-3, trans_sigma=1e-3),
             Gyro(ti, gyro * gyro_scale, sigma=1e-3, bias=True),
             Accel(ti, accel * accel_scale, sigma=1e-2, bias=True)]
    return estimate(_identity_start(), terms, steps=0, verbose=False)


def test_analytic_readings_match_a_fitted_spline():
    """The test's numpy IMU readings are those of the motion (independent check of _data)."""
    tc, poses, ti, gyro, accel = _data()
    spline = nn.BSpline.from_dualquats(poses, tc, n_ctrl=30, form="cumulative")
    with torch.no_grad():
        g, a = spline.imu(ti[20:-20])
    assert torch.allclose(g, gyro[20:-20], atol=1e-4)
    assert torch.allclose(a, accel[20:-20], atol=1e-3)


def test_deg_per_s_gyro_warns_from_an_identity_start():
    """Before the fix the identity start (no rotation rate) silenced the check and the solve
    ended 'no progress', not converged, biases of 5-16 rad/s, without any warning."""
    with pytest.warns(UserWarning, match=r"look like deg/s.*measured poses' angular rate"):
        _run(gyro_scale=180.0 / math.pi)


def test_rad_per_s_gyro_from_an_identity_start_does_not_warn():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _run()


def test_milli_g_accelerometer_warns():
    with pytest.warns(UserWarning, match=r"look like milli-g.*multiply them by 0\.00980665"):
        _run(accel_scale=1000.0 / 9.80665)


def test_g_accelerometer_still_warns():
    with pytest.warns(UserWarning, match=r"look like g, not m/s.*multiply them by 9\.80665"):
        _run(accel_scale=1.0 / 9.80665)


def test_read_imu_names_a_milli_g_accelerometer(tmp_path):
    """A plain ``t gx gy gz ax ay az`` file at 200 Hz at rest, the accelerometer in milli-g
    (1000 / 9.80665 per m/s^2) warns and names the factor; in m/s^2 it does not."""
    from torch_dq import io
    t = np.arange(400) / 200.0
    rows = np.column_stack((t, np.zeros((400, 3)), np.tile([0.0, 0.0, 9.81], (400, 1))))
    rows[:, 4:] += 0.01 * np.random.default_rng(0).standard_normal((400, 3))
    path = tmp_path / "imu.txt"
    np.savetxt(path, rows)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        io.read_imu(path)
    rows[:, 4:] *= 1000.0 / 9.80665
    np.savetxt(path, rows)
    with pytest.warns(UserWarning, match=r"look like milli-g.*multiply them by 0\.00980665"):
        _, _, accel = io.read_imu(path)
    assert abs(float(accel[:, 2].mean()) - 1000.0 * 9.81 / 9.80665) < 1.0  # read as written

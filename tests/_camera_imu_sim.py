"""Simulated camera-IMU rig for tests/test_camera_imu.py and benchmarks/bench_calibration.py:
closed-form motion (sums of sines in a rotation vector and a position), two EuRoC-like
pinhole-radtan cameras seeing an AprilGrid, corners projected by OpenCV (``cv2.projectPoints``
of points moved into each camera by numpy/scipy: independent of torch_dq), an IMU at 200 Hz
from the analytic derivatives, with biases and white noise."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY = np.array([0.3, -9.80, 0.2]) / np.linalg.norm([0.3, -9.80, 0.2]) * 9.81  # target axes
K = np.array([[458.654, 0.0, 367.215], [0.0, 457.296, 248.375], [0.0, 0.0, 1.0]])
DIST = np.array([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05])
RESOLUTION = (752, 480)
GYRO_DENSITY, ACCEL_DENSITY = 1.6968e-4, 2.0e-3  # EuRoC's ADIS16448 imu.yaml
GYRO_BIAS = np.array([0.002, -0.003, 0.0015])
ACCEL_BIAS = np.array([0.05, -0.04, 0.07])
# T_imu_cam (camera pose on the body) of EuRoC's cam0 / cam1 (sensor.yaml), rounded
R_IMU_CAM = [np.array([[0.0148655, -0.9998809, 0.0041403], [0.9995572, 0.0150221, 0.0257744],
                       [-0.0257744, 0.0037486, 0.9996608]]),
             np.array([[0.0125553, -0.9999755, 0.0005495], [0.9997625, 0.0125549, 0.0172084],
                       [-0.0172081, -0.0007658, 0.9998517]])]
T_IMU_CAM = [np.array([-0.0216401, -0.0646769, 0.0098107]),
             np.array([-0.0198435, 0.0453689, 0.0078620])]

_FREQ = np.array([[0.31, 0.57, 0.83], [0.43, 0.71, 0.97], [0.37, 0.61, 1.13]])
_PHASE = np.array([[0.1, 1.3, 2.1], [0.7, 2.5, 0.4], [1.9, 0.2, 2.9]])


def _rig_rotation(i: int) -> np.ndarray:
    """Orthonormalised rotation of camera i on the body."""
    u, _, vt = np.linalg.svd(R_IMU_CAM[i])
    return u @ vt


def extrinsic_matrix(i: int) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _rig_rotation(i), T_IMU_CAM[i]
    return T


def _sines(t, amp, scale=1.0):
    """(N, 3) value, first and second derivative of sum_k amp sin(2 pi f t + phase)."""
    w = 2 * np.pi * _FREQ * scale
    arg = w[None] * t[:, None, None] + _PHASE[None]
    a = amp[None, :, None]
    return ((a * np.sin(arg)).sum(-1), (a * w * np.cos(arg)).sum(-1),
            (-a * w ** 2 * np.sin(arg)).sum(-1))


def _skew(v):
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


_R_MEAN_CAM = np.diag([1.0, -1.0, -1.0])  # camera looking at the board (target -Z)
_R0 = _R_MEAN_CAM @ _rig_rotation(0).T  # body orientation of the mean view
_P0 = np.array([0.34, 0.34, 1.1])  # mean camera position (metres, target axes)
_ROT_AMP = np.array([0.12, 0.12, 0.15])
_POS_AMP = np.array([0.10, 0.07, 0.08])


def motion(t):
    """Body poses in the target frame and IMU readings (noise-free, bias-free) at IMU times
    ``t``: R (N, 3, 3), p (N, 3), gyro (N, 3), accel (N, 3)."""
    r, dr, _ = _sines(t, _ROT_AMP)
    p, _, ddp = _sines(t, _POS_AMP)
    R = _R0 @ Rotation.from_rotvec(r).as_matrix()
    th = np.linalg.norm(r, axis=-1)[:, None, None]
    S = _skew(r)
    Jr = np.eye(3) - (1 - np.cos(th)) / th ** 2 * S + (th - np.sin(th)) / th ** 3 * S @ S
    gyro = (Jr @ dr[..., None])[..., 0]
    p = p + _P0 - _R0 @ T_IMU_CAM[0]
    accel = np.einsum("nji,nj->ni", R, ddp - GRAVITY)
    return R, p, gyro, accel


def target_points(rows=6, cols=6, size=0.088, spacing=0.3):
    """AprilGrid points in Kalibr's order (independent of torch_dq's aprilgrid)."""
    pitch = size * (1 + spacing)
    pts = []
    for r in range(rows):
        for c in range(cols):
            x, y = c * pitch, r * pitch
            pts += [(x, y), (x + size, y), (x + size, y + size), (x, y + size)]
    return np.array([(x, y, 0.0) for x, y in pts])


def _project(Rc, tc, pts):
    """Pixels (N, 2) of target points through cv2.projectPoints of points already moved
    into the camera (one pose per point); valid mask."""
    import cv2
    pc = np.einsum("nji,nj->ni", Rc, pts - tc)
    uv, _ = cv2.projectPoints(pc[:, None, :], np.zeros(3), np.zeros(3), K, DIST)
    uv = uv[:, 0, :]
    ok = (pc[:, 2] > 0.1) & (uv[:, 0] >= 0) & (uv[:, 0] <= RESOLUTION[0] - 1) & (
        uv[:, 1] >= 0) & (uv[:, 1] <= RESOLUTION[1] - 1)
    return uv, ok


def corners(cam, frame_times, offset, line_delay, noise, rng):
    """(times, points, pixels) of camera ``cam``: frame stamped t seen at IMU time
    t + offset + line_delay * row (the row found by fixed-point iteration)."""
    pts = target_points()
    n = pts.shape[0]
    t = np.repeat(frame_times, n)
    P = np.tile(pts, (frame_times.size, 1))
    E = extrinsic_matrix(cam)
    row = np.zeros(t.size)
    for _ in range(4 if line_delay else 1):
        R, p, _, _ = motion(t + offset + line_delay * row)
        Rc = R @ E[:3, :3]
        tc = p + np.einsum("nij,j->ni", R, E[:3, 3])
        uv, ok = _project(Rc, tc, P)
        row = np.clip(uv[:, 1], 0, RESOLUTION[1])
    uv = uv + noise * rng.standard_normal(uv.shape)
    return t[ok], P[ok], uv[ok]


def rig(duration=12.0, offset=0.004, line_delay=0.0, seed=0, imu_rate=200.0, fps=20.0):
    """The whole simulated recording: IMU (times, gyro, accel) over [-0.5, duration + 0.5]
    and two cameras' corners at ``fps`` over [0, duration] (0.3 px noise)."""
    rng = np.random.default_rng(seed)
    t_imu = np.arange(-0.5, duration + 0.5, 1.0 / imu_rate)
    _, _, g, a = motion(t_imu)
    g = g + GYRO_BIAS + GYRO_DENSITY * np.sqrt(imu_rate) * rng.standard_normal(g.shape)
    a = a + ACCEL_BIAS + ACCEL_DENSITY * np.sqrt(imu_rate) * rng.standard_normal(a.shape)
    frames = np.arange(0.0, duration, 1.0 / fps)
    cams = [corners(i, frames, offset, line_delay, 0.3, rng) for i in range(2)]
    return (t_imu, g, a), cams

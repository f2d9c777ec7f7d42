"""A synthetic camera-IMU rig for the calib12 tests, numpy / scipy / OpenCV only.

An analytic body (IMU) motion in the target's frame (sines in position, intrinsic XYZ Euler
angles in rotation), an AprilGrid on the plane Z = 0 (target X right, Y up, Z towards the
viewer, as Kalibr's), cameras mounted on the body at known extrinsics with their own clock
offsets, pixels from independent projections (OpenCV for radtan and equidistant, the
paper's formula for the double sphere), only corners inside the image, 0.3 px noise; IMU
readings from the analytic derivatives with biases, gravity and white noise from densities.

Conventions under test (API.md): the extrinsic ``e`` is the camera's pose on the body,
``p_body = R_bc p_cam + t_bc``; a frame stamped ``t`` by its camera shows the body at IMU
time ``t + dt``; a rolling-shutter row ``v`` at ``t + dt + line_delay * v``; the gyroscope
reads ``R_wb^T w`` (body axes), the accelerometer ``R_wb^T (a - g)`` plus biases.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY = np.array([0.0, -9.81, 0.0])  # the board stands upright: gravity along -Y
WIDTH, HEIGHT = 752, 480
# the pose of a camera looking at the board's front at zero angles: x = X, y = -Y, z = -Z
R_FRONT = np.diag([1.0, -1.0, -1.0])
BOARD_CENTRE = np.array([0.343, 0.343, 0.0])


def grid(rows=6, cols=6, tag=0.088, spacing=0.3) -> np.ndarray:
    """Kalibr's AprilGrid points written here independently: tag ids row by row from the
    bottom-left, corners counter-clockwise from the lower-left, pitch ``tag (1 + spacing)``."""
    pitch = tag * (1 + spacing)
    pts = []
    for r in range(rows):
        for c in range(cols):
            x0, y0 = c * pitch, r * pitch
            pts += [(x0, y0, 0.0), (x0 + tag, y0, 0.0), (x0 + tag, y0 + tag, 0.0),
                    (x0, y0 + tag, 0.0)]
    return np.array(pts)


@dataclass
class Cam:
    model: str
    params: np.ndarray
    R_bc: np.ndarray  # camera axes -> body axes
    t_bc: np.ndarray  # camera centre in body axes (m)
    dt: float  # IMU time = camera stamp + dt
    line_delay: float = 0.0  # seconds per row

    def kalibr(self) -> dict:
        """The camera's camchain entry (Kalibr's names and parameter order)."""
        p = [float(x) for x in self.params]
        if self.model == "double-sphere":
            return {"camera_model": "ds", "distortion_model": "none",
                    "intrinsics": [p[4], p[5], *p[:4]], "distortion_coeffs": [],
                    "resolution": [WIDTH, HEIGHT]}
        dist = {"pinhole-radtan": "radtan", "pinhole-equidistant": "equidistant"}[self.model]
        return {"camera_model": "pinhole", "distortion_model": dist, "intrinsics": p[:4],
                "distortion_coeffs": p[4:], "resolution": [WIDTH, HEIGHT]}


def project(model: str, params: np.ndarray, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) and validity of camera-frame points (N, 3), independent of torch_dq."""
    fu, fv, cu, cv_ = params[:4]
    K = np.array([[fu, 0, cu], [0, fv, cv_], [0, 0, 1.0]])
    z = np.zeros(3)
    if model == "pinhole-radtan":
        d = np.array([*params[4:8], 0.0])
        uv = cv2.projectPoints(pc.reshape(-1, 1, 3), z, z, K, d)[0].reshape(-1, 2)
        return uv, pc[:, 2] > 0.05
    if model == "pinhole-equidistant":
        uv = cv2.fisheye.projectPoints(pc.reshape(-1, 1, 3), z, z, K,
                                       np.asarray(params[4:8], float))[0].reshape(-1, 2)
        return uv, pc[:, 2] > 0.05
    xi, alpha = params[4:6]
    x, y, zc = pc.T
    d1 = np.sqrt(x * x + y * y + zc * zc)
    d2 = np.sqrt(x * x + y * y + (xi * d1 + zc) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + zc)
    return np.stack([fu * x / den + cu, fv * y / den + cv_], -1), zc > 0.05


@dataclass
class Motion:
    """Body pose ``R_wb(t) = R0 Rx(a) Ry(b) Rz(c)``, ``p_wb(t) = p0 + A sin(2 pi f t + phi)``."""

    R0: np.ndarray
    p0: np.ndarray
    rot_amp: np.ndarray = field(default_factory=lambda: np.array([0.22, 0.2, 0.25]))
    rot_f: np.ndarray = field(default_factory=lambda: np.array([0.7, 0.9, 0.55]))
    rot_ph: np.ndarray = field(default_factory=lambda: np.array([0.3, 1.2, 2.0]))
    pos_amp: np.ndarray = field(default_factory=lambda: np.array([0.12, 0.10, 0.10]))
    pos_f: np.ndarray = field(default_factory=lambda: np.array([0.8, 1.1, 0.65]))
    pos_ph: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.7, 1.5]))

    def _angles(self, t, order=0):
        w = 2 * np.pi * self.rot_f
        arg = w * np.asarray(t)[..., None] + self.rot_ph
        return [self.rot_amp * np.sin(arg), self.rot_amp * w * np.cos(arg)][order]

    def rotation(self, t) -> np.ndarray:
        return self.R0 @ Rotation.from_euler("XYZ", self._angles(t)).as_matrix()

    def position(self, t, order=0) -> np.ndarray:
        w = 2 * np.pi * self.pos_f
        arg = w * np.asarray(t)[..., None] + self.pos_ph
        if order == 0:
            return self.p0 + self.pos_amp * np.sin(arg)
        return -self.pos_amp * w ** 2 * np.sin(arg)  # order 2: acceleration

    def omega_body(self, t) -> np.ndarray:
        """Body-axes angular velocity of intrinsic XYZ Euler angles (analytic)."""
        _, b, c = np.moveaxis(self._angles(t), -1, 0)
        da, db, dc = np.moveaxis(self._angles(t, 1), -1, 0)
        ex = np.stack([np.cos(b) * np.cos(c), -np.cos(b) * np.sin(c), np.sin(b)], -1)
        ey = np.stack([np.sin(c), np.cos(c), np.zeros_like(c)], -1)
        ez = np.stack([np.zeros_like(c), np.zeros_like(c), np.ones_like(c)], -1)
        return da[..., None] * ex + db[..., None] * ey + dc[..., None] * ez


@dataclass
class Rig:
    motion: Motion
    cams: list
    duration: float
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_noise: float  # densities
    accel_noise: float
    gravity: np.ndarray = field(default_factory=lambda: GRAVITY)
    imu: tuple = ()
    observations: list = field(default_factory=list)


def mount(R_bc: np.ndarray, t_bc: np.ndarray, distance=0.9) -> tuple[np.ndarray, np.ndarray]:
    """(R0, p0): the body's rest pose that puts a camera at ``(R_bc, t_bc)`` in front of the
    board's centre at ``distance``, looking at it."""
    R0 = R_FRONT @ R_bc.T
    p0 = BOARD_CENTRE + np.array([0, 0, distance]) - R0 @ t_bc
    return R0, p0


def make_rig(cams: list, *, seed=0, duration=8.0, rate_imu=200.0, rate_cam=20.0,
             pixel_sigma=0.3, gyro_noise=1.7e-4, accel_noise=2.0e-3, motion=None,
             t0=1000.0, gravity=GRAVITY) -> Rig:
    """Observations per camera ``(t_cam, points, pixels)`` and IMU ``(t, gyro, accel)``,
    all float64 numpy; camera stamps on the camera's clock (IMU time minus its dt)."""
    rng = np.random.default_rng(seed)
    if motion is None:
        motion = Motion(*mount(cams[0].R_bc, cams[0].t_bc))
    rig = Rig(motion, cams, duration, np.array([0.004, -0.006, 0.005]),
              np.array([0.08, -0.05, 0.06]), gyro_noise, accel_noise, np.asarray(gravity))
    t = np.arange(0, duration, 1 / rate_imu)
    R = motion.rotation(t)
    gyro = motion.omega_body(t) + rig.gyro_bias
    accel = np.einsum("nji,nj->ni", R, motion.position(t, 2) - rig.gravity) + rig.accel_bias
    gyro += rng.normal(0, gyro_noise * np.sqrt(rate_imu), gyro.shape)
    accel += rng.normal(0, accel_noise * np.sqrt(rate_imu), accel.shape)
    rig.imu = (t + t0, gyro, accel)
    P = grid()
    for cam in cams:
        stamps = np.arange(0.25, duration - 0.25, 1 / rate_cam)
        ts, ps, us = [], [], []
        for s in stamps:
            uv, ok = _frame(motion, cam, P, s + cam.dt)
            uv = uv + rng.normal(0, pixel_sigma, uv.shape)
            ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= WIDTH - 1) & (uv[:, 1] >= 0) & (
                uv[:, 1] <= HEIGHT - 1)
            if ok.sum() < 8:
                continue
            ts.append(np.full(ok.sum(), s + t0))
            ps.append(P[ok])
            us.append(uv[ok])
        rig.observations.append((np.concatenate(ts), np.concatenate(ps), np.concatenate(us)))
    return rig


def _frame(motion: Motion, cam: Cam, P: np.ndarray, t_imu: float):
    """Pixels of the target points seen at IMU time ``t_imu`` (rolling shutter: each row at
    ``t_imu + line_delay * v``, solved by fixed-point iteration on ``v``)."""
    times = np.full(len(P), t_imu)
    for _ in range(6 if cam.line_delay else 1):
        Rw = motion.rotation(times) @ cam.R_bc  # camera in world, per point
        cw = motion.position(times) + np.einsum("nij,j->ni", motion.rotation(times), cam.t_bc)
        pc = np.einsum("nji,nj->ni", Rw, P - cw)
        uv, ok = project(cam.model, cam.params, pc)
        times = t_imu + cam.line_delay * uv[:, 1]
    return uv, ok


def rot(axis: str, deg: float) -> np.ndarray:
    return Rotation.from_euler(axis, deg, degrees=True).as_matrix()


RADTAN = np.array([458.0, 457.0, 367.0, 248.0, -0.28, 0.074, 2e-4, 2e-5])
EQUI = np.array([360.0, 360.0, 376.0, 240.0, 0.01, -0.005, 0.002, -0.0005])
DS = np.array([300.0, 300.0, 376.0, 240.0, -0.2, 0.58])

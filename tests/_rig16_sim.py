"""A camera-IMU rig from an analytic motion for tests/test_rig16_*.py, numpy / scipy only
(no torch_dq, no OpenCV): a figure-eight (Lissajous) translation in front of a planar grid and
a rotation ``R(t) = R0 Rz(a(t)) Ry(b(t)) Rx(c(t))`` with sinusoidal angles, whose body rate
``w_b = Rx^T Ry^T ez a' + Rx^T ey b' + ex c'`` and specific force ``R^T (p'' - g)`` are
written by hand here. A pinhole-radtan camera (Kalibr's ``radtan``, written as a formula) is
mounted on the body at ``(R_bc, t_bc)`` (``p_body = R_bc p_cam + t_bc``); a frame stamped
``s`` by the camera shows the body at IMU time ``s + dt`` (row ``v`` of a rolling shutter at
``s + dt + line_delay v``, solved by fixed-point iteration); corners outside the image are
dropped; pixel and IMU white noise, constant biases, gravity in the grid's axes."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

WIDTH, HEIGHT = 640, 480
PARAMS = np.array([420.0, 421.0, 318.0, 242.0, -0.21, 0.05, 3e-4, -2e-4])  # fu fv cu cv k1 k2 p1 p2
GRAVITY = np.array([0.35, -9.79, 0.42]) / np.linalg.norm([0.35, -9.79, 0.42]) * 9.81


def grid(rows: int = 6, cols: int = 6, tag: float = 0.08, spacing: float = 0.3) -> np.ndarray:
    """AprilGrid-like corners ``(rows cols 4, 3)`` on ``Z = 0`` (metres)."""
    pitch = tag * (1 + spacing)
    corners = np.array([[0, 0], [tag, 0], [tag, tag], [0, tag]])
    out = [np.c_[corners + np.array([c * pitch, r * pitch]), np.zeros(4)]
           for r in range(rows) for c in range(cols)]
    return np.concatenate(out)


def radtan(params: np.ndarray, pc: np.ndarray) -> np.ndarray:
    """Pixels ``(N, 2)`` of camera-frame points ``(N, 3)`` (z > 0): OpenCV's plumb bob, k3 = 0."""
    fu, fv, cu, cv, k1, k2, p1, p2 = params
    x, y = pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2]
    r2 = x * x + y * y
    rad = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fu * xd + cu, fv * yd + cv], -1)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1),
                     np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1),
                     np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1),
                     np.stack([z, z, o], -1)], -2)


@dataclass
class Motion:
    """``p(t) = p0 + (A sin(w t), B sin(2 w t + phi), C sin(w_z t))`` (a figure eight) and
    angles ``amp_k sin(f_k t + ph_k)`` about z, y, x (in that order from ``R0``)."""

    R0: np.ndarray
    p0: np.ndarray
    w: float = 2 * np.pi * 0.35
    amp_p: np.ndarray = field(default_factory=lambda: np.array([0.25, 0.12, 0.08]))
    w_z: float = 2 * np.pi * 0.5
    phi: float = 0.4
    amp_r: np.ndarray = field(default_factory=lambda: np.array([0.35, 0.3, 0.3]))
    f_r: np.ndarray = field(default_factory=lambda: 2 * np.pi * np.array([0.45, 0.6, 0.75]))
    ph_r: np.ndarray = field(default_factory=lambda: np.array([0.2, 1.1, 2.3]))

    def _angles(self, t):
        arg = self.f_r * np.asarray(t)[..., None] + self.ph_r
        return self.amp_r * np.sin(arg), self.amp_r * self.f_r * np.cos(arg)

    def rotation(self, t) -> np.ndarray:
        (a, b, c), _ = (np.moveaxis(v, -1, 0) for v in self._angles(t))
        return self.R0 @ _rz(a) @ _ry(b) @ _rx(c)

    def omega_body(self, t) -> np.ndarray:
        (_, b, c), (da, db, dc) = (np.moveaxis(v, -1, 0) for v in self._angles(t))
        Rx, Ry = _rx(c), _ry(b)
        ez, ey, ex = np.eye(3)[2], np.eye(3)[1], np.eye(3)[0]
        RxT, RyT = np.swapaxes(Rx, -1, -2), np.swapaxes(Ry, -1, -2)
        return (np.einsum("...ij,...jk,k->...i", RxT, RyT, ez) * da[..., None]
                + np.einsum("...ij,j->...i", RxT, ey) * db[..., None] + ex * dc[..., None])

    def position(self, t, order: int = 0) -> np.ndarray:
        t = np.asarray(t)
        A, B, C = self.amp_p
        w, wz = self.w, self.w_z
        if order == 0:
            return self.p0 + np.stack([A * np.sin(w * t), B * np.sin(2 * w * t + self.phi),
                                       C * np.sin(wz * t)], -1)
        return -np.stack([A * w * w * np.sin(w * t),
                          4 * B * w * w * np.sin(2 * w * t + self.phi),
                          C * wz * wz * np.sin(wz * t)], -1)


@dataclass
class Rig:
    """The truth and the data: ``imu = (t, gyro, accel)``, ``obs = (t, points, pixels)``
    (numpy float64; camera stamps on the camera's clock)."""

    motion: Motion
    R_bc: np.ndarray
    t_bc: np.ndarray
    dt: float
    line_delay: float
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    gyro_noise: float  # densities
    accel_noise: float
    pixel_sigma: float
    imu: tuple = ()
    obs: tuple = ()


def make_rig(*, seed: int = 0, duration: float = 6.0, R_bc=None, t_bc=(0.06, -0.03, 0.02),
             dt: float = 0.025, line_delay: float = 0.0, pixel_sigma: float = 0.5,
             rate_imu: float = 200.0, rate_cam: float = 20.0, t0: float = 1000.0,
             gyro_noise: float = 2e-4, accel_noise: float = 2e-3, motion_kw=None) -> Rig:
    rng = np.random.default_rng(seed)
    R_bc = Rotation.from_euler("zyx", [90, 5, -80], degrees=True).as_matrix() if R_bc is None \
        else np.asarray(R_bc)
    t_bc = np.asarray(t_bc, float)
    # rest pose: the camera 0.8 m in front of the grid's centre, looking at it (z towards -Z)
    R_front = np.diag([1.0, -1.0, -1.0])
    R0 = R_front @ R_bc.T
    centre = grid().mean(0)
    p0 = centre + np.array([0.0, 0.0, 0.8]) - R0 @ t_bc
    motion = Motion(R0, p0, **(motion_kw or {}))
    rig = Rig(motion, R_bc, t_bc, dt, line_delay, rng.normal(0, 0.005, 3),
              rng.normal(0, 0.06, 3), gyro_noise, accel_noise, pixel_sigma)
    t = np.arange(0.0, duration, 1 / rate_imu)
    R = motion.rotation(t)
    gyro = motion.omega_body(t) + rig.gyro_bias
    accel = np.einsum("nji,nj->ni", R, motion.position(t, 2) - GRAVITY) + rig.accel_bias
    gyro += rng.normal(0, gyro_noise * np.sqrt(rate_imu), gyro.shape)
    accel += rng.normal(0, accel_noise * np.sqrt(rate_imu), accel.shape)
    rig.imu = (t + t0, gyro, accel)
    P = grid()
    ts, ps, us = [], [], []
    for s in np.arange(0.3, duration - 0.3, 1 / rate_cam):
        v = np.full(len(P), HEIGHT / 2)
        for _ in range(6):  # rolling shutter: the row's time depends on the row
            uv = _pixels(rig, P, s + dt + line_delay * v)
            v = uv[:, 1]
        uv = uv + rng.normal(0, pixel_sigma, uv.shape)
        ok = (uv[:, 0] >= 0) & (uv[:, 0] <= WIDTH - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= HEIGHT - 1)
        if ok.sum() >= 12:
            ts.append(np.full(ok.sum(), s + t0))
            ps.append(P[ok])
            us.append(uv[ok])
    rig.obs = (np.concatenate(ts), np.concatenate(ps), np.concatenate(us))
    return rig


def _pixels(rig: Rig, P: np.ndarray, t_imu: np.ndarray) -> np.ndarray:
    """Pixels of grid points ``P (N, 3)`` seen at body times ``t_imu (N,)``."""
    R = rig.motion.rotation(t_imu)
    p = rig.motion.position(t_imu)
    R_wc = R @ rig.R_bc
    p_wc = p + R @ rig.t_bc
    pc = np.einsum("nji,nj->ni", R_wc, P - p_wc)
    return radtan(PARAMS, pc)


def extrinsic_error(R_bc, t_bc, R_est, t_est) -> np.ndarray:
    """The error in the chart ``e exp(delta)`` to first order: the rotation vector of
    ``R_bc^T R_est`` and ``R_bc^T (t_est - t_bc)`` (camera axes)."""
    return np.concatenate([Rotation.from_matrix(R_bc.T @ R_est).as_rotvec(),
                           R_bc.T @ (np.asarray(t_est) - t_bc)])

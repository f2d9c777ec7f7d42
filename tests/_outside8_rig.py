"""Truth for the outside8 camera-IMU tests, written independently of torch_dq (numpy only).

The body (IMU) turns by Euler angles ``R(t) = R0 Rz(a0(t)) Ry(a1(t)) Rx(a2(t))`` with
``a_i(t) = A_i sin(w_i t + phi_i)`` and moves by ``p(t) = c + B sin(W t + psi)`` (per axis), so
that its body rates and specific force are closed-form:
``omega = Rx^T Ry^T (0, 0, a0') + Rx^T (0, a1', 0) + (a2', 0, 0)`` and
``f = R^T (p'' - g)``, ``g = (0, 0, -9.81)`` in the target frame. ``R0`` makes the camera,
mounted at ``(R_bc, t_bc)`` (``p_body = R_bc p_cam + t_bc``), look down at an AprilGrid
(Kalibr's 6 x 6, 0.088 m tags, spacing 0.3, ``Z = 0``) from 0.75 m. Corners are projected by
the camera formulas written below (OpenCV's plumb bob with ``k3 = 0``; Kannala-Brandt), a
rolling shutter by solving ``v = proj(s + delay * v)`` by fixed-point iteration; the frame
exposed at IMU time ``s`` is stamped ``s - offset`` (Kalibr: ``t_imu = t_cam + shift``).
"""

import numpy as np

G = np.array([0.0, 0.0, -9.81])
RATE_IMU, RATE_CAM = 200.0, 20.0
A_ROT, W_ROT, P_ROT = (np.array(v) for v in ([0.35, 0.3, 0.4], [2.1, 2.9, 3.7], [0.3, 1.1, 2.0]))
A_POS, W_POS, P_POS = (np.array(v) for v in ([0.15, 0.12, 0.1], [1.7, 2.3, 3.1], [0.5, 0.9, 1.4]))
SIN = (np.sin, np.cos, lambda x: -np.sin(x))  # the derivatives of sin


def grid():
    """Kalibr's aprilgrid(6, 6, 0.088, 0.3) corners: tags row by row from the bottom left,
    corners counter-clockwise from the lower left."""
    pitch = 0.088 * 1.3
    pts = [(c * pitch + dx, r * pitch + dy) for r in range(6) for c in range(6)
           for dx, dy in ((0, 0), (0.088, 0), (0.088, 0.088), (0, 0.088))]
    return np.column_stack([np.array(pts), np.zeros(len(pts))])


def _axis(a, i, j):
    c, s = np.cos(a), np.sin(a)
    m = np.tile(np.eye(3), (*a.shape, 1, 1))
    m[..., i, i], m[..., j, j], m[..., i, j], m[..., j, i] = c, c, -s, s
    return m


class Rig:
    def __init__(self, R_bc, t_bc):
        self.R_bc, self.t_bc = np.asarray(R_bc, float), np.asarray(t_bc, float)
        self.R0 = np.diag([1.0, -1.0, -1.0]) @ self.R_bc.T
        centre = grid()[:, :2].mean(0)
        self.c = np.array([centre[0], centre[1], 0.75]) - self.R0 @ self.t_bc

    def angles(self, t, d=0):
        return A_ROT * W_ROT ** d * SIN[d](W_ROT * t[:, None] + P_ROT)

    def rotation(self, t):
        a = self.angles(t)
        return self.R0 @ _axis(a[:, 0], 0, 1) @ _axis(a[:, 1], 2, 0) @ _axis(a[:, 2], 1, 2)

    def position(self, t, d=0):
        return A_POS * W_POS ** d * SIN[d](W_POS * t[:, None] + P_POS) + (self.c if d == 0 else 0)

    def gyro(self, t):
        a, da = self.angles(t), self.angles(t, 1)
        rx, ry = _axis(a[:, 2], 1, 2), _axis(a[:, 1], 2, 0)
        z = np.zeros_like(da)
        ez, ey, ex = z.copy(), z.copy(), z.copy()
        ez[:, 2], ey[:, 1], ex[:, 0] = da[:, 0], da[:, 1], da[:, 2]
        tr = lambda m, v: np.einsum("tji,tj->ti", m, v)  # noqa: E731  m^T v
        return tr(rx, tr(ry, ez)) + tr(rx, ey) + ex

    def accel(self, t):
        return np.einsum("tji,tj->ti", self.rotation(t), self.position(t, 2) - G)

    def camera_pose(self, t):
        R = self.rotation(t)
        return R @ self.R_bc, self.position(t) + R @ self.t_bc


def radtan(k, xc):
    x, y = xc[..., 0] / xc[..., 2], xc[..., 1] / xc[..., 2]
    r2 = x * x + y * y
    f = 1 + k[4] * r2 + k[5] * r2 * r2
    xd = x * f + 2 * k[6] * x * y + k[7] * (r2 + 2 * x * x)
    yd = y * f + k[6] * (r2 + 2 * y * y) + 2 * k[7] * x * y
    return np.stack([k[0] * xd + k[2], k[1] * yd + k[3]], -1)


def equidistant(k, xc):
    r = np.hypot(xc[..., 0], xc[..., 1])
    th = np.arctan2(r, xc[..., 2])
    d = th * (1 + k[4] * th ** 2 + k[5] * th ** 4 + k[6] * th ** 6 + k[7] * th ** 8)
    s = d / np.where(r > 0, r, 1)
    return np.stack([k[0] * s * xc[..., 0] + k[2], k[1] * s * xc[..., 1] + k[3]], -1)


def simulate(rig, intr, proj, res, *, duration, offset, line_delay, pixel_sigma, gyro_density,
             accel_density, bg, ba, seed):
    """``(imu_times, gyro, accel)`` and ``(times, points, pixels)`` as numpy arrays."""
    rng = np.random.default_rng(seed)
    ti = np.arange(0.0, duration, 1 / RATE_IMU)
    gyro = rig.gyro(ti) + bg + rng.normal(0, gyro_density * np.sqrt(RATE_IMU), (len(ti), 3))
    accel = rig.accel(ti) + ba + rng.normal(0, accel_density * np.sqrt(RATE_IMU), (len(ti), 3))
    P = grid()
    T, X, U = [], [], []
    for s in np.arange(0.3, duration - 0.3, 1 / RATE_CAM):
        v = np.full(len(P), res[1] / 2)
        for _ in range(8 if line_delay else 1):
            R, p = rig.camera_pose(s + line_delay * v)
            xc = np.einsum("nji,nj->ni", R, P - p)
            uv = proj(intr, xc)
            v = uv[:, 1]
        ok = ((xc[:, 2] > 0.05) & (uv[:, 0] > 2) & (uv[:, 0] < res[0] - 3) & (uv[:, 1] > 2)
              & (uv[:, 1] < res[1] - 3))
        T.append(np.full(ok.sum(), s - offset))
        X.append(P[ok])
        U.append(uv[ok] + rng.normal(0, pixel_sigma, (ok.sum(), 2)))
    return (ti, gyro, accel), (np.concatenate(T), np.concatenate(X), np.concatenate(U))

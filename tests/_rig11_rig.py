"""Truth for the rig11 tests, written independently of torch_dq (numpy and scipy only).

The body turns by intrinsic Z-Y-X Euler angles ``R(t) = Rz(a0) Ry(a1) Rx(a2)`` with
``a_i(t) = A_i sin(w_i t + phi_i)`` and moves by ``p(t) = c + B_i sin(W_i t + psi_i)`` per
axis, so its body rates and specific force are closed-form:
``omega_body = Rx^T Ry^T (0, 0, a0') + Rx^T (0, a1', 0) + (a2', 0, 0)`` and
``f = R^T (p'' - g)``, ``g = (0, 0, -9.81)``.
"""

import numpy as np
from scipy.spatial.transform import Rotation

G = np.array([0.0, 0.0, -9.81])
A_ROT, W_ROT, P_ROT = (np.array(v) for v in ([0.8, 0.4, 0.5], [1.3, 2.2, 2.9], [0.2, 1.0, 2.1]))
A_POS, W_POS, P_POS = (np.array(v) for v in ([1.0, 0.7, 0.3], [1.1, 1.7, 2.5], [0.4, 0.8, 1.5]))
C = np.array([2.0, -1.0, 1.5])
_D = (np.sin, np.cos, lambda x: -np.sin(x))


def angles(t, d=0):
    return A_ROT * W_ROT ** d * _D[d](W_ROT * np.asarray(t)[:, None] + P_ROT)


def rotation(t):
    """``R(t)`` as a scipy Rotation (body to world)."""
    return Rotation.from_euler("ZYX", angles(t))


def position(t, d=0):
    return A_POS * W_POS ** d * _D[d](W_POS * np.asarray(t)[:, None] + P_POS) + (
        C if d == 0 else 0.0)


def gyro(t):
    """Body-axes angular rate."""
    a, da = angles(t), angles(t, 1)
    ry = Rotation.from_euler("Y", a[:, 1:2])
    rx = Rotation.from_euler("X", a[:, 2:3])
    z = np.zeros_like(da)
    ez, ey, ex = z.copy(), z.copy(), z.copy()
    ez[:, 2], ey[:, 1], ex[:, 0] = da[:, 0], da[:, 1], da[:, 2]
    return rx.inv().apply(ry.inv().apply(ez)) + rx.inv().apply(ey) + ex


def accel(t):
    """Body-axes specific force ``R^T (p'' - g)``."""
    return rotation(t).inv().apply(position(t, 2) - G)

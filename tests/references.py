"""Independent references shared by the tests, written without torch_dq: the Hamilton product
in plain torch, screw interpolation of 4x4 transforms (pytransform3d's exponential
coordinates) and the textbook De Casteljau and De Boor schemes over any interpolation."""

import numpy as np
import pytransform3d.transformations as pt
import torch


def hamilton(a, b):
    """Hamilton product of ``(..., 4)`` quaternions ``(w, x, y, z)``, written out in torch."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw), -1)


def sclerp_mat(Ta, Tb, s):
    """Screw interpolation of 4x4 transforms: Ta exp(s log(Ta^-1 Tb))."""
    xi = pt.exponential_coordinates_from_transform(np.linalg.solve(Ta, Tb))
    return Ta @ pt.transform_from_exponential_coordinates(s * xi)


def casteljau_np(points, s, interp):
    """De Casteljau's scheme (paper 4.1) with ``interp(a, b, s)`` at every level."""
    pts = list(points)
    while len(pts) > 1:
        pts = [interp(pts[i], pts[i + 1], s) for i in range(len(pts) - 1)]
    return pts[0]


def deboor_np(points, knots, p, s, interp):
    """De Boor's scheme (paper 4.2) of degree ``p`` at ``s``, ``interp(a, b, alpha)``."""
    n = len(points)
    r = p
    while r < n - 1 and knots[r + 1] <= s:  # knots[r] <= s < knots[r+1], last span at the end
        r += 1
    d = {i: points[i] for i in range(r - p, r + 1)}
    for j in range(1, p + 1):
        for i in range(r, r - p + j - 1, -1):
            a = (s - knots[i]) / (knots[i + p + 1 - j] - knots[i])
            d[i] = interp(d[i - 1], d[i], a)
    return d[r]


def double_sphere_np(p, pts: np.ndarray) -> np.ndarray:
    """Usenko et al.'s double sphere projection, eqs. 40-42, ``p = (fx, fy, cx, cy, xi,
    alpha)``, ``pts (N, 3)``: pixels ``(N, 2)`` (no domain test)."""
    fx, fy, cx, cy, xi, alpha = p
    x, y, z = pts.T
    d1 = np.sqrt(x * x + y * y + z * z)
    w = xi * d1 + z
    den = alpha * np.sqrt(x * x + y * y + w * w) + (1 - alpha) * w
    return np.stack([fx * x / den + cx, fy * y / den + cy], -1)

r"""The camera models' closed-form formulas (private; the public entry points, argument
checks and safe-where replacement of the parameters are ``torch_dq.camera``'s).

Each ``project_<model>(p, x, y, z)`` takes the parameters ``p`` and the point's coordinates
as lists of tensors (already in the compute dtype, out-of-domain parameters replaced) and
returns ``(u, v, valid)``; each closed-form ``unproject_<model>(p, a, b)`` takes the
normalised pixel ``a = (u - cu) / fu``, ``b = (v - cv) / fv`` and returns ``(x, y, z,
valid)``, a unit ray. The iterative inversions of the distorted pinhole models are
``torch_dq._undistort``'s.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._numerics import even, threshold

__all__ = ["normalised", "pinhole", "poly", "poly_slope", "project_ds", "project_equidistant",
           "project_pinhole", "project_radtan", "radtan", "unit", "unproject_ds",
           "unproject_pinhole"]


def normalised(x: Tensor, y: Tensor, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(valid, a, b)``: ``z > 0`` with ``|x|, |y| < z / eps`` (points closer to the plane
    ``z = 0`` than ``eps`` radians would overflow the pixels or their derivatives), and
    ``(a, b) = (x, y) / z`` there, ``(0, 0)`` elsewhere (safe where: replaced before the
    division)."""
    far = threshold("camera_off_axis", x.dtype) * z
    valid = (z > 0) & (abs(x) < far) & (abs(y) < far)
    zs = torch.where(valid, z, 1.0)
    return valid, torch.where(valid, x, 0.0) / zs, torch.where(valid, y, 0.0) / zs


def pinhole(p: list[Tensor], a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    return p[0] * a + p[2], p[1] * b + p[3]


def project_pinhole(p, x, y, z):
    valid, a, b = normalised(x, y, z)
    return (*pinhole(p, a, b), valid)


def radtan(k: list[Tensor], a: Tensor, b: Tensor, jacobian: bool = False) -> tuple[Tensor, ...]:
    """The radial-tangential map of normalised coordinates (OpenCV's plumb bob, k3 = 0):
    ``(a', b')``, and with ``jacobian`` also its Jacobian's ``(daa, dab, dbb)`` (symmetric)."""
    k1, k2, p1, p2 = k
    a2, b2, ab = a * a, b * b, a * b
    r2 = a2 + b2
    k2r2 = k2 * r2
    radial = 1.0 + r2 * (k1 + k2r2)
    ta, tb = (2.0 * p1) * b, (2.0 * p2) * a  # d(2 p1 a b)/da, d(2 p2 a b)/db
    out = (a * radial + ta * a + p2 * (r2 + 2.0 * a2), b * radial + p1 * (r2 + 2.0 * b2) + tb * b)
    if not jacobian:
        return out
    q = 2.0 * (k1 + 2.0 * k2r2)  # d radial / d(a, b) = q (a, b)
    return (*out, radial + q * a2 + ta + 3.0 * tb, q * ab + (2.0 * p1) * a + (2.0 * p2) * b,
            radial + q * b2 + 3.0 * ta + tb)


def project_radtan(p, x, y, z):
    valid, a, b = normalised(x, y, z)
    return (*pinhole(p, *radtan(p[4:], a, b)), valid)


def poly(k: list[Tensor], t: Tensor) -> Tensor:
    """``1 + k1 t + k2 t^2 + k3 t^3 + k4 t^4`` (t = theta^2: theta_d = theta * poly)."""
    return 1.0 + t * (k[0] + t * (k[1] + t * (k[2] + t * k[3])))


def poly_slope(k: list[Tensor], t: Tensor) -> Tensor:
    """``d theta_d / d theta = 1 + 3 k1 t + 5 k2 t^2 + 7 k3 t^3 + 9 k4 t^4``."""
    return 1.0 + t * (3.0 * k[0] + t * (5.0 * k[1] + t * (7.0 * k[2] + t * 9.0 * k[3])))


def project_equidistant(p, x, y, z):
    valid, a, b = normalised(x, y, z)
    r2 = a * a + b * b
    ratio = even("atanc", r2)  # theta / r with theta = atan(r), smooth at r = 0
    scale = ratio * poly(p[4:], r2 * ratio * ratio)  # theta_d / r
    return (*pinhole(p, scale * a, scale * b), valid)


def ds_w1(alpha: Tensor) -> Tensor:
    r""":math:`w_1` of eq. 43, safe where at :math:`\alpha = 0` and 1 (each branch sees only
    its own half of the alpha range)."""
    low = alpha <= 0.5
    a_lo, a_hi = torch.where(low, alpha, 0.5), torch.where(low, 0.5, alpha)
    return torch.where(low, a_lo / (1.0 - a_lo), (1.0 - a_hi) / a_hi)


def ds_w2(xi: Tensor, alpha: Tensor) -> Tensor:
    r""":math:`w_2` of the double sphere's projection domain (eq. 43)."""
    w1 = ds_w1(alpha)
    return (w1 + xi) / torch.sqrt(2.0 * w1 * xi + xi * xi + 1.0)


def ds_sees(xi: Tensor, alpha: Tensor, x: Tensor, y: Tensor, z: Tensor) -> Tensor:
    r"""The double sphere's projection domain (no gradient): eq. 43 and :math:`w > -w_1
    d_2` (:math:`w = \xi d_1 + z`), the second sphere's part that eq. 40 sees one-to-one,
    which eq. 43 implies only for :math:`\xi \ge 0` (``xi = -0.5, alpha = 0.1``: 3 % of
    the directions beyond it, their pixels through infinity on the image's other side)."""
    d1 = torch.sqrt(x * x + y * y + z * z)
    w = xi * d1 + z
    return (z > -ds_w2(xi, alpha) * d1) & (w > -ds_w1(alpha) * torch.sqrt(x * x + y * y + w * w))


def project_ds(p, x, y, z):
    # eq. 40 has degree 0: a constant scale to max |x, y, z| = 1 (no d1 = inf at 1e160, 0/0)
    s = torch.maximum(torch.maximum(abs(x), abs(y)), abs(z)).detach()
    x, y, z = (c / torch.where(s > 0, s, 1.0) for c in (x, y, z))
    with torch.no_grad():
        valid = ds_sees(p[4], p[5], x, y, z)  # eq. 43 (and eq. 40's denominator)
    x, y, z = torch.where(valid, x, 0.0), torch.where(valid, y, 0.0), torch.where(valid, z, 1.0)
    d1 = torch.sqrt(x * x + y * y + z * z)  # eq. 41
    w = p[4] * d1 + z
    d2 = torch.sqrt(x * x + y * y + w * w)  # eq. 42
    den = p[5] * d2 + (1.0 - p[5]) * w  # eq. 40
    return (*pinhole(p, x / den, y / den), valid)


def unit(x: Tensor, y: Tensor, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    n = torch.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


def unproject_pinhole(p, a, b):
    far = threshold("camera_off_axis", a.dtype)  # project's limit (|a|^2 would overflow)
    valid = (abs(a) < far) & (abs(b) < far)
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)
    return (*unit(a, b, torch.ones_like(a)), valid)


def ds_ray(xi: Tensor, alpha: Tensor, a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The double sphere's unprojection (eqs. 47-50): a unit ray."""
    r2 = a * a + b * b
    mz = (1.0 - alpha * alpha * r2) / (
        alpha * torch.sqrt(1.0 - (2.0 * alpha - 1.0) * r2) + 1.0 - alpha)  # m_z
    scale = (mz * xi + torch.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
    return scale * a, scale * b, scale * mz - xi


def unproject_ds(p, a, b):
    xi, alpha = p[4], p[5]
    with torch.no_grad():  # where the formula's square roots are real (safe where)
        r2 = a * a + b * b
        inside = (alpha <= 0.5) | (r2 * (2.0 * alpha - 1.0) < 1.0)  # the paper's domain
        mz = (1.0 - alpha * alpha * r2) / (
            alpha * torch.sqrt(torch.clamp(1.0 - (2.0 * alpha - 1.0) * r2, min=0.0))
            + 1.0 - alpha)
        keep = inside & (mz * mz + (1.0 - xi * xi) * r2 > 0)  # a first sphere's point
    x, y, z = ds_ray(xi, alpha, torch.where(keep, a, 0.0), torch.where(keep, b, 0.0))
    # project's domain on the ray (eq. 50's boundary maps slightly outside it for xi != 0)
    # and, for xi > 1, the first sphere's near side (else eq. 50's root is negative)
    with torch.no_grad():
        return x, y, z, keep & ds_sees(xi, alpha, x, y, z) & (1.0 + xi * z > 0)



r"""Camera models: pixels from points (:func:`project`), rays from pixels (:func:`unproject`).

Camera axes are OpenCV's and Kalibr's: ``x`` right, ``y`` down, ``z`` forward; a pixel
``(u, v)`` has ``(0, 0)`` at the centre of the top-left pixel, ``v`` the row. A model is a
name and a parameter vector ``(..., P)`` in Kalibr's and basalt's order:

=========================  ======================================  ==========================
model                      params                                  source
=========================  ======================================  ==========================
``"pinhole"``              ``fu, fv, cu, cv``                      the pinhole camera
``"pinhole-radtan"``       ``fu, fv, cu, cv, k1, k2, p1, p2``      OpenCV's plumb bob with
                                                                   ``k3 = 0``; Kalibr radtan
``"pinhole-equidistant"``  ``fu, fv, cu, cv, k1, k2, k3, k4``      Kannala-Brandt; OpenCV
                                                                   fisheye; Kalibr
                                                                   equidistant
``"double-sphere"``        ``fu, fv, cu, cv, xi, alpha``           Usenko, Demmel, Cremers
                                                                   2018; basalt ``ds``
=========================  ======================================  ==========================

Both functions broadcast ``params`` against the points or pixels like torch ops, follow
their dtype and device (float16/bfloat16 compute in float32) and are exact and twice
differentiable w.r.t. both arguments. Each returns a ``valid`` mask: where it is False
the outputs are finite, with finite gradients (safe where: the unsafe inputs are replaced
by a harmless constant before the formula), and must be masked by the caller. NaN or inf
in an element's inputs gives NaN or inf outputs in that element only.

Unprojection of the distorted pinhole models has no closed form: it runs a fixed number
of Newton iterations (no data-dependent branching or host reads: ``torch.func.vmap`` and
``torch.compile(fullgraph=True)`` go through) without autograd, then attaches the
derivatives by two Newton steps from that detached root. One Newton step
``x - J(x)^{-1} (F(x) - y)`` from a detached root has the implicit function's exact first
derivatives; a second step from it has the exact second derivatives too (the Newton map's
derivative in ``x`` vanishes at the root), so gradients and Hessians are exact without
differentiating through the iteration.

:class:`Camera` is a small value (model, ``(P,)`` params, resolution) that reads and writes
one camera of a Kalibr ``camchain.yaml``.

Example:
    >>> import torch
    >>> from torch_dq import camera
    >>> params = torch.tensor([458.654, 457.296, 367.215, 248.375,
    ...                        -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
    ...                       dtype=torch.float64)
    >>> px, ok = camera.project("pinhole-radtan", params, torch.tensor([0.1, -0.2, 1.0],
    ...                                                                  dtype=torch.float64))
    >>> [round(float(c), 3) for c in px], bool(ok)
    ([412.436, 158.206], True)
    >>> ray, ok = camera.unproject("pinhole-radtan", params, px)
    >>> [round(float(c), 6) for c in ray / ray[2]]
    [0.1, -0.2, 1.0]
"""

from __future__ import annotations

import contextlib
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from . import _checks
from ._numerics import compute_dtype, even, nan_unless, threshold

__all__ = ["MODELS", "Camera", "project", "unproject"]

#: The models and their parameter names, in the order of the ``params`` vector.
MODELS: dict[str, tuple[str, ...]] = {
    "pinhole": ("fu", "fv", "cu", "cv"),
    "pinhole-radtan": ("fu", "fv", "cu", "cv", "k1", "k2", "p1", "p2"),
    "pinhole-equidistant": ("fu", "fv", "cu", "cv", "k1", "k2", "k3", "k4"),
    "double-sphere": ("fu", "fv", "cu", "cv", "xi", "alpha"),
}

# Newton iterations of the detached radtan root search (2-D on the normalised point). Over
# whole images (tests/test_camera.py) the residual reaches rounding (2e-16) after 4 on EuRoC's
# cam0, 6 on a stronger lens (k1 = -0.35, f = 300 px on 752 x 480): 8 leave a margin (the two
# differentiable steps that follow square the error twice more).
_ITERATIONS = 8
# The equidistant root's safeguarded iteration (rtsafe): 12 steps invert every pixel inside
# the fold of a strong fisheye (k1 = 0.6, tests/test_rigs_cameras.py: 401 x 401 on 800 x 600).
_ITERATIONS_BRACKETED = 12


def _checked(fn: str, model, params, x, name: str, event: int) -> torch.Size:
    """Validate a call of project/unproject; return the broadcast batch shape."""
    if not isinstance(model, str) or model not in MODELS:
        _checks.fail(fn, f"expected model to be one of {', '.join(map(repr, MODELS))}, "
                         f"got {model!r}")
    _checks.tensor(fn, "params", params, len(MODELS[model]))
    _checks.tensor(fn, name, x, event)
    _checks.same_dtype_device(fn, params=params, **{name: x})
    return _checks.broadcast_batch(fn, params=(params, 1), **{name: (x, 1)})


# Parameter values that replace those outside a model's domain (safe where): unit focal
# lengths, no distortion, the double sphere's alpha = 1/2 and xi = 0.
_SAFE = {model: (1.0, 1.0) + (0.0,) * (len(names) - 2) for model, names in MODELS.items()}
_SAFE["double-sphere"] = (1.0, 1.0, 0.0, 0.0, 0.0, 0.5)


def _in_domain(model: str, p: list[Tensor]) -> Tensor:
    """The ``(...)`` mask of parameters (``p`` unbound) inside the model's domain."""
    ok = (p[0] > 0) & (p[1] > 0)
    return ok & (p[4] > -1) & (p[5] >= 0) & (p[5] <= 1) if model == "double-sphere" else ok


def _parts(model: str, params: Tensor, x: Tensor) -> tuple[list[Tensor], list[Tensor], Tensor]:
    """The parameters and coordinates as lists of tensors in the compute dtype, and the
    ``(...)`` mask of finite parameters in the model's domain (``fu, fv > 0``; the double
    sphere's ``alpha`` in ``[0, 1]``, ``xi > -1``: else no point has ``xi d1 + z > 0``).
    Outside it the parameters are ``_SAFE``'s, and non-finite coordinates are 0 (safe where:
    finite outputs, and gradients without 0 * NaN reaching shared arguments; no host read)."""
    cd = compute_dtype(x.dtype)
    p = list(params.to(cd).unbind(-1))
    ok = _in_domain(model, p) & torch.isfinite(params).all(-1)
    p = [torch.where(ok, c, s) for c, s in zip(p, _SAFE[model], strict=True)]
    return p, list(torch.where(torch.isfinite(x), x, 0.0).to(cd).unbind(-1)), ok


def _outputs(batch: torch.Size, parts: tuple[Tensor, ...], valid: Tensor, params: Tensor,
             x: Tensor) -> tuple[Tensor, Tensor]:
    """Stack the output's components, NaN where an input is not finite (the formulas'
    finite limits, a point at infinity's pixel, must not come back; the safe-where
    replacements of the models do not look at finiteness), and ``valid`` False there."""
    finite = torch.isfinite(params).all(-1) & torch.isfinite(x).all(-1)
    out = nan_unless(finite[..., None], torch.stack(torch.broadcast_tensors(*parts), -1))
    return out.to(x.dtype).expand(*batch, len(parts)), (valid & finite).expand(batch)


def project(model: str, params: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
    r"""Pixels of points in camera axes under a camera model.

    Args:
        model: ``"pinhole"``, ``"pinhole-radtan"``, ``"pinhole-equidistant"`` or
            ``"double-sphere"`` (:data:`MODELS`).
        params: ``(..., P)`` the model's parameters in :data:`MODELS`' order; broadcasts
            against ``points``' batch.
        points: ``(..., 3)`` points in camera axes (``z`` forward).

    Returns:
        ``(pixels, valid)``: ``(..., 2)`` pixels ``(u, v)`` and a ``(...)`` bool mask, False
        where the point has no image: ``z <= 0`` for the pinhole models (and points within
        ``eps`` radians of the plane ``z = 0``, ``max(|x|, |y|) >= z / eps``, whose pixels
        or derivatives would overflow); for the double sphere where the paper's condition
        :math:`z > -w_2 d_1` (eq. 43) fails (the origin is invalid) or, for
        :math:`\xi < 0` where eq. 43 is not exact, the point lies beyond the part of the
        second sphere that the projection sees, :math:`w \le -w_1 d_2` (its pixel would
        pass through infinity to the other side of the image); where the parameters
        lie outside the model's domain (``fu <= 0`` or ``fv <= 0``; for the double sphere
        ``xi <= -1`` or ``alpha`` outside ``[0, 1]``): every element of that camera is
        invalid, a mask and not an error (no host read); and where an input is not finite
        (the pixels are NaN there). Invalid points get finite pixels with finite gradients
        (they are computed at a replacement point, out-of-domain parameters at replacement
        parameters): mask them.

    Formulas (normalised coordinates :math:`a = x/z,\ b = y/z`, :math:`r^2 = a^2 + b^2`):

    - pinhole: :math:`u = f_u a + c_u,\ v = f_v b + c_v`;
    - radtan (OpenCV ``projectPoints`` with ``k3 = 0``): :math:`a' = a (1 + k_1 r^2 +
      k_2 r^4) + 2 p_1 a b + p_2 (r^2 + 2 a^2)`, :math:`b' = b (1 + k_1 r^2 + k_2 r^4) +
      p_1 (r^2 + 2 b^2) + 2 p_2 a b`;
    - equidistant (OpenCV ``fisheye.projectPoints``): :math:`\theta = \arctan r`,
      :math:`\theta_d = \theta (1 + k_1 \theta^2 + k_2 \theta^4 + k_3 \theta^6 +
      k_4 \theta^8)`, :math:`(a', b') = (\theta_d / r) (a, b)`, evaluated through
      :math:`\arctan(r)/r` as an even function of :math:`r` (smooth on the axis);
    - double sphere (eqs. 40-43): :math:`d_1 = |p|`, :math:`d_2 = |(x, y, \xi d_1 + z)|`,
      :math:`u = f_u x / (\alpha d_2 + (1 - \alpha)(\xi d_1 + z)) + c_u` (and ``v``).

    Example:
        >>> px, ok = project("pinhole", torch.tensor([500.0, 500.0, 320.0, 240.0]),
        ...                  torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, -1.0]]))
        >>> px[0].tolist(), ok.tolist()
        ([320.0, 240.0], [True, False])
    """
    fn = "camera.project"
    batch = _checked(fn, model, params, points, "points", 3)
    p, (x, y, z), ok = _parts(model, params, points)
    u, v, valid = _PROJECT[model](p, x, y, z)
    return _outputs(batch, (u, v), valid & ok, params, points)


def _normalised(x: Tensor, y: Tensor, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(valid, a, b)``: ``z > 0`` with ``|x|, |y| < z / eps`` (points closer to the plane
    ``z = 0`` than ``eps`` radians would overflow the pixels or their derivatives), and
    ``(a, b) = (x, y) / z`` there, ``(0, 0)`` elsewhere (safe where: replaced before the
    division)."""
    far = threshold("camera_off_axis", x.dtype) * z
    valid = (z > 0) & (abs(x) < far) & (abs(y) < far)
    zs = torch.where(valid, z, 1.0)
    return valid, torch.where(valid, x, 0.0) / zs, torch.where(valid, y, 0.0) / zs


def _pinhole(p: list[Tensor], a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    return p[0] * a + p[2], p[1] * b + p[3]


def _project_pinhole(p, x, y, z):
    valid, a, b = _normalised(x, y, z)
    return (*_pinhole(p, a, b), valid)


def _radtan(k: list[Tensor], a: Tensor, b: Tensor, jacobian: bool = False) -> tuple[Tensor, ...]:
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


def _project_radtan(p, x, y, z):
    valid, a, b = _normalised(x, y, z)
    return (*_pinhole(p, *_radtan(p[4:], a, b)), valid)


def _poly(k: list[Tensor], t: Tensor) -> Tensor:
    """``1 + k1 t + k2 t^2 + k3 t^3 + k4 t^4`` (t = theta^2: theta_d = theta * _poly)."""
    return 1.0 + t * (k[0] + t * (k[1] + t * (k[2] + t * k[3])))


def _poly_slope(k: list[Tensor], t: Tensor) -> Tensor:
    """``d theta_d / d theta = 1 + 3 k1 t + 5 k2 t^2 + 7 k3 t^3 + 9 k4 t^4``."""
    return 1.0 + t * (3.0 * k[0] + t * (5.0 * k[1] + t * (7.0 * k[2] + t * 9.0 * k[3])))


def _project_equidistant(p, x, y, z):
    valid, a, b = _normalised(x, y, z)
    r2 = a * a + b * b
    ratio = even("atanc", r2)  # theta / r with theta = atan(r), smooth at r = 0
    scale = ratio * _poly(p[4:], r2 * ratio * ratio)  # theta_d / r
    return (*_pinhole(p, scale * a, scale * b), valid)


def _ds_w1(alpha: Tensor) -> Tensor:
    r""":math:`w_1` of eq. 43, safe where at :math:`\alpha = 0` and 1 (each branch sees only
    its own half of the alpha range)."""
    low = alpha <= 0.5
    a_lo, a_hi = torch.where(low, alpha, 0.5), torch.where(low, 0.5, alpha)
    return torch.where(low, a_lo / (1.0 - a_lo), (1.0 - a_hi) / a_hi)


def _ds_w2(xi: Tensor, alpha: Tensor) -> Tensor:
    r""":math:`w_2` of the double sphere's projection domain (eq. 43)."""
    w1 = _ds_w1(alpha)
    return (w1 + xi) / torch.sqrt(2.0 * w1 * xi + xi * xi + 1.0)


def _ds_sees(xi: Tensor, alpha: Tensor, x: Tensor, y: Tensor, z: Tensor) -> Tensor:
    r"""The double sphere's projection domain (no gradient): eq. 43 and :math:`w > -w_1
    d_2` (:math:`w = \xi d_1 + z`), the second sphere's part that eq. 40 sees one-to-one,
    which eq. 43 implies only for :math:`\xi \ge 0` (``xi = -0.5, alpha = 0.1``: 3 % of
    the directions beyond it, their pixels through infinity on the image's other side)."""
    d1 = torch.sqrt(x * x + y * y + z * z)
    w = xi * d1 + z
    return (z > -_ds_w2(xi, alpha) * d1) & (w > -_ds_w1(alpha) * torch.sqrt(x * x + y * y + w * w))


def _project_ds(p, x, y, z):
    # eq. 40 has degree 0: a constant scale to max |x, y, z| = 1 (no d1 = inf at 1e160, 0/0)
    s = torch.maximum(torch.maximum(abs(x), abs(y)), abs(z)).detach()
    x, y, z = (c / torch.where(s > 0, s, 1.0) for c in (x, y, z))
    with torch.no_grad():
        valid = _ds_sees(p[4], p[5], x, y, z)  # eq. 43 (and eq. 40's denominator)
    x, y, z = torch.where(valid, x, 0.0), torch.where(valid, y, 0.0), torch.where(valid, z, 1.0)
    d1 = torch.sqrt(x * x + y * y + z * z)  # eq. 41
    w = p[4] * d1 + z
    d2 = torch.sqrt(x * x + y * y + w * w)  # eq. 42
    den = p[5] * d2 + (1.0 - p[5]) * w  # eq. 40
    return (*_pinhole(p, x / den, y / den), valid)


_PROJECT: dict[str, Callable] = {
    "pinhole": _project_pinhole, "pinhole-radtan": _project_radtan,
    "pinhole-equidistant": _project_equidistant, "double-sphere": _project_ds}


def unproject(model: str, params: Tensor, pixels: Tensor) -> tuple[Tensor, Tensor]:
    r"""Unit rays of pixels under a camera model (the inverse of :func:`project`).

    Args:
        model: a name of :data:`MODELS`.
        params: ``(..., P)`` the model's parameters; broadcasts against ``pixels``' batch.
        pixels: ``(..., 2)`` pixels ``(u, v)``.

    Returns:
        ``(rays, valid)``: ``(..., 3)`` unit vectors in camera axes and a ``(...)`` bool
        mask, False where the pixel is not the image of a ray under :func:`project`, and
        everywhere for parameters outside the model's domain (``fu <= 0`` or ``fv <= 0``;
        for the double sphere ``xi <= -1`` or ``alpha`` outside ``[0, 1]``; a mask, not an
        error: no host read). Invalid rays are finite with finite gradients (out-of-domain
        parameters are replaced before the formulas); mask them:

        - pinhole: closed form, valid within :func:`project`'s ``1 / eps`` of the axis.
        - radtan: 2-D Newton on the distortion map from the distorted point (a fixed
          number of iterations, then two differentiable steps, see the module's notes).
          Invalid beyond the fold-over: where the root's radius reaches the first zero of
          :math:`d(r\,(1 + k_1 r^2 + k_2 r^4))/dr = 1 + 3 k_1 r^2 + 5 k_2 r^4`, where the
          map's Jacobian determinant is not positive, or where the iteration did not
          converge (no preimage: beyond the largest distorted radius).
        - equidistant: 1-D Newton on :math:`\theta_d(\theta) = |m|` (``m`` the normalised
          pixel) safeguarded by bisection in a bracket of the first root within
          :math:`[0, \pi/2]`. Invalid where the root is at
          or beyond 90 degrees (``z <= 0``: not an image of :func:`project`), where
          :math:`d\theta_d/d\theta \le 0` at the root (fold-over) or where it did not
          converge.
        - double sphere (eqs. 47-50): closed form; invalid outside the paper's unprojection
          domain, :math:`r^2 \ge 1/(2\alpha - 1)` for :math:`\alpha > 0.5`, where
          :math:`m_z^2 + (1 - \xi^2) r^2 \le 0` (no real point of the first sphere, possible
          for :math:`\xi > 1`), where the ray fails :func:`project`'s domain (for
          :math:`\xi \ne 0` the boundary of eq. 50 maps slightly outside it) and, for
          :math:`\xi > 1`, where it is not on the first sphere's near side,
          :math:`1 + \xi z \le 0` (eq. 50's root is then a negative distance: the ray would
          point away from the pixel's point).

    The iterations' accuracy: ``project(unproject(px)) == px`` to 1e-10 px in float64 over
    the whole image of EuRoC's cam0 (radtan) and of a 190-degree fisheye (tested).

    Example:
        >>> ray, ok = unproject("pinhole", torch.tensor([500.0, 500.0, 320.0, 240.0]),
        ...                     torch.tensor([320.0, 240.0]))
        >>> ray.tolist(), bool(ok)
        ([0.0, 0.0, 1.0], True)
    """
    fn = "camera.unproject"
    batch = _checked(fn, model, params, pixels, "pixels", 2)
    p, (u, v), ok = _parts(model, params, pixels)
    a, b = (u - p[2]) / p[0], (v - p[3]) / p[1]  # normalised (distorted) coordinates
    x, y, z, valid = _UNPROJECT[model](p, a, b)
    return _outputs(batch, (x, y, z), valid & ok, params, pixels)


def _unit(x: Tensor, y: Tensor, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    n = torch.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


def _unproject_pinhole(p, a, b):
    far = threshold("camera_off_axis", a.dtype)  # project's limit (|a|^2 would overflow)
    valid = (abs(a) < far) & (abs(b) < far)
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)
    return (*_unit(a, b, torch.ones_like(a)), valid)


def _converged(residual: Tensor, scale: Tensor) -> Tensor:
    return residual <= threshold("camera_root", residual.dtype) * (1.0 + scale)


def _radtan_fold(k: list[Tensor]) -> Tensor:
    r"""The squared radius of the radtan map's first fold: the smallest positive root
    ``s`` of :math:`1 + 3 k_1 s + 5 k_2 s^2` (as ``2 / (-3 k_1 + \sqrt{9 k_1^2 - 20
    k_2})``, stable), ``inf`` where there is none."""
    disc = 9.0 * k[0] * k[0] - 20.0 * k[1]
    den = -3.0 * k[0] + torch.sqrt(torch.clamp(disc, min=0.0))
    fold = (disc >= 0) & (den > 0)
    return torch.where(fold, 2.0 / torch.where(fold, den, 1.0), math.inf)


def _radtan_step(k, a, b, da, db, guard: bool = False):
    """One Newton step on ``_radtan(k, a, b) = (da, db)`` (with ``guard``, a determinant
    that is not positive, beyond the fold, is replaced by 1: no division by ~0)."""
    fa, fb, j00, j01, j11 = _radtan(k, a, b, jacobian=True)
    det = j00 * j11 - j01 * j01
    if guard:
        det = torch.where(det > 0, det, 1.0)
    ea, eb = fa - da, fb - db
    return a - (j11 * ea - j01 * eb) / det, b - (j00 * eb - j01 * ea) / det


def _radtan_root(k, da, db):
    """Detached Newton iterations from the distorted point divided by its radial factor
    (one fixed-point step), each start kept inside 0.999 of the first fold's disk; returns
    the root and whether it is valid."""
    fold = _radtan_fold(k)
    r2 = da * da + db * db
    radial = 1.0 + r2 * (k[0] + k[1] * r2)
    radial = torch.where(radial > 0, radial, 1.0)
    a, b = da / radial, db / radial
    for _ in range(_ITERATIONS):
        shrink = torch.sqrt(torch.clamp(0.999 * fold / (a * a + b * b), max=1.0))
        a, b = _radtan_step(k, a * shrink, b * shrink, da, db, guard=True)
    fa, fb, j00, j01, j11 = _radtan(k, a, b, jacobian=True)
    ok = (_converged(torch.maximum(abs(fa - da), abs(fb - db)), abs(da) + abs(db))
          & (a * a + b * b < fold) & (j00 * j11 - j01 * j01 > 0))
    return a, b, ok


def _unproject_radtan(p, a, b):
    k = p[4:]
    with torch.no_grad():  # detached also from forward-mode tangents
        ra, rb, valid = _radtan_root([c.detach() for c in k], a.detach(), b.detach())
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)  # safe where
    ra, rb = torch.where(valid, ra, 0.0), torch.where(valid, rb, 0.0)
    ra, rb = _radtan_step(k, ra, rb, a, b)  # exact first derivatives
    ra, rb = _radtan_step(k, ra, rb, a, b)  # exact second derivatives
    return (*_unit(ra, rb, torch.ones_like(ra)), valid)


def _equidistant_root(k, s):
    r"""Detached safeguarded Newton iterations on :math:`\theta_d(\theta) = \sqrt s` in a
    bracket ``[lo, hi]`` of the first root from :math:`[0, \pi/2]`: bisection where a Newton
    step leaves it, does not halve the step before last, or the slope is not positive
    (beyond the fold, where plain Newton stays; Press et al., Numerical Recipes, 3rd ed.,
    sec. 9.4, ``rtsafe``). Returns :math:`\rho = \theta / \theta_d` (1 at the centre)
    and whether the root is valid."""
    half_pi = 0.5 * math.pi
    td = torch.sqrt(s)
    lo, hi = torch.zeros_like(td), torch.full_like(td, half_pi)
    theta = torch.clamp(td, max=half_pi)
    dx = dx_old = hi  # the last two steps' lengths
    for _ in range(_ITERATIONS_BRACKETED):
        t = theta * theta
        g, slope = theta * _poly(k, t) - td, _poly_slope(k, t)
        rising = slope > 0
        lo = torch.where(rising & (g < 0), theta, lo)
        hi = torch.where(~rising | (g > 0), theta, hi)
        step = theta - g / torch.where(rising, slope, 1.0)
        # Newton inside the bracket and at most half the step before last (rtsafe: else it
        # bounces between the ends, 0.008 and 1.54 rad with k1 = 0.6); a root at rounding level
        # stays (its Newton step, rounded onto the bracket's end, would restart a bisection)
        newton = rising & (step > lo) & (step < hi) & (2.0 * abs(step - theta) <= dx_old)
        new = torch.where(newton, step, 0.5 * (lo + hi))
        theta, dx_old, dx = torch.where(_converged(g.abs(), td), theta, new), dx, abs(new - theta)
    t = theta * theta
    ok = (_converged(abs(theta * _poly(k, t) - td), td) & (theta < half_pi)
          & (_poly_slope(k, t) > 0))
    rho = torch.where(td > 0, theta / torch.where(td > 0, td, 1.0), 1.0)
    return rho, ok


def _unproject_equidistant(p, a, b):
    k = p[4:]
    s = a * a + b * b  # theta_d^2
    with torch.no_grad():
        rho, valid = _equidistant_root([c.detach() for c in k], s.detach())
    s, rho = torch.where(valid, s, 0.0), torch.where(valid, rho, 1.0)  # safe where
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)
    for _ in range(2):  # Newton on rho P(rho^2 s) = 1: exact first, then second derivatives
        t = rho * rho * s  # theta^2
        rho = rho - (rho * _poly(k, t) - 1.0) / _poly_slope(k, t)
    t = rho * rho * s
    side = even("sinc", t) * rho  # sin(theta) / theta_d
    return side * a, side * b, even("cos", t), valid


def _ds_ray(xi: Tensor, alpha: Tensor, a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The double sphere's unprojection (eqs. 47-50): a unit ray."""
    r2 = a * a + b * b
    mz = (1.0 - alpha * alpha * r2) / (
        alpha * torch.sqrt(1.0 - (2.0 * alpha - 1.0) * r2) + 1.0 - alpha)  # m_z
    scale = (mz * xi + torch.sqrt(mz * mz + (1.0 - xi * xi) * r2)) / (mz * mz + r2)
    return scale * a, scale * b, scale * mz - xi


def _unproject_ds(p, a, b):
    xi, alpha = p[4], p[5]
    with torch.no_grad():  # where the formula's square roots are real (safe where)
        r2 = a * a + b * b
        inside = (alpha <= 0.5) | (r2 * (2.0 * alpha - 1.0) < 1.0)  # the paper's domain
        mz = (1.0 - alpha * alpha * r2) / (
            alpha * torch.sqrt(torch.clamp(1.0 - (2.0 * alpha - 1.0) * r2, min=0.0))
            + 1.0 - alpha)
        keep = inside & (mz * mz + (1.0 - xi * xi) * r2 > 0)  # a first sphere's point
    x, y, z = _ds_ray(xi, alpha, torch.where(keep, a, 0.0), torch.where(keep, b, 0.0))
    # project's domain on the ray (eq. 50's boundary maps slightly outside it for xi != 0)
    # and, for xi > 1, the first sphere's near side (else eq. 50's root is negative)
    with torch.no_grad():
        return x, y, z, keep & _ds_sees(xi, alpha, x, y, z) & (1.0 + xi * z > 0)


_UNPROJECT: dict[str, Callable] = {
    "pinhole": _unproject_pinhole, "pinhole-radtan": _unproject_radtan,
    "pinhole-equidistant": _unproject_equidistant, "double-sphere": _unproject_ds}


# Kalibr's (camera_model, distortion_model) of each model, and back.
_KALIBR = {"pinhole": ("pinhole", "none"), "pinhole-radtan": ("pinhole", "radtan"),
           "pinhole-equidistant": ("pinhole", "equidistant"), "double-sphere": ("ds", "none")}
_FROM_KALIBR = {names: model for model, names in _KALIBR.items()}


def _numbers(fn: str, name: str, value, count: int) -> list[float]:
    """A list of ``count`` finite real numbers (a list, tuple, 1-D array or tensor)."""
    value = _checks.listed(value)
    ok = isinstance(value, Sequence) and not isinstance(value, str) and len(value) == count
    ok = ok and all(isinstance(v, numbers.Real) and not isinstance(v, bool)
                    and math.isfinite(v) for v in value)
    if not ok:
        want = f"a list of {count} finite numbers" if count else "empty (or zeros): no distortion"
        _checks.fail(fn, f"expected {name} to be {want}, got {value!r}")
    return [float(v) for v in value]


def _normalised_hint(pixels: Tensor, params: Tensor) -> str | None:
    """A sentence where ``(M, 2)`` measured pixels look like normalised image coordinates
    (``x / z``, ``y / z``) of a camera with the ``(P,)`` params: all of them within 4 of
    ``(0, 0)``, the top-left pixel, while the principal point lies over 20 px from it;
    else None. (A target seen in pixels is spread over more than a few pixels and sits
    near the image's corner only by accident.)"""
    if pixels.numel() == 0:
        return None
    reach = float(pixels.detach().abs().max())
    centre = float(params.detach()[2:4].abs().min())
    if reach >= 4.0 or centre <= 20.0:
        return None
    return (f"the pixels all lie within {reach:.3g} of (0, 0) while the principal point is "
            f"at ({float(params[2]):.6g}, {float(params[3]):.6g}): they look like normalised "
            f"coordinates (x/z, y/z), not pixels; project them with the camera's "
            f"intrinsics (u = fu x/z + cu, v = fv y/z + cv, then the distortion)")


def _outside(pixels: Tensor, resolution: tuple[int, int],
             slack: float = 0.0) -> tuple[str, float, str] | None:
    """Where ``(M, 2)`` measured pixels leave an image of ``resolution`` ``(width, height)``:
    ``(0, 0)`` is the top-left pixel's centre, so ``u`` in ``[-0.5, width - 0.5]`` and ``v``
    in ``[-0.5, height - 0.5]``, each widened by ``slack`` times the image's size. None when
    all lie inside, else the axis (``"u"`` or ``"v"``), the farthest value and the range
    expected (text)."""
    if pixels.numel() == 0:
        return None
    for axis, name, size in ((0, "u", resolution[0]), (1, "v", resolution[1])):
        lo, hi = float(pixels[:, axis].min()), float(pixels[:, axis].max())
        low, high = -0.5 - slack * size, size - 0.5 + slack * size
        if lo < low or hi > high:
            return name, lo if lo < low else hi, f"{name} in [{low:.6g}, {high:.6g}]"
    return None


def _yaml_number(value):
    """``value``, or the number a string reads as: YAML 1.1 (PyYAML) reads ``2e-4`` (no dot)
    as a string, and a quoted ``'6'`` is one; an integral string reads as an ``int``."""
    for kind in (int, float) if isinstance(value, str) else ():
        with contextlib.suppress(ValueError):
            return kind(value)
    return value


def _kalibr_list(value) -> list | object:
    """A Kalibr list (or 1-D array) with :func:`_yaml_number` applied (others as they are)."""
    if isinstance(value := _checks.listed(value), Sequence) and not isinstance(value, str):
        return [_yaml_number(v) for v in value]
    return value


def _resolution(fn: str, res) -> tuple[int, int]:
    """``(width, height)``: two positive ints."""
    res = _checks.listed(res)
    if (not isinstance(res, Sequence) or isinstance(res, str) or len(res) != 2
            or not all(isinstance(n, numbers.Integral) and not isinstance(n, bool)
                       and int(n) > 0 for n in res)):
        _checks.fail(fn, f"expected resolution to be (width, height), two positive ints, "
                         f"got {res!r}")
    return int(res[0]), int(res[1])


@dataclass(frozen=True, eq=False)
class Camera:
    r"""A camera: a model of :data:`MODELS`, its ``(P,)`` parameters and its resolution.

    A small frozen value; :meth:`project` and :meth:`unproject` are :func:`project` and
    :func:`unproject` with this camera's model and parameters. Two cameras are equal when
    their models, resolutions and parameters (dtype included) are.

    Args:
        model: a name of :data:`MODELS`.
        params: ``(P,)`` floating tensor in the model's order (a sequence of numbers is
            turned into a float64 tensor).
        resolution: ``(width, height)`` in pixels, positive ints.

    Raises:
        ValueError: an unknown model, params of the wrong shape, not finite or outside the
            model's domain (``fu``, ``fv`` not positive; for the double sphere ``xi <= -1``
            or ``alpha`` outside ``[0, 1]``: a camera that projects nothing), a bad
            resolution.
        TypeError: params that are not floating point.

    Example:
        >>> cam = Camera.from_kalibr({
        ...     "camera_model": "pinhole", "distortion_model": "radtan",
        ...     "intrinsics": [458.654, 457.296, 367.215, 248.375],
        ...     "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
        ...     "resolution": [752, 480]})
        >>> cam.model, cam.resolution, cam.params.dtype
        ('pinhole-radtan', (752, 480), torch.float64)
        >>> Camera.from_kalibr(cam.to_kalibr()) == cam
        True
    """

    model: str
    params: Tensor
    resolution: tuple[int, int]

    def __post_init__(self) -> None:
        fn = "camera.Camera"
        if not isinstance(self.model, str) or self.model not in MODELS:
            _checks.fail(fn, f"expected model to be one of {', '.join(map(repr, MODELS))}, "
                             f"got {self.model!r}")
        params = self.params
        if not isinstance(params, Tensor):
            params = torch.tensor(_numbers(fn, "params", params, len(MODELS[self.model])),
                                  dtype=torch.float64)
        _checks.tensor(fn, "params", params)
        if params.shape != (len(MODELS[self.model]),):
            _checks.fail(fn, f"expected a ({len(MODELS[self.model])},) tensor for params of a "
                             f"{self.model!r} camera, got shape {_checks.shape_str(params.shape)}")
        values = params.detach()
        if not bool((torch.isfinite(values).all() & _in_domain(self.model, list(values))).item()):
            limits = " > -1, alpha in [0, 1]" if self.model == "double-sphere" else ""
            _checks.fail(fn, f"expected finite params of a {self.model!r} camera with fu, fv "
                             f"> 0{' and xi' + limits if limits else ''} ("
                             f"{', '.join(MODELS[self.model])}), got {values.tolist()}")
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "resolution", _resolution(fn, self.resolution))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (self.model == other.model and self.resolution == other.resolution
                and self.params.dtype == other.params.dtype
                and torch.equal(self.params.cpu(), other.params.cpu()))

    __hash__ = None  # type: ignore[assignment]  # equal by value, and tensors are mutable

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """:func:`project` with this camera: ``(pixels (..., 2), valid (...))``."""
        return project(self.model, self.params, points)

    def unproject(self, pixels: Tensor) -> tuple[Tensor, Tensor]:
        """:func:`unproject` with this camera: ``(rays (..., 3), valid (...))``."""
        return unproject(self.model, self.params, pixels)

    def to(self, *args, **kwargs) -> Camera:
        """The camera with its params moved or cast by ``Tensor.to(*args, **kwargs)``."""
        return Camera(self.model, self.params.to(*args, **kwargs), self.resolution)

    @classmethod
    def from_kalibr(cls, entry: Mapping, *, dtype: torch.dtype = torch.float64,
                    device=None) -> Camera:
        """Read one camera of a Kalibr ``camchain.yaml`` (the mapping under ``cam0``, ...).

        Args:
            entry: with ``camera_model`` (``pinhole`` or ``ds``), ``distortion_model``
                (``none``, ``radtan``, ``equidistant``; absent means ``none``),
                ``intrinsics`` (``[fu, fv, pu, pv]``; ``[xi, alpha, fu, fv, pu, pv]`` for
                ``ds``), ``distortion_coeffs`` (4 numbers for radtan and equidistant, none
                or zeros otherwise) and ``resolution`` (``[width, height]``, ints or
                integral floats); other keys (``T_cam_imu``, ``rostopic``, ...) are
                ignored. Numbers written without a dot (``2e-4``), which YAML 1.1 (PyYAML)
                reads as strings, are read as numbers.
            dtype, device: of the params tensor.

        Raises:
            ValueError: an unknown camera or distortion model (Kalibr's ``omni``, ``eucm``,
                ``fov``, ... are not supported), or malformed numbers, naming the key.
        """
        fn = "camera.Camera.from_kalibr"
        if not isinstance(entry, Mapping):
            _checks.fail(fn, f"expected a mapping (one camera of a camchain), got "
                             f"{type(entry).__name__}", TypeError)
        names = (entry.get("camera_model"), entry.get("distortion_model", "none"))
        if not all(isinstance(n, str) for n in names) or names not in _FROM_KALIBR:
            _checks.fail(fn, f"unsupported camera_model {names[0]!r} with distortion_model "
                             f"{names[1]!r}: expected pinhole with none, radtan or "
                             f"equidistant, or ds with none")
        model = _FROM_KALIBR[names]
        intr = _numbers(fn, "intrinsics", _kalibr_list(entry.get("intrinsics")),
                        6 if names[0] == "ds" else 4)
        raw = _kalibr_list(entry.get("distortion_coeffs", []))
        if names[1] == "none" and isinstance(raw, list) and all(
                isinstance(v, numbers.Real) and v == 0 for v in raw):
            raw = []  # no distortion written as zeros
        coeffs = _numbers(fn, "distortion_coeffs", raw, 0 if names[1] == "none" else 4)
        params = intr[2:] + intr[:2] if names[0] == "ds" else intr + coeffs
        res = _kalibr_list(entry.get("resolution"))
        if isinstance(res, list):  # 752.0: an integral float is the int
            res = [int(v) if isinstance(v, float) and v.is_integer() else v for v in res]
        return cls(model, torch.tensor(params, dtype=dtype, device=device),
                   _resolution(fn, res))

    def to_kalibr(self) -> dict:
        """This camera as one entry of a Kalibr ``camchain.yaml``: a dict of plain Python
        strings, floats and lists (``yaml.safe_dump`` writes it), the inverse of
        :meth:`from_kalibr` (float64 parameters round-trip exactly)."""
        camera_model, distortion = _KALIBR[self.model]
        p = [float(v) for v in self.params.detach().cpu().double().tolist()]
        intrinsics, coeffs = (p[4:] + p[:4], []) if camera_model == "ds" else (p[:4], p[4:])
        return {"camera_model": camera_model, "intrinsics": intrinsics,
                "distortion_model": distortion, "distortion_coeffs": coeffs,
                "resolution": list(self.resolution)}

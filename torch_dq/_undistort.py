r"""Unprojection of the distorted pinhole models by iteration (private; the public entry
point is ``torch_dq.camera.unproject``).

Neither the radtan nor the equidistant map has a closed-form inverse. Each root is found by
a fixed number of detached iterations (no data-dependent branching or host reads:
``torch.func.vmap`` and ``torch.compile(fullgraph=True)`` go through), then the derivatives
are attached by two Newton steps from that detached root: one step ``x - J(x)^{-1} (F(x) -
y)`` from a detached root has the implicit function's exact first derivatives, a second step
from it the exact second derivatives too (the Newton map's derivative in ``x`` vanishes at
the root).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ._camera_models import poly, poly_slope, radtan, unit
from ._numerics import even, threshold

__all__ = ["unproject_equidistant", "unproject_radtan"]

# Newton iterations of the detached radtan root search (2-D on the normalised point). Over
# whole images (tests/test_camera.py) the residual reaches rounding (2e-16) after 4 on EuRoC's
# cam0, 6 on a stronger lens (k1 = -0.35, f = 300 px on 752 x 480): 8 leave a margin (the two
# differentiable steps that follow square the error twice more).
_ITERATIONS = 8
# The equidistant root's safeguarded iteration (rtsafe): 12 steps invert every pixel inside
# the fold of a strong fisheye (k1 = 0.6, tests/test_rigs_cameras.py: 401 x 401 on 800 x 600).
_ITERATIONS_BRACKETED = 12


def converged(residual: Tensor, scale: Tensor) -> Tensor:
    return residual <= threshold("camera_root", residual.dtype) * (1.0 + scale)


def radtan_fold(k: list[Tensor]) -> Tensor:
    r"""The squared radius of the radtan map's first fold: the smallest positive root
    ``s`` of :math:`1 + 3 k_1 s + 5 k_2 s^2` (as ``2 / (-3 k_1 + \sqrt{9 k_1^2 - 20
    k_2})``, stable), ``inf`` where there is none."""
    disc = 9.0 * k[0] * k[0] - 20.0 * k[1]
    den = -3.0 * k[0] + torch.sqrt(torch.clamp(disc, min=0.0))
    fold = (disc >= 0) & (den > 0)
    return torch.where(fold, 2.0 / torch.where(fold, den, 1.0), math.inf)


def radtan_step(k, a, b, da, db, guard: bool = False):
    """One Newton step on ``radtan(k, a, b) = (da, db)`` (with ``guard``, a determinant
    that is not positive, beyond the fold, is replaced by 1: no division by ~0)."""
    fa, fb, j00, j01, j11 = radtan(k, a, b, jacobian=True)
    det = j00 * j11 - j01 * j01
    if guard:
        det = torch.where(det > 0, det, 1.0)
    ea, eb = fa - da, fb - db
    return a - (j11 * ea - j01 * eb) / det, b - (j00 * eb - j01 * ea) / det


def radtan_root(k, da, db):
    """Detached Newton iterations from the distorted point divided by its radial factor
    (one fixed-point step), each start kept inside 0.999 of the first fold's disk; returns
    the root and whether it is valid."""
    fold = radtan_fold(k)
    r2 = da * da + db * db
    radial = 1.0 + r2 * (k[0] + k[1] * r2)
    radial = torch.where(radial > 0, radial, 1.0)
    a, b = da / radial, db / radial
    for _ in range(_ITERATIONS):
        shrink = torch.sqrt(torch.clamp(0.999 * fold / (a * a + b * b), max=1.0))
        a, b = radtan_step(k, a * shrink, b * shrink, da, db, guard=True)
    fa, fb, j00, j01, j11 = radtan(k, a, b, jacobian=True)
    ok = (converged(torch.maximum(abs(fa - da), abs(fb - db)), abs(da) + abs(db))
          & (a * a + b * b < fold) & (j00 * j11 - j01 * j01 > 0))
    return a, b, ok


def unproject_radtan(p, a, b):
    k = p[4:]
    with torch.no_grad():  # detached also from forward-mode tangents
        ra, rb, valid = radtan_root([c.detach() for c in k], a.detach(), b.detach())
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)  # safe where
    ra, rb = torch.where(valid, ra, 0.0), torch.where(valid, rb, 0.0)
    ra, rb = radtan_step(k, ra, rb, a, b)  # exact first derivatives
    ra, rb = radtan_step(k, ra, rb, a, b)  # exact second derivatives
    return (*unit(ra, rb, torch.ones_like(ra)), valid)


def equidistant_root(k, s):
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
        g, slope = theta * poly(k, t) - td, poly_slope(k, t)
        rising = slope > 0
        lo = torch.where(rising & (g < 0), theta, lo)
        hi = torch.where(~rising | (g > 0), theta, hi)
        step = theta - g / torch.where(rising, slope, 1.0)
        # Newton inside the bracket and at most half the step before last (rtsafe: else it
        # bounces between the ends, 0.008 and 1.54 rad with k1 = 0.6); a root at rounding level
        # stays (its Newton step, rounded onto the bracket's end, would restart a bisection)
        newton = rising & (step > lo) & (step < hi) & (2.0 * abs(step - theta) <= dx_old)
        new = torch.where(newton, step, 0.5 * (lo + hi))
        theta, dx_old, dx = torch.where(converged(g.abs(), td), theta, new), dx, abs(new - theta)
    t = theta * theta
    ok = (converged(abs(theta * poly(k, t) - td), td) & (theta < half_pi)
          & (poly_slope(k, t) > 0))
    rho = torch.where(td > 0, theta / torch.where(td > 0, td, 1.0), 1.0)
    return rho, ok


def unproject_equidistant(p, a, b):
    k = p[4:]
    s = a * a + b * b  # theta_d^2
    with torch.no_grad():
        rho, valid = equidistant_root([c.detach() for c in k], s.detach())
    s, rho = torch.where(valid, s, 0.0), torch.where(valid, rho, 1.0)  # safe where
    a, b = torch.where(valid, a, 0.0), torch.where(valid, b, 0.0)
    for _ in range(2):  # Newton on rho P(rho^2 s) = 1: exact first, then second derivatives
        t = rho * rho * s  # theta^2
        rho = rho - (rho * poly(k, t) - 1.0) / poly_slope(k, t)
    t = rho * rho * s
    side = even("sinc", t) * rho  # sin(theta) / theta_d
    return side * a, side * b, even("cos", t), valid



r"""Unprojection of the distorted pinhole models by iteration (private; the public entry
point is ``torch_dq.camera.unproject``).

Neither the radtan nor the equidistant map has a closed-form inverse. Each root is found by
a fixed number of detached iterations (no data-dependent branching or host reads:
``torch.func.vmap`` and ``torch.compile(fullgraph=True)`` go through; in plain eager mode
the radtan iteration stops once every pixel is at rounding, read every 4 steps: a pixel at
rounding moves no more, so the bits are the same), then the derivatives are attached by two
Newton steps from that detached root: one step ``x - J(x)^{-1} (F(x) - y)`` from a detached
root has the implicit function's exact first derivatives, a second step from it the exact
second derivatives too (the Newton map's derivative in ``x`` vanishes at the root).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torch._C._functorch import is_functorch_wrapped_tensor

from ._camera_models import poly, poly_slope, radtan, unit
from ._numerics import even, threshold

__all__ = ["unproject_equidistant", "unproject_radtan"]

# Damped Newton iterations of the detached radtan root search (2-D on the normalised point).
# Over whole images the residual reaches rounding (2e-16) after 4 on EuRoC's cam0; near a fold
# (k1 = -0.4, k2 = 0.05; k1 = -0.3) or a near-fold (k1 = -0.45, k2 = 0.1: the radial slope
# dips to 0.09), 12 leave 1e-3 of the pixels inside the fold unconverged, 16 leave 3e-5, all
# at roots within 2e-5 of the fold's radius or, with tangential terms, where the Jacobian's
# determinant is below 1e-5 (tests/test_cam13_radtan.py; plain Newton, 8 steps, left 2 % and
# 9 %: it bounced between the fold and the far side of the root).
_ITERATIONS = 16
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


def radtan_step(k, a, b, da, db):
    """One Newton step on ``radtan(k, a, b) = (da, db)``."""
    return _newton(a, b, _radtan_error(k, a, b, da, db))


_Error = tuple[Tensor, Tensor, Tensor, Tensor, Tensor]


def _radtan_error(k, a, b, da, db) -> _Error:
    """The radtan map's error ``(ea, eb) = radtan(k, a, b) - (da, db)`` and its Jacobian."""
    fa, fb, j00, j01, j11 = radtan(k, a, b, jacobian=True)
    return fa - da, fb - db, j00, j01, j11


def _newton(a: Tensor, b: Tensor, error: _Error, guard: bool = False) -> tuple[Tensor, Tensor]:
    """The Newton step's end from ``(a, b)`` with ``_radtan_error`` there (with ``guard``, a
    determinant that is not positive, beyond the fold, is replaced by 1)."""
    ea, eb, j00, j01, j11 = error
    det = j00 * j11 - j01 * j01
    if guard:
        det = torch.where(det > 0, det, 1.0)
    return a - (j11 * ea - j01 * eb) / det, b - (j00 * eb - j01 * ea) / det


def radtan_root(k, da, db):
    """Detached damped Newton iterations (a step taken where it lowers the error's largest
    component and stays inside the first fold's disk, else halved for the next iteration,
    doubled back to a full step after a success: a globalised Newton method, Nocedal and
    Wright, Numerical Optimization, 2nd ed., sec. 11.2) from the distorted point divided by
    its radial factor, kept inside 0.999 of the fold's disk; returns the root and whether
    it is valid (converged, inside the fold, a positive Jacobian determinant)."""
    fold = radtan_fold(k)
    r2 = da * da + db * db
    radial = 1.0 + r2 * (k[0] + k[1] * r2)
    radial = torch.where(radial > 0, radial, 1.0)
    a, b = da / radial, db / radial
    shrink = torch.sqrt(torch.clamp(0.999 * fold / (a * a + b * b), max=1.0))
    a, b = a * shrink, b * shrink
    e = _radtan_error(k, a, b, da, db)
    error, damping = torch.maximum(abs(e[0]), abs(e[1])), torch.ones_like(a)
    na, nb = _newton(a, b, e, guard=True)
    scale, eager = abs(da) + abs(db), _eager(da)
    for i in range(_ITERATIONS):
        if eager and i % 4 == 0 and i and bool(converged(error, scale).all()):
            break  # every pixel at rounding (a check per 4 steps: few host syncs)
        step_a, step_b = na - a, nb - b
        na, nb = a + damping * step_a, b + damping * step_b
        e = _radtan_error(k, na, nb, da, db)
        new_error = torch.maximum(abs(e[0]), abs(e[1]))
        better = (new_error < error) & (na * na + nb * nb < fold) & ~converged(error, scale)
        a, b = torch.where(better, na, a), torch.where(better, nb, b)
        error = torch.where(better, new_error, error)
        damping = torch.where(better, torch.clamp(2.0 * damping, max=1.0), 0.5 * damping)
        na, nb = _newton(na, nb, e, guard=True)  # the next full step's end
        na, nb = torch.where(better, na, a + step_a), torch.where(better, nb, b + step_b)
    e = _radtan_error(k, a, b, da, db)
    ok = (converged(error, scale) & (a * a + b * b < fold)
          & (e[2] * e[4] - e[3] * e[3] > 0))
    return a, b, ok


def _eager(x: Tensor) -> bool:
    """Whether an iteration on ``x`` may read its convergence on the host and stop: not
    under ``torch.compile`` nor a ``torch.func`` transform (``vmap``)."""
    return not torch.compiler.is_compiling() and not is_functorch_wrapped_tensor(x)


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



"""``camera.unproject("pinhole-radtan", ...)`` near and beyond the fold (API.md,
torch_dq.camera: "exact to 1e-12 in the image"), against the plumb-bob map written here in
numpy, OpenCV's ``undistortPoints`` and ``scipy.optimize.root``.

A radtan lens folds where the radial map ``r (1 + k1 r^2 + k2 r^4)`` stops rising, at the
first root ``s = r^2`` of ``1 + 3 k1 s + 5 k2 s^2``: a pixel is valid exactly where it has a
preimage inside that radius with a positive Jacobian determinant.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import scipy.optimize
import torch

from torch_dq import camera

F64 = torch.float64
WIDTH, HEIGHT = 752, 480
# fu, fv, cu, cv and (k1, k2, p1, p2): folding lenses (one with tangential terms), one whose
# radial slope dips to 0.09 without folding (plain Newton left 9 % of its pixels invalid) and
# one without a fold (30 % of the points within radius 2 left invalid)
LENSES = {
    "no-fold": [300.0, 300.0, 376.0, 240.0, -0.4, 0.2, 0.0, 0.0],
    "fold": [300.0, 300.0, 376.0, 240.0, -0.4, 0.05, 0.0, 0.0],
    "fold-k2-0": [300.0, 300.0, 376.0, 240.0, -0.3, 0.0, 0.0, 0.0],
    "fold-tangential": [300.0, 300.0, 376.0, 240.0, -0.4, 0.05, 1e-3, -1e-3],
    "near-fold": [300.0, 300.0, 376.0, 240.0, -0.45, 0.1, 0.002, 0.001],
}


def fold_s(k1, k2):
    """The fold's squared radius (inf without one), from the quadratic formula."""
    roots = np.roots([5 * k2, 3 * k1, 1.0]) if k2 != 0 else np.array([-1 / (3 * k1)])
    real = [r.real for r in np.atleast_1d(roots) if abs(r.imag) < 1e-14 and r.real > 0]
    return min(real) if real else np.inf


def distort(p, a, b):
    """OpenCV's plumb bob (k3 = 0) on normalised coordinates."""
    k1, k2, p1, p2 = p[4:]
    r2 = a * a + b * b
    rad = 1 + k1 * r2 + k2 * r2 * r2
    return (a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a),
            b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b)


def jac(p, a, b):
    """The plumb bob's Jacobian ``(..., 2, 2)`` by its derivatives written out."""
    k1, k2, p1, p2 = p[4:]
    r2 = a * a + b * b
    rad = 1 + k1 * r2 + k2 * r2 * r2
    drad = 2 * k1 + 4 * k2 * r2  # d rad / da = drad * a
    return np.stack([np.stack([rad + drad * a * a + 2 * p1 * b + 6 * p2 * a,
                               drad * a * b + 2 * p1 * a + 2 * p2 * b], -1),
                     np.stack([drad * a * b + 2 * p1 * a + 2 * p2 * b,
                               rad + drad * b * b + 6 * p1 * b + 2 * p2 * a], -1)], -2)


def to_pixels(p, a, b):
    da, db = distort(p, a, b)
    return np.stack([p[0] * da + p[2], p[1] * db + p[3]], -1)


def _unproject(p, px, dtype=F64):
    rays, ok = camera.unproject("pinhole-radtan", torch.tensor(p, dtype=dtype),
                                torch.tensor(px, dtype=dtype))
    return rays.double().numpy(), ok.numpy()


def _inside(p, n, margin, seed=0):
    """``n`` points uniform in the fold's disk (radius 2 without a fold) at least ``margin``
    of its radius from it, with a Jacobian determinant above 1e-4: their preimages."""
    rng = np.random.default_rng(seed)
    s = fold_s(*p[4:6])
    rmax = np.sqrt(s) * (1 - margin) if np.isfinite(s) else 2.0
    r, t = rmax * np.sqrt(rng.uniform(0, 1, 4 * n)), rng.uniform(0, 2 * np.pi, 4 * n)
    a, b = r * np.cos(t), r * np.sin(t)
    keep = np.linalg.det(jac(p, a, b)) > 1e-4
    return a[keep][:n], b[keep][:n]


@pytest.mark.parametrize("lens", list(LENSES))
def test_every_pixel_inside_the_fold_is_valid(lens):
    """Points up to 1e-5 of the fold's radius: every pixel valid (8 plain Newton steps left
    2 % of them invalid on the folding lenses, 9 % on the near-fold one), the root within
    1e-9 of the point (the root is ill-conditioned at the fold) and re-projecting to 1e-12 of
    the image."""
    p = LENSES[lens]
    a, b = _inside(p, 20000, 1e-5)
    px = to_pixels(p, a, b)
    rays, ok = _unproject(p, px)
    assert ok.all(), f"{(~ok).sum()} of {len(ok)} invalid"
    m = rays[:, :2] / rays[:, 2:]
    assert np.abs(m - np.stack([a, b], -1)).max() < 1e-9
    assert np.abs(to_pixels(p, m[:, 0], m[:, 1]) - px).max() < 1e-12 * WIDTH


@pytest.mark.parametrize("lens", ["fold", "fold-k2-0"])
def test_valid_exactly_inside_the_folds_image(lens):
    """Radial lenses: a pixel's preimage inside the fold exists exactly where its distorted
    radius is below the fold's, ``g(r_f)``: pixels at radii 1e-6 below it valid, 1e-6 above
    it and beyond invalid, in every direction."""
    p = LENSES[lens]
    rf = np.sqrt(fold_s(*p[4:6]))
    gf = rf * (1 + p[4] * rf**2 + p[5] * rf**4)
    t = np.linspace(0, 2 * np.pi, 37)
    for factor, expect in ((0.5, True), (1 - 1e-6, True), (1 + 1e-6, False), (1.01, False),
                           (3.0, False)):
        d = gf * factor
        px = np.stack([p[0] * d * np.cos(t) + p[2], p[1] * d * np.sin(t) + p[3]], -1)
        rays, ok = _unproject(p, px)
        assert (ok == expect).all(), (factor, ok)
        assert np.isfinite(rays).all()


def test_matches_opencv_and_scipy_on_the_image():
    """A 61 x 41 grid over the image of the tangential folding lens at f = 600 px (the
    fold's image a circle of about 390 px: the corners beyond it): where OpenCV's fixed-point
    iteration (200 steps) re-projects onto the pixel from inside the fold, and where a scipy
    root of the numpy map started at the distorted point lands inside the fold, the rays
    agree to 1e-10 and are valid; the pixels without either are invalid (OpenCV's answers
    there lie beyond the fold, on the map's second rising branch)."""
    p = [600.0, 600.0, *LENSES["fold-tangential"][2:]]
    u, v = np.meshgrid(np.linspace(0, WIDTH - 1, 61), np.linspace(0, HEIGHT - 1, 41))
    px = np.stack([u.ravel(), v.ravel()], -1)
    rays, ok = _unproject(p, px)
    mine = rays[:, :2] / rays[:, 2:]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)
    kmat = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    cv = cv2.undistortPoints(px[:, None], kmat, np.array([*p[4:], 0.0]), None, None, None,
                             crit)[:, 0]
    cv_good = ((np.abs(to_pixels(p, cv[:, 0], cv[:, 1]) - px).max(-1) < 1e-9)
               & ((cv * cv).sum(-1) < fold_s(*p[4:6])))
    assert 0.5 * len(px) < cv_good.sum() < len(px)
    assert ok[cv_good].all() and np.abs(mine[cv_good] - cv[cv_good]).max() < 1e-10
    m = np.stack([(px[:, 0] - p[2]) / p[0], (px[:, 1] - p[3]) / p[1]], -1)
    found = np.zeros(len(px), bool)
    for i, (da, db) in enumerate(m):
        sol = scipy.optimize.root(lambda x, da=da, db=db: np.array(distort(p, *x)) - (da, db),
                                  [da, db], jac=lambda x: jac(p, *x), tol=1e-15)
        x = sol.x
        if (np.abs(np.array(distort(p, *x)) - (da, db)).max() < 1e-13
                and x @ x < fold_s(*p[4:6]) and np.linalg.det(jac(p, *x)) > 0):
            found[i] = True
            assert np.abs(mine[i] - x).max() < 1e-10
    assert found.sum() > 0.5 * len(px) and ok[found].all() and not ok[~found & ~cv_good].any()


@pytest.mark.parametrize("lens", ["fold", "fold-tangential", "near-fold"])
@pytest.mark.parametrize("where", [0.3, 0.995])
def test_derivatives_ordinary_and_near_fold(lens, where):
    """At a pixel whose root lies at 0.3 and at 0.995 of the fold's radius: the ray's
    derivatives in the pixel and in k1 are the implicit function's, ``J^-1`` and ``-J^-1
    r^2 (a, b)`` from the numpy map, and gradcheck / gradgradcheck pass w.r.t. pixels and
    params (steps of 1e-8 near the fold, where 1e-6 differences are 5e-4 off)."""
    p = LENSES[lens]
    s = fold_s(*p[4:6])
    r = where * (np.sqrt(s) if np.isfinite(s) else 1.5)
    a, b = r * np.cos(0.7), r * np.sin(0.7)
    px = torch.tensor(to_pixels(p, np.array([a]), np.array([b])), dtype=F64,
                      requires_grad=True)
    prm = torch.tensor(p, dtype=F64, requires_grad=True)

    def normalised(pix, params):
        rays, ok = camera.unproject("pinhole-radtan", params, pix)
        assert bool(ok.all())
        return rays[..., :2] / rays[..., 2:]

    got = torch.autograd.functional.jacobian(lambda x: normalised(x, prm.detach()), px)
    want = np.linalg.inv(jac(p, np.array(a), np.array(b))) / np.array([p[0], p[1]])
    np.testing.assert_allclose(got[0, :, 0, :].numpy(), want, rtol=1e-9, atol=1e-12)
    got = torch.autograd.functional.jacobian(lambda k: normalised(px.detach(), k), prm)
    want = -np.linalg.solve(jac(p, np.array(a), np.array(b)), (a * a + b * b) * np.array([a, b]))
    np.testing.assert_allclose(got[0, :, 4].numpy(), want, rtol=1e-9)
    eps = 1e-6 if where < 0.9 else 1e-8
    assert torch.autograd.gradcheck(normalised, (px, prm), eps=eps)
    assert torch.autograd.gradgradcheck(normalised, (px, prm), eps=eps)


@pytest.mark.parametrize("lens", list(LENSES))
def test_float32_accuracy(lens):
    """float32 (pixels and params): inside 1e-3 of the fold's radius every pixel valid and
    re-projecting (float64 numpy) within 2e-3 px; the ray within 1e-4 (normalised) of the
    float64 answer away from the fold (determinant above 0.05). Measured: 1.8e-4 px,
    4e-6."""
    p = LENSES[lens]
    a, b = _inside(p, 20000, 1e-3, seed=1)
    px = to_pixels(p, a, b).astype(np.float32).astype(np.float64)
    rays, ok = _unproject(p, px, torch.float32)
    assert ok.all(), f"{(~ok).sum()} invalid"
    m = rays[:, :2] / rays[:, 2:]
    assert np.abs(to_pixels(p, m[:, 0], m[:, 1]) - px).max() < 2e-3
    well = np.linalg.det(jac(p, a, b)) > 0.05
    ref, _ = _unproject(p, px)
    assert np.abs(m[well] - (ref[:, :2] / ref[:, 2:])[well]).max() < 1e-4

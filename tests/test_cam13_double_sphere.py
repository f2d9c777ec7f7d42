"""The double sphere's ``valid`` for xi in (0, 2], alpha in [0, 1] (API.md, torch_dq.camera;
Usenko, Demmel, Cremers 2018, eqs. 40-50) against the paper's formulas written here in numpy.

For xi > 1 the second sphere's centre ``(0, 0, -xi)`` lies outside the first sphere: a line
through it meets the first sphere twice, and both points have one pixel. Eq. 43 admits part
of the entry side there (the points nearer that centre); ``valid`` keeps the exit side,
``d1 + xi z > 0`` (eq. 50's root), so that a valid point's pixel unprojects to its own ray.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch

from torch_dq import camera

F64 = torch.float64
XIS = [0.25, 0.5, 1.0, 1.2, 1.5, 2.0]
ALPHAS = [0.0, 0.3, 0.5, 0.7, 1.0]


def _w(alpha):
    w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha  # eq. 43
    return w1


def ref_project(xi, alpha, pts):
    """Eqs. 40-42 (unit focal lengths, no offset) and the domain: eq. 43, the second sphere
    seen one-to-one (``w > -w1 d2``) and the first sphere's exit side (``d1 + xi z > 0``);
    also the smallest margin of the three conditions (relative)."""
    x, y, z = pts.T
    d1 = np.sqrt(x * x + y * y + z * z)
    w = xi * d1 + z
    d2 = np.sqrt(x * x + y * y + w * w)
    w1 = _w(alpha)
    w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi * xi + 1)
    margins = np.stack([z + w2 * d1, d1 + xi * z, w + w1 * d2], -1) / d1[:, None]
    den = alpha * d2 + (1 - alpha) * w
    with np.errstate(divide="ignore", invalid="ignore"):
        px = np.stack([x / den, y / den], -1)
    return px, (margins > 0).all(-1), np.abs(margins).min(-1)


def ref_unproject(xi, alpha, m):
    """Eqs. 47-50: the ray of normalised pixels ``m`` (NaN outside the formula's domain)."""
    r2 = (m * m).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mz = (1 - alpha * alpha * r2) / (alpha * np.sqrt(1 - (2 * alpha - 1) * r2) + 1 - alpha)
        k = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
    return np.stack([k * m[:, 0], k * m[:, 1], k * mz - xi], -1)


def _directions(n, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _lib(fn, xi, alpha, x):
    out, ok = fn("double-sphere", torch.tensor([1.0, 1.0, 0.0, 0.0, xi, alpha], dtype=F64),
                 torch.tensor(x, dtype=F64))
    return out.numpy(), ok.numpy()


@pytest.mark.parametrize("xi,alpha", list(itertools.product(XIS, ALPHAS)))
def test_project_valid_is_the_papers_domain_and_round_trips(xi, alpha):
    """``project``'s ``valid`` equals the numpy domain away from its boundary (1e-9), the
    pixels agree to 1e-12, and every valid point's pixel unprojects valid to its own ray
    (1e-12; for xi > 1 eq. 43 alone admitted up to 25 % of the directions, whose pixels
    unprojected to the exit-side point)."""
    pts = _directions(20000) * np.random.default_rng(1).uniform(0.1, 10, (20000, 1))
    want_px, want, margin = ref_project(xi, alpha, pts)
    px, ok = _lib(camera.project, xi, alpha, pts)
    far = margin > 1e-9
    assert (ok[far] == want[far]).all()
    assert np.abs(px[ok] - want_px[ok]).max() < 1e-12 * max(1.0, np.abs(want_px[ok]).max())
    rays, ok2 = _lib(camera.unproject, xi, alpha, px[ok])
    assert ok2.all()
    d = pts[ok] / np.linalg.norm(pts[ok], axis=-1, keepdims=True)
    assert np.abs(rays - d).max() < 1e-9


@pytest.mark.parametrize("xi,alpha", list(itertools.product(XIS, ALPHAS)))
def test_unproject_valid_is_the_image_of_the_domain(xi, alpha):
    """``unproject``'s ``valid`` on normalised pixels up to radius 4: True exactly where the
    numpy eqs. 47-50 give a ray in the projection's domain whose pixel is the pixel (1e-9),
    away from the domain's boundary; the rays agree to 1e-12."""
    rng = np.random.default_rng(2)
    r, t = 4 * np.sqrt(rng.uniform(0, 1, 20000)), rng.uniform(0, 2 * np.pi, 20000)
    m = np.stack([r * np.cos(t), r * np.sin(t)], -1)
    ray = ref_unproject(xi, alpha, m)
    fin = np.isfinite(ray).all(-1)
    back, dom, margin = ref_project(xi, alpha, np.where(fin[:, None], ray, 1.0))
    want = fin & dom & (np.abs(back - m).max(-1) < 1e-9)
    rays, ok = _lib(camera.unproject, xi, alpha, m)
    far = ~fin | (margin > 1e-9)
    assert (ok[far] == want[far]).all(), (ok[far] != want[far]).sum()
    unit = ray[ok] / np.linalg.norm(ray[ok], axis=-1, keepdims=True)
    assert np.abs(rays[ok] - unit).max() < 1e-12


def test_entry_side_shares_the_exit_sides_pixel():
    """xi = 2, alpha = 0.5: the first sphere's point (0.6, 0, -0.8) (where the line from
    (0, 0, -2) enters it; inside eq. 43's z > -w2 d1 = -d1) and that line's exit point
    have one pixel (numpy eqs. 40-42): the entry one is invalid, the exit one valid, and
    the pixel unprojects to the exit one."""
    xi, alpha = 2.0, 0.5
    entry = np.array([[0.6, 0.0, -0.8]])
    c, dvec = np.array([0.0, 0.0, -xi]), entry[0] - np.array([0.0, 0.0, -xi])
    ts = np.roots([dvec @ dvec, 2 * c @ dvec, c @ c - 1])  # the line meets the sphere
    exit_ = (c + ts.max() * dvec)[None]
    assert abs(np.linalg.norm(exit_) - 1) < 1e-12 and abs(ts.min() - 1) < 1e-12
    pe, ve, _ = ref_project(xi, alpha, entry)
    px, vx, _ = ref_project(xi, alpha, exit_)
    np.testing.assert_allclose(pe, px, atol=1e-12)
    _, ok = _lib(camera.project, xi, alpha, np.concatenate([entry, exit_]))
    assert ok.tolist() == [False, True] and vx.tolist() == [True] and ve.tolist() == [False]
    rays, ok = _lib(camera.unproject, xi, alpha, pe)
    assert bool(ok[0]) and np.abs(rays - exit_).max() < 1e-12

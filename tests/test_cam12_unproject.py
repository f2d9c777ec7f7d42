"""Outside tests of ``camera.unproject`` (API.md, torch_dq.camera) against OpenCV's
``undistortPoints`` / ``fisheye.undistortPoints`` and round trips through the references."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from test_cam12_project import PARAMS, _k, ds_project, ref_project

from torch_dq import camera

F64 = torch.float64
WIDTH, HEIGHT = 752, 480  # EuRoC cam0 (README of the calibration data: 752 x 480)
STRONG = {
    "pinhole-radtan": [300.0, 300.0, 376.0, 240.0, -0.35, 0.1, 0.001, -0.002],
    "pinhole-equidistant": [250.0, 250.0, 376.0, 240.0, 0.6, -0.3, 0.1, -0.02],
    "double-sphere": [250.0, 250.0, 376.0, 240.0, 0.8, 0.6],
}
CRIT = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)


def _grid(nu=61, nv=41, lo=(0.0, 0.0), hi=(WIDTH - 1.0, HEIGHT - 1.0)):
    u, v = np.meshgrid(np.linspace(lo[0], hi[0], nu), np.linspace(lo[1], hi[1], nv))
    return np.stack([u.ravel(), v.ravel()], -1)


def cv_undistort(model, p, px):
    """OpenCV's normalised undistorted coordinates ``(N, 2)`` (iterated to convergence)."""
    src = np.asarray(px, dtype=np.float64)[:, None]
    if model == "pinhole-radtan":
        return cv2.undistortPoints(src, _k(p), np.array([*p[4:], 0.0]), None, None, None,
                                   CRIT)[:, 0]
    return cv2.fisheye.undistortPoints(src, _k(p), np.array(p[4:], dtype=np.float64),
                                       criteria=CRIT)[:, 0]


def _unproject(model, p, px):
    return camera.unproject(model, torch.tensor(p, dtype=F64), torch.tensor(px, dtype=F64))


@pytest.mark.parametrize("model,p", [("pinhole-radtan", PARAMS["pinhole-radtan"]),
                                     ("pinhole-radtan", STRONG["pinhole-radtan"]),
                                     ("pinhole-equidistant", PARAMS["pinhole-equidistant"]),
                                     ("pinhole-equidistant", STRONG["pinhole-equidistant"])])
def test_unproject_matches_opencv(model, p):
    """Where OpenCV's own answer re-projects onto the pixel (its fixed-point iteration does
    not converge at a strong lens's corners), the rays agree to 1e-12; everywhere in the
    image the library's rays re-project (OpenCV's projection) to 1e-12 px."""
    px = _grid()
    rays, ok = _unproject(model, p, px)
    assert rays.shape == (px.shape[0], 3) and bool(ok.all())
    np.testing.assert_allclose(torch.linalg.norm(rays, dim=-1).numpy(), 1.0, atol=4e-16)
    mine = (rays[:, :2] / rays[:, 2:]).numpy()
    back = ref_project(model, p, np.concatenate([mine, np.ones((len(px), 1))], -1))
    assert np.abs(back - px).max() < 1e-12 * max(WIDTH, HEIGHT)
    und = cv_undistort(model, p, px)
    cv_back = ref_project(model, p, np.concatenate([und, np.ones((len(px), 1))], -1))
    good = np.abs(cv_back - px).max(-1) < 1e-9
    assert good.mean() > 0.7
    np.testing.assert_allclose(mine[good], und[good], rtol=1e-11, atol=1e-12)


def test_unproject_euroc_cam0_centre_and_corners():
    """EuRoC cam0 (radtan): the centre's and the four corners' rays against OpenCV."""
    p = PARAMS["pinhole-radtan"]
    px = np.array([[p[2], p[3]], [0.0, 0.0], [WIDTH - 1.0, 0.0], [0.0, HEIGHT - 1.0],
                   [WIDTH - 1.0, HEIGHT - 1.0], [-0.5, -0.5], [WIDTH - 0.5, HEIGHT - 0.5]])
    rays, ok = _unproject("pinhole-radtan", p, px)
    assert bool(ok.all())
    assert rays[0].tolist() == [0.0, 0.0, 1.0]  # the principal point: the optical axis
    und = cv_undistort("pinhole-radtan", p, px)
    np.testing.assert_allclose((rays[:, :2] / rays[:, 2:]).numpy(), und, rtol=1e-12,
                               atol=1e-15)


@pytest.mark.parametrize("model", list(camera.MODELS))
@pytest.mark.parametrize("strong", [False, True])
def test_round_trip_pixels(model, strong):
    """``project(unproject(px)) == px`` to 1e-12 of the image size (float64) wherever the
    ray is valid; with the library's ``project`` and with the reference's."""
    p = (STRONG if strong else PARAMS).get(model, PARAMS[model])
    px = _grid(81, 51)
    rays, ok = _unproject(model, p, px)
    assert bool(ok.all())
    back, ok2 = camera.project(model, torch.tensor(p, dtype=F64), rays)
    assert bool(ok2.all())
    assert (back.numpy() - px).__abs__().max() < 1e-12 * WIDTH
    ref = ref_project(model, p, rays.numpy())
    assert np.abs(ref - px).max() < 1e-12 * WIDTH


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_round_trip_rays(model):
    """Directions that project inside the image come back as the same unit ray."""
    p = STRONG.get(model, PARAMS[model])
    rng = np.random.default_rng(5)
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    px = ref_project(model, p, d) if model != "double-sphere" else ds_project(p, d)[0]
    with np.errstate(invalid="ignore"):
        inside = (d[:, 2] > 0.05) & (np.abs(px - [376, 240]) < [376, 240]).all(-1)
    if model == "double-sphere":
        inside &= ds_project(p, d)[1]
    assert inside.sum() > 200
    rays, ok = _unproject(model, p, px[inside])
    assert bool(ok.all())
    np.testing.assert_allclose(rays.numpy(), d[inside], atol=1e-12)


@pytest.mark.parametrize("model", ["pinhole-radtan", "pinhole-equidistant", "double-sphere"])
def test_outside_valid_region(model):
    """Pixels far outside a strong lens's image: valid exactly where they are an image, the
    rays finite with finite gradients everywhere, and every valid ray re-projects."""
    p = STRONG[model]
    px = _grid(101, 101, lo=(-5000.0, -5000.0), hi=(5000.0, 5000.0))
    pix = torch.tensor(px, requires_grad=True)
    prm = torch.tensor(p, dtype=F64, requires_grad=True)
    rays, ok = camera.unproject(model, prm, pix)
    # the radtan lens has no fold (9 k1^2 < 20 k2) and k2 > 0: every pixel has a preimage
    assert bool(ok.all()) if model == "pinhole-radtan" else 0 < ok.float().mean() < 0.5
    assert bool(torch.isfinite(rays).all())
    gx, gp = torch.autograd.grad(rays.sum(), (pix, prm))
    assert bool(torch.isfinite(gx).all()) and bool(torch.isfinite(gp).all())
    back, ok2 = camera.project(model, prm.detach(), rays.detach())
    assert bool(ok2[ok].all())
    assert (back - pix.detach())[ok].abs().max() < 1e-12 * 5000


def test_radtan_beyond_fold_invalid():
    """Pincushion-free barrel radtan (k1 < 0, k2 = 0): the distorted radius ``r (1 + k1
    r^2)`` peaks at ``r^2 = -1 / (3 k1)``, value ``(2/3) r``; larger radii have no
    preimage: invalid."""
    k1 = -0.3
    p = [100.0, 100.0, 0.0, 0.0, k1, 0.0, 0.0, 0.0]
    rmax = np.sqrt(-1 / (3 * k1))
    dmax = rmax * (1 + k1 * rmax**2)
    radii = dmax * np.array([0.5, 0.99, 0.999, 1.0001, 1.01, 2.0])
    px = np.stack([100 * radii, np.zeros_like(radii)], -1)
    rays, ok = _unproject("pinhole-radtan", p, px)
    assert ok.tolist() == [True, True, True, False, False, False]
    r = (rays[:3, 0] / rays[:3, 2]).numpy()
    np.testing.assert_allclose(r * (1 + k1 * r**2), radii[:3], rtol=1e-13)
    assert bool((torch.from_numpy(r) < rmax).all())


def test_equidistant_beyond_ninety_degrees_invalid():
    """Without distortion ``theta_d = theta``: pixels at radius ``f pi/2`` or more are rays
    at or beyond 90 degrees (``z <= 0``), not images of ``project``."""
    p = [100.0, 100.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    theta = np.array([0.0, 1e-9, 0.5, 1.5, np.pi / 2 - 1e-9, np.pi / 2 + 1e-6, 3.0])
    px = np.stack([100 * theta, np.zeros_like(theta)], -1)
    rays, ok = _unproject("pinhole-equidistant", p, px)
    assert ok.tolist() == [True] * 5 + [False] * 2
    np.testing.assert_allclose(rays[:5].numpy(), np.stack(
        [np.sin(theta[:5]), 0 * theta[:5], np.cos(theta[:5])], -1), atol=1e-14)


@pytest.mark.parametrize("xi,alpha", [(0.0, 0.5), (0.8, 0.7), (-0.3, 0.2), (1.3, 0.6)])
def test_double_sphere_unproject_domain(xi, alpha):
    """Eqs. 47-50: for ``alpha > 1/2`` the pixels with ``r^2 >= 1 / (2 alpha - 1)`` (``r``
    the normalised radius) are invalid; valid rays re-project onto their pixels."""
    p = [200.0, 200.0, 0.0, 0.0, xi, alpha]
    r = np.linspace(0.0, 6.0, 601)
    px = np.stack([200 * r * 0.6, 200 * r * 0.8], -1)
    rays, ok = _unproject("double-sphere", p, px)
    ok = ok.numpy()
    if alpha > 0.5:
        assert not ok[r * r >= 1 / (2 * alpha - 1)].any()
    assert ok[:10].all()
    back, ref_ok = ds_project(p, rays.numpy())
    assert ref_ok[ok].all()
    assert np.abs(back[ok] - px[ok]).max() < 1e-10


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_unproject_nonfinite_per_element_and_not_in_place(model):
    p = torch.tensor(PARAMS[model], dtype=F64).repeat(5, 1)
    px = torch.tensor(_grid(5, 1), dtype=F64)
    px[1, 0] = float("nan")
    px[2, 1] = float("inf")
    p[3, 4 if model != "pinhole" else 2] = float("nan")
    p0, x0 = p.clone(), px.clone()
    rays, ok = camera.unproject(model, p, px)
    assert torch.equal(torch.nan_to_num(p), torch.nan_to_num(p0))
    assert torch.equal(torch.nan_to_num(px), torch.nan_to_num(x0))
    assert ok.tolist() == [True, False, False, False, True]
    assert not bool(torch.isfinite(rays[1:4]).any())
    ref, _ = camera.unproject(model, p[0], px[[0, 4]])
    assert torch.equal(rays[[0, 4]], ref)


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_unproject_float32(model):
    """float32: rays within 2e-6 (radians) of the float64 rays over the image."""
    p = PARAMS[model]
    px = _grid(31, 21)
    r32, ok = camera.unproject(model, torch.tensor(p, dtype=torch.float32),
                               torch.tensor(px, dtype=torch.float32))
    r64, _ = _unproject(model, torch.tensor(p, dtype=torch.float32).double().tolist(), px)
    assert r32.dtype == torch.float32 and bool(ok.all())
    assert (r32.double() - r64).abs().max() < 2e-6


def test_out_of_domain_params_invalid_not_error():
    for model, bad in (("pinhole", [0.0, 1.0, 0.0, 0.0]),
                       ("pinhole-radtan", [-1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
                       ("double-sphere", [1.0, 1.0, 0.0, 0.0, -1.0, 0.5]),
                       ("double-sphere", [1.0, 1.0, 0.0, 0.0, 0.0, 1.5])):
        prm = torch.tensor(bad, dtype=F64, requires_grad=True)
        pts = torch.tensor([[0.1, 0.2, 1.0]], dtype=F64)
        px, ok = camera.project(model, prm, pts)
        rays, ok2 = camera.unproject(model, prm, torch.tensor([[0.1, 0.2]], dtype=F64))
        assert not bool(ok.any()) and not bool(ok2.any())
        g = torch.autograd.grad(px.sum() + rays.sum(), prm)[0]
        assert bool(torch.isfinite(px).all() & torch.isfinite(rays).all()
                    & torch.isfinite(g).all())


@pytest.mark.parametrize("k", [[0.6, -0.3, 0.1, -0.02], [0.6, -0.3, 0.05, -0.01]])
def test_equidistant_every_pixel_inside_the_fold_valid(k):
    """Every pixel whose normalised radius is below theta_d's first maximum on [0, pi/2]
    (numpy, on a fine grid of theta) has a preimage: valid, and it re-projects. The
    safeguarded iteration used to bounce between its bracket's ends (0.008 and 1.54 rad)
    and call 17 of these 90,601 pixels invalid (0.4 px wide arcs near 1.54 rad)."""
    p = [250.0, 250.0, 376.0, 240.0, *k]
    th = np.linspace(0.0, np.pi / 2, 2_000_001)
    td = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
    falling = np.diff(td) <= 0
    fold = td[: np.argmax(falling) + 1].max() if falling.any() else td.max()
    px = _grid(301, 301, lo=(-0.5, -0.5), hi=(WIDTH - 0.5, HEIGHT - 0.5))
    r = np.hypot((px[:, 0] - p[2]) / p[0], (px[:, 1] - p[3]) / p[1])
    has = r < fold * (1 - 1e-9)
    assert has.sum() > 80_000
    rays, ok = _unproject("pinhole-equidistant", p, px)
    ok = ok.numpy()
    assert int((has & ~ok).sum()) == 0 and int((~has & ok).sum()) == 0
    back = ref_project("pinhole-equidistant", p, rays.numpy()[ok])
    assert np.abs(back - px[ok]).max() < 1e-12 * WIDTH


@pytest.mark.parametrize("xi", [-0.6, -0.3, 0.0, 0.5, 1.0])
@pytest.mark.parametrize("alpha", [0.0, 0.2, 0.5, 0.6, 1.0])
def test_double_sphere_valid_directions_round_trip(xi, alpha):
    """Every direction that ``project`` calls valid comes back from ``unproject`` (valid, the
    same ray): no two valid directions share a pixel. (Not for ``xi > 1``: there eq. 43,
    the contract's validity, lets through directions with ``d1 + xi z <= 0``, up to 26 % of
    the sphere at xi = 2.5, whose pixels are those of directions in front.)"""
    p = torch.tensor([300.0, 300.0, 320.0, 240.0, xi, alpha], dtype=F64)
    d = np.random.default_rng(10).normal(size=(20000, 3))
    d = torch.tensor(d / np.linalg.norm(d, axis=-1, keepdims=True))
    px, ok = camera.project("double-sphere", p, d)
    assert ok.float().mean() > 0.1
    rays, ok2 = camera.unproject("double-sphere", p, px[ok])
    assert bool(ok2.all())
    assert float((rays - d[ok]).abs().max()) < 1e-8

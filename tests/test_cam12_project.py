"""Outside tests of ``camera.project`` (API.md, torch_dq.camera) against OpenCV and a numpy
transcription of Usenko, Demmel, Cremers 2018 (the double sphere, eqs. 40-43)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from torch_dq import camera

F64 = torch.float64
EUROC = [458.654, 457.296, 367.215, 248.375]
RADTAN = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
FISHEYE = [0.1, -0.05, 0.01, -0.002]
PARAMS = {
    "pinhole": EUROC,
    "pinhole-radtan": EUROC + RADTAN,
    "pinhole-equidistant": EUROC + FISHEYE,
    "double-sphere": [350.0, 340.0, 370.0, 250.0, -0.2, 0.6],
}


def _k(p):
    return np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])


def ref_project(model: str, p, pts: np.ndarray) -> np.ndarray:
    """Reference pixels ``(N, 2)`` of ``(N, 3)`` points (OpenCV; the paper for ``ds``)."""
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    if model == "pinhole":
        out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), _k(p), np.zeros(5))
        return out[:, 0]
    if model == "pinhole-radtan":
        out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), _k(p),
                                   np.array([*p[4:8], 0.0]))
        return out[:, 0]
    if model == "pinhole-equidistant":
        out, _ = cv2.fisheye.projectPoints(pts[None], np.zeros(3), np.zeros(3), _k(p),
                                           np.array(p[4:8], dtype=np.float64))
        return out[0]
    return ds_project(p, pts)[0]


def ds_w2(xi, alpha):
    w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha  # eq. 43
    return (w1 + xi) / np.sqrt(2 * w1 * xi + xi * xi + 1)


def ds_project(p, pts):
    """Eqs. 40-43, the pixels ``(N, 2)`` and the validity ``z > -w2 d1``."""
    fu, fv, cu, cv, xi, alpha = p
    pts = np.asarray(pts, dtype=np.float64)  # scale-free: no overflow at 1e300
    pts = pts / np.maximum(np.abs(pts).max(-1, keepdims=True), 1e-300)
    x, y, z = pts.T
    d1 = np.sqrt(x * x + y * y + z * z)
    w = xi * d1 + z
    d2 = np.sqrt(x * x + y * y + w * w)
    den = alpha * d2 + (1 - alpha) * w
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([fu * x / den + cu, fv * y / den + cv], -1)
    return uv, z > -ds_w2(xi, alpha) * d1


def _points(n=300, seed=0, spread=1.0):
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * [spread, spread, 1.0]
    pts[:, 2] = np.abs(pts[:, 2]) + 0.3
    return pts


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_project_matches_reference(model):
    pts = _points(spread=0.5)
    px, ok = camera.project(model, torch.tensor(PARAMS[model], dtype=F64), torch.tensor(pts))
    ref = ref_project(model, PARAMS[model], pts)
    assert px.dtype == F64 and px.shape == (300, 2) and ok.shape == (300,)
    assert bool(ok.all())
    # OpenCV computes in double; relative 1e-12 of the pixel's distance from the centre
    scale = 1.0 + np.abs(ref).max(-1)
    np.testing.assert_array_less(np.abs(px.numpy() - ref).max(-1) / scale, 1e-12)


def test_project_radtan_far_off_axis():
    """Far off axis the radtan polynomial is large; still OpenCV to relative 1e-12."""
    pts = np.array([[10.0, -7.0, 1.0], [1e3, 1.0, 1.0], [3.0, 4.0, 1e-3]])
    p = PARAMS["pinhole-radtan"]
    px, ok = camera.project("pinhole-radtan", torch.tensor(p, dtype=F64), torch.tensor(pts))
    ref = ref_project("pinhole-radtan", p, pts)
    assert bool(ok.all())
    np.testing.assert_allclose(px.numpy(), ref, rtol=1e-12)


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_project_on_the_optical_axis(model):
    """``x = y = 0`` exactly: the principal point, for every depth, tiny or large."""
    p = PARAMS[model]
    pts = np.array([[0.0, 0.0, z] for z in (1.0, 1e-300, 5e-324, 1e-8, 1e300)])
    px, ok = camera.project(model, torch.tensor(p, dtype=F64), torch.tensor(pts))
    assert bool(ok.all())
    np.testing.assert_array_equal(px.numpy(), np.tile(p[2:4], (5, 1)))
    if model != "double-sphere":  # OpenCV divides by z: nan at 5e-324 (1 / z overflows)
        np.testing.assert_array_equal(ref_project(model, p, pts[[0, 1, 3]]), px.numpy()[[0, 1, 3]])


def test_equidistant_near_axis_matches_fisheye_series():
    """Near the axis ``theta_d / r -> 1``: no cancellation in ``atan(r) / r``."""
    p = PARAMS["pinhole-equidistant"]
    r = np.array([1e-300, 1e-150, 1e-12, 1e-8, 1e-5, 1e-3])
    pts = np.stack([r, 0.5 * r, np.ones_like(r)], -1)
    px, ok = camera.project("pinhole-equidistant", torch.tensor(p, dtype=F64),
                            torch.tensor(pts))
    rr = np.hypot(pts[:, 0], pts[:, 1])
    th = np.arctan(rr)  # mpmath-free: for rr <= 1e-3, atan to 1 ulp
    thd = th * (1 + p[4] * th**2 + p[5] * th**4 + p[6] * th**6 + p[7] * th**8)
    u = p[0] * thd / rr * pts[:, 0] + p[2]
    np.testing.assert_allclose(px[:, 0].numpy() - p[2], u - p[2], rtol=1e-13)
    assert bool(ok.all())


@pytest.mark.parametrize("model", list(camera.MODELS))
@pytest.mark.parametrize("z", [0.0, -0.0, -1.0, -1e-300, -1e300])
def test_behind_camera_invalid_finite(model, z):
    p = torch.tensor(PARAMS[model], dtype=F64, requires_grad=True)
    pts = torch.tensor([[0.3, -0.2, z], [0.0, 0.0, z]], dtype=F64, requires_grad=True)
    px, ok = camera.project(model, p, pts)
    assert bool(torch.isfinite(px).all())
    gp, gx = torch.autograd.grad(px.sum(), (p, pts))
    assert bool(torch.isfinite(gp).all()) and bool(torch.isfinite(gx).all())
    if model != "double-sphere":
        assert not bool(ok.any())
    else:  # the paper's condition decides
        assert ok.tolist() == ds_project(PARAMS[model], pts.detach().numpy())[1].tolist()


def test_double_sphere_origin_invalid():
    for xi, alpha in ((0.0, 0.5), (-0.2, 0.6), (0.8, 0.3), (0.0, 0.0), (1.5, 1.0)):
        p = torch.tensor([300.0, 300.0, 320.0, 240.0, xi, alpha], dtype=F64)
        pt = torch.zeros(3, dtype=F64, requires_grad=True)
        px, ok = camera.project("double-sphere", p, pt)
        assert not bool(ok) and bool(torch.isfinite(px).all())
        assert bool(torch.isfinite(torch.autograd.grad(px.sum(), pt)[0]).all())


@pytest.mark.parametrize("xi,alpha", [(0.0, 0.5), (0.3, 0.6), (0.8, 0.3), (1.2, 0.7),
                                      (0.0, 0.0), (0.5, 1.0)])
def test_double_sphere_validity_boundary(xi, alpha):
    """Eq. 43 exactly (xi >= 0): directions at angles just inside and outside the boundary
    ``z = -w2 d1`` of the paper, and random directions of the whole sphere."""
    p = [300.0, 300.0, 320.0, 240.0, xi, alpha]
    w2 = ds_w2(xi, alpha)
    # the boundary direction: z / d1 = -w2 (cos of the angle from the axis)
    angles = np.arccos(np.clip(-w2, -1, 1)) + np.array([-1e-6, 1e-6])
    phi = np.array([0.3, 2.0])
    dirs = np.stack([np.sin(angles) * np.cos(phi), np.sin(angles) * np.sin(phi),
                     np.cos(angles)], -1)
    rng = np.random.default_rng(1)
    rand = rng.normal(size=(500, 3))
    pts = np.concatenate([dirs * 2.0, rand])
    px, ok = camera.project("double-sphere", torch.tensor(p, dtype=F64), torch.tensor(pts))
    ref, ref_ok = ds_project(p, pts)
    if abs(w2) < 1:
        assert ref_ok[:2].tolist() == [True, False]
    assert ok.tolist() == ref_ok.tolist()
    sane = ref_ok & (np.abs(ref).max(-1) < 1e5)  # at the boundary the pixels go to infinity
    np.testing.assert_allclose(px.numpy()[sane], ref[sane], rtol=1e-12, atol=1e-9)
    assert bool(torch.isfinite(px).all())


def test_double_sphere_negative_xi_valid_subset_of_paper():
    """For ``xi < 0`` the library may refuse more than eq. 43 (documented), never less."""
    p = [300.0, 300.0, 320.0, 240.0, -0.5, 0.1]
    pts = np.random.default_rng(2).normal(size=(2000, 3))
    px, ok = camera.project("double-sphere", torch.tensor(p, dtype=F64), torch.tensor(pts))
    ref, ref_ok = ds_project(p, pts)
    ok = ok.numpy()
    assert not (ok & ~ref_ok).any()
    assert ok.mean() > 0.9 * ref_ok.mean() > 0.25  # a cone of 68.6 deg: 32 % of directions
    np.testing.assert_allclose(px.numpy()[ok], ref[ok], rtol=1e-12, atol=1e-9)


SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


@pytest.mark.parametrize("model", list(camera.MODELS))
@pytest.mark.parametrize("pshape", SHAPES)
@pytest.mark.parametrize("xshape", SHAPES)
def test_broadcasting(model, pshape, xshape):
    rng = np.random.default_rng(3)
    base = np.array(PARAMS[model])
    params = base * (1 + 0.01 * rng.normal(size=(*pshape, base.size)))
    pts = _points(int(np.prod(xshape, dtype=int)), seed=4, spread=0.4).reshape(*xshape, 3)
    px, ok = camera.project(model, torch.tensor(params), torch.tensor(pts))
    batch = np.broadcast_shapes(pshape, xshape)
    assert px.shape == (*batch, 2) and ok.shape == batch
    pb = np.broadcast_to(params, (*batch, base.size)).reshape(-1, base.size)
    xb = np.broadcast_to(pts, (*batch, 3)).reshape(-1, 3)
    ref = np.stack([ref_project(model, list(pp), xx[None])[0]
                    for pp, xx in zip(pb, xb, strict=True)])
    np.testing.assert_allclose(px.numpy().reshape(-1, 2), ref, rtol=1e-12)


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_float32_accuracy(model):
    """float32: the pixels within 2e-4 px of the float64 reference inside a 752 x 480 image
    (float32's spacing at 700 is 6e-5), relative 1e-6 outside it (radtan at -6e4 px: 0.02
    px), the dtype kept."""
    pts = _points(spread=0.4)
    p32 = torch.tensor(PARAMS[model], dtype=torch.float32)
    px, ok = camera.project(model, p32, torch.tensor(pts, dtype=torch.float32))
    assert px.dtype == torch.float32 and bool(ok.all())
    ref = ref_project(model, p32.double().tolist(), torch.tensor(pts, dtype=torch.float32)
                      .double().numpy())
    err = np.abs(px.double().numpy() - ref).max(-1)
    inside = ((ref >= 0) & (ref <= [752, 480])).all(-1)
    assert inside.sum() > 100
    assert err[inside].max() < 2e-4
    assert (err / np.maximum(np.abs(ref).max(-1), 752)).max() < 1e-6


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_nonfinite_propagate_per_element(model):
    pts = torch.tensor(_points(6, spread=0.3))
    pts[1, 0] = float("nan")
    pts[2, 2] = float("inf")
    pts[3, 1] = -float("inf")
    params = torch.tensor(PARAMS[model], dtype=F64).repeat(6, 1)
    params[4, 0] = float("nan")
    keep_pts, keep_params = pts.clone(), params.clone()
    px, ok = camera.project(model, params, pts)
    assert torch.equal(pts.isnan(), keep_pts.isnan())
    assert torch.equal(torch.nan_to_num(pts), torch.nan_to_num(keep_pts))
    assert torch.equal(torch.nan_to_num(params), torch.nan_to_num(keep_params))
    bad = [1, 2, 3, 4]
    assert not bool(torch.isfinite(px[bad]).any(-1).any()), px[bad]
    assert not bool(ok[bad].any())
    good = [0, 5]
    ref = ref_project(model, PARAMS[model], pts[good].numpy())
    np.testing.assert_allclose(px[good].numpy(), ref, rtol=1e-12)
    assert bool(ok[good].all())


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_inputs_not_modified(model):
    p = torch.tensor(PARAMS[model], dtype=F64)
    pts = torch.tensor([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=F64)
    p0, x0 = p.clone(), pts.clone()
    camera.project(model, p, pts)
    assert torch.equal(p, p0) and torch.equal(pts, x0)


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_scale_invariance_extreme_points(model):
    """A point and its multiples by 2^-1000 ... 2^1000 (exact) have one pixel, valid (the
    double sphere computed |p| = inf at 1e160, valid False, and 0 / 0 at 5e-324 on the axis,
    valid True with a NaN pixel), and gradients scaled by 1 / s."""
    p = torch.tensor(PARAMS[model], dtype=F64)
    base = torch.tensor([[0.3, -0.2, 1.0], [0.0, 0.0, 1.0], [-0.1, 0.05, 0.4]], dtype=F64)
    ref, _ = camera.project(model, p, base)
    g_ref = torch.autograd.functional.jacobian(lambda x: camera.project(model, p, x)[0],
                                               base[0])
    for s in (2.0**-1000, 2.0**-500, 2.0**500, 2.0**540, 2.0**1000):
        px, ok = camera.project(model, p, base * s)
        assert bool(ok.all()), (s, ok)
        torch.testing.assert_close(px, ref, rtol=1e-14, atol=0.0)
        g = torch.autograd.functional.jacobian(
            lambda x: camera.project(model, p, x)[0], base[0] * s)
        torch.testing.assert_close(g * s, g_ref, rtol=1e-13, atol=0.0)


@pytest.mark.parametrize("model", ["pinhole", "pinhole-radtan", "pinhole-equidistant"])
def test_grazing_points(model):
    """``z`` tiny and positive: valid while the point is within ``1 / eps`` of the axis
    (``|x| / z < 4.5e15``), with the reference's pixel; invalid beyond (documented: the
    pixels or their derivatives would overflow), finite either way."""
    p = PARAMS[model]
    pts = np.array([[0.3, -0.2, 1e-14], [0.3, -0.2, 1e-20], [0.3, -0.2, 5e-324]])
    px, ok = camera.project(model, torch.tensor(p, dtype=F64), torch.tensor(pts))
    assert ok.tolist() == [True, False, False]
    assert bool(torch.isfinite(px).all())
    np.testing.assert_allclose(px[0].numpy(), ref_project(model, p, pts[:1])[0], rtol=1e-12)

"""Audit 10: the double sphere's domain where eq. 43 of Usenko, Demmel, Cremers (2018) is
not exact, and the Kalibr camera entries a user builds by hand.

References written here in numpy: the paper's projection (eqs. 40-42) and unprojection
(eqs. 47-50). A point the projection sees has one pixel and that pixel one ray: the pixel of
a valid point lies on the point's side of the principal point, and the paper's unprojection
of it gives the point's direction back; a valid ray of :func:`unproject` projects (numpy,
eq. 40) onto its pixel.
"""

import numpy as np
import pytest
import torch
from references import double_sphere_np

from torch_dq import camera

F64 = torch.float64


def _directions(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _ds_unproject(p, px: np.ndarray) -> np.ndarray:
    """Eqs. 47-50: unit rays (NaN outside the formula's real domain)."""
    fx, fy, cx, cy, xi, alpha = p
    mx, my = (px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy
    r2 = mx * mx + my * my
    with np.errstate(invalid="ignore", divide="ignore"):
        mz = (1 - alpha * alpha * r2) / (alpha * np.sqrt(1 - (2 * alpha - 1) * r2) + 1 - alpha)
        k = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
    ray = np.stack([k * mx, k * my, k * mz - xi], -1)
    return ray / np.linalg.norm(ray, axis=1, keepdims=True)


# xi < 0 with alpha away from 1/2: eq. 43 admitted points beyond the second sphere's seen
# part (3 % of all directions for xi = -0.5, alpha = 0.1), their pixels on the wrong side
NEGATIVE_XI = [(-0.9, 0.2), (-0.5, 0.1), (-0.5, 0.0), (-0.1, 1.0), (-0.3, 0.0), (-0.99, 0.8)]


@pytest.mark.parametrize("xi,alpha", NEGATIVE_XI)
def test_double_sphere_valid_pixels_are_on_the_points_side_and_invert(xi, alpha):
    p = [300.0, 310.0, 320.0, 240.0, xi, alpha]
    d = _directions(20000)
    px, valid = camera.project("double-sphere", torch.tensor(p, dtype=F64), torch.tensor(d))
    v = valid.numpy()
    assert v.sum() > 1000
    ref = double_sphere_np(p, d)[v]
    assert np.abs(px.numpy()[v] - ref).max() < 1e-6 * max(1.0, np.abs(ref).max())
    # the pixel of a valid point lies on its side of the principal point
    off = px.numpy()[v] - [320.0, 240.0]
    side = np.abs(d[v, :2]) > 1e-9
    assert (np.sign(off[side]) == np.sign(d[v, :2][side])).all()
    # and the paper's unprojection of that pixel is the point's direction
    assert np.abs(_ds_unproject(p, px.numpy()[v]) - d[v]).max() < 1e-7
    assert torch.isfinite(px).all()


@pytest.mark.parametrize("xi,alpha", NEGATIVE_XI)
def test_double_sphere_invalid_points_keep_finite_gradients(xi, alpha):
    p = torch.tensor([300.0, 310.0, 320.0, 240.0, xi, alpha], dtype=F64, requires_grad=True)
    d = torch.tensor(_directions(2000, seed=1), requires_grad=True)
    px, valid = camera.project("double-sphere", p, d)
    assert (~valid).any()
    gp, gd = torch.autograd.grad(px.sum(), (p, d))
    assert torch.isfinite(gp).all() and torch.isfinite(gd).all()


@pytest.mark.parametrize("xi,alpha", [(1.2, 0.5), (1.2, 0.3), (2.0, 0.3), (1.5, 0.9)])
def test_double_sphere_unproject_valid_rays_project_onto_their_pixels(xi, alpha):
    """xi > 1: the root of eq. 50 can be a negative distance (the ray then points away from
    the pixel's point, (0.04, 0.04, -0.999) for the pixel (-3000, -2957) of xi = 1.2,
    alpha = 0.5): such pixels are invalid."""
    p = [300.0, 300.0, 320.0, 240.0, xi, alpha]
    u, v = np.meshgrid(np.linspace(-3000, 3640, 201), np.linspace(-3000, 3480, 201))
    px = np.stack([u.ravel(), v.ravel()], -1)
    rays, valid = camera.unproject("double-sphere", torch.tensor(p, dtype=F64),
                                   torch.tensor(px))
    ok = valid.numpy()
    assert ok.sum() > 50
    assert np.abs(double_sphere_np(p, rays.numpy()[ok]) - px[ok]).max() < 1e-6
    assert np.abs(np.linalg.norm(rays.numpy(), axis=1) - 1).max() < 1e-12
    assert torch.isfinite(rays).all()


def test_double_sphere_fix_keeps_the_paper_where_eq43_is_exact():
    """xi >= 0 (and the realistic xi = -0.17, alpha = 0.59): the mask is eq. 43's."""
    d = _directions(20000, seed=2)
    for xi, alpha in [(0.0, 0.3), (0.4, 0.4), (0.9, 0.8), (-0.1716, 0.5927), (1.0, 0.5)]:
        p = [300.0, 300.0, 320.0, 240.0, xi, alpha]
        w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha
        w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi * xi + 1)
        _, valid = camera.project("double-sphere", torch.tensor(p, dtype=F64), torch.tensor(d))
        assert (valid.numpy() == (d[:, 2] > -w2)).all()


# ------------------------------------------------------------- Camera from numpy arrays

EUROC = [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
         1.76187114e-05]


def test_camera_takes_numpy_params_and_resolution():
    """What OpenCV's calibrateCamera gives (K, dist as numpy arrays) builds a Camera; its
    pixels are cv2.projectPoints'."""
    import cv2

    K = np.array([[EUROC[0], 0, EUROC[2]], [0, EUROC[1], EUROC[3]], [0, 0, 1.0]])
    dist = np.array([*EUROC[4:], 0.0])
    params = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist[:4]]
    cam = camera.Camera("pinhole-radtan", params, np.array([752, 480]))
    assert cam.params.dtype == F64 and cam.params.tolist() == params.tolist()
    assert cam.resolution == (752, 480) and isinstance(cam.resolution[0], int)
    pts = np.array([[0.1, -0.2, 1.0], [-0.4, 0.3, 1.5]])
    ref = cv2.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)[0][:, 0]
    assert np.abs(cam.project(torch.tensor(pts))[0].numpy() - ref).max() < 1e-6
    # float32 arrays, and a Kalibr entry built by hand with arrays
    assert camera.Camera("pinhole", np.float32([1, 2, 3, 4]), (8, 6)).params.tolist() == \
        [1.0, 2.0, 3.0, 4.0]
    entry = {"camera_model": "pinhole", "distortion_model": "radtan",
             "intrinsics": np.array(EUROC[:4]), "distortion_coeffs": np.array(EUROC[4:]),
             "resolution": np.array([752, 480])}
    assert camera.Camera.from_kalibr(entry) == camera.Camera("pinhole-radtan", EUROC,
                                                             (752, 480))
    with pytest.raises(ValueError, match="params"):
        camera.Camera("pinhole", np.ones((2, 2)), (8, 6))  # 2-D: not a parameter vector
    with pytest.raises(ValueError, match="resolution"):
        camera.Camera("pinhole", [1.0, 1.0, 0.0, 0.0], np.array([8.5, 6.0]))


def test_kalibr_none_distortion_with_coefficients_says_so():
    entry = {"camera_model": "pinhole", "distortion_model": "none",
             "intrinsics": EUROC[:4], "distortion_coeffs": EUROC[4:], "resolution": [752, 480]}
    with pytest.raises(ValueError, match=r"distortion_coeffs to be empty \(or zeros\)"):
        camera.Camera.from_kalibr(entry)
    entry["distortion_coeffs"] = [0.0, 0, 0, 0]
    assert camera.Camera.from_kalibr(entry).model == "pinhole"


def test_kalibr_none_distortion_written_as_a_numpy_array_of_zeros():
    entry = {"camera_model": "pinhole", "distortion_model": "none",
             "intrinsics": np.array(EUROC[:4]), "distortion_coeffs": np.zeros(4),
             "resolution": [752, 480]}
    assert camera.Camera.from_kalibr(entry) == camera.Camera("pinhole", EUROC[:4], (752, 480))

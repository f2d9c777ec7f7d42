"""torch_dq.camera against independent references.

- projection: OpenCV (``cv2.projectPoints`` with ``(k1, k2, p1, p2, 0)``,
  ``cv2.fisheye.projectPoints``) and the double sphere paper's equations (Usenko, Demmel,
  Cremers 2018: projection eqs. 40-43, unprojection eqs. 47-50) written in numpy here;
- unprojection: OpenCV's ``undistortPoints`` / ``fisheye.undistortPoints`` run to
  convergence, the paper's eqs. 47-50 in numpy, and ``project(unproject(px)) == px`` over
  whole images of realistic cameras; the valid region against its definition computed here;
- gradcheck and gradgradcheck (float64) at generic and degenerate points (the optical axis,
  the principal point), finite gradients where invalid;
- float32 accuracy, batch shapes and broadcasting, NaN isolation, no input modified, errors;
- ``Camera`` and Kalibr camchain entries.
"""

import math

import numpy as np
import pytest
import torch
from torch.autograd import gradcheck, gradgradcheck

from torch_dq import camera
from torch_dq.camera import Camera, project, unproject

F64 = torch.float64
cv2 = pytest.importorskip("cv2")

# EuRoC MAV cam0 (Kalibr's published calibration), 752 x 480.
EUROC = [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
EUROC_RES = (752, 480)
# TUM VI 512 x 512 cam0, Kalibr equidistant (a 190-degree fisheye).
TUMVI = [190.97847715128717, 190.9733070521226, 254.93170605935475, 256.8974428996504,
         0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
         0.00020293673591811182]
# A strong synthetic fisheye (1280 x 1024): large k1, k2; the image corners lie beyond 90 deg.
STRONG = [300.0, 310.0, 640.0, 512.0, 0.1, -0.05, 0.01, -0.001]
# Double sphere close to basalt's TUM VI calibration (512 x 512), and a xi > 1 lens.
DS = [158.28, 158.27, 254.94, 256.90, -0.1716, 0.5927]
DS_BIG_XI = [300.0, 300.0, 320.0, 240.0, 1.2, 0.3]

CAMERAS = {  # model -> (params, resolution)
    "pinhole": (EUROC[:4], EUROC_RES),
    "pinhole-radtan": (EUROC, EUROC_RES),
    "pinhole-equidistant": (TUMVI, (512, 512)),
    "double-sphere": (DS, (512, 512)),
}


def _t(x, dtype=F64):
    return torch.as_tensor(np.asarray(x), dtype=dtype)


def _points(n, seed=0, max_angle=1.2):
    """Points in front of the camera up to ``max_angle`` radians off axis, depths 0.3-8 m."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(0.0, max_angle, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    d = rng.uniform(0.3, 8.0, n)
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                     np.cos(theta)], -1) * d[:, None]


def _grid(resolution, step=4):
    w, h = resolution
    u, v = np.meshgrid(np.arange(0, w, step, dtype=float), np.arange(0, h, step, dtype=float))
    corners = [[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]]
    return np.concatenate([np.stack([u.ravel(), v.ravel()], -1), corners])


def _K(p):
    return np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])


# ----------------------------------------------------------------------------- projection

@pytest.mark.parametrize("model", ["pinhole", "pinhole-radtan"])
def test_project_matches_opencv(model):
    p = CAMERAS[model][0]
    pts = _points(2000, max_angle=0.9)
    dist = np.array([*p[4:], 0.0]) if len(p) > 4 else np.zeros(5)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), _K(p), dist)
    px, valid = project(model, _t(p), _t(pts))
    assert valid.all()
    assert np.abs(px.numpy() - ref[:, 0]).max() < 1e-9


@pytest.mark.parametrize("params", [TUMVI, STRONG])
def test_project_equidistant_matches_opencv_fisheye_to_85_degrees(params):
    pts = _points(2000, max_angle=math.radians(85))
    pts = np.concatenate([pts, [[0.0, 0.0, 2.0], [1e-9, -1e-9, 1.0]]])  # on and near the axis
    ref, _ = cv2.fisheye.projectPoints(pts[None], np.zeros(3), np.zeros(3), _K(params),
                                       np.array(params[4:]))
    px, valid = project("pinhole-equidistant", _t(params), _t(pts))
    assert valid.all()
    assert np.abs(px.numpy() - ref[0]).max() < 1e-8


def _ds_paper(p, pts):
    """Double sphere projection (eqs. 40-42) and its domain (eq. 43), in numpy."""
    fx, fy, cx, cy, xi, alpha = p
    x, y, z = pts.T
    d1 = np.sqrt(x * x + y * y + z * z)  # eq. 41
    d2 = np.sqrt(x * x + y * y + (xi * d1 + z) ** 2)  # eq. 42
    den = alpha * d2 + (1 - alpha) * (xi * d1 + z)
    w1 = alpha / (1 - alpha) if alpha <= 0.5 else (1 - alpha) / alpha
    w2 = (w1 + xi) / np.sqrt(2 * w1 * xi + xi * xi + 1)
    return np.stack([fx * x / den + cx, fy * y / den + cy], -1), z > -w2 * d1  # eqs. 40, 43


@pytest.mark.parametrize("params", [DS, DS_BIG_XI, [200.0, 210.0, 320.0, 240.0, 0.4, 0.4]])
def test_project_double_sphere_matches_the_paper(params):
    pts = _points(3000, max_angle=math.pi)  # all directions, half of them behind
    ref, ref_valid = _ds_paper(params, pts)
    px, valid = project("double-sphere", _t(params), _t(pts))
    assert (valid.numpy() == ref_valid).all() and 0 < ref_valid.mean() < 1
    assert np.abs(px.numpy() - ref)[ref_valid].max() < 1e-9
    assert torch.isfinite(px).all()


def test_project_valid_is_z_positive_for_the_pinhole_models():
    # z > 0 but within eps radians of the plane z = 0 (pixels would overflow): invalid too
    pts = _t([[0.1, 0.2, 1.0], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0], [0.0, 0.0, 0.0],
              [0.0, 0.0, 1e-300], [0.0, 1.0, 4.458e-122], [1e200, -1e200, 1e200]])
    for model, (p, _) in CAMERAS.items():
        if model != "double-sphere":
            x = pts.clone().requires_grad_(True)
            px, valid = project(model, _t(p), x)
            assert valid.tolist() == [True, False, False, False, True, False, True]
            assert torch.isfinite(px).all()
            px.sum().backward()
            assert torch.isfinite(x.grad).all()


def test_project_double_sphere_origin_is_invalid():
    px, valid = project("double-sphere", _t(DS), torch.zeros(3, dtype=F64))
    assert not valid and torch.isfinite(px).all()


# ----------------------------------------------------------------------------- unprojection

CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)


def test_unproject_radtan_matches_opencv_undistort():
    px = _grid(EUROC_RES, 16)
    # OpenCV's fixed-point iteration, run until it stops moving: equal to 1e-9 (normalised).
    ref = cv2.undistortPoints(px[:, None], _K(EUROC), np.array([*EUROC[4:], 0.0]),
                              criteria=CRITERIA)[:, 0]
    rays, valid = unproject("pinhole-radtan", _t(EUROC), _t(px))
    assert valid.all()
    got = (rays[:, :2] / rays[:, 2:]).numpy()
    assert np.abs(got - ref).max() < 1e-9
    # With its default criteria (5 iterations) OpenCV is approximate: loosely equal.
    loose = cv2.undistortPoints(px[:, None], _K(EUROC), np.array([*EUROC[4:], 0.0]))[:, 0]
    assert np.abs(got - loose).max() < 0.05


def test_unproject_equidistant_matches_opencv_fisheye_undistort():
    px = _grid((512, 512), 16)
    theta_d = np.hypot((px[:, 0] - TUMVI[2]) / TUMVI[0], (px[:, 1] - TUMVI[3]) / TUMVI[1])
    px = px[theta_d < 1.4]  # OpenCV's undistortion of rays beyond 90 degrees is undefined
    # eps 1e-14: with 1e-16 OpenCV flags some points as not converged (-1e6, -1e6).
    ref = cv2.fisheye.undistortPoints(px[:, None], _K(TUMVI), np.array(TUMVI[4:]),
                                      criteria=(CRITERIA[0], 200, 1e-14))[:, 0]
    rays, valid = unproject("pinhole-equidistant", _t(TUMVI), _t(px))
    assert valid.all()
    assert np.abs((rays[:, :2] / rays[:, 2:]).numpy() - ref).max() < 1e-10


def _ds_unproject_paper(p, px):
    """Double sphere unprojection (eqs. 47-50) and its domain, in numpy."""
    fx, fy, cx, cy, xi, alpha = p
    mx, my = (px[:, 0] - cx) / fx, (px[:, 1] - cy) / fy
    r2 = mx * mx + my * my
    with np.errstate(invalid="ignore"):
        mz = (1 - alpha * alpha * r2) / (alpha * np.sqrt(1 - (2 * alpha - 1) * r2)
                                         + 1 - alpha)
        k = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
    inside = r2 < 1 / (2 * alpha - 1) if alpha > 0.5 else np.ones_like(r2, dtype=bool)
    return np.stack([k * mx, k * my, k * mz - xi], -1), inside


@pytest.mark.parametrize("params", [DS, DS_BIG_XI])
def test_unproject_double_sphere_matches_the_paper(params):
    px = _grid((640, 512), 8)
    ref, inside = _ds_unproject_paper(params, px)
    rays, valid = unproject("double-sphere", _t(params), _t(px))
    ok = inside & np.isfinite(ref).all(-1)
    assert valid.numpy()[~ok].sum() == 0 and valid.numpy().sum() > 0.9 * ok.sum()
    v = valid.numpy()
    assert np.abs(rays.numpy() - ref)[v].max() < 1e-12
    # valid rays are images of project (eq. 43 holds for them)
    assert _ds_paper(params, ref[v])[1].all()


# Over the whole image of a realistic camera: unproject inverts project to 1e-10 px.
ROUND_TRIP = [("pinhole", EUROC[:4], EUROC_RES), ("pinhole-radtan", EUROC, EUROC_RES),
              ("pinhole-radtan", [300.0, 300.0, 376.0, 240.0, -0.35, 0.09, 0.001, -0.001],
               EUROC_RES),
              ("pinhole-equidistant", TUMVI, (512, 512)),
              ("pinhole-equidistant", STRONG, (1280, 1024)),
              ("double-sphere", DS, (512, 512)), ("double-sphere", DS_BIG_XI, (640, 480))]


@pytest.mark.parametrize("model,params,res", ROUND_TRIP)
def test_unproject_inverts_project_over_the_image(model, params, res):
    px = _t(_grid(res, 2))
    rays, valid = unproject(model, _t(params), px)
    assert torch.isfinite(rays).all()
    assert (rays.norm(dim=-1) - 1).abs().max() < 1e-15 * 8
    back, ok = project(model, _t(params), rays)
    assert ok[valid].all()
    assert (back - px)[valid].abs().max() < 1e-10
    if model == "pinhole-equidistant":  # valid exactly where theta_d < theta_d(90 degrees)
        k = np.array(params[4:])
        th = math.pi / 2
        limit = th * (1 + k[0] * th**2 + k[1] * th**4 + k[2] * th**6 + k[3] * th**8)
        m = ((px[:, 0] - params[2]) / params[0]) ** 2 + ((px[:, 1] - params[3]) / params[1]) ** 2
        inside = m.sqrt() < limit
        assert (valid == inside).all() and 0.5 < float(valid.double().mean()) < 1.0
    elif model != "double-sphere":
        assert valid.all()


def test_unproject_radtan_invalid_beyond_the_fold():
    # k1 = -0.5: r_d = r (1 - r^2 / 2) folds at r^2 = 2/3, the largest r_d is 0.5443.
    params = _t([400.0, 400.0, 300.0, 200.0, -0.5, 0.0, 0.0, 0.0])
    rmax = math.sqrt(2 / 3) * (1 - 1 / 3)
    rd = torch.tensor([0.0, 0.3, 0.5, 0.95 * rmax, 1.05 * rmax, 0.7, 2.0, 10.0], dtype=F64)
    px = torch.stack([params[2] + 400.0 * rd * 0.6, params[3] + 400.0 * rd * 0.8], -1)
    px.requires_grad_(True)
    rays, valid = unproject("pinhole-radtan", params, px)
    assert valid.tolist() == [True] * 4 + [False] * 4
    r = rays[:, :2].norm(dim=-1) / rays[:, 2]
    assert (r[valid] ** 2 < 2 / 3).all()
    assert torch.isfinite(rays).all()
    rays.sum().backward()
    assert torch.isfinite(px.grad).all()


def test_unproject_equidistant_invalid_beyond_the_fold():
    # k1 = -0.3: theta_d = theta - 0.3 theta^3 folds at theta^2 = 1 / 0.9; max 0.7027.
    params = _t([300.0, 300.0, 320.0, 240.0, -0.3, 0.0, 0.0, 0.0])
    th = math.sqrt(1 / 0.9)
    tmax = th - 0.3 * th**3
    td = torch.tensor([0.0, 0.5, 0.9 * tmax, 1.05 * tmax, 1.5, 3.0], dtype=F64)
    px = torch.stack([320.0 + 300.0 * td, 240.0 + 0.0 * td], -1).requires_grad_(True)
    rays, valid = unproject("pinhole-equidistant", params, px)
    assert valid.tolist() == [True] * 3 + [False] * 3
    theta = torch.atan2(rays[:, 0], rays[:, 2])
    assert (theta[valid] < th).all()
    rays.sum().backward()
    assert torch.isfinite(px.grad).all() and torch.isfinite(rays).all()


# ----------------------------------------------------------------------------- derivatives

GRAD_PARAMS = {"pinhole": EUROC[:4], "pinhole-radtan": EUROC,
               "pinhole-equidistant": STRONG, "double-sphere": DS}


def _generic_points(seed=3):
    return _t(_points(4, seed, max_angle=1.0))


@pytest.mark.parametrize("model", list(GRAD_PARAMS))
def test_project_gradcheck_and_gradgradcheck(model):
    p = _t(GRAD_PARAMS[model]).requires_grad_(True)
    axis = _t([[0.0, 0.0, 2.0]])  # degenerate: the optical axis (r = 0)
    for pts in (_generic_points(), axis):
        pts = pts.clone().requires_grad_(True)

        def f(p, x):
            return project(model, p, x)[0]

        assert gradcheck(f, (p, pts))
        assert gradgradcheck(f, (p, pts))


@pytest.mark.parametrize("model", list(GRAD_PARAMS))
def test_unproject_gradcheck_and_gradgradcheck(model):
    p = _t(GRAD_PARAMS[model]).requires_grad_(True)
    px = project(model, p.detach(), _generic_points())[0]
    centre = p.detach()[None, 2:4]  # degenerate: the principal point
    for x in (px, centre):
        x = x.clone().requires_grad_(True)

        def f(p, x):
            return unproject(model, p, x)[0]

        assert gradcheck(f, (p, x))
        assert gradgradcheck(f, (p, x))


@pytest.mark.parametrize("model", list(GRAD_PARAMS))
def test_invalid_points_have_finite_values_and_gradients(model):
    p = _t(GRAD_PARAMS[model]).requires_grad_(True)
    pts = [[0.1, 0.2, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, -3.0], [0.0, 1e-30, -1.0]]
    if model != "double-sphere":  # 90 degrees off axis: inside the double sphere's view
        pts.append([1.0, 0.0, 0.0])
    pts = _t(pts).requires_grad_(True)
    px, valid = project(model, p, pts)
    assert not valid.any()
    assert torch.isfinite(px).all()
    gp, gx = torch.autograd.grad(px.square().sum(), (p, pts), create_graph=True)
    assert torch.isfinite(gp).all() and torch.isfinite(gx).all()
    hess = torch.autograd.grad((gp.sum() + gx.sum()), (p, pts))
    assert all(torch.isfinite(h).all() for h in hess)


def test_invalid_pixels_have_finite_values_and_gradients():
    cases = {"pinhole-radtan": [400.0, 400.0, 300.0, 200.0, -0.5, 0.0, 0.0, 0.0],
             "pinhole-equidistant": [300.0, 300.0, 320.0, 240.0, -0.3, 0.0, 0.0, 0.0],
             "double-sphere": [300.0, 300.0, 320.0, 240.0, 0.2, 0.8]}
    for model, params in cases.items():
        p = _t(params).requires_grad_(True)
        px = _t([[320.0 + 5000.0, 240.0], [-4000.0, 240.0]]).requires_grad_(True)
        rays, valid = unproject(model, p, px)
        assert not valid.any(), model
        assert torch.isfinite(rays).all()
        gp, gx = torch.autograd.grad(rays.sum(), (p, px), create_graph=True)
        assert torch.isfinite(gp).all() and torch.isfinite(gx).all()


def test_torch_func_jacobians_and_vmap():
    """No data-dependent branching: torch.func's jacrev and vmap give autograd's Jacobian."""
    p = _t(EUROC)
    px = project("pinhole-radtan", p, _generic_points())[0]
    jac = torch.func.vmap(torch.func.jacrev(
        lambda x: unproject("pinhole-radtan", p, x)[0]))(px)
    ref = torch.stack([torch.autograd.functional.jacobian(
        lambda x: unproject("pinhole-radtan", p, x)[0], x) for x in px])
    assert torch.allclose(jac, ref, rtol=1e-12, atol=1e-14)


# ----------------------------------------------------------------------------- float32

# max |pixel32 - pixel64| (px) of project, and max |ray32 - ray64| of unproject, on the
# float32-rounded inputs. Measured over ROUND_TRIP (images up to 1280 px): project 9.7e-5 px
# (EuRoC radtan; about one ulp of the pixel value), rays 4.6e-7 (double sphere, xi = 1.2);
# the valid masks agree everywhere.
F32_PIXELS = 1.5e-4
F32_RAYS = 7e-7


@pytest.mark.parametrize("model,params,res", ROUND_TRIP)
def test_float32_accuracy(model, params, res):
    p32 = _t(params, torch.float32)
    pts = _t(_points(2000, 5, max_angle=1.0), torch.float32)
    px32, v32 = project(model, p32, pts)
    px64, v64 = project(model, p32.double(), pts.double())
    assert px32.dtype == torch.float32 and (v32 == v64).all()
    assert (px32.double() - px64).abs().max() < F32_PIXELS
    grid = _t(_grid(res, 8), torch.float32)
    r32, ok32 = unproject(model, p32, grid)
    r64, ok64 = unproject(model, p32.double(), grid.double())
    both = ok32 & ok64
    assert (ok32 != ok64).double().mean() < 1e-3
    assert (r32.double() - r64)[both].abs().max() < F32_RAYS


def test_half_precision_computes_in_float32():
    p = _t(EUROC[:4], torch.float16)
    px, valid = project("pinhole", p, _t([0.1, 0.2, 1.0], torch.float16))
    assert px.dtype == torch.float16 and bool(valid)
    ref = project("pinhole", p.float(), _t([0.1, 0.2, 1.0], torch.float16).float())[0]
    assert torch.equal(px, ref.half())


# ----------------------------------------------------------------------------- batches

SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


@pytest.mark.parametrize("model", list(CAMERAS))
@pytest.mark.parametrize("shape", SHAPES)
def test_batch_shapes_and_broadcasting(model, shape):
    n = math.prod(shape)
    p = _t(CAMERAS[model][0])
    pts = _t(_points(n, 7, 1.0)).reshape(*shape, 3)
    px, valid = project(model, p, pts)
    assert px.shape == (*shape, 2) and valid.shape == shape
    flat = project(model, p, pts.reshape(-1, 3))[0]
    assert torch.equal(px.reshape(-1, 2), flat)
    rays, ok = unproject(model, p, px)
    assert rays.shape == (*shape, 3) and ok.shape == shape
    # params with their own batch, broadcast against the points: (2, 1, P) x (3, 3)
    scale = torch.tensor([1.0, 1.1], dtype=F64)[:, None, None]
    ps = torch.cat([p[:4] * scale, p[4:].expand(2, 1, -1)], -1)
    pts3 = _t(_points(3, 8, 1.0))
    px2, v2 = project(model, ps, pts3)
    assert px2.shape == (2, 3, 2) and v2.shape == (2, 3)
    for i in range(2):
        assert torch.equal(px2[i], project(model, ps[i, 0], pts3)[0])
    r2, _ = unproject(model, ps, px2)
    assert r2.shape == (2, 3, 3)
    assert torch.allclose(r2, pts3 / pts3.norm(dim=-1, keepdim=True), atol=1e-12)


def test_inputs_not_modified_and_nan_stays_in_its_element():
    for model, (params, _) in CAMERAS.items():
        p = _t(params)
        pts = _t(_points(4, 9, 1.0))
        pts[1, 0] = math.nan
        saved_p, saved_x = p.clone(), pts.clone()
        px, valid = project(model, p, pts)
        assert torch.equal(p, saved_p) and torch.equal(pts.nan_to_num(), saved_x.nan_to_num())
        assert torch.isnan(px[1]).any() and not valid[1]
        clean = project(model, p, pts[[0, 2, 3]])[0]
        assert torch.equal(px[[0, 2, 3]], clean)
        px = px.clone()
        px[1, 1] = math.nan
        saved = px.clone()
        rays, ok = unproject(model, p, px)
        assert torch.equal(px.nan_to_num(), saved.nan_to_num())
        assert torch.isnan(rays[1]).any() and not ok[1]
        assert torch.equal(rays[[0, 2, 3]], unproject(model, p, px[[0, 2, 3]])[0])
        # NaN in the params of one batch element
        pb = p.expand(3, -1).clone()
        pb[1, -1] = math.nan
        px3, v3 = project(model, pb, pts[0])
        assert torch.isnan(px3[1]).all() and v3.tolist() == [True, False, True]
        rays3, ok3 = unproject(model, pb, px3[0])
        assert torch.isfinite(rays3[[0, 2]]).all() and ok3.tolist() == [True, False, True]
        assert torch.isnan(rays3[1]).all()


def test_nan_in_distortion_params_is_not_hidden():
    for model, (params, _) in CAMERAS.items():
        if model == "pinhole":
            continue
        p = _t(params)
        p[5] = math.nan
        px, valid = project(model, p, _t([0.1, 0.2, 1.0]))
        rays, ok = unproject(model, p, _t([100.0, 100.0]))
        assert torch.isnan(px).any() and not valid and torch.isnan(rays).any() and not ok


def _out_of_domain(model, params):
    """Copies of ``params`` outside the model's domain (and, for the double sphere, on
    its boundary ``alpha = 0``, ``alpha = 1``, which is inside)."""
    bad = []
    for i, v in ((0, 0.0), (0, -params[0]), (1, 0.0), (1, -params[1])):
        q = list(params)
        q[i] = v
        bad.append(q)
    if model == "double-sphere":
        for i, v in ((5, -0.1), (5, 1.2), (4, -1.0), (4, -1.5)):
            q = list(params)
            q[i] = v
            bad.append(q)
    return bad


@pytest.mark.parametrize("model", list(CAMERAS))
def test_parameters_outside_the_domain_are_invalid_and_finite(model):
    """Zero or negative focal lengths (double sphere: xi <= -1, alpha outside [0, 1]) give
    valid False everywhere, finite outputs and finite gradients in params and inputs (a
    zero focal length gave NaN rays with valid True); the in-domain element of the same
    batch is unchanged, and the whole works under vmap (a mask, no host read)."""
    params, res = CAMERAS[model]
    bad = _out_of_domain(model, params)
    p = _t([params, *bad])[:, None].requires_grad_(True)  # (B, 1, P)
    pts = _t(_points(30, 4, 1.0)).requires_grad_(True)
    px = _t(_grid(res, 97)).requires_grad_(True)
    for fn, x in ((project, pts), (unproject, px)):
        out, ok = fn(model, p, x)
        assert ok[0].any() and not ok[1:].any()
        assert torch.isfinite(out).all()
        assert torch.equal(out[0], fn(model, p[0, 0].detach(), x.detach())[0])
        gp, gx = torch.autograd.grad(out.sum(), (p, x))
        assert torch.isfinite(gp).all() and torch.isfinite(gx).all()
        vout, vok = torch.func.vmap(lambda q, x=x, fn=fn: fn(model, q, x.detach()))(
            p[:, 0].detach())
        assert torch.equal(vok, ok) and torch.equal(vout, out.detach())
    if model == "double-sphere":  # alpha = 0 (the unified model) and 1 lie in the domain
        for alpha in (0.0, 1.0):
            q = _t([*params[:5], alpha])
            assert project(model, q, _t([0.1, 0.2, 1.0]))[1]
            assert unproject(model, q, _t([260.0, 250.0]))[1]


def test_pinhole_zero_focal_length_regression():
    """The trial's case: unproject('pinhole', [0, 500, 320, 240], ...) was NaN, valid."""
    rays, ok = unproject("pinhole", _t([0.0, 500, 320, 240]), _t([[320.0, 240], [100, 50]]))
    assert not ok.any() and torch.isfinite(rays).all()


# ----------------------------------------------------------------------------- errors

@pytest.mark.parametrize("fn,arg,event", [(project, "points", 3), (unproject, "pixels", 2)])
def test_bad_arguments_raise_naming_function_and_argument(fn, arg, event):
    name = f"camera.{fn.__name__}"
    p = _t(EUROC)
    x = torch.ones(5, event, dtype=F64)
    with pytest.raises(ValueError, match=rf"^{name}: expected model to be one of 'pinhole', "
                                          r".*got 'radtan'$"):
        fn("radtan", p, x)
    with pytest.raises(ValueError, match=rf"^{name}: expected a \(\.\.\., 4\) tensor for "
                                          r"params, got shape \(8,\)$"):
        fn("pinhole", p, x)
    with pytest.raises(ValueError, match=rf"^{name}: expected a \(\.\.\., {event}\) tensor "
                                          rf"for {arg}, got shape \(5, 4\)$"):
        fn("pinhole-radtan", p, torch.ones(5, 4, dtype=F64))
    with pytest.raises(TypeError, match=rf"^{name}: expected a floating-point tensor for "
                                         rf"{arg}, got dtype torch.int64$"):
        fn("pinhole-radtan", p, x.long())
    with pytest.raises(TypeError, match=rf"^{name}: {arg} has dtype torch.float32 but params "
                                         r"has dtype torch.float64$"):
        fn("pinhole-radtan", p, x.float())
    with pytest.raises(TypeError, match=rf"^{name}: expected a torch.Tensor for params, "
                                         r"got list$"):
        fn("pinhole-radtan", EUROC, x)
    with pytest.raises(ValueError, match=rf"^{name}: batch shapes do not broadcast: params "
                                          rf"\(3,\), {arg} \(5,\)$"):
        fn("pinhole-radtan", p.expand(3, 8), x)


# ----------------------------------------------------------------------------- Camera

EUROC_CAMCHAIN = """
cam0:
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
"""


def test_camera_reads_a_kalibr_euroc_camchain_entry():
    yaml = pytest.importorskip("yaml")
    cam = Camera.from_kalibr(yaml.safe_load(EUROC_CAMCHAIN)["cam0"])
    assert cam.model == "pinhole-radtan" and cam.resolution == (752, 480)
    assert cam.params.dtype == F64 and cam.params.tolist() == EUROC
    px, valid = cam.project(_t([0.1, -0.2, 1.0]))
    assert valid and torch.equal(px, project("pinhole-radtan", _t(EUROC),
                                             _t([0.1, -0.2, 1.0]))[0])
    rays, ok = cam.unproject(px)
    assert ok and torch.allclose(rays / rays[2], _t([0.1, -0.2, 1.0]), atol=1e-13)


KALIBR = {
    "pinhole": {"camera_model": "pinhole", "distortion_model": "none",
                "intrinsics": EUROC[:4], "distortion_coeffs": []},
    "pinhole-radtan": {"camera_model": "pinhole", "distortion_model": "radtan",
                       "intrinsics": EUROC[:4], "distortion_coeffs": EUROC[4:]},
    "pinhole-equidistant": {"camera_model": "pinhole", "distortion_model": "equidistant",
                            "intrinsics": TUMVI[:4], "distortion_coeffs": TUMVI[4:]},
    "double-sphere": {"camera_model": "ds", "distortion_model": "none",
                      "intrinsics": DS[4:] + DS[:4], "distortion_coeffs": []},
}


@pytest.mark.parametrize("model", list(CAMERAS))
def test_camera_kalibr_round_trip(model):
    params, res = CAMERAS[model]
    cam = Camera(model, _t(params), res)
    entry = cam.to_kalibr()
    assert entry == {**KALIBR[model], "resolution": list(res)}
    assert all(type(v) is float for v in entry["intrinsics"] + entry["distortion_coeffs"])
    assert all(type(v) is int for v in entry["resolution"])
    assert Camera.from_kalibr(entry) == cam
    yaml = pytest.importorskip("yaml")
    assert Camera.from_kalibr(yaml.safe_load(yaml.safe_dump(entry))) == cam


def test_camera_value_semantics_and_errors():
    cam = Camera("pinhole", EUROC[:4], [752, 480])
    assert cam.params.dtype == F64 and cam.resolution == (752, 480)
    assert cam.to(torch.float32).params.dtype == torch.float32
    assert cam.to(torch.float32) != cam and cam == Camera("pinhole", _t(EUROC[:4]), (752, 480))
    with pytest.raises(AttributeError):
        cam.model = "pinhole-radtan"  # type: ignore[misc]
    with pytest.raises(ValueError, match=r"^camera.Camera: expected a \(8,\) tensor for params"):
        Camera("pinhole-radtan", _t(EUROC[:4]), (752, 480))
    with pytest.raises(ValueError, match=r"^camera.Camera: expected resolution"):
        Camera("pinhole", _t(EUROC[:4]), (752, 0))
    with pytest.raises(ValueError, match=r"^camera.Camera: expected model .* got 'fisheye'$"):
        Camera("fisheye", _t(EUROC[:4]), (752, 480))
    bad = [({"camera_model": "omni", "intrinsics": [0.8, 400, 400, 320, 240]}, "'omni'"),
           ({**KALIBR["pinhole"], "distortion_model": "fov"}, "'fov'"),
           ({**KALIBR["pinhole-radtan"], "distortion_coeffs": [0.1, 0.2]}, "distortion_coeffs"),
           ({k: v for k, v in KALIBR["pinhole-equidistant"].items()
             if k != "distortion_coeffs"}, "needs distortion_coeffs .* has none"),
           ({**KALIBR["double-sphere"], "intrinsics": EUROC[:4]}, "intrinsics"),
           ({**KALIBR["pinhole"], "resolution": [640.5, 480]}, "resolution")]
    for entry, word in bad:
        with pytest.raises(ValueError, match=rf"^camera.Camera.from_kalibr: .*{word}"):
            Camera.from_kalibr({"resolution": [640, 480], **entry})


def test_models_table_lists_the_parameter_orders():
    assert {m: len(n) for m, n in camera.MODELS.items()} == {
        "pinhole": 4, "pinhole-radtan": 8, "pinhole-equidistant": 8, "double-sphere": 6}

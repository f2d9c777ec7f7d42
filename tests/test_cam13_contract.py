"""``torch_dq.camera`` against API.md's conventions: ``Camera`` a frozen value (no alias of
the caller's params, no silent in-place change), broadcasting of params against points and
pixels over the conventions' batch shapes, float32 accuracy, every device. References:
OpenCV's ``projectPoints`` / the paper's double sphere in numpy (``test_cam12_project``)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from conftest import DEVICES
from test_cam12_project import PARAMS, ref_project
from test_cam12_unproject import STRONG

from torch_dq import camera
from torch_dq.camera import Camera

F64 = torch.float64
WIDTH, HEIGHT = 752, 480
POINTS = np.array([[0.1, -0.2, 1.0], [-0.3, 0.25, 2.0], [0.5, 0.4, 1.5], [0.0, 0.0, 3.0],
                   [-0.2, -0.1, 0.8]])


def test_camera_does_not_alias_the_callers_params():
    """Changing the tensor a camera was made from leaves the camera's pixels as they were;
    ``camera.params`` is another tensor with the same values."""
    p = torch.tensor(PARAMS["pinhole"], dtype=F64)
    cam = Camera("pinhole", p, (WIDTH, HEIGHT))
    p[0] = 1.0
    px, _ = cam.project(torch.tensor(POINTS, dtype=F64))
    np.testing.assert_allclose(px.numpy(), ref_project("pinhole", PARAMS["pinhole"], POINTS),
                               rtol=1e-14)
    assert cam.params.data_ptr() != p.data_ptr() and cam.params[0] == PARAMS["pinhole"][0]


@pytest.mark.parametrize("method", ["project", "unproject", "to", "to_kalibr"])
def test_camera_params_changed_in_place_raise(method):
    """A camera whose ``params`` were changed in place refuses to answer (ValueError naming
    the change) instead of silently using the new values."""
    cam = Camera("pinhole-radtan", torch.tensor(PARAMS["pinhole-radtan"], dtype=F64),
                 (WIDTH, HEIGHT))
    cam.params[4] = 0.0
    args = {"project": (torch.zeros(3, dtype=F64),), "unproject": (torch.zeros(2, dtype=F64),),
            "to": (torch.float32,), "to_kalibr": ()}[method]
    with pytest.raises(ValueError, match="changed in place"):
        getattr(cam, method)(*args)


def test_camera_gradients_reach_the_callers_params():
    """The copy is differentiable: d u / d fu = x / z and d v / d cv = 1 reach the tensor the
    camera was made from (a pinhole: u = fu x / z + cu)."""
    p = torch.tensor(PARAMS["pinhole"], dtype=F64, requires_grad=True)
    px, _ = Camera("pinhole", p, (WIDTH, HEIGHT)).project(torch.tensor(POINTS[:1], dtype=F64))
    px[0, 0].backward()
    x, _, z = POINTS[0]
    np.testing.assert_allclose(p.grad.numpy(), [x / z, 0.0, 1.0, 0.0], rtol=1e-15)


SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


@pytest.mark.parametrize("model", list(camera.MODELS))
@pytest.mark.parametrize("pshape,xshape", list(itertools.product(SHAPES, SHAPES)))
def test_broadcasting(model, pshape, xshape):
    """params of batch shape ``pshape`` against points (pixels) of ``xshape``: the output's
    batch is the broadcast one and each element is the reference of its own params and
    point (params differ along the batch: the focal lengths scaled by 1 + i / 10)."""
    base = np.array(PARAMS[model])
    scale = 1 + np.arange(int(np.prod(pshape))).reshape(pshape) / 10
    params = np.broadcast_to(base, (*pshape, base.size)).copy()
    params[..., :2] *= scale[..., None]
    pts = POINTS[np.arange(int(np.prod(xshape))).reshape(xshape) % len(POINTS)]
    batch = np.broadcast_shapes(pshape, xshape)
    px, ok = camera.project(model, torch.tensor(params), torch.tensor(pts))
    assert px.shape == (*batch, 2) and ok.shape == batch and bool(ok.all())
    bp = np.broadcast_to(params, (*batch, base.size)).reshape(-1, base.size)
    bx = np.broadcast_to(pts, (*batch, 3)).reshape(-1, 3)
    want = np.stack([ref_project(model, list(q), x[None])[0] for q, x in zip(bp, bx, strict=True)])
    np.testing.assert_allclose(px.numpy().reshape(-1, 2), want, rtol=1e-12)
    rays, ok = camera.unproject(model, torch.tensor(params), px)
    assert rays.shape == (*batch, 3) and bool(ok.all())
    unit = bx / np.linalg.norm(bx, axis=-1, keepdims=True)
    np.testing.assert_allclose(rays.numpy().reshape(-1, 3), unit, atol=1e-12)


@pytest.mark.parametrize("model,lens", [(m, "euroc") for m in camera.MODELS]
                         + [(m, "strong") for m in STRONG])
def test_float32_accuracy(model, lens):
    """float32 params and pixels over a 121 x 81 grid of a 752 x 480 image: every pixel
    valid where float64 is, each ray re-projecting (float64 reference) within 3e-4 px
    (measured: 1.8e-4 px at most, all models); project's float32 pixels within 2e-6 of the
    reference relative to the larger of the pixel's size and fu (measured 8.3e-7: 7 ulp)."""
    p = (PARAMS if lens == "euroc" else STRONG)[model]
    u, v = np.meshgrid(np.linspace(0, WIDTH - 1, 121), np.linspace(0, HEIGHT - 1, 81))
    px = np.stack([u.ravel(), v.ravel()], -1)
    _, ok64 = camera.unproject(model, torch.tensor(p, dtype=F64), torch.tensor(px))
    rays, ok = camera.unproject(model, torch.tensor(p, dtype=torch.float32),
                                torch.tensor(px, dtype=torch.float32))
    assert rays.dtype == torch.float32 and bool(ok[ok64].all())
    back = ref_project(model, p, rays.double().numpy()[ok.numpy()])
    assert np.abs(back - px[ok.numpy()]).max() < 3e-4
    pts = np.random.default_rng(0).normal(size=(2000, 3)) * [0.5, 0.5, 1.0]
    pts[:, 2] = np.abs(pts[:, 2]) + 0.3
    got, valid = camera.project(model, torch.tensor(p, dtype=torch.float32),
                                torch.tensor(pts, dtype=torch.float32))
    want = ref_project(model, p, pts.astype(np.float32).astype(np.float64))
    err = np.abs(got.double().numpy() - want).max(-1) / np.maximum(np.abs(want).max(-1), p[0])
    assert bool(valid.all()) and err.max() < 2e-6


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("model", list(camera.MODELS))
def test_every_device(model, device):
    """Outputs on the inputs' device, equal to the CPU's float64 reference."""
    p = torch.tensor(PARAMS[model], dtype=F64, device=device)
    px, ok = camera.project(model, p, torch.tensor(POINTS, dtype=F64, device=device))
    assert px.device == p.device and ok.device == p.device
    np.testing.assert_allclose(px.cpu().numpy(), ref_project(model, PARAMS[model], POINTS),
                               rtol=1e-12)
    rays, ok = camera.unproject(model, p, px)
    assert rays.device == p.device and bool(ok.all())
    np.testing.assert_allclose(rays.cpu().numpy(),
                               POINTS / np.linalg.norm(POINTS, axis=-1, keepdims=True),
                               atol=1e-12)

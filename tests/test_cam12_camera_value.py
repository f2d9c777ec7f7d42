"""Outside tests of ``camera.Camera`` (frozen value, validation, Kalibr round trips) and of
the argument checks of ``project`` / ``unproject`` (API.md, Conventions and
torch_dq.camera)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import yaml

from torch_dq import camera
from torch_dq.camera import Camera

F64 = torch.float64
EUROC_CAM0 = {  # EuRoC's sensor.yaml for cam0, as a Kalibr camchain writes it
    "camera_model": "pinhole", "distortion_model": "radtan",
    "intrinsics": [458.654, 457.296, 367.215, 248.375],
    "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
    "resolution": [752, 480], "rostopic": "/cam0/image_raw",
    "T_cam_imu": [[1.0, 0.0, 0.0, 0.0]] * 4,
}
ENTRIES = {
    "pinhole-radtan": EUROC_CAM0,
    "pinhole": {"camera_model": "pinhole", "distortion_model": "none",
                "intrinsics": [400.0, 401.0, 320.5, 240.25], "distortion_coeffs": [],
                "resolution": [640, 480]},
    "pinhole-equidistant": {"camera_model": "pinhole", "distortion_model": "equidistant",
                            "intrinsics": [190.97, 190.97, 254.93, 256.90],
                            "distortion_coeffs": [0.0034, 0.0007, -0.0020, 0.0002],
                            "resolution": [512, 512]},
    # basalt / Kalibr ds: [xi, alpha, fu, fv, pu, pv]
    "double-sphere": {"camera_model": "ds", "distortion_model": "none",
                      "intrinsics": [-0.2, 0.59, 158.3, 158.2, 254.9, 256.9],
                      "resolution": [512, 512]},
}
EXPECTED = {
    "pinhole-radtan": [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907,
                       0.00019359, 1.76187114e-05],
    "pinhole": [400.0, 401.0, 320.5, 240.25],
    "pinhole-equidistant": [190.97, 190.97, 254.93, 256.90, 0.0034, 0.0007, -0.0020, 0.0002],
    "double-sphere": [158.3, 158.2, 254.9, 256.9, -0.2, 0.59],
}


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_from_kalibr_order_and_round_trip(model):
    cam = Camera.from_kalibr(ENTRIES[model])
    assert cam.model == model
    assert cam.params.dtype == F64 and cam.params.tolist() == EXPECTED[model]
    assert cam.resolution == (ENTRIES[model]["resolution"][0],
                              ENTRIES[model]["resolution"][1])
    out = cam.to_kalibr()
    for key in ("camera_model", "distortion_model", "intrinsics", "resolution"):
        assert out[key] == ENTRIES[model][key], key
    # through YAML text and back: equal, bit for bit
    again = Camera.from_kalibr(yaml.safe_load(yaml.safe_dump(out)))
    assert again == cam and again.params.tolist() == cam.params.tolist()


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_camera_methods_are_the_functions(model):
    cam = Camera.from_kalibr(ENTRIES[model])
    pts = torch.tensor([[0.1, -0.2, 1.0], [0.0, 0.0, 2.0], [0.3, 0.1, -1.0]], dtype=F64)
    px, ok = cam.project(pts)
    px2, ok2 = camera.project(model, cam.params, pts)
    assert torch.equal(px, px2) and torch.equal(ok, ok2)
    rays, ok = cam.unproject(px[:2])
    rays2, ok2 = camera.unproject(model, cam.params, px[:2])
    assert torch.equal(rays, rays2) and torch.equal(ok, ok2)


def test_camera_frozen_and_params_tensor():
    cam = Camera("pinhole", [400.0, 400.0, 320.0, 240.0], (640, 480))
    assert isinstance(cam.params, torch.Tensor) and cam.params.shape == (4,)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.model = "pinhole-radtan"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.resolution = (1, 1)  # type: ignore[misc]
    assert cam.resolution == (640, 480)
    res = [640, 480]
    cam2 = Camera("pinhole", torch.tensor([400.0, 400.0, 320.0, 240.0]), res)
    res[0] = 1
    assert cam2.resolution == (640, 480)  # a tuple, not the caller's list


@pytest.mark.parametrize("args,match", [
    (("fisheye", [1.0, 1.0, 0.0, 0.0], (10, 10)), "model"),
    (("pinhole", [1.0, 1.0, 0.0], (10, 10)), "params"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0, 0.0], (10, 10)), "params"),
    (("pinhole-radtan", [1.0, 1.0, 0.0, 0.0], (10, 10)), "params"),
    (("pinhole", torch.ones(1, 4, dtype=F64), (10, 10)), "params"),
    (("pinhole", [1.0, 1.0, 0.0, float("nan")], (10, 10)), "params"),
    (("pinhole", [0.0, 1.0, 0.0, 0.0], (10, 10)), "params"),
    (("double-sphere", [1.0, 1.0, 0.0, 0.0, 0.0, 1.5], (10, 10)), "params"),
    (("double-sphere", [1.0, 1.0, 0.0, 0.0, -1.0, 0.5], (10, 10)), "params"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], (10,)), "resolution"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], (10, 0)), "resolution"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], (10.5, 10)), "resolution"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], (-640, 480)), "resolution"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], "640x480"), "resolution"),
    (("pinhole", [1.0, 1.0, 0.0, 0.0], (True, 480)), "resolution"),
])
def test_camera_validation(args, match):
    with pytest.raises(ValueError, match=match):
        Camera(*args)


def test_camera_int_params_type_error():
    with pytest.raises(TypeError, match="params"):
        Camera("pinhole", torch.tensor([400, 400, 320, 240]), (640, 480))


def _entry(**changes):
    e = dict(EUROC_CAM0)
    e.update(changes)
    return {k: v for k, v in e.items() if v is not ...}


@pytest.mark.parametrize("entry,key", [
    (_entry(intrinsics=[458.654, 457.296, 367.215]), "intrinsics"),
    (_entry(intrinsics="458 457 367 248"), "intrinsics"),
    (_entry(intrinsics=[458.654, 457.296, 367.215, float("inf")]), "intrinsics"),
    (_entry(intrinsics=...), "intrinsics"),
    (_entry(distortion_coeffs=[0.1, 0.2]), "distortion_coeffs"),
    (_entry(distortion_coeffs=[0.1, 0.2, 0.0, "x"]), "distortion_coeffs"),
    (_entry(distortion_coeffs=...), "distortion_coeffs"),
    (_entry(distortion_model="fov"), "distortion_model"),
    (_entry(camera_model="omni"), "camera_model"),
    (_entry(camera_model=...), "camera_model"),
    (_entry(resolution=[752]), "resolution"),
    (_entry(resolution=...), "resolution"),
    (_entry(resolution=[752.5, 480]), "resolution"),
    (_entry(camera_model="ds", distortion_model="none",
            intrinsics=[458.654, 457.296, 367.215, 248.375]), "intrinsics"),
    (_entry(distortion_model="none"), "distortion_coeffs"),
])
def test_from_kalibr_bad_entries_name_the_key(entry, key):
    with pytest.raises(ValueError, match=key):
        Camera.from_kalibr(entry)


def test_from_kalibr_out_of_domain_raises():
    with pytest.raises(ValueError):
        Camera.from_kalibr(_entry(intrinsics=[-458.654, 457.296, 367.215, 248.375]))
    with pytest.raises(ValueError):
        Camera.from_kalibr({"camera_model": "ds", "intrinsics": [0.1, 1.2, 1, 1, 0, 0],
                            "resolution": [10, 10]})


def test_from_kalibr_yaml_quirks():
    """PyYAML reads ``2e-4`` (no dot) as a string; integral floats as resolution."""
    text = """
camera_model: pinhole
distortion_model: radtan
intrinsics: [458.654, 457.296, 367.215, 248.375]
distortion_coeffs: [-0.28340811, 0.07395907, 2e-4, 1.76187114e-05]
resolution: [752.0, 480]
"""
    cam = Camera.from_kalibr(yaml.safe_load(text))
    assert cam.params[6].item() == 2e-4 and cam.resolution == (752, 480)


# ---------------------------------------------------------------- project / unproject args

P4 = torch.tensor([400.0, 400.0, 320.0, 240.0], dtype=F64)


@pytest.mark.parametrize("fn,x", [(camera.project, torch.zeros(5, 2, dtype=F64)),
                                  (camera.project, torch.zeros(5, 4, dtype=F64)),
                                  (camera.project, torch.zeros((), dtype=F64)),
                                  (camera.unproject, torch.zeros(5, 3, dtype=F64)),
                                  (camera.unproject, torch.zeros(2, 1, dtype=F64))])
def test_wrong_trailing_dim(fn, x):
    name = "points" if fn is camera.project else "pixels"
    with pytest.raises(ValueError, match=name):
        fn("pinhole", P4, x)


@pytest.mark.parametrize("fn", [camera.project, camera.unproject])
def test_bad_params_and_model(fn):
    n = 3 if fn is camera.project else 2
    x = torch.ones(4, n, dtype=F64)
    with pytest.raises(ValueError, match="params"):
        fn("pinhole", torch.ones(5, dtype=F64), x)
    with pytest.raises(ValueError, match="params"):
        fn("pinhole-radtan", P4, x)
    with pytest.raises(ValueError, match="model"):
        fn("radtan", P4, x)
    with pytest.raises(ValueError, match="model"):
        fn(None, P4, x)
    with pytest.raises(ValueError):
        fn("pinhole", P4.expand(3, 4), x)  # (3,) against (4,): not broadcastable
    with pytest.raises(TypeError, match="params"):
        fn("pinhole", torch.tensor([400, 400, 320, 240]), x)
    with pytest.raises(TypeError):
        fn("pinhole", P4, torch.ones(4, n, dtype=torch.int64))
    with pytest.raises(TypeError):
        fn("pinhole", P4, torch.ones(4, n, dtype=torch.bool))
    with pytest.raises((TypeError, ValueError)):
        fn("pinhole", P4, np.ones((4, n)))
    with pytest.raises((TypeError, ValueError)):
        fn("pinhole", P4, torch.ones(4, n, dtype=torch.float32))  # mixed dtypes


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_follows_dtype(dtype):
    p = P4.to(dtype)
    px, ok = camera.project("pinhole", p, torch.tensor([0.1, -0.2, 1.0], dtype=dtype))
    assert px.dtype == dtype and bool(ok)
    np.testing.assert_allclose(px.double().numpy(), [360.0, 160.0], rtol=1e-2)
    rays, ok = camera.unproject("pinhole", p, px)
    assert rays.dtype == dtype and bool(ok)


def test_empty_batches():
    px, ok = camera.project("pinhole-radtan", torch.ones(0, 8, dtype=F64).add(1),
                            torch.ones(0, 3, dtype=F64))
    assert px.shape == (0, 2) and ok.shape == (0,)
    rays, ok = camera.unproject("pinhole-equidistant", P4.new_ones(8), torch.ones(2, 0, 2,
                                                                                  dtype=F64))
    assert rays.shape == (2, 0, 3) and ok.shape == (2, 0)


def test_unproject_far_pixels_of_pinhole():
    """Pixels far beyond anything ``project`` returns (it refuses points more than 1/eps
    off axis): never a zero-length ray passed as valid."""
    px = torch.tensor([[1e300, 0.0], [1e200, 1e200], [1e155, 3e154], [1e10, 0.0]], dtype=F64)
    rays, ok = camera.unproject("pinhole", P4, px)
    assert bool(torch.isfinite(rays).all())
    norms = torch.linalg.norm(rays, dim=-1)
    assert bool(((norms - 1).abs() < 1e-15)[ok].all()), (rays, ok)
    back, ok2 = camera.project("pinhole", P4, rays)
    assert bool(ok2[ok].all())
    torch.testing.assert_close(back[ok], px[ok], rtol=1e-12, atol=0.0)
    assert bool(ok[3])

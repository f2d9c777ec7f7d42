"""Outside-tester regressions for cameras, Kalibr entries and camera_imu's inputs (rigs7).

Each test failed before its fix:

- a strong fisheye's equidistant unprojection against OpenCV (``cv2.fisheye``): pixels whose
  ray lies inside the fold came back invalid (plain Newton started beyond the fold);
- ``Camera`` with parameters outside the model's domain (a negative focal length, NaN, a
  double sphere's ``alpha = 2``) was built silently and projected nothing;
- ``Camera.from_kalibr`` refused odd but valid camchain entries (``2e-4`` without a dot,
  which YAML 1.1 reads as a string; ``resolution: [512.0, 512.0]``; ``distortion_model:
  none`` with four zero coefficients); ``read_target`` read a quoted ``'6'`` as ``6.0``
  and refused it;
- ``calibration.camera_imu`` accepted pixels far outside the camera's resolution (another
  camera's, or swapped width and height).
"""

import math

import numpy as np
import pytest
import torch

from torch_dq import calibration
from torch_dq.camera import Camera, project, unproject

F64 = torch.float64
cv2 = pytest.importorskip("cv2")

# A strongly distorted fisheye: theta_d(theta) folds at about 1.41 rad (81 deg).
STRONG = [300.0, 300.0, 320.0, 240.0, 0.6, -0.3, 0.05, -0.01]
STRONG_RES = (800, 600)


def _strong_image_pixels() -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, STRONG_RES[0] - 1, 101),
                       np.linspace(0, STRONG_RES[1] - 1, 101))
    return np.stack([u.ravel(), v.ravel()], 1)


def _opencv_roundtrip(px: np.ndarray) -> np.ndarray:
    """Pixels whose OpenCV undistortion projects back onto them (to 1e-6 px) with the
    angle inside the fold (slope of theta_d positive: numpy here)."""
    K = np.array([[STRONG[0], 0, STRONG[2]], [0, STRONG[1], STRONG[3]], [0, 0, 1.0]])
    D = np.array(STRONG[4:])
    m = cv2.fisheye.undistortPoints(px[:, None], K, D)[:, 0]
    back, _ = cv2.fisheye.projectPoints(np.c_[m, np.ones(len(m))][:, None], np.zeros(3),
                                        np.zeros(3), K, D)
    theta = np.arctan(np.linalg.norm(m, axis=1))
    k1, k2, k3, k4 = D
    t = theta ** 2
    slope = 1 + 3 * k1 * t + 5 * k2 * t ** 2 + 7 * k3 * t ** 3 + 9 * k4 * t ** 4
    return (np.linalg.norm(back[:, 0] - px, axis=1) < 1e-6) & (slope > 0)


def test_strong_fisheye_unprojection_valid_wherever_opencv_inverts():
    px = _strong_image_pixels()
    ref = _opencv_roundtrip(px)
    assert ref.sum() > 8000  # most of the image (8668 of 10201): the test covers something
    rays, ok = unproject("pinhole-equidistant", torch.tensor(STRONG, dtype=F64),
                         torch.tensor(px, dtype=F64))
    assert bool(ok[torch.from_numpy(ref)].all()), int((~ok[torch.from_numpy(ref)]).sum())
    back, ok2 = project("pinhole-equidistant", torch.tensor(STRONG, dtype=F64), rays)
    err = (back - torch.tensor(px, dtype=F64)).norm(dim=-1)[ok & ok2]
    assert float(err.max()) < 1e-9
    # and the rays are OpenCV's (its undistorted points, normalised)
    K = np.array([[STRONG[0], 0, STRONG[2]], [0, STRONG[1], STRONG[3]], [0, 0, 1.0]])
    m = cv2.fisheye.undistortPoints(px[ref][:, None], K, np.array(STRONG[4:]))[:, 0]
    r = rays.numpy()[ref]
    np.testing.assert_allclose(r[:, :2] / r[:, 2:], m, atol=1e-9, rtol=1e-9)


def test_strong_fisheye_unprojection_beyond_the_fold_is_invalid():
    # a pixel farther out than theta_d's maximum (about 1.75 rad: 525 px) has no preimage
    px = torch.tensor([[STRONG[2] + 560.0, STRONG[3]]], dtype=F64)
    rays, ok = unproject("pinhole-equidistant", torch.tensor(STRONG, dtype=F64), px)
    assert not bool(ok[0]) and bool(torch.isfinite(rays).all())


@pytest.mark.parametrize("model, params", [
    ("pinhole", [-400.0, 400.0, 320.0, 240.0]),
    ("pinhole", [400.0, 0.0, 320.0, 240.0]),
    ("pinhole-radtan", [400.0, 400.0, math.nan, 240.0, 0.0, 0.0, 0.0, 0.0]),
    ("pinhole-equidistant", [400.0, 400.0, 320.0, 240.0, math.inf, 0.0, 0.0, 0.0]),
    ("double-sphere", [300.0, 300.0, 320.0, 240.0, 0.1, 2.0]),
    ("double-sphere", [300.0, 300.0, 320.0, 240.0, -1.5, 0.5]),
])
def test_camera_refuses_params_outside_the_domain(model, params):
    with pytest.raises(ValueError, match=r"camera\.Camera: expected finite params"):
        Camera(model, torch.tensor(params, dtype=F64), (640, 480))


def test_camera_edge_of_the_domain_is_accepted():
    for alpha in (0.0, 1.0):
        cam = Camera("double-sphere", torch.tensor([300.0, 300, 320, 240, -0.2, alpha]),
                     (640, 480))
        assert cam.params[5] == alpha


def test_from_kalibr_numbers_without_a_dot():
    yaml = pytest.importorskip("yaml")
    entry = yaml.safe_load("camera_model: pinhole\ndistortion_model: radtan\n"
                           "distortion_coeffs: [-0.28, 0.07, 2e-4, 1e-5]\n"
                           "intrinsics: [458, 457, 367, 248]\nresolution: [752, 480]\n")
    assert isinstance(entry["distortion_coeffs"][2], str)  # what PyYAML makes of 2e-4
    cam = Camera.from_kalibr(entry)
    assert cam.params.tolist() == [458.0, 457.0, 367.0, 248.0, -0.28, 0.07, 2e-4, 1e-5]
    assert Camera.from_kalibr(yaml.safe_load(yaml.safe_dump(cam.to_kalibr()))) == cam


def test_from_kalibr_integral_float_resolution_and_zero_coefficients():
    cam = Camera.from_kalibr({"camera_model": "pinhole", "distortion_model": "none",
                              "distortion_coeffs": [0.0, 0.0, 0.0, 0.0],
                              "intrinsics": [190.0, 191.0, 255.0, 256.0],
                              "resolution": [512.0, 512.0]})
    assert cam.model == "pinhole" and cam.resolution == (512, 512)
    assert isinstance(cam.resolution[0], int)
    for bad in ({"resolution": [512.5, 512]}, {"distortion_coeffs": [0.1, 0.0, 0.0, 0.0]},
                {"intrinsics": [190.0, "abc", 255.0, 256.0]}):
        entry = {"camera_model": "pinhole", "distortion_model": "none",
                 "intrinsics": [190.0, 191.0, 255.0, 256.0], "resolution": [512, 512], **bad}
        with pytest.raises(ValueError, match=r"camera\.Camera\.from_kalibr: expected"):
            Camera.from_kalibr(entry)


def test_read_target_quoted_integer(tmp_path):
    pytest.importorskip("yaml")
    path = tmp_path / "april.yaml"
    path.write_text("target_type: aprilgrid\ntagCols: '6'\ntagRows: 5\ntagSize: 88e-3\n"
                    "tagSpacing: 0.3\n")
    target = calibration.read_target(path)
    assert (target.rows, target.cols, target.size) == (5, 6, 0.088)
    path.write_text("target_type: aprilgrid\ntagCols: '6.5'\ntagRows: 5\ntagSize: 0.088\n"
                    "tagSpacing: 0.3\n")
    with pytest.raises(ValueError, match="tagCols must be an int"):
        calibration.read_target(path)


def _tiny_recording(width: int = 752, height: int = 480):
    """Inputs that pass camera_imu's shape checks (the pixels' check comes before any
    estimation): 2 s of IMU at 200 Hz, 20 frames of 4 corners."""
    t = torch.arange(0.0, 2.0, 0.005, dtype=F64)
    imu = (t, torch.zeros(t.numel(), 3, dtype=F64), torch.zeros(t.numel(), 3, dtype=F64))
    ft = torch.arange(0.1, 1.9, 0.09, dtype=F64).repeat_interleave(4)
    pts = torch.tensor([[0.0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0]],
                       dtype=F64).repeat(ft.numel() // 4, 1)
    px = torch.tensor([[100.0, 100], [width - 1.0, 100], [width - 1.0, height - 1.0],
                       [100, height - 1.0]], dtype=F64).repeat(ft.numel() // 4, 1)
    return imu, (ft, pts, px)


@pytest.mark.parametrize("resolution", [(640, 480), (480, 752)])
def test_camera_imu_refuses_pixels_outside_the_resolution(resolution):
    imu, obs = _tiny_recording()
    cam = Camera("pinhole", torch.tensor([450.0, 450.0, 370.0, 240.0], dtype=F64), resolution)
    with pytest.raises(ValueError, match=r"calibration\.camera_imu: observations\[0\] pixels "
                                         r"reach [uv] = \d+, outside cameras\[0\]\.resolution"):
        calibration.camera_imu([cam], [obs], imu, gyro_noise=1e-4, accel_noise=1e-3)


def test_camera_imu_refuses_normalised_coordinates_for_pixels():
    imu, (ft, pts, px) = _tiny_recording()
    cam = Camera("pinhole", torch.tensor([450.0, 450.0, 370.0, 240.0], dtype=F64), (752, 480))
    normalised = (px - cam.params[2:]) / cam.params[:2]  # x/z, y/z: within [-0.8, 0.8]
    with pytest.raises(ValueError, match=r"camera_imu: observations\[0\]: the pixels all lie "
                                         r"within 0\.8\d* of \(0, 0\).*normalised"):
        calibration.camera_imu([cam], [(ft, pts, normalised)], imu, gyro_noise=1e-4,
                               accel_noise=1e-3)


def test_camera_imu_refuses_target_points_in_millimetres():
    imu, (ft, pts, px) = _tiny_recording()
    pts = pts * 1000.0 * 100  # a 10 m board in mm
    cam = Camera("pinhole", torch.tensor([450.0, 450.0, 370.0, 240.0], dtype=F64), (752, 480))
    with pytest.raises(ValueError, match=r"observations\[0\] points span 1\.414e\+04 \(metres "
                                         r"expected\): millimetres\?"):
        calibration.camera_imu([cam], [(ft, pts, px)], imu, gyro_noise=1e-4, accel_noise=1e-3)


def test_reprojections_warns_on_normalised_coordinates():
    from torch_dq import fitting
    cam = Camera("pinhole", torch.tensor([450.0, 450.0, 370.0, 240.0], dtype=F64), (752, 480))
    t = torch.linspace(0.1, 0.9, 8, dtype=F64)
    pts = torch.rand(8, 3, dtype=F64) * torch.tensor([0.5, 0.5, 0.0], dtype=F64)
    pix = torch.rand(8, 2, dtype=F64) * 1.2 - 0.6
    with pytest.warns(UserWarning, match=r"fitting\.Reprojections: the pixels all lie within"):
        fitting.Reprojections(t, pts, pix, camera=cam, sigma=1.0)
    # pixels of a target near the image's corner, a few pixels wide, stay quiet: a spread
    # of pixels beyond 4 px
    pix = torch.rand(8, 2, dtype=F64) * 30.0
    fitting.Reprojections(t, pts, pix, camera=cam, sigma=1.0)

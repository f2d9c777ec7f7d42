"""A new user's bad inputs and edge pixels (outside8): cameras, calibration files, terms.

References: OpenCV's ``undistortPoints`` and ``fisheye.undistortPoints`` (rays of pixels);
the messages must name the function, the argument (or the file and line) and what was
expected.
"""

import math
import os

import numpy as np
import pytest
import torch

from torch_dq import calibration, camera, fitting
from torch_dq.camera import Camera

cv2 = pytest.importorskip("cv2")

# EuRoC cam0 as Kalibr calibrated it: radtan (EuRoC's sensor.yaml) and equidistant (the
# camchain-imucam.yaml kept in github.com/ethz-asl/voxblox)
RADTAN = [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
          1.76187114e-05]
EQUI = [461.3418503026154, 460.13885656354387, 366.4281018364134, 248.8415565479774,
        -0.011602611404146694, 0.05399058892805103, -0.07542693754837938, 0.03666365316319072]
CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 1000, 1e-15)


def _grid(n=301):
    u, v = np.meshgrid(np.linspace(-0.5, 751.5, n), np.linspace(-0.5, 479.5, n))
    return np.stack([u.ravel(), v.ravel()], 1)


def _rays(xy):
    r = np.column_stack([xy, np.ones(len(xy))])
    return r / np.linalg.norm(r, axis=1, keepdims=True)


@pytest.mark.parametrize("model", ["pinhole-radtan", "pinhole-equidistant"])
def test_every_pixel_of_the_image_unprojects_as_opencv(model):
    """Every pixel of a 301 x 301 grid over EuRoC's image is valid and its ray is OpenCV's.
    (Before the fix, 8 equidistant pixels had a converged root thrown away by the bracket
    test and came out invalid, ray (0, 0, 1).)"""
    pix = _grid()
    params = RADTAN if model == "pinhole-radtan" else EQUI
    K = np.array([[params[0], 0, params[2]], [0, params[1], params[3]], [0, 0, 1]])
    if model == "pinhole-radtan":
        xy = cv2.undistortPoints(pix[:, None], K, np.array([*params[4:], 0.0]), criteria=CRITERIA)
    else:
        xy = cv2.fisheye.undistortPoints(pix[:, None], K, np.array(params[4:]), criteria=CRITERIA)
    rays, ok = camera.unproject(model, torch.tensor(params, dtype=torch.float64),
                                torch.tensor(pix))
    assert int((~ok).sum()) == 0
    np.testing.assert_allclose(rays.numpy(), _rays(xy[:, 0]), rtol=0, atol=1e-12)


def test_float32_unprojection_accuracy():
    """float32: valid everywhere, rays within 2e-6 of float64's (measured 4e-7)."""
    pix = torch.tensor(_grid(101))
    p = torch.tensor(EQUI, dtype=torch.float64)
    r64, _ = camera.unproject("pinhole-equidistant", p, pix)
    r32, ok = camera.unproject("pinhole-equidistant", p.float(), pix.float())
    assert bool(ok.all())
    assert float((r32.double() - r64).abs().max()) < 2e-6


def _obs():
    cam = Camera("pinhole-radtan", torch.tensor(RADTAN, dtype=torch.float64), (752, 480))
    t = torch.tensor([0.0, 0.0, 0.05], dtype=torch.float64)
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]], dtype=torch.float64)
    return cam, t, pts


@pytest.mark.parametrize(("pixel", "axis"), [((1000.0, 200.0), "u"), ((100.0, -60.0), "v")])
def test_reprojections_refuse_pixels_outside_the_image(pixel, axis):
    """Another camera's pixels (a 1280 x 720 camera's into a 752 x 480 one) were fitted
    silently; 10 % of the image's size is tolerated (simulations that do not crop)."""
    cam, t, pts = _obs()
    pix = torch.tensor([[300.0, 200.0], [350.0, 210.0], pixel], dtype=torch.float64)
    with pytest.raises(ValueError, match=rf"fitting\.Reprojections: pixels reach {axis} = .*"
                                         r"outside camera\.resolution = \(752, 480\)"):
        fitting.Reprojections(t, pts, pix, camera=cam, sigma=0.5)
    fitting.Reprojections(t, pts, pix, camera=cam, sigma=0.5,
                          mask=torch.tensor([True, True, False]))  # masked: not checked
    fitting.Reprojections(t, pts, pix.clamp(-40.0, 780.0),
                          camera=cam, sigma=0.5)  # within 10 %


def _target(tmp_path, text):
    path = tmp_path / "april_6x6.yaml"
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(("text", "line", "what"), [
    ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: big\ntagSpacing: 0.3\n", 4,
     "tagSize must be a finite real number > 0, got 'big'"),
    ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6.5\ntagSize: 0.088\ntagSpacing: 0.3\n", 3,
     "tagRows must be an int >= 1, got 6.5"),
    ("# Kalibr\ntarget_type: [aprilgrid]\ntagCols: 6\n", 2, "target_type must be 'aprilgrid'"),
    ("target_type: 'circlegrid'\ntargetCols: 6\n", 1, "target_type must be 'aprilgrid'"),
])
def test_read_target_names_the_file_and_line(tmp_path, text, line, what):
    path = _target(tmp_path, text)
    with pytest.raises(ValueError) as info:
        calibration.read_target(path)
    message = str(info.value)
    assert message.startswith(f"calibration.read_target: {path}: {what}"), message
    assert message.endswith(f" (line {line})"), message


def test_read_target_yaml_syntax_error_names_the_line(tmp_path):
    path = _target(tmp_path, "target_type: 'aprilgrid'\ntagCols: 6\n tagRows: [6\n")
    with pytest.raises(ValueError, match=r"read_target: .*april_6x6\.yaml, line 3, column 9: "
                                         r"not a valid yaml file \(mapping values are not"):
        calibration.read_target(path)


ENTRY = {"camera_model": "pinhole", "distortion_model": "radtan", "intrinsics": RADTAN[:4],
         "distortion_coeffs": RADTAN[4:], "resolution": [752, 480]}


@pytest.mark.parametrize(("change", "match"), [
    ({"camera_model": ["pinhole"]}, r"unsupported camera_model \['pinhole'\]"),
    ({"distortion_model": {"k": 1}}, r"unsupported camera_model 'pinhole' with distortion_mo"),
    ({"camera_model": "omni"}, r"unsupported camera_model 'omni'"),
    ({"distortion_model": "plumb_bob"}, r"unsupported .* distortion_model 'plumb_bob'"),
    ({"intrinsics": RADTAN[:3]}, r"expected intrinsics to be a list of 4 finite numbers"),
    ({"distortion_coeffs": [math.nan, 0, 0, 0]}, r"expected distortion_coeffs to be a list"),
    ({"resolution": [752]}, r"expected resolution to be \(width, height\)"),
])
def test_from_kalibr_names_the_key(change, match):
    with pytest.raises(ValueError, match=r"camera\.Camera\.from_kalibr: " + match):
        Camera.from_kalibr({**ENTRY, **change})


def test_from_kalibr_reads_pyyaml_strings_and_round_trips():
    """PyYAML reads ``1.76187114e-05`` as a float but ``2e-4`` (no dot) as a string, and
    Kalibr's files hold both; the written entry reads back bit for bit."""
    cam = Camera.from_kalibr({**ENTRY, "distortion_coeffs": [*RADTAN[4:7], "2e-4"]})
    assert cam.params[7].item() == 2e-4
    assert Camera.from_kalibr(cam.to_kalibr()) == cam


@pytest.mark.parametrize(("args", "kind", "match"), [
    (("radtan", torch.ones(8, dtype=torch.float64), torch.ones(3, dtype=torch.float64)),
     ValueError, "expected model to be one of"),
    (("pinhole-radtan", torch.ones(5, dtype=torch.float64), torch.ones(3, dtype=torch.float64)),
     ValueError, r"expected a \(\.\.\., 8\) tensor for params"),
    (("pinhole", torch.ones(4, dtype=torch.float64), torch.ones(2, dtype=torch.float64)),
     ValueError, r"expected a \(\.\.\., 3\) tensor for points"),
    (("pinhole", torch.ones(4, dtype=torch.float64), torch.ones(3, dtype=torch.int64)),
     TypeError, "expected a floating-point tensor for points"),
    (("pinhole", torch.ones(4), torch.ones(3, dtype=torch.float64)),
     TypeError, "points has dtype torch.float64 but params has dtype torch.float32"),
])
def test_project_argument_errors(args, kind, match):
    with pytest.raises(kind, match=r"camera\.project: " + match):
        camera.project(*args)


def test_points_behind_and_nan_are_flagged_not_made_up():
    """Behind the camera: finite pixels flagged invalid; NaN points: NaN pixels, invalid."""
    p = torch.tensor(RADTAN, dtype=torch.float64)
    pts = torch.tensor([[0.1, 0.2, -1.0], [0.0, 0.0, 0.0], [math.nan, 0.0, 1.0]],
                       dtype=torch.float64)
    pix, ok = camera.project("pinhole-radtan", p, pts)
    assert ok.tolist() == [False, False, False]
    assert bool(torch.isfinite(pix[:2]).all()) and bool(torch.isnan(pix[2]).all())


def test_read_imu_names_file_and_line_of_a_repeated_time(tmp_path):
    """An IMU file's repeated time: the file, the line, and the way out (no 'pose')."""
    from torch_dq import io

    row = "1403715273262142976,-0.099,0.14,0.02,8.1,-0.37,-2.1\n"
    path = tmp_path / "data.csv"
    path.write_text("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad "
                    "s^-1],a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n" + row + row)
    with pytest.raises(ValueError, match=r"data\.csv, line 3: duplicate timestamp "
                                         r"1403715273262142976 ns \(also on line 2\); to keep "
                                         r"the first row of each time, pass duplicates='first'"):
        io.read_imu(path)
    assert io.read_imu(path, duplicates="first")[0].shape == (1,)


def test_unprojection_at_the_once_invalid_pixel_is_exact_and_differentiable():
    """The pixel of EuRoC's Kalibr cam0 whose converged root the bracket test threw away:
    valid, projects back to itself, and its rays' derivatives match finite differences
    (gradcheck and gradgradcheck, float64, w.r.t. the pixel and the parameters)."""
    pixel = torch.tensor([153.75641025641025, 165.01724137931035], dtype=torch.float64)
    params = torch.tensor(EQUI, dtype=torch.float64)
    ray, ok = camera.unproject("pinhole-equidistant", params, pixel)
    assert bool(ok)
    back, _ = camera.project("pinhole-equidistant", params, ray)
    assert float((back - pixel).abs().max()) < 1e-10
    f = lambda p, x: camera.unproject("pinhole-equidistant", p, x)[0]  # noqa: E731
    args = (params.clone().requires_grad_(), pixel.clone().requires_grad_())
    assert torch.autograd.gradcheck(f, args)
    assert torch.autograd.gradgradcheck(f, args)


def test_euroc_corner_file_numbers_corners_as_aprilgrid():
    """The EuRoC/Kalibr CSV's (tag_id, corner_idx) -> (X, Y, Z) is aprilgrid()'s order."""
    path = os.path.join(os.path.dirname(__file__), "data", "calibration",
                        "euroc_cam_april_cam0_corners.csv")
    _, p, _, extra = calibration.read_corners(path, extra=True)
    index = np.asarray(extra["tag_id"]) * 4 + np.asarray(extra["corner_idx"])
    grid = calibration.aprilgrid(6, 6, 0.088, 0.3).numpy()
    np.testing.assert_allclose(grid[index], p.numpy(), rtol=0, atol=1e-12)

"""Rendered images of a simulated rig through ``detect_folder`` and ``python -m torch_dq
calibrate`` give the calibration of the exact corners, within its standard deviations.

The recording (``tests/_render.py``): the stereo rig of ``tests/_camera_imu_sim.py`` (EuRoC's
cameras and ``T_imu_cam``, a 4 ms clock offset, an IMU at 200 Hz with biases and EuRoC's
noise) for 2 s at 20 Hz, each frame an AprilGrid rendered by OpenCV through the true pose
and distortion (2 grey levels of noise), written in EuRoC's layout with Kalibr's yamls and
the exact (noise-free) corners as CSVs. The same command runs once on ``--images`` and once
on ``--corners``; the differences are measured with numpy/scipy from the written camchains.
"""

import json
import os
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from torch_dq import calibration
from torch_dq.__main__ import main

cv2 = pytest.importorskip("cv2")
yaml = pytest.importorskip("yaml")
sys.path.insert(0, os.path.dirname(__file__))
import _camera_imu_sim as sim  # noqa: E402
import _render  # noqa: E402

OFFSET = 0.004
PIXEL_SIGMA = 0.1  # the detector's corners are within 0.04 px of the truth


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("rig")
    return root, _render.euroc_folder(root, duration=2.0, offset=OFFSET, seed=3)


def _calibrate(paths, out, source):
    argv = ["calibrate", "--target", str(paths["target"]), "--imu", str(paths["imu"]),
            "--imu-noise", str(paths["imu_noise"]), "--cameras", str(paths["cameras"]),
            "--out", str(out), "--pixel-sigma", str(PIXEL_SIGMA), "--no-plots", "--quiet"]
    for p in paths[source]:
        argv += [f"--{source}", str(p)]
    assert main(argv) == 0
    chain = yaml.safe_load((out / "camchain-imucam.yaml").read_text())
    return chain, json.loads((out / "summary.json").read_text())


@pytest.fixture(scope="module")
def results(recording):
    root, paths = recording
    return _calibrate(paths, root / "from_images", "images"), _calibrate(
        paths, root / "from_corners", "corners")


def test_detect_folder_finds_the_rendered_corners(recording):
    _, paths = recording
    target = calibration.read_target(paths["target"])
    times, points, pixels, _, _ = calibration.detect_folder(paths["images"][0], target)
    exact = calibration.read_corners(paths["corners"][0])
    truth = {(round(float(t) * 20), *np.round(p, 6)): u
             for t, p, u in zip(exact[0].numpy(), exact[1].numpy(), exact[2].numpy(),
                                strict=True)}
    err = np.array([np.linalg.norm(u - truth[(round(float(t) * 20), *np.round(p, 6))])
                    for t, p, u in zip(times.numpy(), points.numpy(), pixels.numpy(),
                                       strict=True)])
    # measured: 96% of the corners inside the image found, median 0.009 px, max 0.035 px
    assert err.size > 0.9 * exact[0].numel(), (err.size, exact[0].numel())
    assert np.median(err) < 0.03 and err.max() < 0.1, (np.median(err), err.max())


def _pose(chain, i):
    """Camera i's pose on the body (4 x 4) from a camchain."""
    return np.linalg.inv(np.array(chain[f"cam{i}"]["T_cam_imu"]))


def _chart(E_ref, E):
    """E in the chart ``E_ref exp(delta)`` of the extrinsics' std: rotation vector then
    translation, camera axes."""
    rot = Rotation.from_matrix(E_ref[:3, :3].T @ E[:3, :3]).as_rotvec()
    return np.concatenate([rot, E_ref[:3, :3].T @ (E[:3, 3] - E_ref[:3, 3])])


def test_images_calibrate_like_their_exact_corners(results):
    (img_chain, img), (ref_chain, ref) = results
    diff, truth = {}, {}
    for i in range(2):
        std = np.array(ref["values"]["extrinsics"]["std"][i])
        E = _pose(img_chain, i)
        diff[f"extrinsic{i}"] = _chart(_pose(ref_chain, i), E) / std
        truth[f"extrinsic{i}"] = _chart(E, sim.extrinsic_matrix(i)) / np.array(
            img["values"]["extrinsics"]["std"][i])
    for key in ("time_offsets", "gyro_bias", "accel_bias", "gravity"):
        a, b = (np.array(r["values"][key]["value"]) for r in (img, ref))
        diff[key] = (a - b) / np.array(ref["values"][key]["std"])
    truth["time_offsets"] = (np.array(img["values"]["time_offsets"]["value"]) - OFFSET) / (
        np.array(img["values"]["time_offsets"]["std"]))
    for key, z in diff.items():  # measured: at most 0.08 standard deviations apart
        assert np.all(np.abs(z) < 0.5), (key, z)
    for key, z in truth.items():  # measured: 2.0 at most (a translation)
        assert np.all(np.abs(z) < 4.0), (key, z)
    for r in (img, ref):
        assert not any("undetermined" in w for w in r["warnings"]), r["warnings"]
    # measured: 0.011 px from the images, 0.004 px from the exact corners (the spline and
    # the IMU's noise), well below the assumed 0.1 px
    assert max(img["reprojection_rms_px"]) < 0.05, img["reprojection_rms_px"]

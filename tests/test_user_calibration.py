"""An outside tester's bad inputs to ``calibration.camera_imu`` (0.5.0 trial): times in
nanoseconds, float32 times, a gyroscope in deg/s, unsorted or non-finite samples. Each must
end in a ``ValueError`` / ``TypeError`` that names the argument and the likely cause, before
any estimation; each test failed before its fix (nanoseconds: a 1.9 TB allocation; deg/s: a
finite calibration with a warning; float32 UNIX seconds: "strictly increasing")."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import torch

from torch_dq import calibration
from torch_dq.camera import Camera

pytest.importorskip("cv2")
sys.path.insert(0, os.path.dirname(__file__))
import _camera_imu_sim as sim

UNIX = 1403709385.0
KW = {"gyro_noise": sim.GYRO_DENSITY, "accel_noise": sim.ACCEL_DENSITY, "pixel_sigma": 0.3,
      "steps": 1}


def _t(x):
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


@pytest.fixture(scope="module")
def rig():
    """One camera of the simulated rig (3 s, 4 ms clock offset) and its IMU, in UNIX seconds."""
    (t, g, a), cams = sim.rig(duration=3.0, offset=0.004, seed=1)
    k = sim.K
    cam = Camera("pinhole-radtan", _t([k[0, 0], k[1, 1], k[0, 2], k[1, 2], *sim.DIST]),
                 sim.RESOLUTION)
    ot, op, ou = (_t(x) for x in cams[0])
    return cam, (ot + UNIX, op, ou), (_t(t) + UNIX, _t(g), _t(a))


def _call(cam, obs, imu):
    return calibration.camera_imu([cam], [obs], imu, **KW)


def test_nanosecond_times_are_named(rig):
    cam, (ot, op, ou), (t, g, a) = rig
    ns_imu = (torch.round(t * 1e9), g, a)
    with pytest.raises(ValueError, match=r"camera_imu: .*imu times.* nanoseconds"):
        _call(cam, (torch.round(ot * 1e9), op, ou), ns_imu)
    with pytest.raises(ValueError, match=r"camera_imu: .*imu times.* nanoseconds"):
        _call(cam, (ot, op, ou), ns_imu)
    with pytest.raises(ValueError, match=r"camera_imu: .*observations\[0\] times.* "
                                         r"nanoseconds"):
        _call(cam, (torch.round(ot * 1e9), op, ou), (t, g, a))


def test_float32_times_are_a_type_error(rig):
    cam, (ot, op, ou), (t, g, a) = rig
    with pytest.raises(TypeError, match=r"expected float64 seconds for imu times"):
        _call(cam, (ot, op, ou), (t.float(), g.float(), a.float()))
    with pytest.raises(TypeError, match=r"expected float64 seconds for observations\[0\] times"):
        _call(cam, (ot.float(), op.float(), ou.float()), (t, g, a))


def test_gyroscope_in_degrees_per_second_is_an_error(rig):
    cam, obs, (t, g, a) = rig
    with pytest.raises(ValueError, match=r"camera_imu: camera 0: the gyroscope's angular "
                                         r"speeds are 5\d\.\d times the camera's.*deg/s.*"
                                         r"torch\.deg2rad"):
        _call(cam, obs, (t, torch.rad2deg(g), a))


def test_unsorted_and_non_finite_samples_are_located(rig):
    cam, (ot, op, ou), (t, g, a) = rig
    swapped = t.clone()
    swapped[[40, 41]] = swapped[[41, 40]]
    with pytest.raises(ValueError, match=r"camera_imu: imu times must be strictly increasing: "
                                         r"sample 41 .* sample 40"):
        _call(cam, (ot, op, ou), (swapped, g, a))
    bad = g.clone()
    bad[7, 1] = float("nan")
    with pytest.raises(ValueError, match=r"camera_imu: imu gyro holds a non-finite value "
                                         r"at sample 7"):
        _call(cam, (ot, op, ou), (t, bad, a))
    assert torch.isnan(bad[7, 1]) and torch.equal(swapped[40:42], t[[41, 40]])  # untouched
    pixels = ou.clone()
    pixels[3, 0] = float("inf")
    with pytest.raises(ValueError, match=r"camera_imu: observations\[0\] pixels holds a "
                                         r"non-finite value at sample 3"):
        _call(cam, (ot, op, pixels), (t, g, a))


def test_read_corners_refuses_a_repeated_row(tmp_path):
    """A corner listed twice (a file concatenated with itself, a detector's log written
    twice) was read as two observations: double weight in every estimate, without a word.
    Coinciding points of another tag (tag_spacing 0) stay legitimate."""
    head = "# t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m\n"
    rows = ["1403709385487836928,6,0,274.6642,57.4390,0.0,0.1144,0.0",
            "1403709385487836928,6,1,235.9239,51.5984,0.088,0.1144,0.0",
            "1403709385487836928,7,0,235.9239,51.5984,0.088,0.1144,0.0"]
    path = tmp_path / "c.csv"
    path.write_text(head + "\n".join(rows) + "\n")
    assert calibration.read_corners(path)[0].shape == (3,)
    path.write_text(head + "\n".join(rows + rows[1:2]) + "\n")
    with pytest.raises(calibration.CornersFileError, match=r"c\.csv, line 5: the same row as "
                                                           r"line 3"):
        calibration.read_corners(path)


def test_camera_imu_options_are_checked(rig):
    """``rolling_shutter="yes"``, ``shared_time_offset=1``, ``min_points=0`` and
    ``bias_interval=0`` were accepted without a word."""
    cam, obs, imu = rig
    for name, value, message in (("rolling_shutter", "yes", "rolling_shutter to be a bool"),
                                 ("shared_time_offset", 1, "shared_time_offset to be a bool"),
                                 ("min_points", 0, r"min_points must be an int >= 4"),
                                 ("min_points", 5.5, r"min_points must be an int >= 4"),
                                 ("bias_interval", 0.0, "bias_interval to be a positive"),
                                 ("verbose", None, "verbose to be a bool")):
        with pytest.raises((ValueError, TypeError), match=r"calibration\.camera_imu: .*"
                                                          + message):
            calibration.camera_imu([cam], [obs], imu, **(KW | {name: value}))


def test_cameras_names_a_tuple_given_for_the_list(rig):
    """One camera's ``(times, points, pixels)`` given as ``observations`` (not in a list)
    was read as three cameras: "expected models ... (3, as observations), got 1"."""
    _, obs, _ = rig
    with pytest.raises(ValueError, match=r"calibration\.cameras: expected observations to "
                                         r"be a list of \(times, points, pixels\) tuples, "
                                         r"one per camera: observations\[0\] is a Tensor"):
        calibration.cameras(obs, ["pinhole-radtan"], [sim.RESOLUTION])


def test_read_target_takes_numbers_without_a_dot(tmp_path):
    """``tagSize: 88e-3`` (YAML 1.1 reads it as the string '88e-3') was refused as "tagSize
    must be a finite real number > 0, got '88e-3'"."""
    path = tmp_path / "april.yaml"
    path.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 88e-3\n"
                    "tagSpacing: 3e-1\n")
    assert calibration.read_target(path) == calibration.Target("aprilgrid", 6, 6, 0.088, 0.3)
    path.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: abc\n"
                    "tagSpacing: 0.3\n")
    with pytest.raises(ValueError, match=r"april\.yaml: tagSize must be a finite real number "
                                         r"> 0, got 'abc'"):
        calibration.read_target(path)


def test_clock_offset_beyond_the_bound_is_named(rig):
    """A clock 0.15 s off with the default max_time_offset 0.1 ended in fitting.estimate's
    "Reprojections's time_offset starts at 0.1 s, outside its max_time_offset=0.1" (a start
    the user never gave): camera_imu names the bound and the way out."""
    cam = rig[0]
    (ti, gi, ai), cams = sim.rig(duration=3.0, offset=0.15, seed=1)
    obs = tuple(_t(x) for x in cams[0])
    with pytest.raises(ValueError, match=r"calibration\.camera_imu: camera 0: the angular "
                                         r"speeds correlate best at the bound of the "
                                         r"offsets searched \(\+0\.1 s;.*raise "
                                         r"max_time_offset"):
        calibration.camera_imu([cam], [obs], (_t(ti), _t(gi), _t(ai)), **KW)
    res = calibration.camera_imu([cam], [obs], (_t(ti), _t(gi), _t(ai)),
                                 **(KW | {"max_time_offset": 0.2, "steps": 10}))
    assert abs(float(res.time_offsets[0]) - 0.15) < 1e-3

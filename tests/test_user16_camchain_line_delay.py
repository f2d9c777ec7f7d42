"""``calibration.read_camchain`` reads the line delays back (user16).

``python -m torch_dq calibrate --rolling-shutter`` (``CameraImuCalibration.to_kalibr``)
writes each camera's line delay as ``line_delay`` (seconds per row) into
``camchain-imucam.yaml``, but ``read_camchain`` dropped it: a rolling-shutter calibration
read back looked like a global-shutter one. The rolling-shutter Kalibr fork and the readers
built on it (okvis, kalibr's ``kalibr_calibrate_rs_imu_camera`` branch) write
``line_delay_nanoseconds`` (nanoseconds per row) instead. Reference: the numbers written in
the file, converted by hand.
"""

import pytest
import torch

from torch_dq import calibration, dualquat
from torch_dq.camera import Camera

yaml = pytest.importorskip("yaml")


def _entry(**extra):
    return {"camera_model": "pinhole", "distortion_model": "none",
            "intrinsics": [458.0, 457.0, 367.0, 248.0], "resolution": [752, 480],
            "T_cam_imu": [[1, 0, 0, 0.1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
            "timeshift_cam_imu": 0.002, **extra}


def _read(tmp_path, doc):
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(yaml.safe_dump(doc))
    return calibration.read_camchain(path)


def test_written_line_delays_read_back(tmp_path):
    cam = Camera("pinhole", torch.tensor([458.0, 457.0, 367.0, 248.0], dtype=torch.float64),
                 (752, 480))
    e = dualquat.from_rt(torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64),
                         torch.tensor([0.0, 0.05, 0.0], dtype=torch.float64))
    zero = torch.zeros(3, dtype=torch.float64)
    res = calibration.CameraImuCalibration(
        [cam, cam], torch.stack([e, e]), torch.tensor([0.001, 0.002], dtype=torch.float64),
        torch.tensor([3e-5, 2.5e-5], dtype=torch.float64), zero, zero, zero, {},
        zero[:2], None, None, [])
    chain = _read(tmp_path, res.to_kalibr())
    assert chain.line_delays is not None
    assert chain.line_delays.tolist() == pytest.approx([3e-5, 2.5e-5], rel=1e-12)


def test_kalibr_fork_nanoseconds(tmp_path):
    chain = _read(tmp_path, {"cam0": _entry(line_delay_nanoseconds=30000),
                             "cam1": _entry(line_delay_nanoseconds=12500.5)})
    assert chain.line_delays.dtype == torch.float64
    assert chain.line_delays.tolist() == pytest.approx([3.0e-5, 1.25005e-5], rel=1e-12)


def test_global_shutter_and_partial(tmp_path):
    assert _read(tmp_path, {"cam0": _entry()}).line_delays is None
    # one camera stating none: read as a global shutter (0), as to_kalibr omits a zero delay
    chain = _read(tmp_path, {"cam0": _entry(line_delay=2e-5), "cam1": _entry()})
    assert chain.line_delays.tolist() == pytest.approx([2e-5, 0.0])
    # hand-written 3e-05 (no dot) is a string to PyYAML: read as the number it is
    path = tmp_path / "hand.yaml"
    text = yaml.safe_dump({"cam0": _entry()})
    path.write_text(text.replace("cam0:\n", "cam0:\n  line_delay: 3e-05\n"))
    assert calibration.read_camchain(path).line_delays.tolist() == pytest.approx([3e-5])


@pytest.mark.parametrize("extra, key", [({"line_delay": -1e-5}, "line_delay"),
                                        ({"line_delay": "fast"}, "line_delay"),
                                        ({"line_delay_nanoseconds": True},
                                         "line_delay_nanoseconds"),
                                        ({"line_delay": 1e-5, "line_delay_nanoseconds": 1e4},
                                         "line_delay_nanoseconds")])
def test_bad_line_delay_named(tmp_path, extra, key):
    with pytest.raises(ValueError, match=f"cam0.*{key}"):
        _read(tmp_path, {"cam0": _entry(**extra)})


def test_timeshift_written_without_a_dot(tmp_path):
    """``timeshift_cam_imu: 2e-3`` (hand-written; PyYAML reads it as a string) was refused as
    "not a number"; it is read as 0.002 s. A non-finite one stays an error."""
    path = tmp_path / "hand.yaml"
    text = yaml.safe_dump({"cam0": _entry()})
    path.write_text(text.replace("timeshift_cam_imu: 0.002", "timeshift_cam_imu: 2e-3"))
    assert "2e-3" in path.read_text()
    assert calibration.read_camchain(path).time_offsets.tolist() == [0.002]
    path.write_text(text.replace("timeshift_cam_imu: 0.002", "timeshift_cam_imu: .nan"))
    with pytest.raises(ValueError, match="timeshift_cam_imu"):
        calibration.read_camchain(path)

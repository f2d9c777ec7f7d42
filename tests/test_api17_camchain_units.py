"""``calibration.read_camchain`` with values that are not in Kalibr's units (session 17): a
``timeshift_cam_imu`` of 5 (milliseconds) or 4e6 (nanoseconds), a ``line_delay`` of 30
(microseconds per row), a ``T_cam_imu`` written in millimetres were read as seconds and
metres without a word. Each now warns, naming the file, the camera, the key and the likely
unit; a camchain in Kalibr's units (EuRoC's published ``T_cam_imu``, a 4 ms offset, 30 us
per row, an 11 cm stereo baseline) reads silently, its numbers as written."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from torch_dq import calibration, dualquat

yaml = pytest.importorskip("yaml")

# EuRoC cam0's T_cam_imu (sensor.yaml's T_BS inverted), metres
T_CAM_IMU = [[0.0148655429818, 0.999557249008, -0.0257744366974, 0.0652229020056],
             [-0.999880929698, 0.0149672133247, 0.00375618835797, -0.0207063470643],
             [0.00414029679422, 0.025715529948, 0.999660727178, -0.0080546304689],
             [0.0, 0.0, 0.0, 1.0]]
STEREO = [[1.0, 0.0, 0.0, -0.110074], [0.0, 1.0, 0.0, 0.000157], [0.0, 0.0, 1.0, -0.000889],
          [0.0, 0.0, 0.0, 1.0]]


def _entry(**extra):
    return {"camera_model": "pinhole", "distortion_model": "none",
            "intrinsics": [458.654, 457.296, 367.215, 248.375], "resolution": [752, 480],
            **extra}


def _read(tmp_path, doc):
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path, calibration.read_camchain(path)


def _mm(T):
    return [[*row[:3], row[3] * 1000.0] for row in T[:3]] + [T[3]]


def test_kalibr_units_read_silently(tmp_path):
    doc = {"cam0": _entry(T_cam_imu=T_CAM_IMU, timeshift_cam_imu=0.004, line_delay=3e-5),
           "cam1": _entry(T_cam_imu=T_CAM_IMU, timeshift_cam_imu=-0.004, line_delay=3e-5,
                          T_cn_cnm1=STEREO)}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, chain = _read(tmp_path, doc)
    assert chain.time_offsets.tolist() == [0.004, -0.004]
    assert chain.line_delays.tolist() == [3e-5, 3e-5]
    T = np.linalg.inv(np.array(T_CAM_IMU))  # p_imu = e p_cam
    t = dualquat.to_rt(chain.extrinsics[0])[1].numpy()
    np.testing.assert_allclose(t, T[:3, 3], atol=1e-9)


@pytest.mark.parametrize("shift, unit, seconds", [(5.0, "milliseconds", "0.005 s"),
                                                  (4e6, "nanoseconds", "0.004 s"),
                                                  (-2500.0, "microseconds", "-0.0025 s")])
def test_timeshift_in_another_unit_warns(tmp_path, shift, unit, seconds):
    with pytest.warns(UserWarning, match=rf"camchain-imucam.yaml: cam0: timeshift_cam_imu = "
                                         rf".* s is over 1 s .*{unit}\? .*{seconds}") as rec:
        _, chain = _read(tmp_path, {"cam0": _entry(T_cam_imu=T_CAM_IMU,
                                                   timeshift_cam_imu=shift)})
    assert rec[0].filename == __file__  # the user's line
    assert chain.time_offsets.tolist() == [shift]  # read as written


def test_line_delay_in_microseconds_warns(tmp_path):
    with pytest.warns(UserWarning, match=r"cam1: line_delay = 30 s is over 0.001 s \(per row, "
                                         r".*microseconds\? .*3e-05 s"):
        _read(tmp_path, {"cam0": _entry(), "cam1": _entry(line_delay=30)})


@pytest.mark.parametrize("key", ["T_cam_imu", "T_cn_cnm1"])
def test_transform_in_millimetres_warns(tmp_path, key):
    cam1 = _entry(**{key: _mm(T_CAM_IMU if key == "T_cam_imu" else STEREO)})
    cam0 = _entry(T_cam_imu=T_CAM_IMU) if key == "T_cam_imu" else _entry()
    norm = np.linalg.norm(np.array(_mm(T_CAM_IMU if key == "T_cam_imu" else STEREO))[:3, 3])
    with pytest.warns(UserWarning, match=rf"cam1: {key}'s translation is {norm:.4g} m.*"
                                         rf"millimetres\?") as rec:
        _read(tmp_path, {"cam0": cam0, "cam1": cam1})
    assert len(rec) == 1 and rec[0].filename == __file__

"""An outside tester's ``python -m torch_dq calibrate`` runs (0.5.0 trial): an IMU file in
deg/s ends in one error line naming the unit, after one ``warning:`` line from the reader,
with no Python warning format (file, line, source) on stderr. Failed before its fix (the
reader's warning came as a Python warning with its source line, the calibration finished
on readings 57 times too large)."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from torch_dq.__main__ import main

pytest.importorskip("cv2")
pytest.importorskip("yaml")
sys.path.insert(0, os.path.dirname(__file__))
from test_camera_imu import _argv, _inputs, _write_inputs


def test_calibrate_names_a_gyroscope_in_degrees_per_second(tmp_path, capsys):
    obs, imu = _inputs(0.0)
    _write_inputs(tmp_path, obs, imu)
    rows = np.loadtxt(tmp_path / "imu.txt")
    rows[:, 1:4] = np.rad2deg(rows[:, 1:4])
    np.savetxt(tmp_path / "imu.txt", rows, fmt="%.9f", header="t gx gy gz ax ay az")
    out = tmp_path / "out"
    assert main(_argv(tmp_path, out)) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2, err
    assert err[0].startswith("torch-dq calibrate: warning: io.read_imu: ") and "deg/s" in err[0]
    assert err[1].startswith("torch-dq calibrate: error: calibration.camera_imu: camera 0: "
                             "the gyroscope's angular speeds are 57.3 times the camera's")
    assert not out.exists()

"""An outside tester's ``python -m torch_dq calibrate`` and ``fit --imu`` runs (0.5.0
trial): an IMU file in deg/s ends in one error line naming the unit (``calibrate``: after one
``warning:`` line from the reader, with no Python warning format on stderr). Failed before
the fixes (``calibrate``: the reader's warning came as a Python warning with its source
line and the calibration finished on readings 57 times too large; ``fit --imu``: exit 0 with
held-out rotation errors of 110 degrees)."""

from __future__ import annotations

import os
import re
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

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


def test_fit_imu_names_a_gyroscope_in_degrees_per_second(tmp_path, capsys):
    import _camera_imu_sim as sim

    rng = np.random.default_rng(0)
    t = np.arange(0.0, 6.0, 0.05)
    R, p, _, _ = sim.motion(t)
    np.savetxt(tmp_path / "poses.txt", np.column_stack(
        [1.7e9 + t, p + 1e-3 * rng.standard_normal(p.shape), Rotation.from_matrix(R).as_quat()]),
        fmt="%.9f", header="timestamp tx ty tz qx qy qz qw")
    ti = np.arange(0.0, 6.0, 0.005)
    _, _, gyro, accel = sim.motion(ti)
    np.savetxt(tmp_path / "imu.txt", np.column_stack([1.7e9 + ti, np.rad2deg(gyro), accel]),
               fmt="%.9f", header="t gx gy gz ax ay az")
    out = tmp_path / "out"
    argv = ["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu.txt"), "--out",
            str(out), "--no-plots", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    assert re.match(r"torch-dq fit: error: .*imu\.txt: fitting\.Gyro: the readings look like "
                    r"deg/s, not rad/s: .* is 5\d\.\d times the trajectory's", err[-1]), err
    assert not (out / "summary.json").exists()


def test_imu_yaml_numbers_without_a_dot(tmp_path):
    """``gyroscope_noise_density: 1e-4`` (no dot: YAML 1.1 and PyYAML read it as the string
    '1e-4') was refused as "expected a positive number ..., got '1e-4'"."""
    from torch_dq.cli._calibrate import UserError, _noise

    path = tmp_path / "imu.yaml"
    path.write_text("gyroscope_noise_density: 1e-4\naccelerometer_noise_density: 2E-3\n"
                    "gyroscope_random_walk: 2.0e-5\naccelerometer_random_walk: 3e-3\n")
    assert _noise(str(path), walk=True) == {
        "gyroscope_noise_density": 1e-4, "accelerometer_noise_density": 2e-3,
        "gyroscope_random_walk": 2e-5, "accelerometer_random_walk": 3e-3}
    for bad in ("abc", "-1e-4", "nan", "inf", "true"):
        path.write_text(f"gyroscope_noise_density: {bad}\naccelerometer_noise_density: 1e-3\n")
        with pytest.raises(UserError, match="expected a positive number under "
                                            "gyroscope_noise_density"):
            _noise(str(path), walk=False)

"""Audit 10: Kalibr yaml inputs a user can get wrong, read through the library
(``calibration.read_target``) and the ``calibrate`` command: a file that is not UTF-8 (a
comment typed in Latin-1), a camchain whose cameras are not mappings or whose keys are not
strings. Each is one error line naming the file (exit status 2), never a traceback or a
message without the file."""

import re
import warnings

import pytest

from torch_dq import calibration
from torch_dq.cli import main

TARGET = "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n"
IMU = ("gyroscope_noise_density: 1.6968e-04\naccelerometer_noise_density: 2.0e-3\n"
       "gyroscope_random_walk: 1.9393e-05\naccelerometer_random_walk: 3.0e-3\n"
       "update_rate: 200.0\n")
CAMCHAIN = ("cam0:\n  camera_model: pinhole\n  distortion_model: radtan\n"
            "  intrinsics: [458.654, 457.296, 367.215, 248.375]\n"
            "  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]\n"
            "  resolution: [752, 480]\n")
LATIN1 = "# calibr\xe9 au labo\n"  # a comment typed in Latin-1


def test_read_target_not_utf8_names_the_file(tmp_path):
    path = tmp_path / "april_6x6.yaml"
    path.write_bytes((LATIN1 + TARGET).encode("latin-1"))
    with pytest.raises(ValueError, match=r"april_6x6\.yaml: not a UTF-8 text file"):
        calibration.read_target(path)
    path.write_bytes((LATIN1 + TARGET).encode("utf-8"))  # the same text in UTF-8 reads
    assert calibration.read_target(path) == calibration.Target.aprilgrid(6, 6, 0.088, 0.3)


def _files(tmp_path, target=TARGET, imu=IMU, camchain=CAMCHAIN, latin=()):
    paths = {}
    for name, text in (("target.yaml", target), ("imu.yaml", imu),
                       ("camchain.yaml", camchain)):
        paths[name] = tmp_path / name
        data = (LATIN1 + text).encode("latin-1") if name in latin else text.encode()
        paths[name].write_bytes(data)
    return ["calibrate", "--target", str(paths["target.yaml"]), "--imu",
            str(tmp_path / "imu.csv"), "--imu-noise", str(paths["imu.yaml"]), "--cameras",
            str(paths["camchain.yaml"]), "--corners", str(tmp_path / "cam0.csv"), "--out",
            str(tmp_path / "out"), "--quiet"]


@pytest.mark.parametrize("kwargs,match", [
    ({"latin": ("target.yaml",)}, r"target\.yaml: not a UTF-8 text file"),
    ({"latin": ("imu.yaml",)}, r"imu\.yaml: not a UTF-8 text file"),
    ({"latin": ("camchain.yaml",)}, r"camchain\.yaml: not a UTF-8 text file"),
    ({"camchain": "cam0: 5\n"}, r"camchain\.yaml: cam0 must be a mapping"),
    ({"camchain": "cam0: [1, 2]\n"}, r"camchain\.yaml: cam0 must be a mapping"),
    ({"camchain": "0:\n  camera_model: pinhole\n"},
     r"camchain\.yaml: expected cameras cam0, cam1, \.\.\. got \['0'\]"),
])
def test_calibrate_bad_yaml_is_one_line_naming_the_file(tmp_path, capsys, kwargs, match):
    assert main(_files(tmp_path, **kwargs)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torch-dq calibrate: error: ")
    assert re.search(match, err[0]), err[0]
    assert not (tmp_path / "out").exists()


def test_camera_imu_takes_numpy_scalars_for_noises_and_sigmas():
    """np.float32 densities (a numpy config, ``np.float32(cfg["gyro"])``) are numbers: the
    call goes past them exactly as with Python floats (to the static IMU's error here)."""
    import numpy as np
    import torch

    from torch_dq import camera

    t = torch.arange(0.0, 3.0, 0.05, dtype=torch.float64) + 100.0
    grid = calibration.aprilgrid(2, 2, 0.1, 0.3)
    obs = (t.repeat_interleave(len(grid)), grid.repeat(len(t), 1),
           torch.tensor([300.0, 200.0], dtype=torch.float64) + 100 * grid[:, :2].repeat(len(t), 1))
    ti = torch.arange(99.0, 104.0, 0.005, dtype=torch.float64)
    imu = (ti, torch.zeros(len(ti), 3, dtype=torch.float64),
           torch.tensor([0.0, 0.0, 9.81], dtype=torch.float64).expand(len(ti), 3).clone())
    cam = camera.Camera("pinhole", [400.0, 400.0, 320.0, 240.0], (640, 480))
    messages = []
    for cast in (float, np.float32, np.float64):
        with pytest.raises(ValueError) as info, warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # no rotation: said, then the error
            calibration.camera_imu([cam], [obs], imu, gyro_noise=cast(1.7e-4),
                                   accel_noise=cast(2e-3), pixel_sigma=cast(0.5),
                                   verbose=False)
        messages.append(str(info.value))
    assert "noise" not in messages[0] and "pixel_sigma" not in messages[0]
    assert messages[1] == messages[0] == messages[2]

"""``python -m torch_dq calibrate``: an ``imu.yaml`` whose ``update_rate`` is not the IMU
file's rate is warned of (user16).

Kalibr turns the noise densities into per-sample sigmas with ``update_rate``
(``density * sqrt(update_rate)``); torch_dq with the file's median sample spacing. An
``imu.yaml`` copied from another setup (the same IMU logged at 100 Hz instead of 200 Hz)
silently gave sigmas ``sqrt(2)`` apart from Kalibr's, on the same files. The warning names
both rates and the factor. Reference: the rates written into the files by the test.
"""

import pytest

from torch_dq.cli import main

pytest.importorskip("yaml")


def _files(tmp_path, rate_yaml, rate_file=200.0):
    (tmp_path / "target.yaml").write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\n"
                                          "tagSize: 0.088\ntagSpacing: 0.3\n")
    (tmp_path / "imu.yaml").write_text(
        f"update_rate: {rate_yaml}\ngyroscope_noise_density: 1.0e-3\n"
        "accelerometer_noise_density: 1.0e-2\ngyroscope_random_walk: 1.0e-5\n"
        "accelerometer_random_walk: 1.0e-3\n")
    lines = [f"{k / rate_file:.6f} 0.1 0.2 0.3 0.0 0.0 9.81" for k in range(400)]
    (tmp_path / "imu.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "camchain.yaml").write_text(
        "cam0:\n  camera_model: pinhole\n  distortion_model: none\n"
        "  intrinsics: [458.0, 457.0, 367.0, 248.0]\n  resolution: [752, 480]\n")
    # two --corners for one camera: the run stops right after reading the IMU (exit 2)
    return ["calibrate", "--target", str(tmp_path / "target.yaml"), "--imu",
            str(tmp_path / "imu.txt"), "--imu-noise", str(tmp_path / "imu.yaml"), "--cameras",
            str(tmp_path / "camchain.yaml"), "--corners", "a.csv", "--corners", "b.csv",
            "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]


def test_update_rate_off_the_file_rate_warned(tmp_path, capsys):
    assert main(_files(tmp_path, 100.0)) == 2
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "update_rate" in x)
    assert "warning" in line and "100" in line and "200" in line
    assert "0.707" in line  # Kalibr's sigmas: sqrt(100 / 200) times these


@pytest.mark.parametrize("rate", [200.0, 201.0])
def test_matching_update_rate_quiet(tmp_path, capsys, rate):
    assert main(_files(tmp_path, rate)) == 2
    assert "update_rate" not in capsys.readouterr().err


def test_bad_update_rate_named(tmp_path, capsys):
    assert main(_files(tmp_path, "fast")) == 2
    err = capsys.readouterr().err
    assert "update_rate" in err and "'fast'" in err


def _with_line_delay(tmp_path, key, value):
    argv = _files(tmp_path, 200.0)
    chain = tmp_path / "camchain.yaml"
    chain.write_text(chain.read_text() + f"  {key}: {value}\n")
    return argv


@pytest.mark.parametrize("key, value", [("line_delay_nanoseconds", 30000),
                                        ("line_delay", 3.0e-5)])
def test_stated_line_delay_without_rolling_shutter_warned(tmp_path, capsys, key, value):
    """A camchain stating a rolling shutter (the Kalibr RS fork's ``line_delay_nanoseconds``
    or torch_dq's ``line_delay``) was calibrated as a global shutter without a word unless
    ``--rolling-shutter`` was given (user16)."""
    argv = _with_line_delay(tmp_path, key, value)
    assert main(argv) == 2
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "line delay" in x)
    assert "warning" in line and "cam0" in line and "--rolling-shutter" in line
    assert main([*argv, "--rolling-shutter"]) == 2
    assert "line delay" not in capsys.readouterr().err

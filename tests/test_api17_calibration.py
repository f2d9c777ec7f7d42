"""``python -m torch_dq calibrate`` and ``torch_dq.calibration`` with inputs a user gets
wrong (session 17), on EuRoC's corners in ``tests/data/calibration``:

- a Kalibr target yaml written in millimetres (``tagSize: 88``) beside corners in metres
  was diagnosed as "the points are in millimetres, not metres: divide X_m, Y_m, Z_m by
  1000": the corners divided by 1000 all lie within the tolerance of a 0.9 km target's
  corner 0. The yaml is now named as the one in millimetres;
- one camera's corners given for both cameras of the stereo camchain calibrated without a
  word, cam1 at the identity in cam0's frame; ``calibration.cameras`` and
  ``calibration.camera_imu`` now refuse observations that repeat another camera's.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch

from torch_dq import calibration
from torch_dq.__main__ import main
from torch_dq.camera import Camera

pytest.importorskip("yaml")
DATA = Path(__file__).parent / "data" / "calibration"
CAM0 = DATA / "euroc_cam_april_cam0_corners.csv"
CAM1 = DATA / "euroc_cam_april_cam1_corners.csv"


def _argv(tmp_path, target, corners):
    return ["calibrate", "--target", str(target), "--cameras", str(DATA / "camchain.yaml"),
            *[a for c in corners for a in ("--corners", str(c))], "--out",
            str(tmp_path / "out")]


def _error(capsys) -> str:
    lines = [x for x in capsys.readouterr().err.splitlines() if "error:" in x]
    assert len(lines) == 1, lines
    return lines[0]


def test_target_yaml_in_millimetres_is_named(tmp_path, capsys):
    target = tmp_path / "april_mm.yaml"
    target.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 88\n"
                      "tagSpacing: 0.3\n")
    assert main(_argv(tmp_path, target, [CAM0, CAM1])) == 2
    line = _error(capsys)
    assert "the target's sizes are in millimetres, not metres" in line
    assert f"divide them by 1000 in {target}" in line
    assert "divide X_m" not in line
    assert not (tmp_path / "out").exists()


def test_corners_in_millimetres_are_named(tmp_path, capsys):
    """The other way round, as before: a metre target, corners in millimetres."""
    lines = CAM0.read_text().splitlines()
    rows = [r.split(",") for r in lines[1:]]
    mm = tmp_path / "cam0_mm.csv"
    mm.write_text("\n".join([lines[0]] + [",".join(r[:5] + [f"{1000 * float(v):.4f}"
                                                             for v in r[5:]]) for r in rows]))
    assert main(_argv(tmp_path, DATA / "april_6x6.yaml", [mm, CAM1])) == 2
    line = _error(capsys)
    assert "the points are in millimetres, not metres: divide X_m, Y_m, Z_m by 1000" in line


def test_one_corners_file_for_two_cameras_is_refused(tmp_path, capsys):
    assert main(_argv(tmp_path, DATA / "april_6x6.yaml", [CAM0, CAM0])) == 2
    assert "observations[1] repeat observations[0]" in _error(capsys)
    assert not (tmp_path / "out").exists()


def test_repeated_observations_are_refused_by_the_functions():
    obs = calibration.read_corners(CAM0)
    with pytest.raises(ValueError, match=r"calibration.cameras: observations\[1\] repeat "
                                         r"observations\[0\] \(the same times and pixels\)"):
        calibration.cameras([obs, obs], ["pinhole-radtan"] * 2, [(752, 480)] * 2)
    cam = Camera("pinhole-radtan", torch.tensor([458.654, 457.296, 367.215, 248.375,
                                                 -0.2834, 0.0740, 0.0002, 0.0],
                                                dtype=torch.float64), (752, 480))
    t = torch.arange(float(obs[0].min()) - 1.0, float(obs[0].max()) + 1.0, 0.005,
                     dtype=torch.float64)
    imu = (t, torch.zeros(len(t), 3, dtype=torch.float64),
           torch.tensor([0.0, 0.0, 9.81], dtype=torch.float64).expand(len(t), 3))
    with pytest.raises(ValueError, match=r"camera_imu: observations\[1\] repeat "
                                         r"observations\[0\]"):
        calibration.camera_imu([cam, cam], [obs, obs], imu, gyro_noise=1e-4,
                               accel_noise=1e-3)


def test_two_cameras_own_corners_still_calibrate():
    """EuRoC's two cameras (their own corners, some frames shared): no refusal."""
    obs = [calibration.read_corners(CAM0), calibration.read_corners(CAM1)]
    with warnings.catch_warnings(record=True) as caught:  # 2 steps: cut short
        warnings.simplefilter("always")
        res = calibration.cameras(obs, ["pinhole"] * 2, [(752, 480)] * 2, max_iterations=2)
    said = " ".join(str(w.message) for w in caught)
    assert "did not converge" in said
    assert "radial distortion" in said  # EuRoC's lenses distort: the pinhole's k1 test fires
    assert res.relative_poses.shape == (1, 8)

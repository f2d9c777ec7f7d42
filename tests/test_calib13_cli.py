"""``python -m torch_dq calibrate`` on what a real recording brings (calib13): a clock offset
beyond the default search (``--max-time-offset``), a repeated IMU timestamp
(``--duplicates``), EuRoC's ``imu0`` folder as ``--imu``, an ``--out`` inside an images
folder, the detection's summary on ``--images``; Kalibr's files written as Kalibr and EuRoC
write them (comments, CRLF line ends), the result against the simulated truth in numpy."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from _calib12_rig import RADTAN, Cam, make_rig, rot
from scipy.spatial.transform import Rotation
from test_calib12_cli import write_rig

from torch_dq.__main__ import main

yaml = pytest.importorskip("yaml")
pytest.importorskip("cv2")

DATA = Path(__file__).resolve().parent / "data" / "calibration"
# EuRoC's cam0 (T_BS): about 90 degrees about the IMU's z; a clock 0.2 s off the IMU's
CAM = Cam("pinhole-radtan", RADTAN, rot("z", 90) @ rot("x", 2), np.array([-0.02, -0.065, 0.01]),
          0.2)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Kalibr's files of a 6 s one-camera rig, the IMU's line 100 repeated (same stamp)."""
    root = tmp_path_factory.mktemp("rec")
    paths = write_rig(root, make_rig([CAM], seed=5, duration=6.0, t0=0.0))
    imu = Path(paths["--imu"])
    lines = imu.read_text().splitlines(keepends=True)
    imu.write_text("".join([*lines[:100], lines[99], *lines[100:]]))
    for key in ("--target", "--imu-noise"):  # Kalibr's comments, Windows line ends
        path = Path(paths[key])
        text = "".join(f"{x}   # a comment\r\n" for x in path.read_text().splitlines())
        path.write_bytes(("# Kalibr\r\n" + text).encode())
    return paths


def _argv(files: dict, out, *extra) -> list[str]:
    argv = ["calibrate", "--quiet", "--no-plots", "--out", str(out), *extra]
    for key, value in files.items():
        argv += [x for c in value for x in ("--corners", c)] if key == "corners" else [key,
                                                                                    value]
    return argv


def _error(capsys) -> str:
    lines = [x for x in capsys.readouterr().err.splitlines()
             if x.strip() and "warning" not in x]
    assert len(lines) == 1, lines
    return lines[0]


def test_repeated_imu_stamp_names_the_calibrate_option(files, tmp_path, capsys):
    assert main(_argv(files, tmp_path / "out")) == 2
    line = _error(capsys)
    assert "line 101" in line and "--duplicates first" in line and "calibrate" in line, line
    assert not (tmp_path / "out").exists()


def test_offset_beyond_the_search_names_the_option(files, tmp_path, capsys):
    assert main(_argv(files, tmp_path / "out", "--duplicates", "first")) == 2
    line = _error(capsys)
    assert "--max-time-offset" in line and "0.1 s" in line, line


def test_offset_of_0_2_s_found_with_max_time_offset(files, tmp_path):
    """--max-time-offset 0.3 and EuRoC's imu0 folder as --imu: the offset and the ~90 deg
    extrinsic against the truth, in Kalibr's conventions (T_cam_imu: p_cam = T p_imu;
    t_imu = t_cam + timeshift_cam_imu)."""
    files = {**files, "--imu": str(Path(files["--imu"]).parent)}
    argv = _argv(files, tmp_path / "out", "--duplicates", "first", "--max-time-offset", "0.3",
                 "--bias", "constant", "--pixel-sigma", "0.3", "--knot-spacing", "0.04")
    assert main(argv) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert abs(summary["knot_spacing_s"] - 0.04) < 1e-3
    assert not [w for w in summary["warnings"] if "--knot-spacing" in w]  # IMU chi2/dof ~1
    entry = yaml.safe_load((tmp_path / "out" / "camchain-imucam.yaml").read_text())["cam0"]
    assert abs(entry["timeshift_cam_imu"] - CAM.dt) < 5e-4
    T = np.array(entry["T_cam_imu"])
    assert np.degrees(Rotation.from_matrix(T[:3, :3] @ CAM.R_bc).magnitude()) < 0.1
    np.testing.assert_allclose(T[:3, 3], -CAM.R_bc.T @ CAM.t_bc, atol=3e-3)


def test_imu_chi2_far_above_1_names_the_knot_spacing(files, tmp_path):
    """imu.yaml's densities 10 times too small (the IMU's chi2/dof about 100): a warning
    naming the densities, in summary.json; the knots chosen from the readings stay as coarse
    as for the right densities (the spectrum's own noise floor), and the warning names
    --knot-spacing only where it was given."""
    noise = tmp_path / "imu.yaml"
    noise.write_text("".join(
        f"{k}: {float(v) / 10 if 'noise_density' in k else v}\n" for k, v in
        yaml.safe_load(Path(files["--imu-noise"]).read_text()).items()))
    argv = _argv({**files, "--imu-noise": str(noise)}, tmp_path / "out", "--duplicates",
                 "first", "--max-time-offset", "0.3", "--bias", "constant", "--pixel-sigma",
                 "0.3")
    assert main(argv) == 0
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    # chi15: 0.029 s, the right densities' spacing (their floor would give the finest, 0.01)
    assert summary["knot_spacing_s"] >= 0.025
    hints = [w for w in summary["warnings"] if "chi2/dof is" in w]
    assert len(hints) == 1 and "noise densities" in hints[0] and "accel" in hints[0], hints
    assert "--bias random-walk" in hints[0]  # --bias constant: drifting biases, a cause too
    assert "--knot-spacing auto" in hints[0] and "too coarse" not in hints[0]
    assert main([*argv, "--knot-spacing", "0.05", "--out", str(tmp_path / "given")]) == 0
    summary = json.loads((tmp_path / "given" / "summary.json").read_text())
    assert summary["knot_spacing_s"] == 0.05
    hints = [w for w in summary["warnings"] if "--knot-spacing 0.025" in w]
    assert len(hints) == 1 and "noise densities" in hints[0], hints


def test_kalibr_output_imu_yaml_nested_under_imu0(files, tmp_path, capsys):
    """Kalibr's imu-*.yaml output (the noises under imu0, with T_i_b, time_offset) read as
    its imu.yaml: the run gets past it (to the clock offset's bound, here)."""
    flat = yaml.safe_load(Path(files["--imu-noise"]).read_text())
    noise = tmp_path / "imu-camchain-imucam.yaml"
    noise.write_text(yaml.safe_dump({"imu0": {**flat, "T_i_b": np.eye(4).tolist(),
                                              "model": "calibrated", "time_offset": 0.0}}))
    argv = _argv({**files, "--imu-noise": str(noise)}, tmp_path / "out", "--duplicates",
                 "first")
    assert main(argv) == 2
    assert "--max-time-offset" in _error(capsys)


def test_imu_folder_without_data_csv(files, tmp_path, capsys):
    (tmp_path / "imu0").mkdir()
    assert main(_argv({**files, "--imu": str(tmp_path / "imu0")}, tmp_path / "out")) == 2
    assert "imu0 is a folder without data.csv" in _error(capsys)


def test_camera_imu_options_need_the_imu(files, tmp_path, capsys):
    cams = {k: v for k, v in files.items() if k not in ("--imu", "--imu-noise")}
    argv = _argv(cams, tmp_path / "out", "--max-time-offset", "0.3", "--knot-spacing", "0.02")
    assert main(argv) == 2
    assert "--max-time-offset, --knot-spacing need --imu" in _error(capsys)


def _euroc_images(root: Path) -> list[Path]:
    """EuRoC's layout (cam<i>/data/<t_ns>.png, data.csv, sensor.yaml) with the real frame
    of each camera at two stamps."""
    folders = []
    for i in range(2):
        cam = root / "mav0" / f"cam{i}"
        (cam / "data").mkdir(parents=True)
        (cam / "sensor.yaml").write_text("sensor_type: camera\nrate_hz: 20\n")
        (cam / "data.csv").write_text("#timestamp [ns],filename\n")
        for ns in (1403709395937837056, 1403709395987837056):
            shutil.copy(DATA / f"cam{i}_1403709395937837056.png", cam / "data" / f"{ns}.png")
        folders.append(cam)
    return folders


def test_out_inside_an_images_data_folder_is_refused(files, tmp_path, capsys):
    folders = _euroc_images(tmp_path)
    args = {k: v for k, v in files.items() if k != "corners"}
    argv = _argv(args, folders[0] / "data", "--images", str(folders[0]), "--images",
                 str(folders[1]))
    assert main(argv) == 2
    assert "is an --images folder" in _error(capsys)
    assert sorted(p.suffix for p in (folders[0] / "data").iterdir()) == [".png", ".png"]


def test_images_report_what_was_detected(files, tmp_path, capsys):
    """Detection takes about 0.1 s a frame (minutes on a EuRoC recording): without --quiet
    each camera's frames and corners are reported (here two frames, too few to go on)."""
    folders = _euroc_images(tmp_path)
    args = {k: v for k, v in files.items() if k != "corners"}
    chain = {f"cam{i}": {**CAM.kalibr(), "rostopic": f"/cam{i}/image_raw"} for i in range(2)}
    args["--cameras"] = str(tmp_path / "camchain.yaml")
    Path(args["--cameras"]).write_text(yaml.safe_dump(chain))
    argv = [x for x in _argv(args, tmp_path / "out", "--images", str(folders[0]), "--images",
                             str(folders[1]), "--duplicates", "first") if x != "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("2 frames, 2 with 16 corners or more (288 corners)") == 2, err

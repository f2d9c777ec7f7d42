"""``python -m torch_dq calibrate`` end to end on a synthetic rig written as Kalibr's files
(target, imu, camchain yamls, EuRoC imu0/data.csv, corner CSVs), its camchain-imucam.yaml
parsed with PyYAML and compared with the truth; bad inputs end in one line and exit 2."""

import contextlib
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _calib12_rig import DS, RADTAN, Cam, grid, make_rig, rot
from scipy.spatial.transform import Rotation

from torch_dq import dualquat
from torch_dq.calibration import read_camchain
from torch_dq.cli import main

yaml = pytest.importorskip("yaml")
pytest.importorskip("cv2")

ROOT = Path(__file__).resolve().parents[1]
T0_NS = 1403709395_000000000  # a EuRoC-like UNIX time in nanoseconds
CAM = Cam("pinhole-radtan", RADTAN, rot("x", 90), np.array([0.1, 0.0, 0.02]), 0.012)
CAM_DS = Cam("double-sphere", DS, rot("x", 90) @ rot("y", 5), np.array([0.21, 0.0, 0.02]),
             -0.006)


def _ns(t: np.ndarray) -> np.ndarray:
    return T0_NS + np.round(t * 1e9).astype(np.int64)


def write_rig(d: Path, rig, *, gyro_scale=1.0, corner_seconds=False) -> dict:
    """Kalibr's files of ``rig`` in ``d``; the rig's times are seconds from T0_NS."""
    (d / "imu0").mkdir(parents=True, exist_ok=True)
    (d / "target.yaml").write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\n"
                                   "tagSize: 0.088\ntagSpacing: 0.3\n")
    (d / "imu.yaml").write_text(
        f"rostopic: /imu0\nupdate_rate: 200.0\ngyroscope_noise_density: {rig.gyro_noise}\n"
        f"accelerometer_noise_density: {rig.accel_noise}\ngyroscope_random_walk: 1.9e-05\n"
        f"accelerometer_random_walk: 3.0e-03\n")
    t, g, a = rig.imu
    with open(d / "imu0" / "data.csv", "w") as f:
        f.write("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
        for ti, gi, ai in zip(_ns(t), g * gyro_scale, a, strict=True):
            f.write(f"{ti},{','.join(f'{x:.9f}' for x in (*gi, *ai))}\n")
    chain = {f"cam{i}": {**c.kalibr(), "rostopic": f"/cam{i}/image_raw"}
             for i, c in enumerate(rig.cams)}
    (d / "camchain.yaml").write_text(yaml.safe_dump(chain))
    P = grid()
    corners = []
    for i, (tc, pts, uv) in enumerate(rig.observations):
        path = d / f"cam{i}_corners.csv"
        ids = np.array([np.flatnonzero((P == p).all(1))[0] for p in pts])
        stamps = [f"{T0_NS * 1e-9 + s:.6f}" for s in tc] if corner_seconds else _ns(tc)
        with open(path, "w") as f:
            f.write("t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m\n")
            for s, k, u, p in zip(stamps, ids, uv, pts, strict=True):
                f.write(f"{s},{k // 4},{k % 4},{u[0]:.4f},{u[1]:.4f},"
                        f"{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}\n")
        corners.append(str(path))
    return {"--target": str(d / "target.yaml"), "--imu": str(d / "imu0" / "data.csv"),
            "--imu-noise": str(d / "imu.yaml"), "--cameras": str(d / "camchain.yaml"),
            "corners": corners}


def _argv(files: dict, out, *extra) -> list[str]:
    args = ["calibrate", "--no-plots", "--quiet"]
    for k, v in files.items():
        args += [x for c in v for x in ("--corners", c)] if k == "corners" else [k, v]
    return [*args, "--out", str(out), *extra]


def calibrate(files: dict, out, *extra) -> subprocess.CompletedProcess:
    """``python -m torch_dq calibrate`` in a process of its own (the real entry point)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "torch_dq", *_argv(files, out, *extra)],
                          capture_output=True, text=True, env=env, timeout=300, cwd=ROOT)


def calibrate_here(files: dict, out, *extra) -> subprocess.CompletedProcess:
    """The same command line through ``torch_dq.cli.main`` in this process (what ``python -m
    torch_dq`` runs, without a fresh interpreter's ~5 s of imports): its exit status (an
    argparse ``SystemExit`` included), stdout and stderr. For the errors: an uncaught
    exception (a traceback in a process) fails the test here."""
    argv, out_, err = _argv(files, out, *extra), io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out_):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
    return subprocess.CompletedProcess(argv, rc, out_.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def rig():
    return make_rig([CAM, CAM_DS], seed=3, t0=0.0, duration=4.0,
                    gravity=np.array([0.0, -9.80665, 0.0]))


def test_cli_end_to_end_against_the_truth(rig, tmp_path):
    files = write_rig(tmp_path / "in", rig)
    before = {p: p.read_bytes() for p in (tmp_path / "in").rglob("*") if p.is_file()}
    done = calibrate(files, tmp_path / "out", "--pixel-sigma", "0.3", "--gravity", "9.80665")
    assert done.returncode == 0, done.stderr
    assert all(p.read_bytes() == b for p, b in before.items())  # inputs untouched
    chain = yaml.safe_load((tmp_path / "out" / "camchain-imucam.yaml").read_text())
    assert sorted(chain) == ["cam0", "cam1"]
    for i, cam in enumerate((CAM, CAM_DS)):
        entry = chain[f"cam{i}"]
        T = np.array(entry["T_cam_imu"])
        # Kalibr's T_cam_imu maps IMU points into the camera: p_cam = R_bc^T (p_imu - t_bc)
        assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
        angle = Rotation.from_matrix(T[:3, :3] @ cam.R_bc).magnitude()
        assert np.degrees(angle) < 0.1
        np.testing.assert_allclose(T[:3, 3], -cam.R_bc.T @ cam.t_bc, atol=3e-3)
        # Kalibr: t_imu = t_cam + timeshift_cam_imu; the camera stamps are IMU time - dt
        assert abs(entry["timeshift_cam_imu"] - cam.dt) < 5e-4
        for key, value in cam.kalibr().items():  # the models as given, in Kalibr's order
            if isinstance(value, str):
                assert entry[key] == value, (key, entry[key])
            else:
                np.testing.assert_allclose(entry.get(key, []), value)
    # T_cn_cnm1: p_cam1 = T p_cam0 = R_bc1^T (R_bc0 p_cam0 + t_bc0 - t_bc1)
    T10 = np.array(chain["cam1"]["T_cn_cnm1"])
    R10 = CAM_DS.R_bc.T @ CAM.R_bc
    assert np.degrees(Rotation.from_matrix(T10[:3, :3] @ R10.T).magnitude()) < 0.1
    np.testing.assert_allclose(T10[:3, 3], CAM_DS.R_bc.T @ (CAM.t_bc - CAM_DS.t_bc), atol=3e-3)
    # read back by read_camchain: the extrinsics p_imu = e p_cam, the models
    back = read_camchain(tmp_path / "out" / "camchain-imucam.yaml")
    for i, cam in enumerate((CAM, CAM_DS)):
        M = dualquat.to_matrix(back.extrinsics[i]).numpy()
        assert np.degrees(Rotation.from_matrix(cam.R_bc.T @ M[:3, :3]).magnitude()) < 0.1
        np.testing.assert_allclose(M[:3, 3], cam.t_bc, atol=3e-3)
        assert back.cameras[i].model == cam.model
        np.testing.assert_allclose(back.cameras[i].params.numpy(), cam.params)
    np.testing.assert_allclose(back.time_offsets.numpy(), [CAM.dt, CAM_DS.dt], atol=5e-4)
    values = json.loads((tmp_path / "out" / "summary.json").read_text())["values"]
    g = np.array(values["gravity"]["value"])
    assert abs(np.linalg.norm(g) - 9.80665) < 1e-9 and g[1] < -9.8  # board upright: -Y
    # random-walk biases by default (one row per ~1 s segment) around the constant truth
    for key, truth in (("gyro_bias", rig.gyro_bias), ("accel_bias", rig.accel_bias)):
        b, s = np.array(values[key]["value"]), np.array(values[key]["std"])
        assert b.ndim == 2 and b.shape[1] == 3
        assert np.all(np.abs(b - truth) < 4 * s), (key, (b - truth) / s)
    s = values["time_offsets"]["std"][0]
    assert 0 < s < 1e-3 and abs(values["time_offsets"]["value"][0] - CAM.dt) < 4 * s


def _one_line_exit_2(done: subprocess.CompletedProcess, *words: str) -> None:
    lines = [x for x in done.stderr.splitlines() if x.strip() and "warning" not in x.lower()]
    assert done.returncode == 2, (done.returncode, done.stderr[-2000:])
    assert len(lines) == 1, done.stderr
    assert "Traceback" not in done.stderr
    for w in words:
        assert w.lower() in lines[0].lower(), lines[0]


def test_cli_missing_file(rig, tmp_path):
    files = write_rig(tmp_path / "in", rig)
    files["--imu"] = str(tmp_path / "nope.csv")
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"), "nope.csv")
    assert not (tmp_path / "out").exists()


def test_cli_wrong_yaml(rig, tmp_path):
    files = write_rig(tmp_path / "in", rig)
    files["--target"], files["--cameras"] = files["--cameras"], files["--target"]
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"))
    files = write_rig(tmp_path / "in2", rig)
    Path(files["--imu-noise"]).write_text("gyroscope_noise_density: [1, 2\n")
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"), "imu.yaml")


def test_cli_never_writes_over_an_input(rig, tmp_path):
    files = write_rig(tmp_path / "in", rig)
    chain = Path(files["--cameras"])
    renamed = chain.with_name("camchain-imucam.yaml")  # a previous output used as input
    chain.rename(renamed)
    files["--cameras"] = str(renamed)
    text = renamed.read_text()
    _one_line_exit_2(calibrate_here(files, tmp_path / "in"), "overwrite")
    assert renamed.read_text() == text


def test_cli_seconds_under_t_ns(rig, tmp_path):
    """Corner times written in seconds under a ``t_ns`` header: an error naming the file."""
    files = write_rig(tmp_path / "in", rig, corner_seconds=True)
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"), "cam0_corners.csv")


def test_cli_gyro_in_degrees(rig, tmp_path):
    """A gyroscope logged in deg/s under a rad/s header: the rates do not match the
    cameras' (57 times larger), an error, not a calibration."""
    files = write_rig(tmp_path / "in", rig, gyro_scale=180 / np.pi)
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"), "deg")


def test_cli_target_in_millimetres(rig, tmp_path):
    """Corner files with the target points in millimetres: the error says so (it said the
    corners came from another target)."""
    files = write_rig(tmp_path / "in", rig)
    path = Path(files["corners"][0])
    lines = path.read_text().splitlines()
    rows = [v.split(",") for v in lines[1:]]
    path.write_text("\n".join([lines[0]] + [",".join(v[:5] + [f"{1e3 * float(x):.3f}"
                                                              for x in v[5:8]]) for v in rows]))
    _one_line_exit_2(calibrate_here(files, tmp_path / "out"), "millimetres", "1000")


def test_cli_cameras_alone_double_sphere_without_intrinsics(tmp_path):
    """Without --imu, a camchain of models and resolutions only (Kalibr's ds among them):
    the intrinsics and the pair's pose come out near the truth (the ds camera's placeholder
    intrinsics were written in our order, not Kalibr's: fu = 0, an error)."""
    cams = [Cam(CAM.model, CAM.params, CAM.R_bc, CAM.t_bc, 0.01),
            Cam(CAM_DS.model, CAM_DS.params, CAM_DS.R_bc, CAM_DS.t_bc, 0.01)]
    files = write_rig(tmp_path / "in", make_rig(cams, seed=8, t0=0.0, duration=4.0))
    chain = {f"cam{i}": {k: v for k, v in c.kalibr().items()
                         if k not in ("intrinsics", "distortion_coeffs")}
             for i, c in enumerate(cams)}
    Path(files["--cameras"]).write_text(yaml.safe_dump(chain))
    del files["--imu"], files["--imu-noise"]
    done = calibrate_here(files, tmp_path / "out")
    assert done.returncode == 0, done.stderr
    out = yaml.safe_load((tmp_path / "out" / "camchain.yaml").read_text())
    for i, c in enumerate(cams):
        want = c.kalibr()
        assert out[f"cam{i}"]["camera_model"] == want["camera_model"]
        got = np.r_[out[f"cam{i}"]["intrinsics"], out[f"cam{i}"].get("distortion_coeffs", [])]
        want = np.r_[want["intrinsics"], want["distortion_coeffs"]]
        np.testing.assert_allclose(got, want, rtol=0.02, atol=0.02)
    T10 = np.array(out["cam1"]["T_cn_cnm1"])  # p_cam1 = T p_cam0
    np.testing.assert_allclose(T10[:3, 3], CAM_DS.R_bc.T @ (CAM.t_bc - CAM_DS.t_bc), atol=2e-3)

"""``python -m torch_dq calibrate`` without an IMU (user11): the cameras alone, Kalibr's
``calibrate_cameras``. A new user with EuRoC's stereo corners and no IMU file had no command
to run: ``--imu`` and ``--imu-noise`` were required. Now, without both, the command calibrates
the camchain's cameras and writes ``camchain.yaml`` and ``summary.json``.

The reference is independent: corners of an AprilGrid projected in numpy (pinhole with
radtan distortion, the formula written here) through two cameras with known intrinsics and a
known relative pose; noise-free, so the calibration must return them to rounding.
"""

import json

import numpy as np
import pytest
import torch

from torch_dq import calibration, dualquat
from torch_dq.cli import main

yaml = pytest.importorskip("yaml")

RES = (752, 480)
K0 = [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
K1 = [457.587, 456.134, 379.999, 255.238, -0.28368365, 0.07451284, -0.00010473, -3.5559e-05]


def _rot(rv):
    """Rodrigues' formula: the rotation matrix of a rotation vector."""
    rv = np.asarray(rv, dtype=np.float64)
    th = np.linalg.norm(rv)
    if th == 0.0:
        return np.eye(3)
    k = rv / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx


def _radtan(k, X):
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    f = 1 + k[4] * r2 + k[5] * r2 * r2
    xd = x * f + 2 * k[6] * x * y + k[7] * (r2 + 2 * x * x)
    yd = y * f + k[6] * (r2 + 2 * y * y) + 2 * k[7] * x * y
    return np.stack((k[0] * xd + k[2], k[1] * yd + k[3]), 1)


def _grid():
    """Kalibr's 6x6 AprilGrid (tag 0.088 m, spacing 0.3): tag ids row by row from the
    bottom-left, corners counter-clockwise from each tag's lower-left."""
    s, pitch = 0.088, 0.088 * 1.3
    return np.array([(c * pitch + a * s, r * pitch + b * s, 0.0)
                     for r in range(6) for c in range(6)
                     for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))])


# cam1's pose seen from cam0 inverted: p_cam1 = R10 p_cam0 + t10 (Kalibr's T_cn_cnm1)
R10, T10_T = _rot([0.002, -0.014, 0.0015]), np.array([-0.110, 0.0005, -0.0006])


def _write_corners(tmp_path):
    rng = np.random.default_rng(3)
    P = _grid()
    centre = P.mean(0)
    rows = [[], []]
    for f in range(14):
        R = _rot(rng.uniform(-0.45, 0.45, 3)) @ _rot([np.pi, 0, 0])  # board faces the cameras
        t = np.array([rng.uniform(-0.25, 0.25), rng.uniform(-0.15, 0.15), rng.uniform(0.9, 1.5)])
        X0 = (P - centre) @ R.T + t
        for cam, (X, k) in enumerate(((X0, K0), (X0 @ R10.T + T10_T, K1))):
            uv = _radtan(k, X)
            inside = (uv[:, 0] > 0) & (uv[:, 0] < RES[0] - 1) & (uv[:, 1] > 0) \
                & (uv[:, 1] < RES[1] - 1) & (X[:, 2] > 0)
            t_ns = 1403709385487836928 + f * 50_000_000
            rows[cam] += [f"{t_ns},{u:.17g},{v:.17g},{p[0]:.17g},{p[1]:.17g},0"
                          for (u, v), p in zip(uv[inside], P[inside], strict=True)]
    paths = []
    for cam in (0, 1):
        path = tmp_path / f"cam{cam}.csv"
        path.write_text("# t_ns,u_px,v_px,X_m,Y_m,Z_m\n" + "\n".join(rows[cam]) + "\n")
        paths.append(path)
    (tmp_path / "target.yaml").write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\n"
                                          "tagSize: 0.088\ntagSpacing: 0.3\n")
    (tmp_path / "camchain.yaml").write_text("".join(
        f"cam{i}:\n  camera_model: pinhole\n  distortion_model: radtan\n"
        f"  resolution: [752, 480]\n  rostopic: /cam{i}/image_raw\n" for i in (0, 1)))
    return paths


def _argv(tmp_path, paths):
    return ["calibrate", "--target", str(tmp_path / "target.yaml"), "--cameras",
            str(tmp_path / "camchain.yaml"), "--corners", str(paths[0]), "--corners",
            str(paths[1]), "--out", str(tmp_path / "out"), "--quiet"]


def test_calibrate_without_imu_calibrates_the_cameras(tmp_path):
    torch.set_num_threads(1)
    paths = _write_corners(tmp_path)
    assert main(_argv(tmp_path, paths)) == 0
    chain = yaml.safe_load((tmp_path / "out" / "camchain.yaml").read_text())
    for i, k in enumerate((K0, K1)):
        cam = chain[f"cam{i}"]
        assert (cam["camera_model"], cam["distortion_model"]) == ("pinhole", "radtan")
        assert cam["rostopic"] == f"/cam{i}/image_raw" and cam["resolution"] == list(RES)
        np.testing.assert_allclose(cam["intrinsics"], k[:4], rtol=1e-6)
        np.testing.assert_allclose(cam["distortion_coeffs"], k[4:], rtol=1e-4, atol=1e-8)
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    np.testing.assert_allclose(T[:3, :3], R10, atol=1e-7)
    np.testing.assert_allclose(T[:3, 3], T10_T, atol=1e-7)
    back = calibration.read_camchain(tmp_path / "out" / "camchain.yaml")  # cam1 in cam0
    T10 = np.eye(4)
    T10[:3, :3], T10[:3, 3] = R10, T10_T
    np.testing.assert_allclose(dualquat.to_matrix(back.relative_poses[0]).numpy(),
                               np.linalg.inv(T10), atol=1e-7)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [c["model"] for c in summary["cameras"]] == ["pinhole-radtan"] * 2
    assert max(c["reprojection_rms_px"] for c in summary["cameras"]) < 1e-5
    assert len(summary["cameras"][0]["std"]) == 8 and summary["converged"]
    assert not (tmp_path / "out" / "camchain-imucam.yaml").exists()


@pytest.mark.parametrize("extra, message", [
    (["--imu", "imu.csv"], "--imu and --imu-noise go together"),
    (["--imu-noise", "imu.yaml"], "--imu and --imu-noise go together"),
    (["--rolling-shutter"], "--rolling-shutter needs --imu"),
    (["--gravity", "9.80665"], "--gravity needs --imu"),  # was ignored without the IMU
    (["--shared-time-offset", "--bias", "constant", "--bias-interval", "2"],
     "--shared-time-offset, --bias, --bias-interval need --imu"),
])
def test_calibrate_imu_options_without_the_imu_are_one_error_line(tmp_path, capsys, extra,
                                                                 message):
    paths = _write_corners(tmp_path)
    assert main(_argv(tmp_path, paths) + extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torch-dq calibrate: error: ") and message in err[0]
    assert not (tmp_path / "out").exists()


def test_calibrate_runs_on_threads_1_by_default(tmp_path):
    """Like ``fit``: torch's default threads made EuRoC's stereo calibration 8 times slower
    on a busy 2-core machine (13 to 25 s against 1.6 to 3 s on one thread)."""
    paths = _write_corners(tmp_path)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert main(_argv(tmp_path, paths)) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)

"""``python -m torch_dq calibrate --robust {none,huber,cauchy}`` (mend14): a robust kernel on
the corners' reprojection errors. With 24 gross outliers (misdetected corners 25-40 px off)
among the corners of a synthetic rig, ``--robust cauchy`` keeps the extrinsic and the clock
offset at the truth and ``summary.json`` counts the outliers (at least the 24 injected, few
more: 0.1 % of honest corners lie beyond the 99.9 % cutoff) with a chi2/dof of the inliers
near 1 (the corners' 0.3 px noise given as --pixel-sigma). The truth: the rig of
``tests/_calib12_rig.py`` (numpy / OpenCV projections)."""

import json

import numpy as np
import pytest
from _calib12_rig import make_rig
from scipy.spatial.transform import Rotation
from test_calib12_cli import CAM, calibrate_here, write_rig

yaml = pytest.importorskip("yaml")
pytest.importorskip("cv2")

N_OUT = 24


def _with_outliers(rig):
    t, p, uv = rig.observations[0]
    rng = np.random.default_rng(11)
    i = rng.choice(len(t), N_OUT, replace=False)
    angle = rng.uniform(0.0, 2 * np.pi, N_OUT)
    push = rng.uniform(25.0, 40.0, N_OUT)[:, None] * np.c_[np.cos(angle), np.sin(angle)]
    uv = uv.copy()
    uv[i] = np.clip(uv[i] + push, 0.0, [751.0, 479.0])  # still inside the image
    rig.observations[0] = (t, p, uv)
    return rig


def test_cauchy_keeps_the_truth_and_counts_the_outliers(tmp_path):
    rig = _with_outliers(make_rig([CAM], seed=4, t0=0.0, duration=5.0))
    n = len(rig.observations[0][0])
    files = write_rig(tmp_path / "in", rig)
    done = calibrate_here(files, tmp_path / "out", "--pixel-sigma", "0.3", "--bias", "constant",
                     "--robust", "cauchy")
    assert done.returncode == 0, done.stderr
    out = yaml.safe_load((tmp_path / "out" / "camchain-imucam.yaml").read_text())
    T = np.array(out["cam0"]["T_cam_imu"])  # p_cam = R_bc^T (p_imu - t_bc)
    assert np.degrees(Rotation.from_matrix(T[:3, :3] @ CAM.R_bc).magnitude()) < 0.05
    np.testing.assert_allclose(T[:3, 3], -CAM.R_bc.T @ CAM.t_bc, atol=2e-3)
    assert abs(out["cam0"]["timeshift_cam_imu"] - CAM.dt) < 3e-4
    chi2 = json.loads((tmp_path / "out" / "summary.json").read_text())["chi2"]
    cam = chi2["reprojections_cam0"]
    assert N_OUT <= cam["outliers"] <= N_OUT + 0.005 * n, (cam, n)
    assert 0.8 < cam["chi2_per_dof"] < 1.25, cam
    assert chi2["gyro"]["outliers"] == 0 and chi2["accel"]["outliers"] == 0


def test_robust_choices_in_help_and_refused_otherwise(tmp_path):
    rig = make_rig([CAM], seed=4, t0=0.0, duration=2.0)
    files = write_rig(tmp_path / "in", rig)
    done = calibrate_here(files, tmp_path / "out", "--robust", "tukey")
    assert done.returncode == 2 and "--robust" in done.stderr, done.stderr
    helped = calibrate_here(files, tmp_path / "out", "--help")
    assert "--robust {none,huber,cauchy}" in helped.stdout, helped.stdout

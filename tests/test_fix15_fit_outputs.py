"""``python -m torch_dq fit`` (user15 findings 7 and 9): with ``--imu`` the pose-only fit's
line comes before the IMU fit's block and says which curve the errors, ``trajectory.csv``
and ``spline.pt`` are of (the joint fit's: checked by reloading ``spline.pt`` and
recomputing the held-out errors); ``trajectory.csv`` writes times as the shortest decimal
that reads back as the same float64, so a join on the time text with the input works (it
wrote ``1305031098.665899992`` for the file's ``1305031098.6659``). The motion and the IMU
readings are written in numpy and scipy here."""

import json

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torch_dq.cli import main
from torch_dq.nn import BSpline

G = np.array([0.0, 0.0, -9.81])
T0_TENTHOUSANDTHS = 13050310986659  # 1305031098.6659 s, TUM fr1_xyz's first time


def _truth(t):
    """Rotation, position, world angular velocity, acceleration at ``t`` s from the start."""
    phi, dphi = 0.5 * np.sin(t), 0.5 * np.cos(t)
    R = Rotation.from_euler("z", 0.8 * t[:, None]) * Rotation.from_euler("y", phi[:, None])
    p = np.stack((0.6 * t + 0.1 * t**2, np.sin(2 * t), 0.5 * np.cos(t)), -1)
    acc = np.stack((0.2 + 0 * t, -4 * np.sin(2 * t), -0.5 * np.cos(t)), -1)
    ey = np.stack((-np.sin(0.8 * t), np.cos(0.8 * t), 0 * t), -1)
    return R, p, np.array([0.0, 0.0, 0.8]) + dphi[:, None] * ey, acc


def _files(tmp_path, seconds=4.0):
    k = np.arange(round(seconds * 20) + 1)
    stamps = [repr((T0_TENTHOUSANDTHS + 500 * int(i)) / 1e4) for i in k]  # 20 Hz, 4 decimals
    R, p, _, _ = _truth(k / 20.0)
    q = R.as_quat()  # x y z w, as TUM
    rows = [f"{s} " + " ".join(f"{v:.9f}" for v in (*pi, *qi))
            for s, pi, qi in zip(stamps, p, q, strict=True)]
    (tmp_path / "poses.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows)
                                        + "\n")
    ti = np.arange(round(seconds * 100) + 1) / 100.0
    R, _, w, acc = _truth(ti)
    imu = np.column_stack((T0_TENTHOUSANDTHS / 1e4 + ti, R.inv().apply(w),
                           R.inv().apply(acc - G)))
    np.savetxt(tmp_path / "imu.txt", imu, fmt="%.12f", header="t gx gy gz ax ay az")
    return stamps


def test_trajectory_csv_times_join_the_input(tmp_path):
    stamps = _files(tmp_path)
    out = tmp_path / "out"
    assert main(["fit", str(tmp_path / "poses.txt"), "--out", str(out), "--no-plots",
                 "--quiet"]) == 0
    rows = [line.split(",") for line in (out / "trajectory.csv").read_text().splitlines()
            if not line.startswith("#")]
    header, rows = rows[0], rows[1:]
    assert header[0] == "t" and rows[0][0] == "1305031098.6659", rows[0][0]
    assert [r[0] for r in rows] == stamps  # the same rate: every time joins, as text
    assert all(float(r[0]) == float(s) for r, s in zip(rows, stamps, strict=True))
    data = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True, skip_header=3)
    assert data["t"][0] == 1305031098.6659 and len(data) == len(stamps)


def test_imu_report_order_and_which_curve(tmp_path, capsys):
    _files(tmp_path)
    out = tmp_path / "imu"
    capsys.readouterr()
    assert main(["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu.txt"),
                 "--out", str(out), "--no-plots", "--steps", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()

    def at(prefix):
        return next(i for i, s in enumerate(lines) if s.startswith(prefix))

    pose_only, imu_block, errors = at("fit (poses alone): "), at("IMU fit: "), at("held-out")
    assert pose_only < at("IMU fit knots") < imu_block < errors, lines
    assert "below" not in lines[pose_only] and "trajectory.csv and spline.pt are of" in \
        lines[pose_only], lines[pose_only]
    assert "poses and IMU" in lines[errors], lines[errors]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["holdout"]["curve"] == "poses and IMU fitted together"
    assert "and the IMU" in (out / "trajectory.csv").read_text().splitlines()[2]
    # spline.pt is the joint fit's curve: its knots are the IMU fit's, and its errors at the
    # held-out poses (recomputed with scipy) are the ones reported
    spline = BSpline.from_state_dict(torch.load(out / "spline.pt"))
    assert spline.n_ctrl == summary["imu"]["knots"]["n_ctrl"] == summary["model"]["n_ctrl"]
    k = np.arange(1, 81, 2)  # the held-out poses: every other one (--holdout 2)
    t = torch.tensor([(T0_TENTHOUSANDTHS + 500 * int(i)) / 1e4 for i in k], dtype=torch.float64)
    x = spline(t).detach().numpy()
    R, p, _, _ = _truth(k / 20.0)
    fit = Rotation.from_quat(x[:, [1, 2, 3, 0]])
    rot = np.degrees((R.inv() * fit).magnitude())
    q, d = x[:, :4], x[:, 4:]
    qv, dv = q[:, 1:], d[:, 1:]  # translation 2 d q*: vector part
    trans = 2 * (q[:, :1] * dv - d[:, :1] * qv - np.cross(dv, qv))
    err = np.linalg.norm(trans - p, axis=1) * 1e3
    reported = summary["heldout_errors"]
    assert reported["translation_mm"]["mean"] == pytest.approx(err.mean(), rel=1e-3, abs=1e-4)
    assert reported["rotation_deg"]["max"] == pytest.approx(rot.max(), rel=1e-3, abs=1e-5)

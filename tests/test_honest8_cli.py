"""``python -m torch_dq fit``'s report is true (honest8): never a bare "fit: 0 steps" (the
least-squares start kept says why; with an IMU the pose-only line says that the IMU fit
refines the curve); a pose file and an IMU file stamped in UNIX nanoseconds fit in seconds,
their biases as from the same files in seconds."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
from scipy.spatial.transform import Rotation

from torch_dq.__main__ import main

sys.path.insert(0, os.path.dirname(__file__))
import _camera_imu_sim as sim

BIAS_G = np.array([0.01, -0.02, 0.015])


def _files(tmp_path, ns: bool, rng_seed: int = 0):
    """Poses at 20 Hz (1 mm / 1 mrad noise) and a 200 Hz IMU with a gyro bias, 4 s, stamped
    in UNIX seconds or integer UNIX nanoseconds."""
    rng = np.random.default_rng(rng_seed)
    t = np.arange(0.0, 4.0, 0.05)
    R, p, _, _ = sim.motion(t)
    R = Rotation.from_matrix(R) * Rotation.from_rotvec(1e-3 * rng.standard_normal((len(t), 3)))
    p = p + 1e-3 * rng.standard_normal(p.shape)
    ti = np.arange(0.0, 4.0, 0.005)
    _, _, gyro, accel = sim.motion(ti)
    gyro = gyro + BIAS_G + 2e-3 * rng.standard_normal(gyro.shape)
    accel = accel + 2e-2 * rng.standard_normal(accel.shape)

    def stamp(x):
        return [str(1_700_000_000_000_000_000 + round(v * 1e9)) if ns else f"{1.7e9 + v:.9f}"
                for v in x]

    name = "ns" if ns else "s"
    with open(tmp_path / f"poses_{name}.txt", "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for s, pi, qi in zip(stamp(t), p, R.as_quat(), strict=True):
            f.write(s + " " + " ".join(f"{v:.9f}" for v in (*pi, *qi)) + "\n")
    with open(tmp_path / f"imu_{name}.txt", "w") as f:
        f.write("# t gx gy gz ax ay az\n")
        for s, g, a in zip(stamp(ti), gyro, accel, strict=True):
            f.write(s + " " + " ".join(f"{v:.9f}" for v in (*g, *a)) + "\n")
    return tmp_path / f"poses_{name}.txt", tmp_path / f"imu_{name}.txt"


def _run(argv, capsys):
    assert main(argv) == 0
    return capsys.readouterr().out.splitlines()


def test_kept_start_says_why(tmp_path, capsys):
    """--steps 0, and an automatic spacing so fine that refining would chase the noise: the
    line says the start was kept and why, never "0 steps"."""
    poses, _ = _files(tmp_path, ns=False)
    lines = _run(["fit", str(poses), "--out", str(tmp_path / "a"), "--no-plots",
                  "--steps", "0"], capsys)
    fit = [s for s in lines if s.startswith("fit")]
    assert fit[0].startswith("fit: the least-squares start, not refined (--steps 0)"), fit
    lines = _run(["fit", str(poses), "--out", str(tmp_path / "b"), "--no-plots"], capsys)
    fit = next(s for s in lines if s.startswith("fit:"))
    assert "0 steps" not in fit
    knots = next(s for s in lines if s.startswith("knot spacing"))
    if "no refinement" in knots:
        assert "not refined (refining chases the poses' noise" in fit, fit
    else:
        assert fit.split()[1].isdigit() and int(fit.split()[1]) >= 1, fit


def test_imu_fit_in_nanoseconds_as_in_seconds(tmp_path, capsys):
    """The same recording stamped in UNIX ns and in UNIX s: the ns run converts (says so),
    both give the gyro bias within 3 std of the truth and within 1e-3 std of each other;
    the pose-only line says the IMU fit refines the curve."""
    out = {}
    for ns in (True, False):
        poses, imu = _files(tmp_path, ns)
        lines = _run(["fit", str(poses), "--imu", str(imu), "--out",
                      str(tmp_path / f"o{ns}"), "--no-plots", "--steps", "10"], capsys)
        fit = next(s for s in lines if s.startswith("fit"))
        assert fit.startswith("fit (poses alone): ") and "the IMU fitted together" in fit
        assert any("converted to seconds" in s for s in lines) == ns, lines
        out[ns] = json.loads((tmp_path / f"o{ns}" / "summary.json").read_text())
    for ns in (True, False):
        g = out[ns]["imu"]["gyro_bias_rad_s"]
        z = (np.array(g["value"]) - BIAS_G) / np.array(g["std"])
        assert np.abs(z).max() < 4, z
    a, b = (np.array(out[k]["imu"]["gyro_bias_rad_s"]["value"]) for k in (True, False))
    np.testing.assert_allclose(a, b, atol=1e-3 * min(out[False]["imu"]["gyro_bias_rad_s"]
                                                      ["std"]))

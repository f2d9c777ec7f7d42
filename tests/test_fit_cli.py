"""``python -m torch_dq fit FILE`` end to end on the shipped TUM subsample, and its errors."""

import json
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import torch

from torch_dq import io
from torch_dq.__main__ import main
from torch_dq.demo.fit_file import FIGURES, OUTPUTS

ROOT = pathlib.Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "tests" / "data" / "tum_fr1_xyz_sub.txt"
Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

pytestmark = pytest.mark.skipif(not SHIPPED.is_file(), reason=f"{SHIPPED} missing")

# A short piece of the shipped file keeps each fit small (the whole file is fitted once).
QUICK = ["--knot-spacing", "0.2", "--steps", "3", "--quiet"]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """One fit of the whole shipped file with figures: (exit status, out dir, stdout)."""
    pytest.importorskip("matplotlib")
    out = tmp_path_factory.mktemp("fit")
    rate = 200.0
    import contextlib
    import io as stdio

    buf = stdio.StringIO()
    with contextlib.redirect_stdout(buf):
        status = main(["fit", str(SHIPPED), "--out", str(out), "--steps", "5",
                       "--rate", str(rate)])
    return status, out, buf.getvalue(), rate


def test_fit_writes_every_output(full_run):
    status, out, stdout, _ = full_run
    assert status == 0
    for name in OUTPUTS + FIGURES:
        assert (out / name).is_file(), name
    for name in FIGURES:
        assert (out / name).stat().st_size > 20_000  # a real figure, not an empty canvas
    assert "held-out errors" in stdout and "translation [mm]" in stdout
    assert "rotation [deg]" in stdout and "steps in" in stdout


def test_heldout_errors_next_to_scipy(full_run):
    """The reported held-out errors are right (recomputed here) and of scipy's order."""
    _, out, _, _ = full_run
    summary = json.loads((out / "summary.json").read_text())
    data = np.loadtxt(SHIPPED)
    t, p, xyzw = data[:, 0], data[:, 1:4], data[:, 4:]
    fit = np.zeros(len(t), dtype=bool)
    fit[::2] = True
    fit[-1] = True
    assert summary["holdout"] == {"every": 2, "fitted": int(fit.sum()),
                                  "held_out": int((~fit).sum()), "errors_on": "held-out poses"}
    # scipy through the same fitted samples, measured on the same held-out ones
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import RotationSpline

    p_ref = CubicSpline(t[fit], p[fit])(t[~fit])
    r_ref = RotationSpline(t[fit], Rotation.from_quat(xyzw[fit]))(t[~fit])
    scipy_mm = 1e3 * np.linalg.norm(p_ref - p[~fit], axis=1)
    scipy_deg = np.rad2deg((r_ref.inv() * Rotation.from_quat(xyzw[~fit])).magnitude())
    ours = summary["heldout_errors"]
    csv = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    assert csv["t"][0] == pytest.approx(t[0], abs=1e-9) and csv["t"][-1] <= t[-1]
    for key, ref in (("translation_mm", scipy_mm), ("rotation_deg", scipy_deg)):
        for stat in ("mean", "median"):  # the bar: at most 3x scipy's
            assert ours[key][stat] < 3 * getattr(np, stat)(ref), (key, stat)
        assert ours[key]["max"] < 3 * ref.max(), key
    assert summary["model"]["n_ctrl"] == int(np.ceil((t[-1] - t[0]) / 0.1 - 1e-9)) + 3


def test_csv_derivatives_match_finite_differences(full_run):
    _, out, _, rate = full_run
    text = (out / "trajectory.csv").read_text().splitlines()
    assert text[0].split(",") == list(io.CSV_COLUMNS)
    assert "[m/s]" in text[1] and "[rad/s]" in text[1] and "world frame" in text[1]
    d = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    t = d["t"]
    np.testing.assert_allclose(np.diff(t), 1.0 / rate, rtol=0, atol=2e-7)  # UNIX s in float64
    p = np.stack([d[c] for c in "xyz"], -1)
    v = np.stack([d[c] for c in ("vx", "vy", "vz")], -1)
    w = np.stack([d[c] for c in ("wx", "wy", "wz")], -1)
    a = np.stack([d[c] for c in ("ax", "ay", "az")], -1)
    q = np.stack([d[c] for c in ("qw", "qx", "qy", "qz")], -1)
    h = np.diff(t)[:, None]
    # central differences of the CSV's positions against its velocities
    fd_v = (p[2:] - p[:-2]) / (h[1:] + h[:-1])
    np.testing.assert_allclose(fd_v, v[1:-1], rtol=0, atol=2e-3 * np.abs(v).max())
    fd_a = (v[2:] - v[:-2]) / (h[1:] + h[:-1])
    np.testing.assert_allclose(fd_a, a[1:-1], rtol=0, atol=2e-2 * np.abs(a).max())
    # angular velocity (world frame): R(t+h) R(t-h)^T = exp(2h [w]x) to second order
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    fd_w = (R[2:] * R[:-2].inv()).as_rotvec() / (h[1:] + h[:-1])
    np.testing.assert_allclose(fd_w, w[1:-1], rtol=0, atol=2e-3 * np.abs(w).max())
    assert np.abs(v).max() > 0.05 and np.abs(w).max() > 0.05  # a real motion, not zeros


def test_state_dict_reloads_the_same_curve(full_run):
    import torch_dq.dualquat as dq
    from torch_dq import nn

    _, out, _, _ = full_run
    summary = json.loads((out / "summary.json").read_text())
    model = summary["model"]
    spline = nn.BSpline(dq.identity((model["n_ctrl"],), dtype=torch.float64),
                        degree=model["degree"])
    spline.load_state_dict(torch.load(out / "spline.pt"))
    d = np.genfromtxt(out / "trajectory.csv", delimiter=",", names=True)
    t = torch.from_numpy(d["t"][::50].copy())
    with torch.no_grad():
        p = dq.to_rt(spline(t))[1].numpy()
    np.testing.assert_allclose(p, np.stack([d[c][::50] for c in "xyz"], -1), atol=1e-9)


def test_no_plots_and_kitti_with_times(tmp_path):
    traj = io.read_trajectory(SHIPPED).select(slice(0, 100))  # 4 s of the sequence
    poses, times = tmp_path / "00.txt", tmp_path / "times.txt"
    io.write_trajectory(poses, traj, format="kitti", times_path=times)
    out = tmp_path / "out"
    assert main(["fit", str(poses), "--times", str(times), "--out", str(out), "--no-plots",
                 "--holdout", "1", "--steps", "1", "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUTS)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["holdout"]["errors_on"] == "fitted poses"
    assert summary["input"]["poses"] == 100
    assert summary["heldout_errors"]["translation_mm"]["max"] < 20


def _error_line(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith("torch-dq fit: error: ")
    return lines[0]


def test_malformed_file_one_line(tmp_path, capsys):
    rows = SHIPPED.read_text().splitlines()
    data = [i for i, r in enumerate(rows) if r and not r.startswith("#")]
    cases = {
        "columns": (data[5], lambda r: " ".join(r.split()[:7]), "expected 8 columns"),
        "number": (data[6], lambda r: r.replace(r.split()[2], "1.2.3"), "is not a number"),
        "unsorted": (data[7], lambda r: " ".join([rows[data[3]].split()[0], *r.split()[1:]]),
                     "before the previous one"),
        "duplicate": (data[8], lambda r: " ".join([rows[data[7]].split()[0], *r.split()[1:]]),
                      "duplicate timestamp"),
        "quaternion": (data[9], lambda r: " ".join([*r.split()[:7], "0.1"]),
                       "quaternion norm"),
    }
    for name, (index, edit, message) in cases.items():
        bad = list(rows)
        bad[index] = edit(rows[index])
        path = tmp_path / f"{name}.txt"
        path.write_text("\n".join(bad) + "\n")
        assert main(["fit", str(path), "--out", str(tmp_path / "o"), *QUICK]) == 1
        line = _error_line(capsys)
        assert f"{path}, line {index + 1}: " in line and message in line, line
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n")
    assert main(["fit", str(empty), *QUICK]) == 1
    assert "no data" in _error_line(capsys)
    assert main(["fit", str(tmp_path / "missing.txt"), *QUICK]) == 1
    assert "missing.txt" in _error_line(capsys)


def test_options_the_data_cannot_satisfy(tmp_path, capsys):
    short = tmp_path / "short.txt"
    io.write_trajectory(short, io.read_trajectory(SHIPPED).select(slice(0, 20)))
    assert main(["fit", str(short), "--knot-spacing", "0.01", "--quiet",
                 "--out", str(tmp_path / "o")]) == 1
    line = _error_line(capsys)
    assert "raise --knot-spacing" in line and "control points" in line
    kitti = tmp_path / "00.txt"
    io.write_trajectory(kitti, io.read_trajectory(short), format="kitti",
                        times_path=tmp_path / "t.txt")
    assert main(["fit", str(kitti), "--quiet"]) == 1
    assert "carry no times" in _error_line(capsys)
    with pytest.raises(SystemExit) as info:  # argparse: status 2
        main(["fit", str(short), "--knot-spacing", "0"])
    assert info.value.code == 2


def test_subprocess_exit_status_without_traceback(tmp_path):
    bad = tmp_path / "bad.txt"
    rows = SHIPPED.read_text().splitlines()
    bad.write_text("\n".join([*rows[:10], "1 2 3"]) + "\n")
    run = subprocess.run([sys.executable, "-m", "torch_dq", "fit", str(bad)],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert run.returncode == 1
    assert "Traceback" not in run.stderr
    assert run.stderr.strip() == (f"torch-dq fit: error: {bad}, line 11: expected 8 columns "
                                  f"(timestamp tx ty tz qx qy qz qw), got 3")


def test_float32_module_matches_float64(tmp_path):
    """--dtype float32 with float64 UNIX times: the float64 fit to float32 rounding."""
    short = tmp_path / "short.txt"
    io.write_trajectory(short, io.read_trajectory(SHIPPED).select(slice(0, 150)))
    runs = {}
    for dtype in ("float32", "float64"):
        out = tmp_path / dtype
        assert main(["fit", str(short), "--dtype", dtype, "--out", str(out), "--no-plots",
                     *QUICK]) == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["model"]["dtype"] == dtype
        runs[dtype] = (summary, np.genfromtxt(out / "trajectory.csv", delimiter=",",
                                              names=True))
    (s32, c32), (s64, c64) = runs["float32"], runs["float64"]
    np.testing.assert_array_equal(c32["t"], c64["t"])
    for c in ("x", "y", "z"):
        np.testing.assert_allclose(c32[c], c64[c], rtol=0, atol=2e-5)  # metres
    for key, tol in (("translation_mm", 2e-2), ("rotation_deg", 2e-3)):
        for stat in ("mean", "median", "max"):
            assert abs(s32["heldout_errors"][key][stat] - s64["heldout_errors"][key][stat]) < tol


def test_fit_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["fit", "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--format", "--times", "--knot-spacing", "--degree", "--holdout", "--out",
                   "--steps", "--rate", "--duplicates", "--dtype", "--no-plots", "--quiet"):
        assert option in text
    assert "(default: None)" not in text and "torch_dq[plot]" in text
    assert "(default: 0.1)" in text and "(default: 2)" in text

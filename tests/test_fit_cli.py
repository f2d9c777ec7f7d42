"""``python -m torch_dq fit FILE`` end to end on the shipped TUM subsample, and its errors."""

import json
import pathlib
import re
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from torch_dq import io
from torch_dq.__main__ import main
from torch_dq.cli.fit_file import FIGURES, OUTPUTS

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
    rate = 1000.0  # 1 ms: central differences of the CSV close to its exact derivatives
    import contextlib
    import io as stdio

    buf = stdio.StringIO()
    with contextlib.redirect_stdout(buf):
        status = main(["fit", str(SHIPPED), "--out", str(out), "--steps", "5",
                       "--rate", str(rate)])
    return status, out, buf.getvalue(), rate


def _read_csv(path):
    """trajectory.csv as its first line says to read it (numpy.genfromtxt, skip_header)."""
    first = pathlib.Path(path).read_text().splitlines()[0]
    skip = int(first.split("skip_header=")[1].rstrip(")"))
    return np.genfromtxt(path, delimiter=",", names=True, skip_header=skip)


def test_fit_writes_every_output(full_run):
    status, out, stdout, _ = full_run
    assert status == 0
    for name in OUTPUTS + FIGURES:
        assert (out / name).is_file(), name
    for name in FIGURES:
        assert (out / name).stat().st_size > 20_000  # a real figure, not an empty canvas
    assert "held-out errors" in stdout and "translation [mm]" in stdout
    assert "rotation [deg]" in stdout and re.search(r"fit: \d+ steps? in", stdout)


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
                                  "held_out": int((~fit).sum()), "errors_on": "held-out poses",
                                  "curve": "poses alone"}
    # scipy through the same fitted samples, measured on the same held-out ones
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import RotationSpline

    p_ref = CubicSpline(t[fit], p[fit])(t[~fit])
    r_ref = RotationSpline(t[fit], Rotation.from_quat(xyzw[fit]))(t[~fit])
    scipy_mm = 1e3 * np.linalg.norm(p_ref - p[~fit], axis=1)
    scipy_deg = np.rad2deg((r_ref.inv() * Rotation.from_quat(xyzw[~fit])).magnitude())
    ours = summary["heldout_errors"]
    csv = _read_csv(out / "trajectory.csv")
    assert csv["t"][0] == pytest.approx(t[0], abs=1e-9) and csv["t"][-1] <= t[-1]
    for key, ref in (("translation_mm", scipy_mm), ("rotation_deg", scipy_deg)):
        for stat in ("mean", "median"):  # issue 20's bar: within 1.5x of scipy's
            assert ours[key][stat] < 1.5 * getattr(np, stat)(ref), (key, stat)
        assert ours[key]["max"] < 3 * ref.max(), key
    # the automatic knot spacing: as printed, and never more control points than poses
    model = summary["model"]
    assert model["n_ctrl"] == int(np.ceil((t[-1] - t[0]) / model["knot_spacing_s"] - 1e-9)) + 3
    assert model["n_ctrl"] <= fit.sum()
    reason = model["knot_spacing_reason"]
    assert reason.startswith("tried ") and f"{model['knot_spacing_s']:.4g} s" in reason


def test_csv_derivatives_match_finite_differences(full_run):
    _, out, _, rate = full_run
    text = (out / "trajectory.csv").read_text().splitlines()
    assert text[3].split(",") == [*io.CSV_COLUMNS, "in_gap"]  # after 3 comment lines
    assert "[m/s]" in text[1] and "[rad/s]" in text[1] and "world frame" in text[1]
    assert "in_gap" in text[1] and text[0].startswith("# 3 comment lines")
    d = _read_csv(out / "trajectory.csv")
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
    # the De Boor form's acceleration jumps at knots (C1): skip stencils across a knot
    model = json.loads((out / "summary.json").read_text())["model"]
    t0, t1 = model["domain_s"]
    knots = t0 + (t1 - t0) * np.arange(1, model["n_ctrl"] - 3) / (model["n_ctrl"] - 3)
    across = np.searchsorted(knots, t[2:]) != np.searchsorted(knots, t[:-2])
    fd_a = (v[2:] - v[:-2]) / (h[1:] + h[:-1])
    np.testing.assert_allclose(fd_a[~across], a[1:-1][~across], rtol=0,
                               atol=2e-2 * np.abs(a).max())
    # angular velocity (world frame): R(t+h) R(t-h)^T = exp(2h [w]x) to second order
    R = Rotation.from_quat(q[:, [1, 2, 3, 0]])
    fd_w = (R[2:] * R[:-2].inv()).as_rotvec() / (h[1:] + h[:-1])
    np.testing.assert_allclose(fd_w, w[1:-1], rtol=0, atol=2e-3 * np.abs(w).max())
    assert np.abs(v).max() > 0.05 and np.abs(w).max() > 0.05  # a real motion, not zeros


def test_state_dict_reloads_the_same_curve(full_run):
    import torch_dq.dualquat as dq
    from torch_dq import nn

    _, out, stdout, _ = full_run
    summary = json.loads((out / "summary.json").read_text())
    reload = summary["reload"]
    assert reload in stdout and "BSpline.from_state_dict" in reload
    spline = nn.BSpline.from_state_dict(torch.load(out / "spline.pt"))
    assert spline.n_ctrl == summary["model"]["n_ctrl"] and spline.form == "de_boor"
    d = _read_csv(out / "trajectory.csv")
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
        assert main(["fit", str(path), "--out", str(tmp_path / "o"), *QUICK]) == 2
        line = _error_line(capsys)
        assert f"{path}, line {index + 1}: " in line and message in line, line
    empty = tmp_path / "empty.txt"
    empty.write_text("# nothing\n")
    assert main(["fit", str(empty), *QUICK]) == 2
    assert "no data" in _error_line(capsys)
    assert main(["fit", str(tmp_path / "missing.txt"), *QUICK]) == 2
    assert "missing.txt" in _error_line(capsys)
    assert main(["fit", str(tmp_path), "--out", str(tmp_path / "o"), *QUICK]) == 2  # a folder
    assert str(tmp_path) in _error_line(capsys)
    binary = tmp_path / "binary.txt"
    binary.write_bytes(b"\xff\xfe\x00\x81" * 50)
    assert main(["fit", str(binary), "--out", str(tmp_path / "o"), *QUICK]) == 2
    assert "binary.txt" in _error_line(capsys)


def test_options_the_data_cannot_satisfy(tmp_path, capsys):
    short = tmp_path / "short.txt"
    io.write_trajectory(short, io.read_trajectory(SHIPPED).select(slice(0, 20)))
    assert main(["fit", str(short), "--knot-spacing", "0.01", "--quiet",
                 "--out", str(tmp_path / "o")]) == 2
    line = _error_line(capsys)
    assert "--knot-spacing" in line and "control points" in line
    kitti = tmp_path / "00.txt"
    io.write_trajectory(kitti, io.read_trajectory(short), format="kitti",
                        times_path=tmp_path / "t.txt")
    assert main(["fit", str(kitti), "--quiet"]) == 2
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
    assert run.returncode == 2
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
        runs[dtype] = (summary, _read_csv(out / "trajectory.csv"))
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
    assert "(default: auto)" in text and "(default: 2)" in text and "--overwrite" in text


# ----------------------------------------------------------------------------- issue 22: the CLI

DESK = ROOT / "tests" / "data" / "tum_fr2_desk_sub.txt"


def _write_tum(path, traj):
    io.write_trajectory(path, traj)
    return path


def _hint_works(capsys, args, option, extra=()):
    """The command fails (exit 2, one line) naming ``option VALUE``; with that value it works."""
    import re

    assert main(args) == 2
    line = _error_line(capsys)
    found = re.findall(rf"{option} (\S+)", line)  # the last one: the way out
    assert found, line
    value = found[-1]
    fixed = list(args)
    if option in fixed:
        fixed[fixed.index(option) + 1] = value
    else:
        fixed += [option, value]
    out = fixed[fixed.index("--out") + 1]
    assert main([*fixed, "--overwrite", *extra]) == 0, (line, capsys.readouterr().err)
    capsys.readouterr()
    return line, value, out


def test_input_is_never_overwritten(tmp_path, capsys):
    folder = tmp_path / "d"
    folder.mkdir()
    source = _write_tum(folder / "trajectory.csv", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    before = source.read_bytes()
    for extra in ([], ["--overwrite"]):
        assert main(["fit", str(source), "--out", str(folder), "--no-plots", "--quiet",
                     *extra]) == 2
        line = _error_line(capsys)
        assert "would overwrite the input" in line and "choose another --out" in line
        assert source.read_bytes() == before
    assert sorted(p.name for p in folder.iterdir()) == ["trajectory.csv"]


def test_out_naming_a_file_is_one_line_naming_out(tmp_path, capsys):
    """``--out`` naming an existing file (not a folder): one error line naming ``--out``
    (it was a raw 'File exists'), exit 2, the file untouched."""
    short = _write_tum(tmp_path / "short.txt", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    target = tmp_path / "notes.txt"
    target.write_text("keep me")
    assert main(["fit", str(short), "--out", str(target), "--no-plots", "--quiet"]) == 2
    line = _error_line(capsys)
    assert f"--out {target} is a file, not a folder" in line
    assert target.read_text() == "keep me"


def test_three_poses_plot_without_warnings(tmp_path, capsys):
    """Three poses 10 ms apart with ``--degree 1`` (the hint the CLI gives for them) and the
    figures: the finite differences of the kinematics figure span the file (they asked for
    poses 40 ms apart: an empty slice, numpy warnings and a 'nan ms' legend)."""
    pytest.importorskip("matplotlib")
    first = io.read_trajectory(SHIPPED).select(slice(0, 3))
    times = first.times[0] + torch.tensor([0.0, 0.01, 0.02], dtype=torch.float64)  # 100 Hz
    three = _write_tum(tmp_path / "three.txt",
                       io.Trajectory(times, first.rotations, first.translations))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["fit", str(three), "--out", str(tmp_path / "o"), "--degree", "1",
                     "--quiet"]) == 0
    assert (tmp_path / "o" / "kinematics.png").exists()


def test_earlier_results_need_overwrite(tmp_path, capsys):
    short = _write_tum(tmp_path / "short.txt", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    out = tmp_path / "out"
    args = ["fit", str(short), "--out", str(out), "--no-plots", "--quiet", "--steps", "1"]
    assert main(args) == 0
    stamp = (out / "summary.json").read_bytes()
    assert main(args) == 2
    line = _error_line(capsys)
    assert "already holds results of an earlier run" in line and "--overwrite" in line
    assert (out / "summary.json").read_bytes() == stamp
    assert main([*args, "--overwrite", "--steps", "2"]) == 0
    assert json.loads((out / "summary.json").read_text())["fit"]["steps"] <= 2
    missing = ["fit", str(tmp_path / "missing.txt"), "--out", str(out), "--no-plots"]
    assert main(missing) == 2  # the missing input is named, not the earlier results
    line = _error_line(capsys)
    assert "missing.txt" in line and "No such file" in line, line
    assert "Errno" not in line, line  # "FILE: reason", as calibrate says it


def test_five_poses_with_defaults_one_line_with_working_hints(tmp_path, capsys):
    five = _write_tum(tmp_path / "five.txt", io.read_trajectory(SHIPPED).select(slice(0, 5)))
    for option in ("--holdout", "--degree"):
        line, value, _ = _hint_works(capsys, ["fit", str(five), "--out", str(tmp_path / option),
                                              "--quiet", "--no-plots"], option)
        assert "3 fitted poses (1 in 2 of 5, and the last) are too few for a degree-3 " \
               "B-spline" in line
    assert value == "2"  # 3 fitted poses allow degree 2
    line, value, _ = _hint_works(capsys, ["fit", str(five), "--holdout", "4", "--out",
                                          str(tmp_path / "o"), "--quiet", "--no-plots"],
                                 "--holdout")
    assert value == "1" and "-0.0" not in line


def test_huge_holdout_hint_works(tmp_path, capsys):
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 200)))
    line, value, _ = _hint_works(capsys, ["fit", str(short), "--holdout", "100000", "--out",
                                          str(tmp_path / "o"), "--quiet", "--no-plots"],
                                 "--holdout")
    assert int(value) == 99  # 0, 99, 198 and the last: the largest K with 4 fitted poses


def test_knot_spacing_hint_is_rounded_up_on_10hz_data(tmp_path, capsys):
    """Followed literally, the suggested spacing works (0.2 did not: rounded down)."""
    traj = io.read_trajectory(SHIPPED).select(slice(0, None, 5))  # 10 Hz, like KITTI
    poses, times = tmp_path / "00.txt", tmp_path / "times.txt"
    io.write_trajectory(poses, traj, format="kitti", times_path=times)
    line, value, out = _hint_works(capsys, ["fit", str(poses), "--times", str(times),
                                            "--knot-spacing", "0.1", "--out",
                                            str(tmp_path / "o"), "--quiet", "--no-plots",
                                            "--steps", "2"], "--knot-spacing")
    summary = json.loads((pathlib.Path(out) / "summary.json").read_text())
    assert summary["model"]["n_ctrl"] == summary["holdout"]["fitted"]  # the finest that works


def test_rate_is_bounded_by_the_duration(tmp_path, capsys, monkeypatch):
    from torch_dq.cli import fit_file

    monkeypatch.setattr(fit_file, "MAX_RESAMPLED", 2000)  # the bound's logic, on small files
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 30)))
    line, value, out = _hint_works(capsys, ["fit", str(short), "--rate", "1e9", "--out",
                                            str(tmp_path / "o"), "--quiet", "--no-plots",
                                            "--steps", "1"], "--rate")
    rows = json.loads((pathlib.Path(out) / "summary.json").read_text())["resampled"]["samples"]
    assert 1990 < rows <= 2000 and "more than 2000 samples" in line


@pytest.mark.parametrize("option,value,says", [
    ("--steps", "-1", "expected an integer >= 0, got -1"),
    ("--knot-spacing", "-0.1", "expected a finite number > 0, got -0.1"),
    ("--knot-spacing", "0", "expected a finite number > 0, got 0"),
    ("--knot-spacing", "fast", "expected a number, got 'fast'"),
    ("--holdout", "0", "expected an integer >= 1, got 0"),
    ("--rate", "inf", "expected a finite number > 0, got inf"),
])
def test_bad_option_messages_state_the_bound(tmp_path, capsys, option, value, says):
    with pytest.raises(SystemExit) as info:
        main(["fit", str(SHIPPED), option, value])
    assert info.value.code == 2
    assert says in capsys.readouterr().err


def test_steps_zero_is_allowed(tmp_path):
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 40)))
    assert main(["fit", str(short), "--steps", "0", "--out", str(tmp_path / "o"), "--quiet",
                 "--no-plots"]) == 0


def test_without_matplotlib_one_line_no_warning_source(tmp_path):
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 40)))
    code = ("import sys; sys.modules['matplotlib'] = None\n"
            "from torch_dq.__main__ import main\n"
            f"sys.exit(main(['fit', {str(short)!r}, '--out', {str(tmp_path / 'o')!r}, "
            f"'--steps', '1']))")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=300)
    assert run.returncode == 0, run.stderr
    assert run.stderr.count("torch_dq[plot]") == 1 and "torch_dq[plot]" not in run.stdout
    assert "UserWarning" not in run.stderr and "warnings.warn" not in run.stderr
    assert run.stderr.strip().splitlines()[-1].startswith("torch-dq fit: warning: matplotlib")


def test_x_label_without_a_useless_origin():
    from torch_dq.cli.fit_plots import _xlabel

    assert _xlabel(0.0) == "time [s]"
    assert "(0 s)" not in _xlabel(0.0)
    assert "UNIX 1305031098.666" in _xlabel(1305031098.6659)
    assert "t = 12.5 s" in _xlabel(12.5)


def _subsample(traj, step):
    """The first pose, then each pose at least ``step`` s after the last one kept."""
    keep, last = [], -np.inf
    for i, t in enumerate(traj.times.tolist()):
        if t - last >= step - 1e-3:
            keep.append(i)
            last = t
    return traj.select(torch.tensor(keep))


@pytest.mark.parametrize("name,step", [("fr1", None), ("fr1", 0.1), ("desk", None),
                                       ("desk", 0.1)])
def test_auto_knots_within_1_5x_of_scipy(tmp_path, name, step):
    """Issue 20: `fit FILE` with its defaults, held-out errors within 1.5x of scipy's
    CubicSpline + RotationSpline through the same fitted poses (the shipped subsamples, as
    they are and at 10 Hz, car-like)."""
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import RotationSpline

    source = SHIPPED if name == "fr1" else DESK
    traj = io.read_trajectory(source)
    if step is not None:
        traj = _subsample(traj, step)
    path = _write_tum(tmp_path / "in.txt", traj)
    out = tmp_path / "o"
    assert main(["fit", str(path), "--out", str(out), "--no-plots", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    t, p = traj.times.numpy(), traj.translations.numpy()
    rot = Rotation.from_quat(traj.rotations.numpy()[:, [1, 2, 3, 0]])
    fit = np.zeros(len(t), dtype=bool)
    fit[::2] = True
    fit[-1] = True
    p_ref = CubicSpline(t[fit], p[fit])(t[~fit])
    r_ref = RotationSpline(t[fit], rot[fit])(t[~fit])
    scipy = {"translation_mm": 1e3 * np.linalg.norm(p_ref - p[~fit], axis=1),
             "rotation_deg": np.rad2deg((r_ref.inv() * rot[~fit]).magnitude())}
    for key, ref in scipy.items():
        ours = summary["heldout_errors"][key]["mean"]
        assert ours < 1.5 * ref.mean(), (key, ours, ref.mean())


def test_cumulative_form_has_continuous_accelerations(tmp_path):
    """--form cumulative: the fitted curve's accelerations do not jump at knots (C2, where
    the De Boor form's do), and the saved module reloads in its form."""
    from torch_dq import nn

    traj = io.read_trajectory(SHIPPED).select(slice(0, 150))
    traj = io.Trajectory(traj.times - traj.times[0], traj.rotations, traj.translations)
    short = _write_tum(tmp_path / "s.txt", traj)  # times from 0: 1e-7 s is resolved
    jumps = {}
    for form in ("de_boor", "cumulative"):
        out = tmp_path / form
        assert main(["fit", str(short), "--form", form, "--knot-spacing", "0.2", "--out",
                     str(out), "--no-plots", "--quiet"]) == 0
        assert json.loads((out / "summary.json").read_text())["model"]["form"] == form
        spline = nn.BSpline.from_state_dict(torch.load(out / "spline.pt"))
        assert spline.form == form
        knots = spline.knots[spline.degree + 1:-spline.degree - 1].double()
        h = 1e-7
        with torch.no_grad():
            after = spline.kinematics(knots + h).linear_acceleration
            before = spline.kinematics(knots - h).linear_acceleration
            scale = float(spline.kinematics(knots).linear_acceleration.norm(dim=-1).max())
        jumps[form] = float((after - before).norm(dim=-1).max()) / scale
    assert jumps["cumulative"] < 1e-5 < jumps["de_boor"], jumps


# ----------------------------------------------------------------------------- --imu

def _imu_motion(t):
    """A motion with closed-form angular velocity and acceleration (scipy rotations):
    R = Rz(a(t)) Ry(b(t)), w = a' z + b' Rz(a) y (world), p and p'' written out."""
    a, da = 0.8 * np.sin(0.9 * t) + 0.3 * t, 0.72 * np.cos(0.9 * t) + 0.3
    b, db = 0.4 * np.sin(1.3 * t), 0.52 * np.cos(1.3 * t)
    Rz = Rotation.from_rotvec(np.outer(a, [0.0, 0.0, 1.0]))
    R = Rz * Rotation.from_rotvec(np.outer(b, [0.0, 1.0, 0.0]))
    w = da[:, None] * np.array([0.0, 0.0, 1.0]) + db[:, None] * Rz.apply([0.0, 1.0, 0.0])
    p = np.stack((np.sin(t), np.cos(0.7 * t), 0.2 * np.sin(2 * t)), -1)
    acc = np.stack((-np.sin(t), -0.49 * np.cos(0.7 * t), -0.8 * np.sin(2 * t)), -1)
    return R, p, w, acc


def _write_imu_case(folder, bg, ba, dt, seed=0, pose_noise=1e-3):
    """Poses at 20 Hz (TUM) and an IMU at 100 Hz whose stamp t reads the motion at t + dt."""
    rng = np.random.default_rng(seed)
    tc = np.arange(0.0, 6.0001, 0.05)
    R, p, _, _ = _imu_motion(tc)
    R = Rotation.from_rotvec(pose_noise * rng.normal(size=(len(tc), 3))) * R
    p = p + pose_noise * rng.normal(size=p.shape)
    np.savetxt(folder / "poses.txt", np.column_stack((tc, p, R.as_quat())), fmt="%.12g")
    ti = np.arange(0.0, 6.0001, 0.01)
    R, _, w, acc = _imu_motion(ti + dt)
    gyro = R.inv().apply(w) + bg + 2e-3 * rng.normal(size=w.shape)
    force = R.inv().apply(acc - np.array([0.0, 0.0, -9.81])) + ba + 2e-2 * rng.normal(
        size=acc.shape)
    np.savetxt(folder / "imu.txt", np.column_stack((ti, gyro, force)), fmt="%.12g",
               header="t gx gy gz ax ay az")


@pytest.mark.parametrize("pose_noise", [1e-3, 0.0])
def test_imu_biases_and_offset_recovered(tmp_path, capsys, pose_noise):
    """With --imu and no --form, the curve is the C2 cumulative form (no C1 warning).
    Noise-free poses make the automatic spacing data-limited (no refinement of the poses
    alone): the IMU fit still runs to convergence."""
    bg, ba, dt = np.array([0.01, -0.02, 0.005]), np.array([0.1, -0.05, 0.2]), 0.01
    _write_imu_case(tmp_path, bg, ba, dt, pose_noise=pose_noise)
    out = tmp_path / "o"
    assert main(["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu.txt"),
                 "--time-offset", "estimate", "--out", str(out), "--no-plots"]) == 0
    stdout = capsys.readouterr().out
    for label in ("gyro bias [rad/s]", "accel bias [m/s^2]", "gravity", "time offset [ms]"):
        assert label in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["model"]["form"] == "cumulative"
    assert not any("cumulative" in w for w in summary["warnings"]), summary["warnings"]
    imu = summary["imu"]
    # the IMU fit runs to convergence even where the automatic spacing gives the poses alone
    # no refinement steps (it once stopped after 1 step with an accel bias 13 std off)
    assert "steps=" not in imu["reason"] and imu["steps"] > 1, (imu["steps"], imu["reason"])
    for key, truth in (("gyro_bias_rad_s", bg), ("accel_bias_m_s2", ba)):
        value, std = np.array(imu[key]["value"]), np.array(imu[key]["std"])
        assert np.all(std > 0) and np.all(np.abs(value - truth) < 5 * std), (key, value, std)
    off = imu["time_offset_s"]
    assert abs(off["value"] - dt) < 5 * off["std"] + 1e-3, off
    g = np.array(imu["gravity_m_s2"]["value"])
    np.testing.assert_allclose(g, [0.0, 0.0, -9.81], atol=0.02)
    # noise levels from the data: right for noisy poses (no rescaling, chi2/dof near 1);
    # noise-free poses leave the pose-only fit's model error in them: one variance step
    ratios = [v["chi2_per_dof"] for v in imu["chi2"].values()]
    if pose_noise:
        assert imu["sigmas"]["rescaled_by"] is None and all(0.5 < r < 2 for r in ratios)
    else:
        assert imu["sigmas"]["rescaled_by"][0] < 0.5, imu["sigmas"]


def test_imu_ends_kept_when_the_offset_is_estimated(tmp_path):
    """--time-offset estimate keeps every IMU sample within the poses' time span: the curve's
    domain reaches the offset's bound beyond the end poses, so that the estimate's domain
    check (times widened by what the offset can reach) accepts them all (0.5 cut 0.1 s of
    samples at each end, 20 of 601 here)."""
    dt = 0.02
    _write_imu_case(tmp_path, np.zeros(3), np.zeros(3), dt)
    out = tmp_path / "o"
    assert main(["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu.txt"),
                 "--time-offset", "estimate", "--holdout", "1", "--out", str(out),
                 "--no-plots", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    imu = summary["imu"]
    t_imu = np.loadtxt(tmp_path / "imu.txt")[:, 0]
    assert (imu["samples"], imu["left_out"]) == (len(t_imu), 0), imu
    lo, hi = summary["model"]["domain_s"]
    assert lo <= -0.1 + 1e-9 and hi >= 6.0 + 0.1 - 1e-9, (lo, hi)
    off = imu["time_offset_s"]
    assert np.isfinite(off["std"]) and abs(off["value"] - dt) < 5 * off["std"] + 1e-3, off


def test_imu_file_errors_are_one_line(tmp_path, capsys):
    _write_imu_case(tmp_path, np.zeros(3), np.zeros(3), 0.0)
    poses = str(tmp_path / "poses.txt")
    bad = tmp_path / "bad.txt"
    bad.write_text("0.0 0 0 0 0 0 9.81\n0.01 0 0 0 0 9.81\n")
    assert main(["fit", poses, "--imu", str(bad), "--out", str(tmp_path / "a"), "--quiet"]) == 2
    assert f"{bad}, line 2: expected 7 columns" in _error_line(capsys)
    late = tmp_path / "late.txt"
    late.write_text("".join(f"{100 + 0.01 * k} 0 0 0 0 0 9.81\n" for k in range(50)))
    assert main(["fit", poses, "--imu", str(late), "--out", str(tmp_path / "b"), "--quiet"]) == 2
    assert "0 IMU samples lie within the poses' time span" in _error_line(capsys)
    assert main(["fit", poses, "--time-offset", "estimate", "--out", str(tmp_path / "c"),
                 "--quiet"]) == 2
    assert "needs an IMU file: pass --imu" in _error_line(capsys)


# ----------------------------------------------------------------------------- new-user trial

def test_gap_in_warnings_and_marked_in_the_csv(tmp_path, capsys):
    """A gap longer than 2 knot spacings: a warning in summary.json (one gap: singular), and
    the rows inside it marked in_gap = 1 (comments before the header row)."""
    import csv

    traj = io.read_trajectory(SHIPPED).select(slice(0, 200))  # 4 s at 50 Hz
    keep = torch.cat((torch.arange(0, 80), torch.arange(130, 200)))  # a 1 s gap
    path = _write_tum(tmp_path / "gap.txt", traj.select(keep))
    out = tmp_path / "o"
    assert main(["fit", str(path), "--format", "TUM", "--knot-spacing", "0.1", "--steps", "1",
                 "--out", str(out), "--no-plots"]) == 0
    stdout = capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    notes = [w for w in summary["warnings"] if "longer than 2 knot spacings" in w]
    assert len(notes) == 1 and notes[0].startswith("1 gap between poses") and "in_gap" in notes[0]
    assert notes[0] in stdout and summary["input"]["gaps_over_2_knot_spacings"] == 1
    lines = (out / "trajectory.csv").read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    assert head == 3 and lines[head].split(",") == [*io.CSV_COLUMNS, "in_gap"]
    assert any("in_gap 1 inside a gap" in line for line in lines[:head])
    # what pandas.read_csv(path, comment="#") does: skip the comment lines, header, rows
    rows = list(csv.reader(line for line in lines if not line.startswith("#")))
    assert rows[0] == [*io.CSV_COLUMNS, "in_gap"] and all(len(r) == len(rows[0]) for r in rows)
    d = _read_csv(out / "trajectory.csv")
    np.testing.assert_array_equal(np.array([float(r[0]) for r in rows[1:]]), d["t"])
    t = traj.times.numpy()
    inside = (d["t"] > t[79]) & (d["t"] < t[130])
    np.testing.assert_array_equal(d["in_gap"], inside.astype(float))
    assert inside.sum() > 40


def test_no_gap_no_warning(tmp_path):
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    out = tmp_path / "o"
    assert main(["fit", str(short), "--out", str(out), "--no-plots", *QUICK]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["warnings"] == [] and summary["input"]["gaps_over_2_knot_spacings"] == 0
    assert not _read_csv(out / "trajectory.csv")["in_gap"].any()


def test_default_rate_is_rounded_to_a_nominal_value(tmp_path):
    """The median rate 50.0000477 Hz of the shipped file resamples at exactly 50 Hz; --rate
    is used as given."""
    from torch_dq.cli.fit_file import _nominal_rate

    assert _nominal_rate(100.00009536752259) == 100.0
    assert _nominal_rate(303.035) == 303.0
    assert _nominal_rate(9.6455) == 9.65 and _nominal_rate(123.4567) == 123.5
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    for rate, expected in ((None, 50.0), ("33.3", 33.3)):
        out = tmp_path / f"o{rate}"
        args = ["fit", str(short), "--out", str(out), "--no-plots", *QUICK]
        assert main(args + (["--rate", rate] if rate else [])) == 0
        summary = json.loads((out / "summary.json").read_text())
        assert summary["resampled"]["rate_hz"] == expected
        t = _read_csv(out / "trajectory.csv")["t"]
        grid = t[0] + np.arange(len(t)) / expected  # 1 ulp at UNIX times: 2.4e-7 s
        np.testing.assert_allclose(t, grid, rtol=0, atol=2.5e-7)  # 50.0000477: 1.1e-6 off


def test_knot_spacing_longer_than_the_duration_is_refused(tmp_path, capsys):
    short = _write_tum(tmp_path / "s.txt", io.read_trajectory(SHIPPED).select(slice(0, 60)))
    line, value, out = _hint_works(capsys, ["fit", str(short), "--knot-spacing", "100", "--out",
                                            str(tmp_path / "o"), "--quiet", "--no-plots",
                                            "--steps", "1"], "--knot-spacing")
    assert "100 s is longer than the 1.180 s that the fitted poses span" in line
    assert float(value) <= 1.18


def test_imu_pose_noise_counts_the_fit_degrees_of_freedom():
    """The pose noise that ``fit --imu`` takes from the pose fit's residuals: a least-squares
    fit with n control points through N noisy poses leaves residuals smaller than the noise
    by sqrt(1 - n / N); the sigma divides by the degrees of freedom left (here n / N = 1/2,
    the plain RMS would read 0.71 of the truth)."""
    from torch_dq import dualquat
    from torch_dq.cli.fit_imu import _pose_sigmas
    from torch_dq.nn import BSpline

    gen = torch.Generator().manual_seed(3)
    t = torch.linspace(0.0, 10.0, 2000, dtype=torch.float64)
    angle = 0.3 * torch.sin(t)
    q = torch.stack((torch.cos(angle / 2), 0 * t, 0 * t, torch.sin(angle / 2)), -1)
    p = torch.stack((torch.sin(t), torch.cos(0.5 * t), 0.1 * t), -1)
    noise = 1e-3
    p_m = p + noise * torch.randn(p.shape, generator=gen, dtype=torch.float64)
    spline = BSpline.from_poses(q, p_m, t, n_ctrl=1000)
    rot, trans = _pose_sigmas(spline, t, dualquat.from_rt(q, p_m))
    assert abs(trans / noise - 1.0) < 0.05
    assert rot < 1e-5  # noise-free rotations stay at their floor

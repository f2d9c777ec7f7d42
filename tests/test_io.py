"""torch_dq.io: trajectory readers and writers against numpy parses and scipy rotations."""

import pathlib
import re
import warnings
from fractions import Fraction

import numpy as np
import pytest
import torch

from torch_dq import io

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation

SHIPPED = pathlib.Path(__file__).resolve().parent / "data" / "tum_fr1_xyz_sub.txt"
T0 = 1403636579.758555  # absolute UNIX seconds, as in the real files


def _known(n=40, seed=0):
    """A smooth known trajectory: times (UNIX s), scipy rotations, translations (m)."""
    rng = np.random.default_rng(seed)
    t = T0 + 0.05 * np.arange(n) + rng.uniform(0, 0.01, n)
    rotvec = np.stack((np.sin(t - T0), 0.5 * np.cos(2 * (t - T0)), 0.3 * (t - T0)), -1)
    p = np.stack((np.cos(t - T0), np.sin(t - T0), 0.1 * (t - T0)), -1) + 100.0
    return t, Rotation.from_rotvec(rotvec), p


def _wxyz(rot):
    return np.roll(rot.as_quat(), 1, axis=-1)


def _same_rotation(q, rot):
    """q (N, 4) wxyz tensor equals the scipy rotations up to sign, and is unit."""
    q = q.numpy()
    ref = _wxyz(rot)
    sign = np.sign((q * ref).sum(-1, keepdims=True))
    np.testing.assert_allclose(q, sign * ref, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-15)


def _write_tum(path, t, rot, p, fmt="%.6f", sep=" ", header=True):
    xyzw = rot.as_quat()
    lines = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"] if header else []
    lines += [sep.join([f"{ti:.6f}"] + [fmt % v for v in (*pi, *qi)])
              for ti, pi, qi in zip(t, p, xyzw, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _write_kitti(path, times_path, t, rot, p):
    Tm = np.concatenate((rot.as_matrix(), p[:, :, None]), axis=2).reshape(-1, 12)
    np.savetxt(path, Tm, fmt="%.12e")
    np.savetxt(times_path, t - T0, fmt="%.6e")


def _write_euroc(path, ns, rot, p, extra=9):
    header = ("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],"
              "q_RS_y [],q_RS_z [],v_RS_R_x [m s^-1],v_RS_R_y [m s^-1],v_RS_R_z [m s^-1],"
              "b_w_RS_S_x [rad s^-1],b_w_RS_S_y [rad s^-1],b_w_RS_S_z [rad s^-1],"
              "b_a_RS_S_x [m s^-2],b_a_RS_S_y [m s^-2],b_a_RS_S_z [m s^-2]")
    header = ",".join(header.split(",")[: 8 + extra])
    q = _wxyz(rot)
    rows = [",".join([str(n)] + [f"{v:.15g}" for v in (*pi, *qi)] + ["0.5"] * extra)
            for n, pi, qi in zip(ns, p, q, strict=True)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


# ----------------------------------------------------------------------------- readers

@pytest.mark.parametrize("sep", [" ", "\t", ","])
def test_tum_matches_numpy_parse(tmp_path, sep):
    t, rot, p = _known()
    path = _write_tum(tmp_path / "gt.txt", t, rot, p, fmt="%.9f", sep=sep)
    ref = np.loadtxt(path, comments="#", delimiter="," if sep == "," else None)
    traj = io.read_trajectory(path, format="tum")
    assert traj.times.dtype == torch.float64 and len(traj) == len(t)
    np.testing.assert_array_equal(traj.times.numpy(), ref[:, 0])  # exact: no float32 on the way
    np.testing.assert_array_equal(traj.translations.numpy(), ref[:, 1:4])
    q = ref[:, [7, 4, 5, 6]]
    np.testing.assert_allclose(traj.rotations.numpy(), q / np.linalg.norm(q, axis=1)[:, None],
                               rtol=0, atol=1e-15)
    _same_rotation(traj.rotations, rot)
    # auto-detection (commas mean EuRoC, so only whitespace-separated TUM is detected)
    if sep != ",":
        auto = io.read_trajectory(path)
        assert torch.equal(auto.times, traj.times)


def test_shipped_subsample_matches_numpy_parse():
    if not SHIPPED.is_file():
        pytest.skip(f"{SHIPPED} not in this checkout")
    ref = np.loadtxt(SHIPPED)
    traj = io.read_trajectory(SHIPPED)
    np.testing.assert_array_equal(traj.times.numpy(), ref[:, 0])
    np.testing.assert_array_equal(traj.translations.numpy(), ref[:, 1:4])
    ref_q = Rotation.from_quat(ref[:, 4:])  # scipy normalizes
    _same_rotation(traj.rotations, ref_q)
    assert np.all(np.diff(traj.times.numpy()) > 0) and traj.times[0] > 1.3e9


def test_kitti_matches_scipy(tmp_path):
    t, rot, p = _known(seed=1)
    poses, times = tmp_path / "00.txt", tmp_path / "times.txt"
    _write_kitti(poses, times, t, rot, p)
    ref_t = np.loadtxt(times)
    ref = np.loadtxt(poses).reshape(-1, 3, 4)
    for traj in (io.read_trajectory(poses, times=times),
                 io.read_trajectory(str(poses), format="kitti", times=str(times)),
                 io.read_trajectory(poses, times=torch.from_numpy(ref_t)),
                 io.read_trajectory(poses, times=list(ref_t))):
        np.testing.assert_array_equal(traj.times.numpy(), ref_t)
        np.testing.assert_array_equal(traj.translations.numpy(), ref[:, :, 3])
        _same_rotation(traj.rotations, Rotation.from_matrix(ref[:, :, :3]))


def test_euroc_matches_numpy_parse(tmp_path):
    t, rot, p = _known(seed=2)
    ns = [1403636579758555392 + 5_000_000 * k + 123 for k in range(len(t))]
    for extra in (9, 0):  # full ground-truth CSV (17 columns) and pose-only (8 columns)
        path = _write_euroc(tmp_path / f"data{extra}.csv", ns, rot, p, extra=extra)
        ref = np.loadtxt(path, delimiter=",", comments="#")
        if extra == 0:  # a header row without the leading '#' is accepted too
            path.write_text(path.read_text()[1:])
        traj = io.read_trajectory(path)  # auto: EuRoC
        # correctly rounded seconds: the float64 nearest to ns / 1e9
        assert traj.times.tolist() == [float(Fraction(n, 10**9)) for n in ns]
        np.testing.assert_array_equal(traj.translations.numpy(), ref[:, 1:4])
        _same_rotation(traj.rotations, Rotation.from_quat(ref[:, [5, 6, 7, 4]]))
        assert torch.equal(io.read_trajectory(path, format="euroc").times, traj.times)


def test_duplicates_first_keeps_the_first_pose(tmp_path):
    t, rot, p = _known(n=6)
    t[3] = t[2]
    path = _write_tum(tmp_path / "dup.txt", t, rot, p)
    traj = io.read_trajectory(path, duplicates="first")
    ref = np.loadtxt(path)
    keep = [0, 1, 2, 4, 5]
    np.testing.assert_array_equal(traj.translations.numpy(), ref[keep, 1:4])
    np.testing.assert_array_equal(traj.times.numpy(), ref[keep, 0])


def test_trajectory_poses_and_select():
    t, rot, p = _known(n=10)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)), torch.from_numpy(p))
    x = traj.poses()
    assert x.shape == (10, 8) and x.dtype == torch.float64
    r, d = x[:, :4].numpy(), x[:, 4:].numpy()
    np.testing.assert_array_equal(r, _wxyz(rot))
    # translation 2 vec(d r*), written out in numpy: equals the file's positions
    rc = r * np.array([1, -1, -1, -1])
    w1, v1, w2, v2 = d[:, :1], d[:, 1:], rc[:, :1], rc[:, 1:]
    np.testing.assert_allclose(2 * (w1 * v2 + w2 * v1 + np.cross(v1, v2)), p, atol=1e-12)
    sub = traj.select(slice(1, None, 3))
    assert len(sub) == 3 and torch.equal(sub.times, traj.times[1::3])
    assert torch.equal(sub.rotations, traj.rotations[1::3])


# ----------------------------------------------------------------------------- writers

@pytest.mark.parametrize("fmt", io.FORMATS)
def test_write_read_round_trip(tmp_path, fmt):
    t, rot, p = _known(n=25, seed=3)
    q = torch.from_numpy(_wxyz(rot))
    traj = io.Trajectory(torch.from_numpy(t), q, torch.from_numpy(p))
    path = tmp_path / f"out.{fmt}"
    times = tmp_path / "times.txt" if fmt == "kitti" else None
    io.write_trajectory(path, traj, format=fmt, times_path=times)
    back = io.read_trajectory(path, format=fmt, times=times)
    assert torch.equal(back.times, traj.times)  # bit-exact, UNIX seconds included
    assert torch.equal(back.translations, traj.translations)
    _same_rotation(back.rotations, rot)
    if fmt != "kitti":  # auto-detection of what we write
        assert torch.equal(io.read_trajectory(path).times, traj.times)


def test_write_csv_columns_and_units(tmp_path):
    t, rot, p = _known(n=12, seed=4)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)), torch.from_numpy(p))
    rng = np.random.default_rng(5)
    names = ("angular_velocity", "linear_velocity", "angular_acceleration",
             "linear_acceleration")
    kin = type("K", (), {n: torch.from_numpy(rng.normal(size=(12, 3))) for n in names})()
    path = tmp_path / "resampled.csv"
    io.write_csv(path, traj, kin, comments=["source: test"])
    text = path.read_text()
    assert text.startswith(",".join(io.CSV_COLUMNS) + "\n# units (SI")
    assert "\n# source: test\n" in text
    for unit in ("[s]", "[m]", "[m/s]", "[rad/s]", "[m/s^2]", "[rad/s^2]"):
        assert unit in text
    data = np.genfromtxt(path, delimiter=",", names=True, comments="#")
    assert data.dtype.names == io.CSV_COLUMNS
    np.testing.assert_allclose(data["t"], t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.stack([data[c] for c in "xyz"], -1), p, rtol=1e-14)
    np.testing.assert_allclose(np.stack([data[c] for c in ("qw", "qx", "qy", "qz")], -1),
                               _wxyz(rot), rtol=1e-14, atol=1e-15)
    for cols, attr in ((("vx", "vy", "vz"), "linear_velocity"),
                       (("wx", "wy", "wz"), "angular_velocity"),
                       (("ax", "ay", "az"), "linear_acceleration"),
                       (("alpha_x", "alpha_y", "alpha_z"), "angular_acceleration")):
        np.testing.assert_allclose(np.stack([data[c] for c in cols], -1),
                                   getattr(kin, attr).numpy(), rtol=1e-14, atol=1e-15)
    # poses only
    io.write_csv(tmp_path / "poses.csv", traj)
    assert np.genfromtxt(tmp_path / "poses.csv", delimiter=",", names=True,
                         comments="#").dtype.names == io.CSV_COLUMNS[:8]


def test_write_csv_extra_columns_and_comments_first(tmp_path):
    """Extra columns after CSV_COLUMNS (bool as 0/1, floats at 15 digits), their notes on
    the units line, and the comment block first with its own count: the file reads back
    with numpy (skip_header=count) and with a plain line parser (pandas' comment='#')."""
    t, rot, p = _known(n=9, seed=6)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)), torch.from_numpy(p))
    flag = torch.tensor([0, 1, 1, 0, 0, 0, 1, 0, 0], dtype=torch.bool)
    score = np.linspace(-1.0, 1.0, 9) / 3.0
    path = tmp_path / "extra.csv"
    io.write_csv(path, traj, None, ["source: test", "second"], comments_first=True,
                 extra_columns={"in_gap": (flag, "in_gap 1 inside a gap"),
                                "score": (score, "score [1]")})
    lines = path.read_text().splitlines()
    assert lines[0] == ("# 4 comment lines, then the header row: read with "
                        "pandas.read_csv(path, comment='#') or numpy.genfromtxt(path, "
                        "delimiter=',', names=True, skip_header=4)")
    assert lines[1].startswith("# units (SI") and lines[1].endswith(
        "(body to world); in_gap 1 inside a gap; score [1]")
    assert lines[2:4] == ["# source: test", "# second"]
    assert lines[4] == ",".join([*io.CSV_COLUMNS[:8], "in_gap", "score"])
    rows = [line.split(",") for line in lines[5:]]
    assert len(rows) == 9 and [r[8] for r in rows] == [str(int(v)) for v in flag.tolist()]
    data = np.genfromtxt(path, delimiter=",", names=True, skip_header=4)
    np.testing.assert_array_equal(data["in_gap"], flag.numpy().astype(float))
    np.testing.assert_allclose(data["score"], score, rtol=1e-14, atol=0)
    np.testing.assert_allclose(data["t"], t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.stack([data[c] for c in "xyz"], -1), p, rtol=1e-14)
    # the default layout keeps the header first, with the notes on the units line
    io.write_csv(path, traj, extra_columns={"in_gap": (flag, "in_gap note")})
    header, units = path.read_text().splitlines()[:2]
    assert header == ",".join([*io.CSV_COLUMNS[:8], "in_gap"]) and units.endswith("; in_gap note")
    for bad, kind, match in (({"x": (flag, "n")}, ValueError, "new identifier"),
                             ({"a b": (flag, "n")}, ValueError, "new identifier"),
                             ({"g": (flag[:3], "n")}, ValueError, r"expected \(9,\) values"),
                             ({"g": flag}, TypeError, r"pair \(values, note: str\)"),
                             ({"g": ([0] * 9, "n")}, TypeError, "tensor or a numpy array"),
                             ([("g", (flag, "n"))], TypeError, "must be a mapping")):
        with pytest.raises(kind, match=match):
            io.write_csv(path, traj, extra_columns=bad)
    with pytest.raises(TypeError, match="comments_first to be a bool"):
        io.write_csv(path, traj, comments_first="yes")
    with pytest.raises(TypeError, match="comments must be a sequence of str"):
        io.write_csv(path, traj, comments="one line")


def test_writer_argument_errors(tmp_path):
    t, rot, p = _known(n=3)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)), torch.from_numpy(p))
    with pytest.raises(ValueError, match=r"io\.write_trajectory: format"):
        io.write_trajectory(tmp_path / "x", traj, format="ply")
    with pytest.raises(ValueError, match="times_path is required"):
        io.write_trajectory(tmp_path / "x", traj, format="kitti")
    with pytest.raises(TypeError, match="expected a Trajectory"):
        io.write_trajectory(tmp_path / "x", (t, rot, p))
    with pytest.raises(ValueError, match=r"rotations \(N, 4\)"):  # refused on construction
        io.Trajectory(traj.times, traj.rotations[:2], traj.translations)
    kin = type("K", (), {"linear_velocity": torch.zeros(3, 3), "angular_velocity": None})()
    with pytest.raises(ValueError, match="no angular_velocity"):
        io.write_csv(tmp_path / "x.csv", traj, kin)


# ----------------------------------------------------------------------------- malformed files

GOOD = "1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986"
GOOD2 = "1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980"
GOOD3 = "1305031098.6858 1.3523 0.6307 1.6340 0.6129 0.5966 -0.3316 -0.3980"

# (name, file text, expected line, message pattern)
MALFORMED = [
    ("columns", f"# header\n{GOOD}\n{GOOD2[:-8]}\n", 3, r"expected 8 columns .*got 7"),
    ("extra_column", f"{GOOD} 1.0\n", 1, r"expected 8 columns .*got 9"),
    ("non_numeric", f"{GOOD}\n{GOOD2.replace('1.3543', '1.35a3')}\n", 2,
     r"tx: '1\.35a3' is not a number"),
    ("nan", f"{GOOD}\n{GOOD2.replace('0.6306', 'nan')}\n", 2, r"non-finite value"),
    ("inf", f"{GOOD.replace('1.6380', '-inf')}\n", 1, r"non-finite value"),
    ("unsorted", f"{GOOD2}\n{GOOD}\n", 2, r"before the previous one .*line 1.*sorted"),
    ("duplicate", f"{GOOD}\n\n{GOOD.replace('1.3563', '1.3564')}\n", 3,
     r"duplicate timestamp 1305031098\.6659 s \(also on line 1\)"),
    ("non_unit", f"{GOOD}\n{GOOD2}\n{GOOD3.replace('0.6129', '0.9129')}\n", 3,
     r"quaternion norm 1\.2073\d* is not 1"),
    ("zero_quaternion", f"{GOOD}\n1305031099 0 0 0 0 0 0 0\n", 2, r"quaternion norm 0 is not 1"),
]


@pytest.mark.parametrize("name,text,line,pattern", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_tum_names_file_and_line(tmp_path, name, text, line, pattern):
    path = tmp_path / f"{name}.txt"
    path.write_text(text)
    with pytest.raises(io.TrajectoryFileError) as info:
        io.read_trajectory(path, format="tum")
    message = str(info.value)
    assert message.startswith(f"{path}, line {line}: "), message
    assert re.search(pattern, message), message
    assert info.value.line == line and info.value.path == str(path)
    assert isinstance(info.value, ValueError)


def test_bad_lines_are_counted(tmp_path):
    path = tmp_path / "many.txt"
    rows = [GOOD, GOOD2.replace("-0.3980", "0.5"), GOOD3.replace("-0.3980", "0.5")]
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: .*\(2 lines in all\)"):
        io.read_trajectory(path)


def test_atol_controls_the_unit_norm_check(tmp_path):
    path = tmp_path / "rounded.txt"
    path.write_text(f"{GOOD}\n{GOOD2.replace('-0.3980', '-0.3930')}\n")  # norm 0.997
    with pytest.raises(io.TrajectoryFileError, match=r"norm 0\.99\d+ is not 1 .*atol=0\.001"):
        io.read_trajectory(path)
    traj = io.read_trajectory(path, atol=1e-2)
    np.testing.assert_allclose(traj.rotations.norm(dim=-1).numpy(), 1.0, atol=1e-15)


@pytest.mark.parametrize("text", ["", "\n\n", "# only\n# comments\n"])
def test_empty_file(tmp_path, text):
    path = tmp_path / "empty.txt"
    path.write_text(text)
    for fmt in ("auto", "tum", "euroc"):
        with pytest.raises(io.TrajectoryFileError, match=r"empty.txt: no data \(the file is "
                                                         r"empty"):
            io.read_trajectory(path, format=fmt)


def test_binary_file(tmp_path):
    path = tmp_path / "bin.txt"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    with pytest.raises(io.TrajectoryFileError, match="not a UTF-8 text file"):
        io.read_trajectory(path)


def test_undetectable_format(tmp_path):
    path = tmp_path / "five.txt"
    path.write_text("# comment\n1 2 3 4 5\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: cannot tell the format: 5 "):
        io.read_trajectory(path)


def test_malformed_kitti(tmp_path):
    t, rot, p = _known(n=5, seed=6)
    poses, times = tmp_path / "00.txt", tmp_path / "times.txt"
    _write_kitti(poses, times, t, rot, p)
    rows = poses.read_text().splitlines()
    bad = tmp_path / "bad.txt"

    bad.write_text("\n".join([*rows[:2], " ".join(rows[2].split()[:11]), *rows[3:]]) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"bad.txt, line 3: expected 12 columns"):
        io.read_trajectory(bad, format="kitti", times=times)

    scaled = np.loadtxt(poses)
    scaled[1, [0, 5, 10]] *= 1.01  # not orthonormal
    np.savetxt(bad, scaled)
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: rotation is not orthonormal: "
                                                     r"max \|R\^T R - I\| = 0\.02"):
        io.read_trajectory(bad, times=times)

    mirrored = np.loadtxt(poses)
    mirrored[3, [2, 6, 10]] *= -1  # third column flipped: det -1
    np.savetxt(bad, mirrored)
    with pytest.raises(io.TrajectoryFileError, match=r"line 4: rotation matrix has determinant"):
        io.read_trajectory(bad, times=times)

    with pytest.raises(ValueError, match=r"io.read_trajectory: KITTI poses .* carry no times"):
        io.read_trajectory(poses)
    short = tmp_path / "short_times.txt"
    short.write_text("0.0\n0.1\n")
    with pytest.raises(io.TrajectoryFileError, match=r"short_times.txt: holds 2 times but the "
                                                     r"poses file .* has 5"):
        io.read_trajectory(poses, times=short)
    unsorted = tmp_path / "unsorted_times.txt"
    unsorted.write_text("0.0\n0.1\n0.3\n0.2\n0.4\n")
    with pytest.raises(io.TrajectoryFileError, match=r"unsorted_times.txt, line 4: timestamp "
                                                     r"0.2 s is before"):
        io.read_trajectory(poses, times=unsorted)
    with pytest.raises(ValueError, match=r"times must have shape \(5,\)"):
        io.read_trajectory(poses, times=np.zeros(4))
    with pytest.raises(ValueError, match=r"times must be finite"):
        io.read_trajectory(poses, times=[0, 1, 2, 3, float("nan")])


def test_malformed_euroc(tmp_path):
    _t, rot, p = _known(n=5, seed=7)
    ns = [1403636579758555392 + 5_000_000 * k for k in range(5)]
    good = _write_euroc(tmp_path / "data.csv", ns, rot, p)
    lines = good.read_text().splitlines()
    bad = tmp_path / "bad.csv"

    bad.write_text("\n".join([*lines[:3], lines[3].rsplit(",", 1)[0], *lines[4:]]) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 4: expected 17 comma-separated "
                                                     r"columns .*got 16"):
        io.read_trajectory(bad)

    seconds = lines[2].replace(str(ns[1]), "1403636579.76")
    bad.write_text("\n".join([lines[1], seconds, *lines[3:]]) + "\n")  # no '[ns]' header
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: timestamp '1403636579.76' is "
                                                     r"not an integer number of nanoseconds; a "
                                                     r"TUM file with commas\? pass format='tum'"):
        io.read_trajectory(bad)
    bad.write_text(lines[0][1:] + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"bad.csv: no data \(the file holds only a "
                                                     r"header\)"):
        io.read_trajectory(bad, format="euroc")

    swapped = [*lines[:2], lines[3], lines[2], *lines[4:]]
    bad.write_text("\n".join(swapped) + "\n")
    with pytest.raises(io.TrajectoryFileError,
                       match=rf"line 4: timestamp {ns[1]} ns is before the previous one "
                             rf"\({ns[2]} ns, line 3\)"):
        io.read_trajectory(bad)

    dup = [*lines[:3], lines[3].replace(str(ns[2]), str(ns[1])), *lines[4:]]
    bad.write_text("\n".join(dup) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=rf"line 4: duplicate timestamp {ns[1]} ns"):
        io.read_trajectory(bad)
    assert len(io.read_trajectory(bad, duplicates="first")) == 4

    fields = lines[5].split(",")
    fields[4] = "2.0"  # q_RS_w
    bad.write_text("\n".join([*lines[:5], ",".join(fields)]) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 6: quaternion norm 2\.\d+ is not 1"):
        io.read_trajectory(bad)

    fields = lines[2].split(",")
    fields[2] = "x"
    bad.write_text("\n".join([*lines[:2], ",".join(fields), *lines[3:]]) + "\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 3: p_RS_R_y \[m\]: 'x' is not a "
                                                     r"number"):
        io.read_trajectory(bad)


def test_argument_errors(tmp_path):
    path = tmp_path / "gt.txt"
    path.write_text(f"{GOOD}\n{GOOD2}\n")
    with pytest.raises(ValueError, match=r"io.read_trajectory: format must be one of"):
        io.read_trajectory(path, format="ply")
    with pytest.raises(ValueError, match=r"times= applies to KITTI files only"):
        io.read_trajectory(path, times=[0.0, 1.0])
    with pytest.raises(ValueError, match=r"atol must be a finite number > 0"):
        io.read_trajectory(path, atol=0)
    with pytest.raises(ValueError, match=r"duplicates must be 'error' or 'first'"):
        io.read_trajectory(path, duplicates="last")
    with pytest.raises(TypeError, match=r"expected a path"):
        io.read_trajectory(3)
    with pytest.raises(FileNotFoundError):
        io.read_trajectory(tmp_path / "missing.txt")


# ----------------------------------------------------------------------------- issue 22 files

def test_underscore_in_a_number_is_rejected(tmp_path):
    """Python's float reads '1_0' as 10.0; a trajectory file must not."""
    path = tmp_path / "under.txt"
    path.write_text(f"{GOOD}\n{GOOD2.replace('1.3543', '1_0')}\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: tx: '1_0' is not a number"):
        io.read_trajectory(path)
    kitti, times = tmp_path / "00.txt", tmp_path / "t.txt"
    kitti.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n")
    times.write_text("0.0\n1_0\n")
    with pytest.raises(io.TrajectoryFileError, match=r"t.txt, line 2: time: '1_0' is not"):
        io.read_trajectory(kitti, times=times)
    euroc = tmp_path / "data.csv"
    euroc.write_text("#timestamp [ns],x,y,z,qw,qx,qy,qz\n1_000,0,0,0,1,0,0,0\n")
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: timestamp '1_000' is not an "
                                                     r"integer"):
        io.read_trajectory(euroc)


def test_utf8_bom_is_accepted(tmp_path):
    path = tmp_path / "bom.txt"
    path.write_bytes(b"\xef\xbb\xbf" + f"{GOOD}\n{GOOD2}\n".encode())
    traj = io.read_trajectory(path)
    np.testing.assert_array_equal(traj.times.numpy(), [1305031098.6659, 1305031098.6758])


@pytest.mark.parametrize("fmt", io.FORMATS)
@pytest.mark.parametrize("times", ["linspace", "tiny", "negative"])
def test_round_trip_exact_for_times_of_any_scale(tmp_path, fmt, times):
    """write_trajectory's exact float64 round trip, not only at UNIX scale."""
    t = {"linspace": np.linspace(0.0, 1.0, 7), "tiny": 1e-12 * np.arange(1.0, 8.0) / 3.0,
         "negative": np.linspace(-2.0, 1.0, 7) / 3.0}[times]
    _, rot, p = _known(n=7, seed=8)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)),
                         torch.from_numpy(p / 7.0))
    path = tmp_path / f"out.{fmt}"
    times_path = tmp_path / "times.txt" if fmt == "kitti" else None
    io.write_trajectory(path, traj, format=fmt, times_path=times_path)
    with warnings.catch_warnings(record=True) as said:  # EuRoC: 3e-13 s apart as ns
        warnings.simplefilter("always")
        back = io.read_trajectory(path, format=fmt, times=times_path)
        if fmt != "kitti":
            assert io.read_trajectory(path).times.tolist() == t.tolist()  # auto-detected
    assert [str(w.message).split(": ")[-2] for w in said] == (
        ["the times look like seconds, not nanoseconds"] * 2 if (fmt, times) == ("euroc", "tiny")
        else [])
    assert back.times.tolist() == t.tolist()  # bit-exact
    assert back.translations.tolist() == (p / 7.0).tolist()


def test_euroc_nanoseconds_written_as_integers_at_unix_scale(tmp_path):
    t, rot, p = _known(n=5, seed=9)
    traj = io.Trajectory(torch.from_numpy(t), torch.from_numpy(_wxyz(rot)), torch.from_numpy(p))
    path = tmp_path / "data.csv"
    io.write_trajectory(path, traj, format="euroc")
    stamps = [row.split(",")[0] for row in path.read_text().splitlines()[1:]]
    assert all(s.isdigit() for s in stamps)
    assert [float(Fraction(int(s), 10**9)) for s in stamps] == t.tolist()


@pytest.mark.parametrize("sep", [",", ", "])
def test_tum_header_with_commas_is_tum(tmp_path, sep):
    t, rot, p = _known(n=6, seed=10)
    path = _write_tum(tmp_path / "gt.txt", t, rot, p, fmt="%.9f", sep=sep, header=False)
    names = sep.join(("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw"))
    path.write_text(f"# {names}\n" + path.read_text())
    traj = io.read_trajectory(path)  # auto
    ref = np.loadtxt(path, delimiter=",")
    np.testing.assert_array_equal(traj.times.numpy(), ref[:, 0])
    np.testing.assert_array_equal(traj.translations.numpy(), ref[:, 1:4])
    # without any header, 8 comma-separated fields with decimal seconds are TUM too
    path.write_text("\n".join(path.read_text().splitlines()[1:]) + "\n")
    np.testing.assert_array_equal(io.read_trajectory(path).times.numpy(), ref[:, 0])


@pytest.mark.parametrize("kind", ["torch", "numpy"])
def test_float32_kitti_times_say_why_they_repeat(tmp_path, kind):
    t, rot, p = _known(n=6, seed=11)
    poses, times = tmp_path / "00.txt", tmp_path / "times.txt"
    _write_kitti(poses, times, t, rot, p)
    t32 = torch.from_numpy(t).float() if kind == "torch" else t.astype(np.float32)
    with pytest.raises(io.TrajectoryFileError, match=r"duplicate timestamp .*came as float32, "
                                                     r"which rounds them to steps of 1\d\d s: "
                                                     r"pass them as float64"):
        io.read_trajectory(poses, times=t32)
    # float64 times with a real duplicate: no float32 hint
    t64 = t.copy()
    t64[2] = t64[1]
    with pytest.raises(io.TrajectoryFileError) as info:
        io.read_trajectory(poses, times=t64)
    assert "float32" not in str(info.value) and "duplicate timestamp" in str(info.value)


# ----------------------------------------------------------------------------- IMU

def _imu_data(n=20, seed=12):
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, 3)), 9.81 + rng.normal(size=(n, 3))


def test_read_imu_euroc(tmp_path):
    gyro, accel = _imu_data()
    ns = [1403636579758555392 + 5_000_000 * k + 7 for k in range(len(gyro))]
    header = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
              "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
    rows = [",".join([str(n)] + [repr(float(v)) for v in (*g, *a)])
            for n, g, a in zip(ns, gyro, accel, strict=True)]
    path = tmp_path / "data.csv"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    t, g, a = io.read_imu(path)
    assert t.dtype == g.dtype == a.dtype == torch.float64
    assert g.shape == a.shape == (len(ns), 3)
    assert t.tolist() == [float(Fraction(n, 10**9)) for n in ns]  # correctly rounded
    ref = np.loadtxt(path, delimiter=",", comments="#")
    np.testing.assert_array_equal(g.numpy(), ref[:, 1:4])
    np.testing.assert_array_equal(a.numpy(), ref[:, 4:7])
    # no header: 19-digit integers are nanoseconds too
    path.write_text("\n".join(rows) + "\n")
    assert io.read_imu(path)[0].tolist() == t.tolist()


@pytest.mark.parametrize("sep", [" ", ","])
def test_read_imu_plain_seconds(tmp_path, sep):
    gyro, accel = _imu_data(seed=13)
    t = 12.5 + 0.005 * np.arange(len(gyro))
    rows = [sep.join(repr(float(v)) for v in (ti, *g, *a))
            for ti, g, a in zip(t, gyro, accel, strict=True)]
    path = tmp_path / "imu.txt"
    path.write_text("# t gx gy gz ax ay az\n" + "\n".join(rows) + "\n")
    times, g, a = io.read_imu(path)
    assert times.tolist() == t.tolist()
    np.testing.assert_array_equal(g.numpy(), gyro)
    np.testing.assert_array_equal(a.numpy(), accel)
    with pytest.raises(io.TrajectoryFileError, match=r"line 2: timestamp '12.5' is not an "
                                                     r"integer number of nanoseconds"):
        io.read_imu(path, time_unit="ns")


def test_read_imu_malformed(tmp_path):
    good = "0.0 0.1 0.2 0.3 0.0 0.0 9.81"
    cases = [
        ("columns", f"{good}\n0.005 0.1 0.2 0.3 0.0 9.81\n", r"line 2: expected 7 columns "
                                                              r"\(t, gx, .*got 6"),
        ("number", f"{good}\n0.005 0.1 x 0.3 0.0 0.0 9.81\n", r"line 2: gy: 'x' is not a number"),
        ("underscore", f"{good}\n0.005 0.1 0.2 0.3 0.0 0.0 9_81\n", r"line 2: az: '9_81'"),
        ("nan", f"{good}\n0.005 nan 0.2 0.3 0.0 0.0 9.81\n", r"line 2: non-finite value"),
        ("unsorted", f"0.01 0 0 0 0 0 0\n{good}\n", r"line 2: timestamp 0\.0 s is before"),
        ("duplicate", f"{good}\n{good}\n", r"line 2: duplicate timestamp 0\.0 s"),
        ("empty", "# t gx gy gz ax ay az\n", r"imu.txt: no data"),
    ]
    path = tmp_path / "imu.txt"
    for name, text, pattern in cases:
        path.write_text(text)
        with pytest.raises(io.TrajectoryFileError, match=pattern) as info:
            io.read_imu(path)
        assert str(info.value).startswith(str(path)), name
    path.write_text(f"{good}\n{good}\n")
    assert len(io.read_imu(path, duplicates="first")[0]) == 1
    with pytest.raises(ValueError, match=r"io.read_imu: time_unit must be"):
        io.read_imu(path, time_unit="ms")
    with pytest.raises(ValueError, match=r"io.read_imu: duplicates must be"):
        io.read_imu(path, duplicates="last")
    with pytest.raises(TypeError, match=r"io.read_imu: expected a path"):
        io.read_imu(3)

"""A new user's files (0.5.0 trial): quaternion orders named by a header, files that the
writer must refuse (its reader would), an IMU in g or with its columns swapped, and the
``calibrate`` command without PyYAML. Each test failed before its fix."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torch_dq import io
from torch_dq.cli import main


def _poses(n=40, seed=0):
    """Times in UNIX seconds, scipy rotations and translations of a smooth random motion."""
    rng = np.random.default_rng(seed)
    t = 1305031098.6659 + 0.01 * np.arange(n)
    rot = Rotation.from_rotvec(np.cumsum(0.05 * rng.normal(size=(n, 3)), axis=0))
    return t, rot, np.cumsum(0.01 * rng.normal(size=(n, 3)), axis=0)


@pytest.mark.parametrize("header", ["# timestamp tx ty tz qw qx qy qz",
                                    "# t x y z q_w q_x q_y q_z",
                                    "timestamp,tx,ty,tz,qw,qx,qy,qz",
                                    "timestamp tx ty tz w x y z"])
def test_header_naming_w_first_is_followed(tmp_path, header):
    """A header that names the quaternion columns w first was ignored: the rows were read as
    TUM's x y z w, every rotation another one, without a word."""
    t, rot, p = _poses()
    sep = "," if "," in header else " "
    rows = [sep.join(repr(float(v)) for v in (ti, *pi, *qi))
            for ti, pi, qi in zip(t, p, rot.as_quat(scalar_first=True), strict=True)]
    path = tmp_path / "wfirst.txt"
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    traj = io.read_trajectory(path)
    angle = (Rotation.from_quat(traj.rotations.numpy(), scalar_first=True) * rot.inv()
             ).magnitude()
    assert angle.max() < 1e-12
    np.testing.assert_array_equal(traj.translations.numpy(), p)
    assert traj.times.tolist() == t.tolist()


def test_tum_header_keeps_tum_order_and_a_first_nan_row_is_data(tmp_path):
    """TUM's own header reads x y z w as before; a first row ``nan ...`` is a bad row, not a
    header row to drop (``read_imu`` dropped it silently)."""
    t, rot, p = _poses(seed=1)
    rows = [" ".join(repr(float(v)) for v in (ti, *pi, *qi))
            for ti, pi, qi in zip(t, p, rot.as_quat(), strict=True)]
    path = tmp_path / "gt.txt"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows) + "\n")
    angle = (Rotation.from_quat(io.read_trajectory(path).rotations.numpy(), scalar_first=True)
             * rot.inv()).magnitude()
    assert angle.max() < 1e-12
    imu = tmp_path / "imu.txt"
    imu.write_text("nan 0 0 0 0 0 9.81\n" + "".join(f"{0.01 * k} 0 0 0 0 0 9.81\n"
                                                    for k in range(1, 10)))
    with pytest.raises(io.TrajectoryFileError, match=r"imu.txt, line 1: non-finite value"):
        io.read_imu(imu)


def _trajectory(t, q, p):
    return io.Trajectory(torch.as_tensor(t), torch.as_tensor(q), torch.as_tensor(p))


def test_write_trajectory_refuses_what_read_trajectory_rejects(tmp_path):
    """write_trajectory wrote NaN, unsorted or repeated times, non-unit quaternions and
    float32 UNIX seconds (rounded to 128 s steps), which read_trajectory then rejects (or
    reads as other poses); and a KITTI times file over the poses file."""
    t, rot, p = _poses(seed=2)
    q = rot.as_quat(scalar_first=True)
    nan_p = p.copy()
    nan_p[3, 1] = np.nan
    cases = [(_trajectory(t, q, nan_p), r"pose 3 .*translations must be finite"),
             (_trajectory(t, 2 * q, p), r"pose 0 \(of 40 bad\).*norm 2"),
             (_trajectory(t[::-1].copy(), q, p), r"times must increase strictly: times\[1\]"),
             (_trajectory(np.r_[t[:1], t[:-1]], q, p), r"times\[1\] = .* follows times\[0\]"),
             (_trajectory(np.r_[np.nan, t[1:]], q, p), r"times\[0\] is nan"),
             (io.Trajectory(torch.as_tensor(t).float(), torch.as_tensor(q).float(),
                            torch.as_tensor(p).float()), r"came as float32.*pass them as "
                                                         r"float64")]
    for k, (traj, message) in enumerate(cases):
        path = tmp_path / f"bad{k}.txt"
        with pytest.raises(ValueError, match=r"io.write_trajectory: .*" + message):
            io.write_trajectory(path, traj)
        assert not path.exists()
    good = _trajectory(t, q, p)
    with pytest.raises(ValueError, match=r"times_path and path are the same file"):
        io.write_trajectory(tmp_path / "k.txt", good, "kitti", times_path=tmp_path / "./k.txt")
    assert not (tmp_path / "k.txt").exists()
    with pytest.raises(ValueError, match=r"io.write_csv: trajectory.times must increase"):
        io.write_csv(tmp_path / "r.csv", _trajectory(t[::-1].copy(), q, p))
    io.write_trajectory(tmp_path / "ok.txt", good)  # float32 seconds from 0 are fine too
    io.write_trajectory(tmp_path / "ok32.txt", io.Trajectory(
        torch.as_tensor(t - t[0]).float(), torch.as_tensor(q).float(),
        torch.as_tensor(p).float()))
    back = io.read_trajectory(tmp_path / "ok.txt")
    assert back.times.tolist() == t.tolist()


def _write_imu(path, gyro, accel):
    t = 12.5 + 0.005 * np.arange(len(gyro))
    np.savetxt(path, np.column_stack((t, gyro, accel)), fmt="%.12g",
               header="t gx gy gz ax ay az")


def test_read_imu_names_g_and_swapped_columns(tmp_path):
    """An accelerometer in g and gyroscope/accelerometer columns swapped passed without a
    word (the fit then ran 50 steps to garbage biases)."""
    rng = np.random.default_rng(3)
    gyro = 0.3 * rng.normal(size=(400, 3))
    accel = np.array([0.5, -1.0, 9.7]) + 0.5 * rng.normal(size=(400, 3))  # m/s^2
    _write_imu(tmp_path / "ok.txt", gyro, accel)
    io.read_imu(tmp_path / "ok.txt")  # no warning (pytest makes it an error)
    _write_imu(tmp_path / "g.txt", gyro, accel / 9.80665)
    with pytest.warns(UserWarning, match=r"io.read_imu: .*g.txt: the accelerometer readings "
                                         r"look like g .*multiply them by 9.80665"):
        io.read_imu(tmp_path / "g.txt")
    _write_imu(tmp_path / "swap.txt", accel, gyro)
    with pytest.warns(UserWarning, match=r"swap.txt: the gyroscope and accelerometer "
                                         r"columns look swapped"):
        io.read_imu(tmp_path / "swap.txt")


def test_calibrate_without_pyyaml_is_one_line(tmp_path, capsys, monkeypatch):
    """Without PyYAML (a plain ``pip install torch_dq``), ``calibrate`` ended in a
    traceback and exit status 1, not one line naming the extra to install."""
    for name in ("target.yaml", "imu.csv", "imu.yaml", "camchain.yaml", "c0.csv"):
        (tmp_path / name).write_text("x\n")
    monkeypatch.setitem(sys.modules, "yaml", None)  # import yaml raises ImportError
    args = ["calibrate", "--target", "target.yaml", "--imu", "imu.csv", "--imu-noise",
            "imu.yaml", "--cameras", "camchain.yaml", "--corners", "c0.csv", "--out", "out"]
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("torch-dq calibrate: error: ")
    assert "needs PyYAML: pip install torch_dq[calib]" in err[0]


@pytest.mark.parametrize("value", ["inf", "nan", "0", "-1"])
def test_calibrate_pixel_sigma_is_a_finite_positive_number(capsys, value):
    """``--pixel-sigma inf`` passed the parser: the cameras were calibrated first, then
    ``calibration.camera_imu`` refused ``pixel_sigma`` (not the option's name)."""
    args = ["calibrate", "--target", "t.yaml", "--imu", "i.csv", "--imu-noise", "n.yaml",
            "--cameras", "c.yaml", "--corners", "c0.csv", "--out", "out", "--pixel-sigma",
            value]
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    assert (f"argument --pixel-sigma: expected a finite number > 0, got {value}"
            in capsys.readouterr().err)

"""Times and rates in other units than seconds and rad/s never pass silently (honest8): the
terms refuse nanosecond UNIX stamps and warn on relative nanoseconds, naming the argument and
the unit; ``python -m torch_dq fit`` converts a trajectory file's nanoseconds to seconds
(and says so), its outputs in SI units as from the same file in seconds; a gyroscope in
deg/s is refused by the one check of the Gyro term."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.__main__ import main
from torch_dq.fitting import Accel, Gyro, Poses, Positions, estimate
from torch_dq.nn import BSpline

F64 = torch.float64


def _motion(t):
    R = Rotation.from_euler("zy", np.stack((0.8 * t, 0.5 * np.sin(t)), -1))
    p = np.stack((0.6 * t, np.sin(2 * t), 0.5 * np.cos(t)), -1)
    return R, p


def _poses(t):
    R, p = _motion(t)
    return dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p))


@pytest.mark.parametrize("unit,scale", [("nanoseconds", 1e9), ("microseconds", 1e6),
                                        ("milliseconds", 1e3)])
def test_unix_stamps_in_finer_units_are_refused(unit, scale):
    """EuRoC-style UNIX stamps (1.4e18 ns, 1.4e15 us, 1.4e12 ms) fail in every term's
    constructor, naming the argument and the unit; UNIX seconds (1.4e9) are accepted."""
    t = 1.4e9 + np.arange(0, 2, 0.05)
    x, y = _poses(t - t[0]), torch.zeros(len(t), 3, dtype=F64)
    for make in (lambda s: Poses(s, x, rot_sigma=0.01, trans_sigma=0.01),
                 lambda s: Positions(s, y, sigma=0.01),
                 lambda s: Gyro(s, y, sigma=0.01), lambda s: Accel(s, y, sigma=0.1)):
        make(torch.from_numpy(t))  # seconds: fine
        with pytest.raises(ValueError, match=rf"times look like {unit}, not seconds.*"
                                             rf"times \* {1 / scale:g}"):
            make(torch.from_numpy(t * scale))


def test_relative_nanoseconds_warn():
    """A 200 Hz IMU stamped in nanoseconds from 0 (steps of 5e6): the IMU terms warn naming
    times and nanoseconds (200 Hz); poses 20 Hz apart in ns warn as well (5e7 s steps)."""
    ti = np.arange(0, 2, 0.005) * 1e9
    y = torch.zeros(len(ti), 3, dtype=F64)
    for make in (lambda: Gyro(torch.from_numpy(ti), y, sigma=0.01),
                 lambda: Accel(torch.from_numpy(ti), y, sigma=0.1)):
        with pytest.warns(UserWarning, match=r"times look like nanoseconds.*200 Hz"):
            make()
    tc = np.arange(0, 2, 0.05)
    with pytest.warns(UserWarning, match=r"times look like nanoseconds.*20 Hz"):
        Poses(torch.from_numpy(tc * 1e9), _poses(tc), rot_sigma=0.01, trans_sigma=0.01)


def test_gyro_in_degrees_per_second_warns_at_estimate():
    """Readings in deg/s: ``estimate`` warns naming deg/s (the Gyro term's check)."""
    t, ti = np.linspace(0, 4, 41), np.linspace(0.1, 3.9, 191)
    x = _poses(t)
    R = _motion(ti)[0]
    w = R.as_rotvec()  # any rates: the check compares magnitudes with the trajectory's
    spline = BSpline.from_dualquats(x, torch.from_numpy(t), n_ctrl=23, form="cumulative")
    with torch.no_grad():
        rate = spline.kinematics(torch.from_numpy(ti)).angular_velocity
    body = torch.from_numpy(R.inv().apply(rate.numpy()))
    gyro = Gyro(torch.from_numpy(ti), torch.rad2deg(body), sigma=0.01)
    del w
    with pytest.warns(UserWarning, match=r"fitting\.Gyro: the readings look like deg/s"):
        estimate(spline, [Poses(torch.from_numpy(t), x, rot_sigma=0.01, trans_sigma=0.01),
                          gyro], steps=0, verbose=False)


def _tum(path, t, R, p):
    with open(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for ti, pi, qi in zip(t, p, R.as_quat(), strict=True):
            f.write(f"{ti} " + " ".join(f"{v:.9f}" for v in (*pi, *qi)) + "\n")


def test_fit_cli_converts_nanosecond_stamps(tmp_path, capsys):
    """A TUM file with integer UNIX nanoseconds: the fit converts them to seconds, says so on
    stdout and in summary.json, and its trajectory.csv (times, velocities) equals that of
    the same file in seconds, to the stamps' float64 rounding."""
    t = np.arange(0, 6, 0.05)
    R, p = _motion(t)
    stamps = [1_400_000_000_000_000_000 + round(v * 1e9) for v in t]
    _tum(tmp_path / "ns.txt", stamps, R, p)
    _tum(tmp_path / "s.txt", [f"{1.4e9 + v:.9f}" for v in t], R, p)
    for name in ("ns", "s"):
        argv = ["fit", str(tmp_path / f"{name}.txt"), "--out", str(tmp_path / name),
                "--no-plots", "--steps", "2"]
        assert main(argv) == 0
    out = capsys.readouterr().out
    assert re.search(r"times .*nanoseconds.*converted to seconds", out), out
    summary = json.loads((tmp_path / "ns" / "summary.json").read_text())
    assert summary["input"]["time_unit"] == "nanoseconds"
    a = np.genfromtxt(tmp_path / "ns" / "trajectory.csv", delimiter=",", names=True,
                      skip_header=3)
    b = np.genfromtxt(tmp_path / "s" / "trajectory.csv", delimiter=",", names=True,
                      skip_header=3)
    assert len(a) == len(b)
    np.testing.assert_allclose(a["t"], b["t"], atol=1e-6, rtol=0)
    np.testing.assert_allclose(a["vx"], b["vx"], atol=1e-3, rtol=0)
    assert 0.3 < np.abs(a["vx"]).max() < 2.0  # m/s, not m/ns

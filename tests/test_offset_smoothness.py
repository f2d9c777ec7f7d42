"""An accelerometer's clock offset needs accelerations C1 in time (issue 31).

On a cubic B-spline the accelerations are only C0 in time, so the Accel cost kinks in an
estimated offset as samples cross knots and Gauss-Newton can stall short of the optimum (the
IMU-side solve of tests/test_estimation_montecarlo.py did; a quartic converges there).
``fitting.estimate`` warns, naming the term, the parameter and the fix (degree >= 4), and the
``fit`` command picks degree 4 for ``--imu --time-offset estimate`` unless ``--degree`` is
given. The motion here is written out by hand (numpy): a yaw and a tilt, sines in position.
"""

import json
import re
import warnings

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.__main__ import main
from torch_dq.cli.fit_imu import OFFSET_DEGREE, default_degree
from torch_dq.fitting import Accel, Free, Gyro, Poses, estimate
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64
KINK = r"Accel\.time_offset is estimated on a degree-{} B-spline of form='{}'.*degree >= 4"


def _poses():
    """Poses (10 Hz, 1 s) of a body turning at 1 rad/s about z and moving in a parabola."""
    t = torch.linspace(0.0, 1.0, 11, dtype=F64)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    return t, dq.from_rt(quat.from_rotvec(t[:, None] * z), torch.stack((t, t**2, 0 * t), -1))


def _problem(degree=3, form="cumulative", accel_offset=True, gyro_offset=False):
    """The poses and body-frame specific forces (50 Hz, gravity only: the offset is not
    the point) on a B-spline through the poses."""
    t, x = _poses()
    ti = torch.linspace(0.2, 0.8, 31, dtype=F64)
    z = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    spline = BSpline.from_dualquats(x, t, n_ctrl=6, degree=degree, form=form)
    specific = quat.rotate(quat.from_rotvec(-ti[:, None] * z),
                           torch.tensor([0.0, 0.0, 9.81], dtype=F64).expand(31, 3))
    terms = [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01),
             Accel(ti, specific, sigma=0.1, time_offset=Free(0.0) if accel_offset else None)]
    if gyro_offset:
        terms.append(Gyro(ti, z.expand(31, 3), sigma=0.01, time_offset=Free(0.0)))
    return spline, terms


@pytest.mark.parametrize("degree, form", [(3, "cumulative"), (2, "cumulative"),
                                          (3, "split"), (4, "de_boor")])
def test_accel_offset_on_a_curve_without_c1_accelerations_warns(degree, form):
    """A cubic (or lower) cumulative or split B-spline, or any de Boor one (C1 only: also
    the smoothness UserWarning), with an estimated Accel offset: a RuntimeWarning naming
    Accel.time_offset, the curve and the fix."""
    spline, terms = _problem(degree, form)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        estimate(spline, terms, steps=0, verbose=False)
    kinks = [w for w in caught if issubclass(w.category, RuntimeWarning)
             and "not C1 in time" in str(w.message)]
    assert len(kinks) == 1, [str(w.message) for w in caught]
    assert re.search(KINK.format(degree, form), str(kinks[0].message)), kinks[0].message
    assert kinks[0].filename == __file__  # points at the caller's line


@pytest.mark.parametrize("case", ["quartic", "quintic split", "no Accel offset",
                                  "Gyro offset only", "bezier"])
def test_no_kink_warning_where_the_cost_is_smooth(case):
    """No warning on a quartic or higher (C1 accelerations), for an Accel without an
    estimated offset, for a Gyro offset alone (angular rates are C1 on a cubic), on a
    Bezier curve (one polynomial piece): pytest makes torch_dq's warnings errors, and the
    record below catches one attributed to the caller too."""
    kw = {"quartic": dict(degree=4), "quintic split": dict(degree=5, form="split"),
          "no Accel offset": dict(accel_offset=False),
          "Gyro offset only": dict(accel_offset=False, gyro_offset=True), "bezier": {}}[case]
    spline, terms = _problem(**kw)
    if case == "bezier":
        spline = Bezier.from_dualquats(*reversed(_poses()), n_ctrl=4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        estimate(spline, terms, steps=0, verbose=False)
    assert not [w for w in caught if "not C1 in time" in str(w.message)], caught


def test_the_fit_command_picks_a_quartic_for_an_imu_offset(tmp_path, capsys):
    """``fit --imu --time-offset estimate`` without --degree fits a quartic (summary's
    model, the IMU fit's curve) and reports no kink warning; with ``--degree 3`` the user's
    cubic is kept and the warning lands in summary.json. Without an offset: a cubic."""
    assert (default_degree("imu.csv", "estimate"), default_degree("imu.csv", None),
            default_degree(None, None), OFFSET_DEGREE) == (4, 3, 3, 4)
    poses, imu = _write_short_case(tmp_path)
    runs = {}
    for name, extra in (("default", []), ("cubic", ["--degree", "3"])):
        out = tmp_path / name
        assert main(["fit", poses, "--imu", imu, "--time-offset", "estimate", "--out",
                     str(out), "--no-plots", "--quiet", "--steps", "5",
                     "--knot-spacing", "0.2", *extra]) == 0
        runs[name] = json.loads((out / "summary.json").read_text())
        spline = torch.load(out / "spline.pt", weights_only=True)
        assert int(spline["_extra_state"]["degree"]) == runs[name]["model"]["degree"]
    capsys.readouterr()
    assert runs["default"]["model"]["degree"] == 4
    assert not any("not C1" in w for w in runs["default"]["warnings"])
    assert runs["cubic"]["model"]["degree"] == 3
    assert any("Accel.time_offset is estimated on a degree-3" in w
               for w in runs["cubic"]["warnings"]), runs["cubic"]["warnings"]


def _write_short_case(folder):
    """Poses at 20 Hz (TUM) and an IMU at 100 Hz over 2 s, the IMU 10 ms late."""
    rng = np.random.default_rng(1)
    from scipy.spatial.transform import Rotation

    def motion(t):
        a, b = 0.8 * np.sin(0.9 * t) + 0.3 * t, 0.4 * np.sin(1.3 * t)
        da, db = 0.72 * np.cos(0.9 * t) + 0.3, 0.52 * np.cos(1.3 * t)
        Rz = Rotation.from_rotvec(np.outer(a, [0.0, 0.0, 1.0]))
        w = da[:, None] * np.array([0.0, 0.0, 1.0]) + db[:, None] * Rz.apply([0.0, 1.0, 0.0])
        p = np.stack((np.sin(t), np.cos(0.7 * t), 0.2 * np.sin(2 * t)), -1)
        acc = np.stack((-np.sin(t), -0.49 * np.cos(0.7 * t), -0.8 * np.sin(2 * t)), -1)
        return Rz * Rotation.from_rotvec(np.outer(b, [0.0, 1.0, 0.0])), p, w, acc

    tc = np.arange(0.0, 2.0001, 0.05)
    R, p, _, _ = motion(tc)
    p = p + 1e-3 * rng.normal(size=p.shape)
    np.savetxt(folder / "poses.txt", np.column_stack((tc, p, R.as_quat())), fmt="%.12g")
    ti = np.arange(0.0, 2.0001, 0.01)
    R, _, w, acc = motion(ti + 0.01)
    gyro = R.inv().apply(w) + 2e-3 * rng.normal(size=w.shape)
    force = R.inv().apply(acc - np.array([0.0, 0.0, -9.81])) + 2e-2 * rng.normal(
        size=acc.shape)
    np.savetxt(folder / "imu.txt", np.column_stack((ti, gyro, force)), fmt="%.12g",
               header="t gx gy gz ax ay az")
    return str(folder / "poses.txt"), str(folder / "imu.txt")

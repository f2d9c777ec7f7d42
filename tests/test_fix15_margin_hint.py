"""``estimate``'s advice on samples beyond the trajectory's domain gives the ``margin=`` that
works: ``from_poses`` counts it from the poses' own first and last times, so the advice is how
far the samples reach beyond those (not the shortfall against the curve's current margin), and
following it literally passes; a curve not built from poses gets the shortfall to add at each
end (user15 finding 1)."""

import re
import warnings

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.fitting import Gyro, Poses, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
T0 = 1.7e9  # UNIX seconds
OMEGA = (0.0, 0.0, 0.4)


def _data():
    t = T0 + torch.linspace(0.0, 2.0, 41, dtype=F64)
    xi = torch.tensor([*OMEGA, 0.5, 0.0, 0.1], dtype=F64)
    poses = dq.exp((t - T0)[:, None] * xi)
    return t, poses


def _terms(t, poses, gyro_times, **gyro):
    readings = torch.tensor(OMEGA, dtype=F64).expand(gyro_times.shape[0], 3)
    return [Poses(t, poses, rot_sigma=1e-3, trans_sigma=1e-3),
            Gyro(gyro_times, readings, sigma=1e-3, **gyro)]


def _run(spline, terms):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        estimate(spline, terms, steps=0, verbose=False)


def test_the_advised_margin_counts_from_the_poses_and_works():
    t, poses = _data()
    gyro_times = T0 + torch.linspace(0.2, 1.795, 320, dtype=F64)
    terms = _terms(t, poses, gyro_times, time_offset=True, max_time_offset=0.5)
    # reference: how far the widened samples reach beyond the poses' first and last times
    reach = max(float(t[0]) - (float(gyro_times[0]) - 0.5),
                (float(gyro_times[-1]) + 0.5) - float(t[-1]))
    assert reach == pytest.approx(0.3, abs=1e-6)
    for margin in (0.0, 0.1, 0.2):
        spline = BSpline.from_poses(*dq.to_rt(poses), t, n_ctrl=12, form="cumulative",
                                    margin=margin)
        with pytest.raises(ValueError, match=r"leave the trajectory's domain") as err:
            _run(spline, terms)
        advised = float(re.search(r"margin=([0-9.e+-]+)\)", str(err.value)).group(1))
        assert advised == pytest.approx(reach, rel=1e-3), str(err.value)
        assert f"falls {0.3 - margin:g} short" in str(err.value), str(err.value)
        _run(BSpline.from_poses(*dq.to_rt(poses), t, n_ctrl=12, form="cumulative",
                                margin=advised), terms)  # followed literally: it works


def test_samples_past_the_end_of_a_margin_curve():
    t, poses = _data()
    gyro_times = T0 + torch.linspace(0.0, 4.795, 960, dtype=F64)  # 2.795 s past the poses
    terms = _terms(t, poses, gyro_times)
    spline = BSpline.from_poses(*dq.to_rt(poses), t, n_ctrl=12, form="cumulative", margin=0.1)
    with pytest.raises(ValueError, match=r"margin=2\.795\)") as err:
        _run(spline, terms)
    assert "drop those samples" in str(err.value)
    _run(BSpline.from_poses(*dq.to_rt(poses), t, n_ctrl=12, form="cumulative", margin=2.795),
         terms)


def test_a_curve_not_built_from_poses_gets_the_shortfall_at_each_end():
    t, poses = _data()
    gyro_times = T0 + torch.linspace(0.2, 1.795, 320, dtype=F64)
    terms = _terms(t, poses, gyro_times, time_offset=True, max_time_offset=0.5)
    built = BSpline.from_poses(*dq.to_rt(poses), t, n_ctrl=12, form="cumulative", margin=0.1)
    loaded = BSpline.from_state_dict(built.state_dict())  # knots known, the poses not
    with pytest.raises(ValueError, match=r"extend the trajectory's domain by 0\.2 at its start "
                                         r"and 0\.195 at its end \(this curve was not built by"):
        _run(loaded, terms)
    # the shortfall added to the knots at each end (clamped uniform: only the ends move)
    lo, hi = loaded.domain
    inner = torch.linspace(lo, hi, 12 - 3 + 1, dtype=F64)[1:-1]
    knots = torch.cat((torch.full((4,), lo - 0.2, dtype=F64), inner,
                       torch.full((4,), hi + 0.195, dtype=F64)))
    wider = BSpline(loaded.control_points.detach(), knots=knots, form="cumulative")
    _run(wider, terms)

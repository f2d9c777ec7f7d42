"""Terms read at the same times share their span evaluation (``Problem.groups``): an IMU's
gyroscope and accelerometer evaluate the spans' derivatives once per part, for the trial costs
and for the Gauss-Newton system, and chain their Jacobian rows through the spans by one
closed-form vector-Jacobian product. The shared system equals the per-term one (each term its
own evaluation) and its gradient central differences of the costs; the costs and the system
still agree to the bit, the memo keeps a group's derivatives once.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from test_estimation import imu_of, truth

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses, _linearize, _robust
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._linearize import Memo
from torch_dq.fitting._problem import Problem
from torch_dq.nn import BSpline

F64 = torch.float64
FIELDS = ("band", "cn", "nn", "gc", "gn")


def _job(imu=None, accel_times=None):
    """3 s: poses at 20 Hz (1 mrad, 1 mm), IMU at 200 Hz inside, biases, a cumulative
    spline through the poses; ``imu`` the IMU terms' keywords (Gyro's, Accel's),
    ``accel_times`` the accelerometer's times from the gyroscope's."""
    rng = np.random.default_rng(3)
    tc, ti = np.arange(0.0, 3.0 + 1e-9, 0.05), np.arange(0.1, 2.9, 0.005)
    R, p = truth(tc)[:2]
    q = (R * Rotation.from_rotvec(1e-3 * rng.standard_normal((len(tc), 3)))).as_quat(
        scalar_first=True)
    cam = dq.from_rt(torch.from_numpy(q), torch.from_numpy(p + 1e-3 * rng.standard_normal(
        (len(tc), 3))))
    gyro, accel = imu_of(ti, (0.01, -0.02, 0.015), (0.05, -0.08, 0.1))
    gyro = gyro + 2e-3 * torch.from_numpy(rng.standard_normal(gyro.shape))
    accel = accel + 2e-2 * torch.from_numpy(rng.standard_normal(accel.shape))
    tc, ti = torch.from_numpy(tc), torch.from_numpy(ti)
    spline = BSpline.from_dualquats(cam, tc, n_ctrl=61, form="cumulative")
    kg, ka = imu or ({}, {})
    terms = [Poses(tc, cam, rot_sigma=1e-3, trans_sigma=1e-3),
             Gyro(ti, gyro, sigma=2e-3, bias=True, **kg),
             Accel(ti if accel_times is None else accel_times(ti), accel, sigma=2e-2, bias=True,
                   gravity=9.81, **ka)]
    ctrl = spline.control_points.detach()
    problem = Problem(spline, terms, torch.Size(()))
    values = _starts("test", problem, ctrl)
    values = [v + 0.01 * torch.randn(v.shape, generator=torch.Generator().manual_seed(i),
                                     dtype=F64) for i, v in enumerate(values)]  # off zero
    return problem, ctrl, values


def _counted(problem, monkeypatch):
    """Count the span evaluations and closed-form products of ``problem``'s spans."""
    calls = {"shared": 0, "vjp": 0}
    for name in calls:
        inner = getattr(problem.spans, name)

        def spy(*args, _inner=inner, _name=name):
            calls[_name] += 1
            return _inner(*args)

        monkeypatch.setattr(problem.spans, name, spy)
    return calls


def test_gyro_and_accel_at_the_same_times_share_one_span_evaluation(monkeypatch):
    """One group for the IMU (its own times tensors, equal values: the Accel's a clone), two
    span evaluations and two closed-form products per system instead of three; the system
    equals the per-term one to rounding."""
    problem, ctrl, values = _job(accel_times=torch.clone)
    assert problem.groups(values) == [(0,), (1, 2)]
    calls = _counted(problem, monkeypatch)
    w = problem.width(values)
    shared = problem.system(ctrl, values, w)
    assert calls == {"shared": 2, "vjp": 2}
    problem.data_cost(ctrl, values)
    assert calls["shared"] == 4
    problem._groups = [(0,), (1,), (2,)]  # each term its own evaluation
    alone = problem.system(ctrl, values, w)
    assert calls == {"shared": 7, "vjp": 5}
    for field in FIELDS:
        a, b = getattr(alone, field), getattr(shared, field)
        assert float(a.abs().amax()) > 0, field
        torch.testing.assert_close(b, a, atol=1e-12 * float(a.abs().amax()), rtol=0,
                                   msg=field)
    for a, b in zip(alone.residuals + alone.weights, shared.residuals + shared.weights,
                    strict=True):
        torch.testing.assert_close(b, a, atol=1e-12 * float(a.abs().amax()), rtol=0)


@pytest.mark.parametrize("imu", [
    ({"time_offset": Free(0.002)}, {}),  # an estimated time offset moves the gyro's times
    ({"time_offset": 0.002}, {}),  # other times
    ({"time_offset": 0.002}, {"time_offset": 0.002}),  # the same times
])
def test_terms_share_only_identical_times(imu):
    """A group needs identical moved times that no estimated parameter moves."""
    problem, _, values = _job(imu)
    same = imu[0].get("time_offset") == imu[1].get("time_offset")
    assert problem.groups(values) == ([(0,), (1, 2)] if same else [(0,), (1,), (2,)])


def test_other_times_are_not_shared():
    """One sample's time apart: each term its own evaluation."""
    def moved(ti):
        ti = ti.clone()
        ti[7] += 1e-3
        return ti

    problem, _, values = _job(accel_times=moved)
    assert problem.groups(values) == [(0,), (1,), (2,)]


def test_shared_gradient_matches_central_differences_of_the_costs():
    """``g = J^T W r`` of the shared path is half the gradient of the robust costs (central
    differences of ``data_cost`` with the control points moved by ``c exp(h e_j)`` and the
    nuisance values by their charts)."""
    problem, ctrl, values = _job()
    for term in problem.terms[1:]:
        term.robust, term.robust_k = "huber", 1.0  # some weights below one
    assert problem.groups(values) == [(0,), (1, 2)]
    s = problem.system(ctrl, values, problem.width(values))
    assert bool((s.weights[2] < 1).any())
    n, m, h = problem.spans.n, problem.m, 1e-6

    def cost(dc, dn):
        c, v = problem.retract(ctrl, values, dc, dn)
        return float(torch.stack(problem.data_cost(c, v)).sum())

    for j in [(20, 0), (20, 4), (31, 2), (31, 5)]:
        e = torch.zeros(n, 6, dtype=F64)
        e[j] = h
        fd = (cost(e, torch.zeros(m, dtype=F64)) - cost(-e, torch.zeros(m, dtype=F64))) / (2 * h)
        assert fd == pytest.approx(2 * float(s.gc[0][j]), rel=1e-5, abs=1e-3)
    for j in range(m):
        e = torch.zeros(m, dtype=F64)
        e[j] = h
        zero = torch.zeros(n, 6, dtype=F64)
        fd = (cost(zero, e) - cost(zero, -e)) / (2 * h)
        assert fd == pytest.approx(2 * float(s.gn[0][j]), rel=1e-5, abs=1e-3)


def test_shared_costs_agree_with_the_system_and_the_memo_keeps_a_group_once(monkeypatch):
    """The trial costs are the system's residuals' to the bit; the memo keeps the group's
    derivatives once (by its first term) and the system built from them is the fresh one."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    memo = Memo()
    costs = problem.data_cost(ctrl, values, memo)
    assert sorted(memo.entries) == [(0, 0), (1, 0)]
    assert len(memo.entries[(1, 0)][0]) == 3  # to the accelerometer's second derivative
    calls = _counted(problem, monkeypatch)
    kept = problem.system(ctrl, values, w, memo)
    assert not memo.entries and calls["shared"] == 0
    fresh = problem.system(ctrl, values, w)
    for field in FIELDS:
        assert torch.equal(getattr(kept, field), getattr(fresh, field))
    for term, r, c in zip(problem.terms, kept.residuals, costs, strict=True):
        assert torch.equal(_robust.rho(term.robust, r.norm(dim=-1), term.robust_k).sum(-1), c)


def test_a_group_in_parts_equals_the_whole(monkeypatch):
    """Parts of 100 samples (the group's members cut alike): the same system to rounding."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    whole = problem.system(ctrl, values, w)
    monkeypatch.setattr(_linearize, "PART", 100)
    calls = _counted(problem, monkeypatch)
    cut = problem.system(ctrl, values, w)
    assert calls["vjp"] == 1 + 6  # the poses, then the IMU's six parts
    for field in FIELDS:
        a, b = getattr(whole, field), getattr(cut, field)
        torch.testing.assert_close(b, a, atol=1e-12 * float(a.abs().amax()), rtol=0,
                                   msg=field)

"""The Levenberg-Marquardt damping of fitting.estimate (``fitting/_solver.py``'s Marquardt):
it falls with the gain ratio, so that a problem that its quadratic model describes takes
Gauss-Newton's steps, and a rejected step goes back towards the last accepted damping.

The IMU + poses job below (poses at 20 Hz, IMU at 200 Hz, biases started at zero, the spline
from the poses) took four Gauss-Newton systems with a tenfold fall per accepted step: its
first step's gain ratio is 1 - 5e-8, and the damping left after it still held back the
directions that the accelerometer alone determines.
"""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from test_estimation import imu_of, truth

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Gyro, Poses, estimate
from torch_dq.fitting._solver import Marquardt
from torch_dq.nn import BSpline

F64 = torch.float64
BG, BA = np.array([0.01, -0.02, 0.015]), np.array([0.05, -0.08, 0.1])


def _job(seed):
    """10 s: poses at 20 Hz (1 mrad, 1 mm), IMU at 200 Hz (2 mrad/s, 0.02 m/s^2), biases."""
    rng = np.random.default_rng(seed)
    tc, ti = np.arange(0.0, 10.0 + 1e-9, 0.05), np.arange(0.0, 10.0 + 1e-9, 0.005)
    R, p = truth(tc)[:2]
    q = (R * Rotation.from_rotvec(1e-3 * rng.standard_normal((len(tc), 3)))).as_quat(
        scalar_first=True)
    cam = dq.from_rt(torch.from_numpy(q), torch.from_numpy(p + 1e-3 * rng.standard_normal(
        (len(tc), 3))))
    gyro, accel = imu_of(ti, BG, BA)
    gyro = gyro + 2e-3 * torch.from_numpy(rng.standard_normal((len(ti), 3)))
    accel = accel + 2e-2 * torch.from_numpy(rng.standard_normal((len(ti), 3)))
    return torch.from_numpy(tc), cam, torch.from_numpy(ti), gyro, accel


def test_a_near_linear_imu_and_poses_job_takes_gauss_newton_steps():
    """Two steps (four with the tenfold fall), converged, biases within 4 standard
    deviations of the truth."""
    tc, cam, ti, gyro, accel = _job(0)
    spline = BSpline.from_dualquats(cam, tc, n_ctrl=201, form="cumulative")
    terms = [Poses(tc, cam, rot_sigma=1e-3, trans_sigma=1e-3),
             Gyro(ti, gyro, sigma=2e-3, bias=True),
             Accel(ti, accel, sigma=2e-2, bias=True, gravity=torch.tensor([0.0, 0.0, -9.81],
                                                                            dtype=F64))]
    est = estimate(spline, terms, verbose=False)
    assert bool(est.converged) and est.steps <= 2, (est.steps, est.reason)
    for term, truth_bias in ((terms[1], BG), (terms[2], BA)):
        z = (term.bias - torch.from_numpy(truth_bias)) / est.std(term, "bias")
        assert float(z.abs().max()) < 4.0, z
    loss = est.loss.numpy()  # the first step does nearly all of it
    assert loss[1] < 1e-3 * loss[0] and loss[-1] <= loss[-2] < 1.01 * loss[-1]


def test_the_damping_falls_by_the_gain_ratio():
    """After an accepted step: by 4 |1 - rho| where rho > 1/4 (tenfold at least), not at all
    otherwise; the floor 1e-12."""
    m = Marquardt(5, torch.zeros(1, dtype=F64))
    gain = torch.tensor([1 - 1e-6, 0.5, 0.1, 1.0, 1.3], dtype=F64)
    m.accept(torch.zeros(5, dtype=torch.bool), gain)
    expected = 1e-4 * np.array([4e-6, 0.1, 1.0, 1e-8, 0.1])
    np.testing.assert_allclose(m.lam.numpy(), np.maximum(expected, 1e-12), rtol=1e-9)
    np.testing.assert_allclose(m.good.numpy(), 1e-4, rtol=0)  # the accepted dampings


def test_a_rejected_step_goes_back_towards_the_last_accepted_damping():
    """Below the last accepted damping: its geometric mean with it (tenfold at least); at or
    above it: tenfold, to the start's 1e-4 at least; pending elements only."""
    m = Marquardt(3, torch.zeros(1, dtype=F64))
    m.good = torch.tensor([1e-4, 1e-9, 1e-4], dtype=F64)
    m.lam = torch.tensor([1e-10, 1e-9, 1e-10], dtype=F64)
    m.reject(torch.tensor([True, True, False]))
    np.testing.assert_allclose(m.lam.numpy(), [1e-7, 1e-4, 1e-10], rtol=1e-12)
    m.reject(torch.tensor([True, True, False]))
    np.testing.assert_allclose(m.lam.numpy(), [np.sqrt(1e-11), 1e-3, 1e-10], rtol=1e-12)


def test_an_accepted_trial_s_derivatives_give_the_same_system(monkeypatch):
    """The system built from the span derivatives that the cost evaluation kept (``Memo``)
    equals, to the bit, the system that evaluates them again; the memo is spent."""
    from torch_dq.fitting import _linearize
    from torch_dq.fitting._linearize import Memo
    from torch_dq.fitting._problem import Problem

    tc, cam, ti, gyro, accel = _job(1)
    inner = slice(40, -40)  # 0.2 s from the ends: room for the time offset
    spline = BSpline.from_dualquats(cam, tc, n_ctrl=201, form="cumulative")
    terms = [Poses(tc, cam, rot_sigma=1e-3, trans_sigma=1e-3),
             Gyro(ti[inner], gyro[inner], sigma=2e-3, bias=True, time_offset=True),
             Accel(ti, accel, sigma=2e-2, bias=True, gravity=9.81)]
    with pytest.warns(RuntimeWarning, match="steps=1 reached"):  # values set, off the start
        estimate(spline, terms, verbose=False, steps=1)
    ctrl = spline.control_points.detach()
    problem = Problem(spline, terms, torch.Size(()))
    for i, term in enumerate(terms):
        for name, slot in term.slots().items():
            if slot.free is not None:
                problem.add(i, name, slot.free, slot.chart, slot.free.value.clone())
    values = [q.start for q in problem.params]
    memo = Memo()
    problem.data_cost(ctrl, values, memo)
    assert sorted(memo.entries) == [(0, 0), (1, 0), (2, 0)]
    w = problem.width(values)
    kept, fresh = problem.system(ctrl, values, w, memo), problem.system(ctrl, values, w)
    assert not memo.entries
    monkeypatch.setattr(_linearize, "MEMO_BYTES", 1 << 10)  # a long record's: none kept
    memo = Memo()
    problem.data_cost(ctrl, values, memo)
    assert not memo.entries
    for a, b in zip((kept.band, kept.cn, kept.nn, kept.gc, kept.gn),
                    (fresh.band, fresh.cn, fresh.nn, fresh.gc, fresh.gn), strict=True):
        assert torch.equal(a, b)

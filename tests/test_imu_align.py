"""Positions + gyroscope + accelerometer started with no rotation at all (the identity
everywhere: what a GNSS + IMU user has): fitting.estimate aligns the rotations on the IMU
(``fitting._align``) and ends at the optimum with the defaults. Before, gravity's direction
estimated, it crawled 50 steps and stopped unconverged 0.06 rad/s off in the gyroscope bias
(``benchmarks/positions_imu_identity_start.py``). The motion and readings are
test_estimation's formulas (scipy), not the library's."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from test_estimation import G, truth

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.fitting import Accel, Free, Gyro, Positions, _align, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
K = 1.5  # test_estimation's motion at K t
BG, BA = np.array([0.01, -0.02, 0.015]), np.array([0.1, -0.05, 0.08])


def _rig(seed, duration=6.0):
    """Positions at 20 Hz (1 cm), gyroscope (2 mrad/s) and accelerometer (0.02 m/s^2) at
    200 Hz with biases; the spline through the positions with identity rotations."""
    rng = np.random.default_rng(seed)
    tp = np.arange(0.0, duration + 1e-9, 0.05)
    ti = np.arange(0.0, duration + 1e-9, 0.005)
    pos = truth(K * tp)[1] + 0.01 * rng.standard_normal((len(tp), 3))
    R, _, w, _, _, acc = truth(K * ti)
    gyro = R.inv().apply(K * w) + BG + 0.002 * rng.standard_normal((len(ti), 3))
    force = R.inv().apply(K * K * acc - G) + BA + 0.02 * rng.standard_normal((len(ti), 3))
    tp, pos = torch.from_numpy(tp), torch.from_numpy(pos)
    flat = dq.from_rt(quat.identity(dtype=F64).expand(len(tp), 4), pos)
    spline = BSpline.from_dualquats(flat, tp, knot_spacing=0.05, form="cumulative")
    return spline, tp, pos, torch.from_numpy(ti), torch.from_numpy(gyro), torch.from_numpy(force)


def _terms(tp, pos, ti, gyro, force, gravity):
    return [Positions(tp, pos, sigma=0.01), Gyro(ti, gyro, sigma=0.002, bias=True),
            Accel(ti, force, sigma=0.02, bias=True, gravity=gravity)]


def _rotation_errors(spline, t):
    """``(T, 3)`` rotation vectors ``delta`` (body axes) with ``R_true = R exp(delta)``, ``R``
    the spline's rotations at ``t``."""
    q = dq.to_rt(spline(t).detach())[0].numpy()
    R = truth(K * t.numpy())[0]
    return (Rotation.from_quat(q, scalar_first=True).inv() * R).as_rotvec()


def _rotation_error(spline, t):
    """Largest angle (rad) between the spline's rotations and the truth's at ``t``."""
    return float(np.max(np.linalg.norm(_rotation_errors(spline, t), axis=-1)))


@pytest.mark.parametrize("gravity", [tuple(G), 9.81], ids=["fixed", "direction estimated"])
def test_identity_rotations_start_ends_at_the_optimum(gravity):
    spline, tp, pos, ti, gyro, force = _rig(0)
    terms = _terms(tp, pos, ti, gyro, force, gravity)
    est = estimate(spline, terms, verbose=False)
    assert bool(est.converged), est.reason
    assert est.reason.startswith("the scaled gradient test passed"), est.reason
    assert est.steps <= 25, est.steps
    for term, truth_bias in ((terms[1], BG), (terms[2], BA)):
        z = (term.bias - torch.from_numpy(truth_bias)) / est.std(term, "bias")
        assert bool((z.abs() < 4.0).all()), z
    t = torch.linspace(0.2, 5.8, 29, dtype=F64)
    z = _rotation_errors(spline, t) / est.pose_std(t)[:, :3].detach().numpy()
    assert np.all(np.abs(z) < 4.5), np.abs(z).max()
    if isinstance(gravity, float):
        z = (terms[2].gravity - torch.from_numpy(G)) / est.std(terms[2], "gravity")
        assert bool((z.abs() < 4.0).all()), z


def test_aligned_start_is_near_the_truth_and_a_better_start_is_kept():
    spline, tp, pos, ti, gyro, force = _rig(1)
    terms = _terms(tp, pos, ti, gyro, force, tuple(G))
    ctrl = spline.control_points.detach()
    aligned = _align.imu_aligned("test", spline, terms, ctrl)
    assert aligned is not ctrl
    with torch.no_grad():
        spline.control_points = aligned
    # gyroscope bias (0.027 rad/s) integrated over 6 s from the start: the drift bounds it
    assert _rotation_error(spline, torch.linspace(0.0, 6.0, 61, dtype=F64)) < 0.25
    # the truth at the IMU's times with the true biases' starts: the truth's rotations at the
    # positions' times alone (20 Hz) cost more than the aligned start now, whose heading and
    # gyroscope bias are refined together and which is fitted at the gyroscope's times
    R, p = truth(K * ti.numpy())[:2]
    best = BSpline.from_dualquats(dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)),
                                             torch.from_numpy(p)),
                                  ti, knot_spacing=0.05, form="cumulative")
    kept = best.control_points.detach()
    truth_terms = [Positions(tp, pos, sigma=0.01),
                   Gyro(ti, gyro, sigma=0.002, bias=Free(torch.from_numpy(BG))),
                   Accel(ti, force, sigma=0.02, bias=Free(torch.from_numpy(BA)), gravity=tuple(G))]
    assert _align.imu_aligned("test", best, truth_terms, kept) is kept


def test_integrated_rates_against_scipy():
    """A constant rate: exactly exp(w t); a varying one: scipy's composition of the same
    midpoint steps."""
    t = torch.linspace(0.0, 2.0, 201, dtype=F64)
    w = torch.tensor([0.3, -1.2, 0.7], dtype=F64)
    q = _align._integrate(t, w.expand(201, 3))
    ref = Rotation.from_rotvec(t.numpy()[:, None] * w.numpy())
    got = Rotation.from_quat(q.numpy(), scalar_first=True)
    assert float(np.max((got.inv() * ref).magnitude())) < 1e-12
    rng = np.random.default_rng(0)
    rates = rng.standard_normal((201, 3))
    q = _align._integrate(t, torch.from_numpy(rates))
    R = Rotation.identity()
    for k in range(200):
        R = R * Rotation.from_rotvec(0.5 * (rates[k] + rates[k + 1]) * 0.01)
        assert float((Rotation.from_quat(q[k + 1].numpy(), scalar_first=True).inv()
                      * R).magnitude()) < 1e-12


def test_kabsch_against_scipy_align_vectors():
    rng = np.random.default_rng(2)
    u = rng.standard_normal((50, 3))
    R = Rotation.random(random_state=3)
    v = R.apply(u) + 0.01 * rng.standard_normal((50, 3))
    ref = Rotation.align_vectors(v, u)[0]
    q = _align._kabsch(torch.from_numpy(u), torch.from_numpy(v))
    assert float((Rotation.from_quat(q.numpy(), scalar_first=True).inv() * ref).magnitude()) \
        < 1e-10
    line = np.outer(rng.standard_normal(50), [1.0, 2.0, 3.0])  # fixes no rotation
    assert _align._kabsch(torch.from_numpy(line), torch.from_numpy(line)) is None

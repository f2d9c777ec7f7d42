"""Reproductions of the estimation defects of issue 31 (each failed before its fix): pair
times kept as given, bad poses and sigmas refused naming what is bad, one Free of one kind,
correlation starts on shared times in batches, exact structural checks, unit warnings, and
starts on knots finer than the poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses, Positions, RelativePoses, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
A, B, C, D = 0.8, 0.5, 0.6, 0.1  # the motion's constants
G = np.array([0.0, 0.0, -9.81])


def truth(t):
    """numpy (independent of the library): rotation (scipy), position, world angular
    velocity and linear acceleration at times ``t (N,)``."""
    t = np.asarray(t, dtype=float)
    phi, dphi = B * np.sin(t), B * np.cos(t)
    R = Rotation.from_euler("z", (A * t)[:, None]) * Rotation.from_euler("y", phi[:, None])
    p = np.stack((C * t + D * t**2, np.sin(2 * t), 0.5 * np.cos(t)), -1)
    acc = np.stack((2 * D + 0 * t, -4 * np.sin(2 * t), -0.5 * np.cos(t)), -1)
    ey = np.stack((-np.sin(A * t), np.cos(A * t), 0 * t), -1)
    w = A * np.array([0.0, 0.0, 1.0]) + dphi[:, None] * ey
    return R, p, w, acc


def poses_of(t):
    R, p = truth(t)[:2]
    return dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p))


def imu_of(t, bg=(0.0, 0.0, 0.0), ba=(0.0, 0.0, 0.0)):
    """Ideal gyroscope and accelerometer readings (body axes) with biases."""
    R, _, w, acc = truth(t)
    return (torch.from_numpy(R.inv().apply(w) + np.asarray(bg)),
            torch.from_numpy(R.inv().apply(acc - G) + np.asarray(ba)))


def grid(t0, t1, hz):
    return torch.linspace(t0, t1, round((t1 - t0) * hz) + 1, dtype=F64)


def spline_on(t, x, spacing, form="cumulative"):
    n = math.ceil((float(t[-1]) - float(t[0])) / spacing) + 3
    return BSpline.from_dualquats(x, t, n_ctrl=n, form=form)


@pytest.fixture
def gen():
    return torch.Generator().manual_seed(31)


# ----------------------------------------------------------------------------- 1. pairs

def test_relative_pose_pairs_are_kept_as_given():
    """Pairs listed by keyframe (unsorted from-times, loop closures back in time): exact
    odometry has zero residuals on the true trajectory (the running maximum of the times
    compared the pairs with the wrong poses)."""
    t = grid(0.0, 3.0, 10)
    x = poses_of(t)
    spline = spline_on(t, x, 0.2)  # smooth, the odometry taken from it
    i = torch.tensor([0, 5, 3, 20, 2, 29, 10, 1])
    j = torch.tensor([4, 1, 9, 0, 25, 3, 30, 12])  # back in time too (loop closures)
    xs = spline(t).detach()
    rel = dq.mul(dq.conj(xs[i]), xs[j])
    term = RelativePoses(t[i], t[j], rel, rot_sigma=0.01, trans_sigma=0.01)
    torch.testing.assert_close(term.times_from, t[i], rtol=0, atol=0)
    torch.testing.assert_close(term.times_to, t[j], rtol=0, atol=0)
    assert float(term(spline).detach().abs().max()) < 1e-8
    mask = torch.ones(8, dtype=torch.bool)
    mask[3] = False  # a masked pair takes a valid time (inside the domain), the rest kept
    masked = RelativePoses(t[i], t[j], rel, rot_sigma=0.01, trans_sigma=0.01, mask=mask)
    keep = mask.nonzero()[:, 0]
    torch.testing.assert_close(masked.times_from[keep], t[i][keep], rtol=0, atol=0)
    assert float(masked(spline).detach().abs().max()) < 1e-8
    # estimated with them: the odometry (and two absolute poses) pull a perturbed start
    # back onto the exact trajectory
    start = BSpline(dq.mul(spline.control_points.detach(), dq.exp(
        0.02 * torch.randn(spline.n_ctrl, 6, generator=torch.Generator().manual_seed(1),
                           dtype=F64))), knots=spline.knots, form="cumulative")
    anchor = Poses(t[::10], xs[::10], rot_sigma=0.01, trans_sigma=0.01)
    dense = RelativePoses(t[:-1], t[1:], dq.mul(dq.conj(xs[:-1]), xs[1:]), rot_sigma=0.01,
                          trans_sigma=0.01)
    est = estimate(start, [anchor, dense, term], prior=0.0, verbose=False)
    assert float(est.final_loss) < 1e-12


# ----------------------------------------------------------------------------- 2. zero quaternions

@pytest.mark.parametrize("bad", [0.0, float("nan")])
def test_a_zero_quaternion_in_poses_names_the_sample(bad):
    t = grid(0.0, 2.0, 10)
    x = poses_of(t).clone()
    x[7, :4] = bad  # a dropped frame written as zeros (its translation kept)
    if bad == 0.0:
        x[7, 4:] = 0.0
    with pytest.raises(ValueError, match="sample 7"):
        Poses(t, x, rot_sigma=0.01, trans_sigma=0.01)
    xb = torch.stack((poses_of(t), x))
    with pytest.raises(ValueError, match=r"sample 7 of batch element \[1\]"):
        RelativePoses(t, t, xb, rot_sigma=0.01, trans_sigma=0.01)
    mask = torch.ones(21, dtype=torch.bool)
    mask[7] = False  # masked, it is never read
    Poses(t, x, rot_sigma=0.01, trans_sigma=0.01, mask=mask)


# ----------------------------------------------------------------------------- 3. one Free

def test_a_free_shared_by_different_kinds_names_both_and_mutates_nothing(gen):
    t = grid(0.0, 2.0, 10)
    ti = grid(0.2, 1.8, 50)
    gy, ac = imu_of(ti.numpy())
    gy = gy + 0.01 * torch.randn(gy.shape, generator=gen, dtype=F64)  # noise as its sigma
    shared = Free()
    gyro = Gyro(ti, gy, sigma=0.01, bias=shared)
    with pytest.raises(ValueError, match=r"fitting\.Accel.*time_offset.*fitting\.Gyro.*bias"):
        Accel(ti, ac, sigma=0.1, time_offset=shared)
    with pytest.raises(ValueError, match=r"gravity.*bias"):
        Accel(ti, ac, sigma=0.1, gravity=shared)  # (3,) both, of different kinds
    assert shared.value is None
    import copy
    import pickle
    for twin in (copy.deepcopy(gyro), pickle.loads(pickle.dumps(gyro))):  # the uses travel
        with pytest.raises(ValueError, match="another kind"):
            Accel(ti, ac, sigma=0.1, time_offset=twin.slots()["bias"].free)
    # the same kind twice is one parameter (a shared clock)
    clock = Free()
    Gyro(ti, gy, sigma=0.01, time_offset=clock)
    Accel(ti, ac, sigma=0.1, time_offset=clock)
    x = poses_of(t)
    x = dq.mul(x, dq.exp(0.01 * torch.randn(len(t), 6, generator=gen, dtype=F64)))
    est = estimate(spline_on(t, x, 0.2), [Poses(t, x, rot_sigma=0.01, trans_sigma=0.01), gyro],
                   verbose=False)
    assert est.std(gyro, "bias").shape == (3,) and shared.value.shape == (3,)
    del gyro, est  # a term no longer alive does not hold its Free's kind
    import gc
    gc.collect()
    Accel(ti, ac, sigma=0.1, time_offset=Free(start=0.0))


# ----------------------------------------------------------------------------- 4. correlation start

def test_correlation_start_on_shared_times_in_a_batch(gen):
    """Two trajectories on shared (N,) times, their gyroscopes offset by 20 and -30 ms: the
    correlation start finds each offset (it crashed with an expand error)."""
    t = grid(0.0, 3.0, 20)
    ti = grid(0.2, 2.8, 100)
    x = torch.stack((poses_of(t), poses_of(t + 0.5)))
    gy = torch.stack((imu_of(ti.numpy() + 0.02)[0], imu_of(ti.numpy() + 0.5 - 0.03)[0]))
    spline = BSpline.from_dualquats(x, t, n_ctrl=33, form="cumulative")
    gy = gy + 0.001 * torch.randn(gy.shape, generator=gen, dtype=F64)
    gyro = Gyro(ti, gy, sigma=0.001, time_offset=True)
    start = gyro.values(spline)["time_offset"]
    assert start.shape == (2,)
    torch.testing.assert_close(start, torch.tensor([0.02, -0.03], dtype=F64), rtol=0,
                               atol=2e-3)
    row = BSpline(spline.control_points[1].detach(), knots=spline.knots, form="cumulative")
    one = Gyro(ti, gy[1], sigma=0.001, time_offset=True).values(row)["time_offset"]
    torch.testing.assert_close(start[1], one, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- 5. sigmas, matrices

@pytest.mark.parametrize("value", [float("inf"), float("nan"), 0.0, -1.0,
                                   (1.0, float("inf"), 1.0)])
def test_sigmas_must_be_positive_and_finite(value):
    t = grid(0.0, 1.0, 10)
    with pytest.raises(ValueError, match=r"fitting\.Gyro.*sigma"):
        Gyro(t, torch.zeros(11, 3, dtype=F64), sigma=value)
    with pytest.raises(ValueError, match=r"fitting\.Poses.*trans_sigma"):
        Poses(t, poses_of(t), rot_sigma=0.1, trans_sigma=value)


def _matrices(t):
    R, p = truth(t)[:2]
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R.as_matrix(), p
    return torch.from_numpy(T)


@pytest.mark.parametrize(("edit", "what"), [
    (lambda M: M.__setitem__((4, slice(0, 3), slice(0, 3)), 1.1 * M[4, :3, :3]), "rotation"),
    (lambda M: M.__setitem__((4, slice(0, 3), slice(0, 3)), -M[4, :3, :3]), "det"),
    (lambda M: M.__setitem__(4, M[4].mT.clone()), "last row"),  # transposed: translation below
    (lambda M: M.__setitem__((4, 3, 3), 2.0), "last row"),
])
def test_non_rigid_matrices_are_refused_naming_the_sample(edit, what):
    t = grid(0.0, 1.0, 10)
    M = _matrices(t.numpy())
    Poses(t, M, rot_sigma=0.01, trans_sigma=0.01)  # rigid: accepted
    edit(M)
    with pytest.raises(ValueError, match=f"sample 4.*{what}|{what}.*sample 4"):
        Poses(t, M, rot_sigma=0.01, trans_sigma=0.01)
    with pytest.raises(ValueError, match="sample 4"):
        RelativePoses(t, t, M, rot_sigma=0.01, trans_sigma=0.01)
    Poses(t, M.float(), rot_sigma=0.01, trans_sigma=0.01,
          mask=torch.arange(11) != 4)  # masked: not read
    from torch_dq.fitting import fit
    spline = BSpline(dq.identity((5,), dtype=F64), knots=None)
    for optimizer in ("lm", "adam"):  # fit's targets: the same check
        with pytest.raises(ValueError, match=r"nn\.fit: .*sample 4"):
            fit(spline, (t - t[0]) / (t[-1] - t[0]), M, optimizer=optimizer, steps=1,
                verbose=False)


# ----------------------------------------------------------------------------- 6. structure

def _positions_imu(gen, ba, g_true, duration=6.0):
    """Positions at 20 Hz (GNSS-like) and an IMU at 100 Hz with an accelerometer bias, in a
    world whose gravity is ``g_true``; the start spline from the true positions and
    identity rotations tilted 3 degrees."""
    t = grid(0.0, duration, 20)
    ti = grid(0.2, duration - 0.2, 100)
    R, p = truth(t.numpy())[:2]
    Ri, _, wi, acci = truth(ti.numpy())
    gyro = torch.from_numpy(Ri.inv().apply(wi))
    accel = torch.from_numpy(Ri.inv().apply(acci - g_true) + ba)
    pos = torch.from_numpy(p) + 0.002 * torch.randn(len(t), 3, generator=gen, dtype=F64)
    tilt = torch.from_numpy((Rotation.from_rotvec([0.05, 0.0, 0.0]) * R).as_quat(
        scalar_first=True))
    spline = spline_on(t, dq.from_rt(tilt, pos), 0.1)
    terms = [Positions(t, pos, sigma=0.002),
             Gyro(ti, gyro + 0.002 * torch.randn(gyro.shape, generator=gen, dtype=F64),
                  sigma=0.002),
             Accel(ti, accel + 0.02 * torch.randn(accel.shape, generator=gen, dtype=F64),
                   sigma=0.02, bias=True, gravity=9.81)]
    return t, R, spline, terms


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # known
def test_positions_with_an_imu_determine_bias_and_gravity_direction(gen):
    """Positions + Gyro + Accel with the accelerometer bias and gravity's direction both
    estimated: refused before as undetermined, determined under varied motion (the
    positions' world accelerations against the specific forces): the estimate recovers
    the bias, the gravity direction and the rotation. 12 steps (the solve stops at 22 on
    no progress): the values checked agree with the stopped solve's within 0.01 of their
    std, the cost within 1e-4 relatively (measured)."""
    ba = np.array([0.08, -0.05, 0.12])
    g_true = 9.81 * np.array([0.02, -0.03, -1.0]) / np.linalg.norm([0.02, -0.03, -1.0])
    t, R, spline, terms = _positions_imu(gen, ba, g_true)
    est = estimate(spline, terms, prior=0.0, steps=12, verbose=False)
    accel = terms[2]
    std_b, std_g = est.std(accel, "bias"), est.std(accel, "gravity")
    assert bool(torch.isfinite(std_b).all()) and bool(torch.isfinite(std_g).all())
    assert np.all(np.abs(accel.bias.numpy() - ba) < 4 * std_b.numpy())
    assert float(std_b.max()) < 0.01  # the bias to 1e-2 of its size
    # the tilt of gravity about the world y axis is seen through the small x and z
    # accelerations of the motion only: its std is 0.06 m/s^2, the others' 0.005
    assert np.all(np.abs(accel.gravity.numpy() - g_true) < 4 * std_g.numpy())
    assert float(np.linalg.norm(accel.gravity.numpy() - g_true)) < 0.2
    # the rotation, from a 3 degree start, agrees with the truth up to the tilt of the
    # estimated gravity (the world's vertical comes from it)
    g = accel.gravity.numpy()
    axis = np.cross(g_true, g)
    tilt = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.asin(
        np.linalg.norm(axis) / np.linalg.norm(g) / np.linalg.norm(g_true)))
    q = dq.to_rt(spline(t[5:-5]))[0].detach().numpy()
    angle = (Rotation.from_quat(q, scalar_first=True) * (tilt * R[5:-5]).inv()).magnitude()
    assert float(angle.max()) < 2e-3


def test_structural_checks_refuse_only_what_no_motion_determines(gen):
    """A Free with a prior is determined; positions with odometry give the rotation; the
    undetermined cases stay refused."""
    from torch_dq.fitting import _structure
    t = grid(0.0, 2.0, 10)
    ti = grid(0.2, 1.8, 20)
    x = poses_of(t)
    gy, ac = imu_of(ti.numpy())
    pos = dq.to_rt(x)[1]
    odo = RelativePoses(t[:-1], t[1:], dq.mul(dq.conj(x[:-1]), x[1:]), rot_sigma=1,
                        trans_sigma=1)
    ok = [[Positions(t, pos, sigma=1), Accel(ti, ac, sigma=1, gravity=9.81,
                                             bias=Free(start=torch.zeros(3), prior_std=0.1))],
          [Positions(t, pos, sigma=1), odo],
          [Positions(t, pos, sigma=1), odo, Accel(ti, ac, sigma=1, bias=True, gravity=9.81)],
          [Positions(t, pos, sigma=1), Gyro(ti, gy, sigma=1),
           Accel(ti, ac, sigma=1, bias=True, gravity=9.81)],
          [Poses(t, x, rot_sigma=1, trans_sigma=1, time_offset=Free(0.0, prior_std=0.01)),
           Gyro(ti, gy, sigma=1, time_offset=True)]]
    for terms in ok:
        _structure.check("fitting.estimate", terms)
    refused = [([Gyro(ti, gy, sigma=1), Accel(ti, ac, sigma=1)], "absolute pose"),
               ([odo], "absolute pose"),
               ([Positions(t, pos, sigma=1), Gyro(ti, gy, sigma=1)], "rotation is undetermined"),
               ([Positions(t, pos, sigma=1), Accel(ti, ac, sigma=1, bias=True, gravity=9.81)],
                "bias and the gravity direction")]
    for terms, match in refused:
        with pytest.raises(ValueError, match=match):
            _structure.check("fitting.estimate", terms)


# ----------------------------------------------------------------------------- 7. units

def _write_tum(path, t, x, order=(1, 2, 3, 0)):
    q, p = (a.numpy() for a in dq.to_rt(x))
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)  # w >= 0, as most writers keep it
    cols = q[:, list(order)]  # TUM: qx qy qz qw
    with open(path, "w") as f:
        f.write("# timestamp tx ty tz qx qy qz qw\n")
        for ti, pi, qi in zip(t, p, cols, strict=True):
            f.write(f"{float(ti)!r} " + " ".join(f"{v:.9f}" for v in (*pi, *qi)) + "\n")


@pytest.mark.parametrize(("scale", "origin", "unit"), [
    (1e9, 1.7e18, "nanoseconds"), (1e9, 0.0, "nanoseconds"), (1e3, 0.0, "milliseconds"),
    (1e6, 0.0, "microseconds")])
def test_trajectory_times_in_another_unit_warn(tmp_path, scale, origin, unit):
    from torch_dq import io
    t = grid(0.0, 4.0, 30)
    path = tmp_path / "traj.txt"
    _write_tum(path, (origin + scale * t).numpy(), poses_of(t))
    with pytest.warns(UserWarning, match=f"look like {unit}"):
        io.read_trajectory(path)
    _write_tum(path, (1.7e9 + t).numpy(), poses_of(t))  # seconds: no warning
    io.read_trajectory(path)
    _write_tum(path, grid(0.0, 40.0, 1).numpy(), poses_of(grid(0.0, 40.0, 1)))  # 1 Hz, moving
    io.read_trajectory(path)


def test_imu_times_in_milliseconds_warn(tmp_path):
    from torch_dq import io
    path = tmp_path / "imu.txt"
    ti = grid(0.0, 2.0, 200)
    rows = np.concatenate((1e3 * ti.numpy()[:, None], np.ones((len(ti), 6))), 1)
    np.savetxt(path, rows)
    with pytest.warns(UserWarning, match="look like milliseconds"):
        io.read_imu(path)
    np.savetxt(path, np.concatenate((ti.numpy()[:, None], np.ones((len(ti), 6))), 1))
    io.read_imu(path)  # seconds: no warning


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_gyro_in_degrees_per_second_warns(gen):
    t = grid(0.0, 3.0, 20)
    ti = grid(0.2, 2.8, 100)
    x = poses_of(t)
    gy = imu_of(ti.numpy(), bg=(0.01, -0.02, 0.005))[0]
    cam = Poses(t, x, rot_sigma=0.002, trans_sigma=0.002)
    with pytest.warns(UserWarning, match="deg/s"):
        estimate(spline_on(t, x, 0.15), [cam, Gyro(ti, torch.rad2deg(gy), sigma=0.3,
                                                     bias=True)], steps=1, verbose=False)
    gyro = Gyro(ti, gy, sigma=0.005, bias=True)  # rad/s: no warning
    gyro.values(spline_on(t, x, 0.15))


def test_long_gyro_records_are_unit_checked_on_strided_samples(monkeypatch):
    """A long record's units check reads evenly strided samples (its memory bounded): with
    8 of 100 samples read, deg/s still warns and rad/s does not."""
    import warnings

    from torch_dq.fitting import _imu
    monkeypatch.setattr(_imu, "_UNITS_SAMPLES", 8)
    t = grid(0.0, 3.0, 20)
    ti = grid(0.2, 2.8, 100)
    x = poses_of(t)
    gy = imu_of(ti.numpy(), bg=(0.01, -0.02, 0.005))[0]
    with pytest.warns(UserWarning, match="deg/s"):
        Gyro(ti, torch.rad2deg(gy), sigma=0.3).values(spline_on(t, x, 0.15))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Gyro(ti, gy, sigma=0.005).values(spline_on(t, x, 0.15))


@pytest.mark.filterwarnings("ignore:fitting.estimate. steps=:RuntimeWarning")  # on purpose
def test_accel_in_g_warns(gen):
    """Readings in g (mean magnitude about 1 against gravity's 9.81): a warning naming g at
    the estimate's start; the same readings in m/s^2 give none."""
    import warnings
    t = grid(0.0, 3.0, 20)
    ti = grid(0.2, 2.8, 100)
    x = poses_of(t)
    ac = imu_of(ti.numpy())[1]
    cam = Poses(t, x, rot_sigma=0.002, trans_sigma=0.002)
    with pytest.warns(UserWarning, match="look like g, not m/s"):
        estimate(spline_on(t, x, 0.15), [cam, Accel(ti, ac / 9.80665, sigma=0.05, bias=True)],
                 steps=1, verbose=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Accel(ti, ac, sigma=0.05, bias=True).values(spline_on(t, x, 0.15))


# ----------------------------------------------------------------------------- 8. fine knots

def test_from_poses_on_knots_finer_than_the_poses_with_a_margin():
    """knot_spacing finer than the poses (more control points than poses) and a margin:
    exact for a constant screw motion over the whole widened domain; on the motion of
    ``truth`` at 10 Hz with knots every 25 ms, the start's positions, angular rates and
    accelerations agree with the analytic ones (the IMU reads the last two)."""
    t = grid(0.0, 3.0, 10)
    xi = torch.tensor([0.1, -0.3, 0.8, 1.0, 0.2, -0.1], dtype=F64)
    q, p = dq.to_rt(dq.exp(t[:, None] * xi))
    s = BSpline.from_poses(q, p, t, knot_spacing=0.025, margin=0.1, form="cumulative")
    assert s.n_ctrl == 128 + 3 and s.domain == (-0.1, 3.1)  # 3.2 s in 128 spans of 25 ms
    tt = torch.linspace(-0.1, 3.1, 301, dtype=F64)
    torch.testing.assert_close(s(tt).detach(), dq.exp(tt[:, None] * xi), rtol=0, atol=1e-12)
    q, p = dq.to_rt(poses_of(t))
    tt = grid(0.0, 3.0, 200)
    _, P, W, ACC = truth(tt.numpy())
    for form in ("cumulative", "de_boor"):
        s = BSpline.from_poses(q, p, t, knot_spacing=0.025, margin=0.1, form=form)
        k = s.kinematics(tt)
        pos = dq.to_rt(s(tt).detach())[1]
        assert float((pos - torch.from_numpy(P)).norm(dim=-1).max()) < 2e-3  # m
        assert float((k.angular_velocity.detach() - torch.from_numpy(W)).norm(
            dim=-1).max()) < 5e-3  # rad/s, of rates up to 0.94
        if form == "cumulative":  # C2: accelerations continuous
            acc = (k.linear_acceleration.detach() - torch.from_numpy(ACC)).norm(dim=-1)
            assert float(acc.max()) < 0.3 and float(acc.median()) < 0.1  # of up to 4 m/s^2
    # per-trajectory times: each row its own domain, widened
    tb = torch.stack((t, t + 10.0))
    qb, pb = (torch.stack((a, a)) for a in (q, p))
    sb = BSpline.from_poses(qb, pb, tb, knot_spacing=0.05, margin=0.2)
    assert torch.allclose(sb.knots[:, 3], torch.tensor([-0.2, 9.8], dtype=F64))
    for b in range(2):  # each row as its own fit
        one = BSpline.from_poses(q, p, tb[b], knot_spacing=0.05, margin=0.2)
        torch.testing.assert_close(sb(tb)[b], one(tb[b]), rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="n_ctrl or knot_spacing, not both"):
        BSpline.from_poses(q, p, t, n_ctrl=10, knot_spacing=0.1)
    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="knot_spacing must be a finite number > 0"):
            BSpline.from_poses(q, p, t, knot_spacing=bad)
    with pytest.raises(ValueError, match="margin must be a finite number >= 0"):
        BSpline.from_poses(q, p, t, n_ctrl=10, margin=-0.1)
    with pytest.raises(ValueError, match=r"underdetermined.*knot_spacing="):
        BSpline.from_poses(q, p, t, n_ctrl=40)  # n_ctrl alone: no more than the poses


def test_fine_knots_with_an_imu_and_a_margin_for_the_clock_offset(gen):
    """The use that needs both: poses at 10 Hz, an IMU at 200 Hz over the whole pose span
    with a 15 ms clock offset estimated, knots every 25 ms from from_poses(knot_spacing=,
    margin=max_time_offset): no sample trimmed, the offset recovered."""
    t = grid(0.0, 4.0, 10)
    ti = grid(0.0, 4.0, 200)
    x = poses_of(t)
    q, p = dq.to_rt(x)
    gy, ac = imu_of(ti.numpy() + 0.015, (0.01, -0.02, 0.005), (0.1, -0.05, 0.2))
    spline = BSpline.from_poses(q, p, t, knot_spacing=0.025, margin=0.05, form="cumulative")
    clock = Free()
    gyro = Gyro(ti, gy + 0.002 * torch.randn(gy.shape, generator=gen, dtype=F64), sigma=0.002,
                bias=True, time_offset=clock, max_time_offset=0.05)
    accel = Accel(ti, ac + 0.02 * torch.randn(ac.shape, generator=gen, dtype=F64), sigma=0.02,
                  bias=True, time_offset=clock, max_time_offset=0.05)
    import warnings
    with warnings.catch_warnings():  # the margin's first control points have no sample
        warnings.simplefilter("ignore", RuntimeWarning)
        est = estimate(spline, [Poses(t, x, rot_sigma=0.001, trans_sigma=0.001), gyro, accel],
                       prior=0.0, verbose=False)
        std = float(est.std(gyro, "time_offset"))
    assert 0.0 < std < 1e-3 and abs(float(gyro.time_offset) - 0.015) < 4 * std


def test_fit_cli_with_an_imu_chooses_fine_knots_and_reports_chi2(tmp_path, capsys):
    """``fit FILE --imu``: the IMU's knots (5 IMU periods, finer than the 20 Hz poses), each
    term's chi2/dof in summary.json, the IMU file's unit warning there too, finite
    uncertainties."""
    import json

    from torch_dq.__main__ import main
    t = grid(0.0, 6.0, 20)
    _write_tum(tmp_path / "poses.txt", t.numpy(), poses_of(t))
    ti = grid(0.0, 6.0, 100)
    gen = np.random.default_rng(3)
    gy, ac = imu_of(ti.numpy(), (0.01, -0.02, 0.005), (0.1, -0.05, 0.2))
    rows = np.column_stack((1e3 * ti.numpy(), gy.numpy() + 2e-3 * gen.normal(size=gy.shape),
                            ac.numpy() + 2e-2 * gen.normal(size=ac.shape)))
    np.savetxt(tmp_path / "imu_ms.txt", rows, fmt="%.12g")
    main(["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu_ms.txt"),
          "--out", str(tmp_path / "ms"), "--no-plots", "--quiet"])
    assert "the times look like milliseconds" in capsys.readouterr().err
    rows[:, 0] *= 1e-3
    np.savetxt(tmp_path / "imu.txt", rows, fmt="%.12g")
    out = tmp_path / "o"
    assert main(["fit", str(tmp_path / "poses.txt"), "--imu", str(tmp_path / "imu.txt"),
                 "--out", str(out), "--no-plots", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    imu = summary["imu"]
    assert imu["knots"]["spacing_s"] <= 0.05 + 1e-9 and summary["model"]["n_ctrl"] > 121
    assert summary["model"]["knot_spacing_s"] == imu["knots"]["spacing_s"]
    for name in ("Poses", "Gyro", "Accel"):
        assert {"chi2", "dof", "chi2_per_dof"} <= set(imu["chi2"][name])
    assert 0.5 < imu["chi2"]["Gyro"]["chi2_per_dof"] < 2.0
    for key in ("gyro_bias_rad_s", "accel_bias_m_s2"):
        assert np.all(np.isfinite(imu[key]["std"])), (key, imu[key])


def test_fit_cli_tells_swapped_quaternion_columns_by_the_gyroscope(tmp_path):
    """A TUM file written w first (qw qx qy qz): the poses alone cannot tell, the gyroscope
    can: a warning in summary.json names the order; none for the right order."""
    import json

    from torch_dq.__main__ import main
    t = grid(0.0, 6.0, 20)
    ti = grid(0.0, 6.0, 100)
    gy, ac = imu_of(ti.numpy())
    np.savetxt(tmp_path / "imu.txt", np.column_stack((ti.numpy(), gy.numpy(), ac.numpy())),
               fmt="%.12g")
    found = {}
    for name, order in (("right", (1, 2, 3, 0)), ("w_first", (0, 1, 2, 3))):
        _write_tum(tmp_path / f"{name}.txt", t.numpy(), poses_of(t), order)
        out = tmp_path / name
        main(["fit", str(tmp_path / f"{name}.txt"), "--imu", str(tmp_path / "imu.txt"),
              "--out", str(out), "--no-plots", "--quiet", "--steps", "3"])
        found[name] = json.loads((out / "summary.json").read_text())["warnings"]
    assert not any("quaternion columns" in w for w in found["right"]), found["right"]
    assert any("look like qw qx qy qz" in w for w in found["w_first"]), found["w_first"]
    assert sum("quaternion columns" in w for w in found["w_first"]) == 1, found["w_first"]


def test_an_offset_beyond_the_domain_names_the_margin_that_fixes_it():
    """A camera clock offset estimated on a trajectory built from the same poses reaches
    ``max_time_offset`` beyond the domain: the error says which ``margin`` of
    ``from_dualquats`` covers it, and with that margin the estimate runs and finds the
    offset (a new user's path: the message alone was "extend the trajectory")."""
    t = torch.linspace(0.0, 4.0, 81, dtype=F64)
    twist = torch.stack((0.3 * torch.sin(t), 0.2 * torch.cos(0.7 * t), 0.1 * t,
                         torch.sin(0.5 * t), 0.5 * torch.cos(0.3 * t), 0.2 * t), -1)
    truth = BSpline.from_dualquats(dq.exp(twist), t, n_ctrl=30, form="cumulative", margin=0.1)
    seen = truth(t + 0.02).detach()  # the sample stamped t shows the body at t + 0.02
    gyro_times = torch.linspace(0.0, 4.0, 401, dtype=F64)
    with torch.no_grad():
        x, dx = truth.derivatives(gyro_times, 1)
    gyro = Gyro(gyro_times, 2.0 * dq.mul(dq.conj(x), dx)[..., 1:4], sigma=1e-3)  # the clock
    offset = Free()
    poses = Poses(t, seen, rot_sigma=1e-3, trans_sigma=1e-3, time_offset=offset)
    with pytest.raises(ValueError, match=r"margin=0\.1\b.*or lower max_time_offset"):
        estimate(BSpline.from_dualquats(seen, t, n_ctrl=30, form="cumulative"), [poses, gyro],
                 verbose=False)
    spline = BSpline.from_dualquats(seen, t, n_ctrl=30, form="cumulative", margin=0.1)
    est = estimate(spline, [poses, gyro], verbose=False)
    assert est.converged.all()
    assert abs(float(offset.value) - 0.02) < 5e-4

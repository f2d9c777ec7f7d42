"""Per-trajectory times: knots ``(B, K)`` in ``curves.bspline`` / ``bspline_derivatives``, and
layers whose rows have their own knots and float64 origins (``BSpline.from_poses`` with
``(B, N)`` times).

Each batched result is compared row by row with separate 1-D-knot curves (both forms,
derivatives, kinematics, the IMU), and with independent references: the textbook De Boor
scheme over screw interpolation of 4x4 matrices (tests/references.py, pytransform3d) and,
for ``from_poses``, the constant screw motion that the fit contains exactly."""

import io
import math

import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch
from references import deboor_np, sclerp_mat

import torch_dq.dualquat as dq
from torch_dq import curves, quat
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64
FORMS = ("de_boor", "cumulative", "split")


def chain(batch, n, gen, step=0.4):
    """Control points whose neighbours differ by moderate screw motions, ``(*batch, n, 8)``."""
    xi = torch.randn(*batch, n, 6, generator=gen, dtype=F64) * step
    return dq.exp(xi.cumsum(-2))


def row_knots(n, p, ends, interior=None):
    """Clamped knots per row on ``ends[b] = (t0, t1)``; non-uniform when ``interior`` moves
    the interior knots of a row (fractions of the row's length)."""
    rows = []
    for b, (t0, t1) in enumerate(ends):
        u = curves.clamped_uniform_knots(n, p, dtype=F64)
        if interior is not None:
            u[p + 1:n] = torch.tensor(interior[b], dtype=F64)
        rows.append(t0 + (t1 - t0) * u)
    return torch.stack(rows)


def row_times(knots, p, n, count):
    """``(B, count)`` times across each row's domain, ends included."""
    return torch.stack([torch.linspace(float(k[p]), float(k[n]), count, dtype=F64)
                        for k in knots])


ENDS = [(0.0, 2.0), (10.0, 13.5), (-4.0, -3.0)]
INTERIOR = [[0.2, 0.5, 0.6], [0.4, 0.45, 0.9], [0.1, 0.7, 0.8]]


# ----------------------------------------------------------------------------- curves

@pytest.mark.parametrize("form", FORMS)
def test_batched_knots_equal_separate_curves(gen, form):
    """Each row of a (B, K)-knot evaluation is the 1-D-knot curve of that row: poses and
    derivatives to order 3, at times of its own, to 1e-12 in float64."""
    n, p = 7, 3
    ctrl = chain((3,), n, gen)
    knots = row_knots(n, p, ENDS, INTERIOR)
    t = row_times(knots, p, n, 23)
    x = curves.bspline(ctrl, t, knots=knots, form=form)
    jets = curves.bspline_derivatives(ctrl, t, order=3, knots=knots, form=form)
    assert x.shape == (3, 23, 8) and all(j.shape == (3, 23, 8) for j in jets)
    for b in range(3):
        ref = curves.bspline(ctrl[b], t[b], knots=knots[b], form=form)
        torch.testing.assert_close(x[b], ref, rtol=0, atol=1e-12)
        refs = curves.bspline_derivatives(ctrl[b], t[b], order=3, knots=knots[b], form=form)
        for k, (a, r) in enumerate(zip(jets, refs, strict=True)):
            scale = max(1.0, float(r.abs().max()))
            torch.testing.assert_close(a[b], r, rtol=0, atol=1e-12 * scale, msg=f"order {k}")


def test_batched_knots_match_textbook_de_boor(gen):
    """Independent reference: De Boor over screw interpolation of 4x4 matrices, each row on
    its own knots."""
    n, p = 6, 2
    ctrl = chain((2,), n, gen)
    knots = row_knots(n, p, ENDS[:2], [[0.3, 0.4, 0.8], [0.5, 0.6, 0.7]])
    t = row_times(knots, p, n, 9)
    x = dq.to_matrix(curves.bspline(ctrl, t, degree=p, knots=knots)).numpy()
    mats = dq.to_matrix(ctrl).numpy()
    for b in range(2):
        for i, s in enumerate(t[b].tolist()):
            ref = deboor_np(mats[b], knots[b].tolist(), p, s, sclerp_mat)
            np.testing.assert_allclose(x[b, i], ref, atol=1e-10)


def test_knot_rows_broadcast(gen):
    """Knots (B, K) broadcast with ctrl's and t's batch: shared control points (n, 8) with
    per-row knots, shared times (T,) with per-row knots, and a (C, B) batch of control
    points over (B, K) knots."""
    n, p = 6, 3
    knots = row_knots(n, p, [(0.0, 1.0), (0.0, 2.0)])
    ctrl = chain((), n, gen)
    t = torch.linspace(0.0, 1.0, 5, dtype=F64)
    x = curves.bspline(ctrl, t, knots=knots)
    assert x.shape == (2, 5, 8)
    for b in range(2):
        torch.testing.assert_close(x[b], curves.bspline(ctrl, t, knots=knots[b]),
                                   rtol=0, atol=1e-12)
    ctrl4 = chain((4, 2), n, gen)
    x4 = curves.bspline(ctrl4, t, knots=knots, form="cumulative")
    assert x4.shape == (4, 2, 5, 8)
    torch.testing.assert_close(x4[3, 1], curves.bspline(ctrl4[3, 1], t, knots=knots[1],
                                                        form="cumulative"), rtol=0, atol=1e-12)


@pytest.mark.parametrize("form", FORMS)
def test_batched_knots_gradcheck(gen, form):
    """First and second derivatives with respect to the control points and t, on a small
    case with rows of their own knots."""
    n, p = 3, 2
    ctrl = chain((2,), n, gen).requires_grad_()
    knots = row_knots(n, p, [(0.0, 1.0), (5.0, 7.0)])
    t = torch.tensor([[0.1, 0.9], [5.3, 6.9]], dtype=F64, requires_grad=True)

    def pose(c, s):
        return curves.bspline(dq.normalize(c), s, degree=p, knots=knots, form=form)

    def accel(c):
        return curves.bspline_derivatives(dq.normalize(c), t.detach(), order=2, degree=p,
                                          knots=knots, form=form)[2]

    assert torch.autograd.gradcheck(pose, (ctrl, t), fast_mode=True)
    assert torch.autograd.gradcheck(accel, (ctrl,), fast_mode=True)
    assert torch.autograd.gradgradcheck(lambda c: pose(c, t.detach()), (ctrl,),
                                        fast_mode=True)


def test_unix_times_float32_control_points(gen):
    """float64 UNIX-second knots per row with float32 control points: spans and local
    parameters in float64, the result within float32 rounding of the float64 curve and
    equal to the separate 1-D-knot curves."""
    n, p = 6, 3
    ctrl = chain((2,), n, gen)
    knots = row_knots(n, p, [(1.7e9, 1.7e9 + 30.0), (1.7e9 + 100.0, 1.7e9 + 101.0)])
    t = row_times(knots, p, n, 17)
    for form in FORMS:
        x32 = curves.bspline_derivatives(ctrl.float(), t, order=1, knots=knots, form=form)
        x64 = curves.bspline_derivatives(ctrl, t, order=1, knots=knots, form=form)
        for a, r in zip(x32, x64, strict=True):
            assert a.dtype == torch.float32
            scale = float(r.abs().max())
            torch.testing.assert_close(a.double(), r, rtol=0, atol=2e-5 * scale)
        for b in range(2):
            one = curves.bspline(ctrl[b].float(), t[b], knots=knots[b], form=form)
            torch.testing.assert_close(x32[0][b], one, rtol=0, atol=1e-6)


def test_bad_knot_rows(gen):
    n, p = 5, 3
    ctrl = chain((2,), n, gen)
    knots = row_knots(n, p, [(0.0, 1.0), (2.0, 3.0)])
    t = row_times(knots, p, n, 4)
    with pytest.raises(ValueError, match=r"^curves\.bspline: expected \(\.\.\., n \+ degree "
                                         r"\+ 1\) = \(\.\.\., 9\) knots"):
        curves.bspline(ctrl, t, knots=knots[:, :-1])
    with pytest.raises(ValueError, match=r"^curves\.bspline: batch shapes do not broadcast: "
                                         r"ctrl \(2,\), knots \(3,\)"):
        curves.bspline(ctrl, t, knots=torch.cat((knots, knots[:1])))
    bad = knots.clone()
    bad[1, 5] = 2.1  # decreasing in row 1
    with pytest.raises(ValueError, match=r"^curves\.bspline: knots must be non-decreasing "
                                         r"\(trajectory \(1,\)\), got \[2\.0, "):
        curves.bspline(ctrl, t, knots=bad)
    flat = knots.clone()
    flat[1] = 2.5  # empty domain in row 1
    with pytest.raises(ValueError, match=r"knots give an empty domain \[knots\[degree\], "
                                         r"knots\[n\]\] = \[2\.5, 2\.5\] \(trajectory \(1,\)\)"):
        curves.bspline_derivatives(ctrl, t, knots=flat)
    inf = knots.clone()
    inf[1, 0] = -math.inf
    with pytest.raises(ValueError, match=r"knots must be finite \(trajectory \(1,\)\)$"):
        curves.bspline(ctrl, t, knots=inf)
    # the domain rules per row: row 1's times inside row 0's domain are outside its own
    with pytest.raises(ValueError, match=r"^curves\.bspline: t must lie in the domain of "
                                         r"trajectory \(1,\) \[2, 3\], got values in "
                                         r"\[0, 1\].*extrapolate=True"):
        curves.bspline(ctrl, t[[0, 0]], knots=knots, form="cumulative")
    # within each row's own tolerance: evaluated at the row's end
    eps = torch.tensor([[-1e-10, 1e-10], [-3e-10, 3e-10]], dtype=F64)  # outward
    ends = torch.stack((knots[:, p], knots[:, n]), -1)
    x = curves.bspline(ctrl, ends + eps, knots=knots)
    torch.testing.assert_close(x, curves.bspline(ctrl, ends, knots=knots), rtol=0, atol=0)
    assert torch.isnan(curves.bspline(ctrl, t[[0, 0]], knots=knots, check=False)[1]).all()


# ----------------------------------------------------------------------------- layers

def screw_poses(times, xis):
    """Constant screw motions, row b: exp((t - t_b0) xi_b), as quaternions and translations."""
    x = dq.exp((times - times[:, :1])[..., None] * xis[:, None, :])
    return dq.to_rt(x)


def uneven_times():
    base = torch.linspace(0.0, 1.0, 24, dtype=F64)
    return torch.stack((2.0 * base, 1.7e9 + 3.0 * base ** 1.3, -50.0 + 1.5 * base ** 0.8))


@pytest.mark.parametrize("form", FORMS)
def test_from_poses_rows_equal_separate_fits(form):
    """from_poses with (B, N) times: each row is the module that from_poses builds from that
    row alone (control points, knots, domain, poses, kinematics, IMU), float32 poses with
    float64 UNIX seconds included; and it contains each row's constant screw motion (the
    split form approximates it)."""
    times = uneven_times()
    xis = torch.tensor([[0.2, -0.1, 0.5, 1.0, 0.3, 0.0], [0.0, 0.3, 0.1, -0.5, 0.2, 0.4],
                        [0.4, 0.0, -0.2, 0.1, 0.0, 2.0]], dtype=F64)
    q, p = screw_poses(times, xis)
    spline = BSpline.from_poses(q, p, times, n_ctrl=7, form=form)
    assert spline.knots.shape == (3, 11) and spline.control_points.shape == (3, 7, 8)
    t0, t1 = spline.domain
    assert t0.tolist() == times[:, 0].tolist() and t1.tolist() == times[:, -1].tolist()
    k = spline.kinematics(times)
    gyro, accel = spline.imu(times)
    x = spline(times)
    for b in range(3):
        one = BSpline.from_poses(q[b], p[b], times[b], n_ctrl=7, form=form)
        assert one.domain == (float(t0[b]), float(t1[b]))
        torch.testing.assert_close(spline.knots[b], one.knots, rtol=0, atol=0)
        torch.testing.assert_close(spline.control_points[b], one.control_points,
                                   rtol=0, atol=1e-12)
        torch.testing.assert_close(x[b], one(times[b]), rtol=0, atol=1e-12)
        for a, r in zip(k, one.kinematics(times[b]), strict=True):
            torch.testing.assert_close(a[b], r, rtol=0, atol=1e-10)
        for a, r in zip((gyro, accel), one.imu(times[b]), strict=True):
            torch.testing.assert_close(a[b], r, rtol=0, atol=1e-10)
    # independent: pytransform3d's exponential coordinates at the sample times
    ref = np.stack([np.stack([pt.transform_from_exponential_coordinates(
        (s - float(times[b, 0])) * xis[b].numpy()) for s in times[b].tolist()])
        for b in range(3)])
    # the split form holds no screw motion (its translation is a polynomial, the helix's is
    # not): its least-squares fit is close, not exact (measured 1.9e-5)
    atol = 1e-4 if form == "split" else 1e-7
    np.testing.assert_allclose(dq.to_matrix(x).detach().numpy(), ref, atol=atol)


def test_from_poses_rows_float32_and_matrices():
    """float32 rotation matrices with float64 UNIX times: each row equals its separate fit,
    and the fit is within float32 rounding of the motion."""
    times = uneven_times()[:2]
    xis = torch.tensor([[0.2, -0.1, 0.5, 1.0, 0.3, 0.0], [0.0, 0.3, 0.1, -0.5, 0.2, 0.4]],
                       dtype=F64)
    q, p = screw_poses(times, xis)
    R = quat.to_matrix(q).float()
    spline = BSpline.from_poses(R, p.float(), times, n_ctrl=6, form="cumulative")
    assert spline.control_points.dtype == torch.float32
    x = spline(times)
    for b in range(2):
        one = BSpline.from_poses(R[b], p[b].float(), times[b], n_ctrl=6, form="cumulative")
        torch.testing.assert_close(x[b], one(times[b]), rtol=0, atol=0)
    err = (dq.to_rt(x)[1].double() - p).norm(dim=-1).max()
    assert err < 2e-5


def test_rows_save_load_and_move(tmp_path):
    """state_dict, from_state_dict, load_state_dict, torch.save of the whole module and
    .to(dtype): the per-row origins stay float64 and the outputs stay the same."""
    times = uneven_times()
    xis = torch.full((3, 6), 0.2, dtype=F64)
    q, p = screw_poses(times, xis)
    spline = BSpline.from_poses(q.float(), p.float(), times, n_ctrl=5, degree=2,
                                form="cumulative")
    ref = spline(times)
    state = spline.state_dict()
    assert state["_extra_state"]["origin"].dtype == F64
    assert state["_extra_state"]["origin"].shape == (3, 1)
    loaded = BSpline.from_state_dict(state)
    assert loaded.degree == 2 and loaded.form == "cumulative"
    torch.testing.assert_close(loaded(times), ref, rtol=0, atol=0)
    fresh = BSpline(dq.identity((3, 5)), degree=2, knots=spline.knots + 1.0,
                    form="cumulative")
    fresh.load_state_dict(state)
    torch.testing.assert_close(fresh(times), ref, rtol=0, atol=0)
    buf = io.BytesIO()
    torch.save(spline, buf)
    buf.seek(0)
    torch.testing.assert_close(torch.load(buf, weights_only=False)(times), ref, rtol=0, atol=0)
    moved = spline.double()
    assert moved.time_model.origin.dtype == F64 and moved.knots.dtype == F64
    torch.testing.assert_close(moved(times).float(), ref, rtol=0, atol=1e-6)
    assert "per trajectory (3,)" in repr(moved)
    bad = dict(state)
    bad["_extra_state"] = {**state["_extra_state"], "origin": torch.zeros(2, 1, dtype=F64)}
    with pytest.raises(ValueError, match=r"origin' tensor of shape \(3, 1\)"):
        fresh.load_state_dict(bad)


def test_rows_basis_per_trajectory():
    """Curve.basis with a row per trajectory: each row's (first, values) are those of the
    separate module, and the values sum to 1."""
    times = uneven_times()
    q, p = screw_poses(times, torch.full((3, 6), 0.1, dtype=F64))
    spline = BSpline.from_poses(q, p, times, n_ctrl=8)
    first, values = spline.basis(times)
    assert first.shape == (3, 24) and values.shape == (3, 24, 4)
    torch.testing.assert_close(values.sum(-1), torch.ones(3, 24, dtype=F64))
    for b in range(3):
        one = BSpline.from_poses(q[b], p[b], times[b], n_ctrl=8)
        f1, v1 = one.basis(times[b])
        assert first[b].tolist() == f1.tolist()
        torch.testing.assert_close(values[b], v1, rtol=0, atol=1e-12)
        torch.testing.assert_close(spline.greville()[b], one.greville(), rtol=0, atol=0)


def test_rows_layer_domain_rules():
    times = uneven_times()
    q, p = screw_poses(times, torch.full((3, 6), 0.1, dtype=F64))
    spline = BSpline.from_poses(q, p, times, n_ctrl=6)
    with pytest.raises(ValueError, match=r"^nn\.BSpline\.forward: t must lie in the module's "
                                         r"time domain of trajectory \(2,\) \[-50, -48\.5\]"):
        spline(times[[0, 1, 1]])
    out = spline(times[[0, 1, 1]], extrapolate=True)
    assert torch.isfinite(out).all()
    spline.check = False
    assert torch.isnan(spline.derivatives(times[[0, 1, 1]])[1][2]).all()


def test_bad_per_row_from_poses():
    times = uneven_times()
    q, p = screw_poses(times, torch.full((3, 6), 0.1, dtype=F64))
    bad = times.clone()
    bad[1, 5] = bad[1, 4]
    with pytest.raises(ValueError, match=r"^nn\.BSpline\.from_poses: times must be strictly "
                                         r"increasing in each row, not so in row 1 \(sort"):
        BSpline.from_poses(q, p, bad, n_ctrl=5)
    bad = times.clone()
    bad[2, 0] = math.nan
    with pytest.raises(ValueError, match=r"times must be finite in each row, not so in row "
                                         r"2$"):
        BSpline.from_poses(q, p, bad, n_ctrl=5)
    with pytest.raises(ValueError, match=r"times must hold one time per pose: expected shape "
                                         r"\(\.\.\., 24\)"):
        BSpline.from_poses(q, p, times[:, :-1], n_ctrl=5)
    with pytest.raises(ValueError, match=r"batch shapes do not broadcast: poses \(3,\), "
                                         r"times \(2,\)"):
        BSpline.from_poses(q, p, times[:2], n_ctrl=5)
    with pytest.raises(ValueError, match=r"underdetermined: n_ctrl = 25.*N = 24"):
        BSpline.from_poses(q, p, times, n_ctrl=25)
    with pytest.raises(ValueError, match=r"n_ctrl=None chooses the knots from one trajectory"):
        BSpline.from_poses(q[0], p[0], times)
    with pytest.raises(ValueError, match=r"^nn\.Bezier\.from_poses: expected \(N,\) times "
                                         r"shared by the batch.*BSpline\.from_poses\(\.\.\., "
                                         r"n_ctrl=4, degree=3\)"):
        Bezier.from_poses(q, p, times, n_ctrl=4)
    with pytest.raises(ValueError, match=r"^nn\.BSpline: expected \(\.\.\., n \+ degree \+ 1\) "
                                         r"= \(\.\.\., 9\) knots \(a row per trajectory\)"):
        BSpline(dq.identity((3, 5)), knots=torch.zeros(3, 8))
    with pytest.raises(ValueError, match=r"^nn\.BSpline: batch shapes do not broadcast"):
        BSpline(dq.identity((3, 5)), knots=row_knots(5, 3, ENDS[:2]))
    with pytest.raises(ValueError, match=r"time_range \(deprecated\) rescales one knot vector"):
        BSpline(dq.identity((2, 5)), knots=row_knots(5, 3, ENDS[:2]), time_range=(0.0, 1.0))


def test_each_row_has_its_own_tolerance(gen):
    """The tolerance max(1e-9 (t1 - t0), 4 eps max(|t0|, |t1|)) is each row's own: 1e-7
    beyond the end is a rounding for UNIX seconds (tolerance ~1.5e-6) and is evaluated at
    the end, but lies outside a [0, 1] row (tolerance 1e-9)."""
    n, p = 5, 3
    ctrl = chain((2,), n, gen)
    knots = row_knots(n, p, [(0.0, 1.0), (1.7e9, 1.7e9 + 10.0)])
    ends = knots[:, n:n + 1]
    x = curves.bspline(ctrl, ends + torch.tensor([[0.0], [1e-7]], dtype=F64), knots=knots)
    torch.testing.assert_close(x, curves.bspline(ctrl, ends, knots=knots), rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"domain of trajectory \(0,\) \[0, 1\]"):
        curves.bspline(ctrl, ends + 1e-7, knots=knots)
    times = torch.stack((torch.linspace(0.0, 1.0, 12, dtype=F64),
                         torch.linspace(1.7e9, 1.7e9 + 10.0, 12, dtype=F64)))
    q, t = screw_poses(times, torch.full((2, 6), 0.1, dtype=F64))
    spline = BSpline.from_poses(q, t, times, n_ctrl=5)
    spline(times[:, -1:] + torch.tensor([[0.0], [1e-7]], dtype=F64))
    with pytest.raises(ValueError, match=r"module's time domain of trajectory \(0,\)"):
        spline(times[:, -1:] + 1e-7)

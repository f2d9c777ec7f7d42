"""Outside tests of ``fitting.Reprojections`` (API.md, torch_dq.fitting: cameras): residuals
against OpenCV's projection of a pose chain composed in numpy (pytransform3d's matrices),
rolling shutter and clock offset times, and argument checks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import pytransform3d.transformations as ptr
import torch

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.camera import Camera
from torch_dq.nn import BSpline

F64 = torch.float64
PARAMS = [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
          1.76187114e-05]
CAM = Camera("pinhole-radtan", torch.tensor(PARAMS, dtype=F64), (752, 480))
K = np.array([[PARAMS[0], 0, PARAMS[2]], [0, PARAMS[1], PARAMS[3]], [0, 0, 1.0]])
DIST = np.array([*PARAMS[4:], 0.0])
SIGMA = (0.5, 0.7)


def _pose(rotvec, t):
    """An (8,) dual quaternion and its 4 x 4 matrix (pytransform3d)."""
    m = np.eye(4)
    m[:3, :3] = cv2.Rodrigues(np.asarray(rotvec, dtype=np.float64))[0]
    m[:3, 3] = t
    return torch.tensor(ptr.dual_quaternion_from_transform(m)), m


E, E_M = _pose([0.02, -0.03, 0.01], [0.05, -0.02, 0.01])  # camera on the body
T, T_M = _pose([0.1, 0.05, -0.02], [0.1, -0.05, 1.0])  # target in the world


def _spline():
    g = torch.Generator().manual_seed(0)
    return BSpline(dq.exp(torch.randn(8, 6, generator=g, dtype=F64) * 0.05))


def _data(n=60, seed=1):
    rng = np.random.default_rng(seed)
    times = np.sort(rng.uniform(0.2, 0.8, n))
    pts = np.concatenate([rng.uniform(-0.25, 0.25, (n, 2)), np.zeros((n, 1))], -1)
    return times, pts


def ref_pixels(spline, times_eff, pts, e_m=E_M, t_m=T_M):
    """OpenCV pixels of target points from body poses at ``times_eff`` (numpy chain:
    ``p_cam = (T^-1 X E)^-1 p``)."""
    x = spline(torch.tensor(times_eff, dtype=F64)).detach().numpy()
    out = []
    for xi, p in zip(x, pts, strict=True):
        m = np.linalg.inv(t_m) @ ptr.transform_from_dual_quaternion(xi) @ e_m
        pc = np.linalg.inv(m) @ np.append(p, 1.0)
        px, _ = cv2.projectPoints(pc[None, :3], np.zeros(3), np.zeros(3), K, DIST)
        out.append(px[0, 0])
    return np.array(out)


def test_residuals_global_shutter():
    spline = _spline()
    times, pts = _data()
    true = ref_pixels(spline, times, pts)
    assert ((true > 0) & (true < [752, 480])).all()
    measured = true + np.random.default_rng(2).normal(size=true.shape)
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(measured),
                                 camera=CAM, sigma=SIGMA, extrinsic=E, target=T)
    r = term(spline).detach().numpy()
    assert r.shape == (60, 2)
    np.testing.assert_allclose(r, (true - measured) / np.array(SIGMA), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("line_delay,offset", [(5e-5, None), (3e-5, 0.01), (0.0, -0.02)])
def test_rolling_shutter_and_clock_offset(line_delay, offset):
    """``t' = t + time_offset + line_delay * v`` with ``v`` the measured row."""
    spline = _spline()
    times, pts = _data(seed=3)
    measured = ref_pixels(spline, times, pts) + np.random.default_rng(4).normal(size=(60, 2))
    t_eff = times + (offset or 0.0) + line_delay * measured[:, 1]
    expect = (ref_pixels(spline, t_eff, pts) - measured) / np.array(SIGMA)
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(measured),
                                 camera=CAM, sigma=SIGMA, extrinsic=E, target=T,
                                 line_delay=line_delay, time_offset=offset)
    np.testing.assert_allclose(term(spline).detach().numpy(), expect, rtol=1e-9, atol=1e-9)
    if line_delay:  # the global shutter's residuals differ (the body moves)
        glob = (ref_pixels(spline, times + (offset or 0.0), pts) - measured) / np.array(SIGMA)
        assert np.abs(glob - expect).max() > 1e-3


def test_identity_defaults_and_other_models():
    """No extrinsic / target: the camera is the body, the target frame the world; the
    double sphere's pixels through Usenko et al.'s eq. 40 written here."""
    spline = BSpline(dq.identity((4,), dtype=F64))
    times, pts = _data(10, seed=5)
    pts = pts + np.array([0.0, 0.0, 1.0])
    p = [300.0, 310.0, 376.0, 240.0, -0.2, 0.6]
    cam = Camera("double-sphere", p, (752, 480))
    x, y, z = pts.T
    d1 = np.sqrt(x * x + y * y + z * z)
    w = p[4] * d1 + z
    den = p[5] * np.sqrt(x * x + y * y + w * w) + (1 - p[5]) * w
    true = np.stack([p[0] * x / den + p[2], p[1] * y / den + p[3]], -1)
    measured = true + 0.3
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(measured),
                                 camera=cam, sigma=0.3)
    np.testing.assert_allclose(term(spline).detach().numpy(), -np.ones((10, 2)), atol=1e-9)


def test_points_without_image_and_mask_give_zero_residuals():
    spline = BSpline(dq.identity((4,), dtype=F64))
    times = torch.full((4,), 0.5, dtype=F64)
    pts = torch.tensor([[0.0, 0.0, 1.0], [0.1, 0.0, -1.0], [0.1, 0.1, 1.0], [0.0, 0.1, 2.0]],
                       dtype=F64)
    pix = torch.tensor([[300.0, 200.0], [400.0, 250.0], [100.0, 100.0], [367.0, 248.0]],
                       dtype=F64)
    mask = torch.tensor([True, True, False, True])
    term = fitting.Reprojections(times, pts, pix, camera=CAM, sigma=1.0, mask=mask)
    r = term(spline).detach()
    assert r[1].tolist() == [0.0, 0.0] and r[2].tolist() == [0.0, 0.0]
    assert abs(r[0, 0].item() - (PARAMS[2] - 300.0)) < 1e-12
    assert bool(torch.isfinite(r).all())


def test_inputs_not_modified():
    times, pts = _data(8, seed=6)
    t, p = torch.tensor(times), torch.tensor(pts)
    pix = torch.full((8, 2), 300.0, dtype=F64)
    copies = [t.clone(), p.clone(), pix.clone(), E.clone()]
    term = fitting.Reprojections(t, p, pix, camera=CAM, sigma=1.0, extrinsic=E, target=T)
    term(_spline())
    for a, b in zip((t, p, pix, E), copies, strict=True):
        assert torch.equal(a, b)


def _args(n=5):
    return (torch.linspace(0.2, 0.8, n, dtype=F64), torch.zeros(n, 3, dtype=F64) + 0.1,
            torch.full((n, 2), 300.0, dtype=F64))


@pytest.mark.parametrize("change,match", [
    ({"line_delay": -1e-5}, "line_delay"),
    ({"line_delay": torch.tensor(-1e-5, dtype=F64)}, "line_delay"),
    ({"line_delay": float("nan")}, "line_delay"),
    ({"sigma": -1.0}, "sigma"),
    ({"sigma": 0.0}, "sigma"),
    ({"sigma": (1.0, 2.0, 3.0)}, "sigma"),
    ({"max_line_delay": 0.0}, "max_line_delay"),
    ({"extrinsic": torch.zeros(7, dtype=F64)}, "extrinsic"),
    ({"target": torch.zeros(3, 8, 8, dtype=F64)}, "target"),
    ({"intrinsics": torch.zeros(7, dtype=F64)}, "intrinsics"),
    ({"intrinsics": torch.tensor([-1.0, 1, 1, 1, 0, 0, 0, 0], dtype=F64)}, "intrinsics"),
    ({"mask": torch.ones(4, dtype=torch.bool)}, "mask"),
    ({"robust": "tukey"}, "robust"),
])
def test_bad_arguments_raise_naming_them(change, match):
    with pytest.raises(ValueError, match=match):
        fitting.Reprojections(*_args(), camera=CAM, **{"sigma": 1.0, **change})


@pytest.mark.parametrize("args,match", [
    ((torch.linspace(0.2, 0.8, 4, dtype=F64), *_args()[1:]), "times"),
    ((_args()[0], torch.zeros(5, 2, dtype=F64), _args()[2]), "points"),
    ((_args()[0], _args()[1], torch.zeros(5, 3, dtype=F64)), "pixels"),
    ((_args()[0], torch.zeros(4, 3, dtype=F64), _args()[2]), "points"),
    ((_args()[0], _args()[1], torch.zeros(3, 2, dtype=F64)), "pixels"),
    ((_args()[0], _args()[1], torch.zeros(2, dtype=F64)), "pixels"),
])
def test_mismatched_shapes_raise(args, match):
    with pytest.raises(ValueError, match=match):
        fitting.Reprojections(*args, camera=CAM, sigma=1.0)


def test_bad_types_raise():
    t, p, px = _args()
    with pytest.raises(TypeError, match="camera"):
        fitting.Reprojections(t, p, px, camera=PARAMS, sigma=1.0)
    with pytest.raises(TypeError):
        fitting.Reprojections(t, p, px.long(), camera=CAM, sigma=1.0)
    with pytest.raises(TypeError):
        fitting.Reprojections(t.long(), p, px, camera=CAM, sigma=1.0)
    with pytest.raises(ValueError, match="finite"):
        fitting.Reprojections(t, p.index_fill(0, torch.tensor([1]), float("nan")), px,
                              camera=CAM, sigma=1.0)


def test_batch_rows_are_independent_problems():
    """times (B, N), pixels (B, N, 2), points (N, 3) shared, control points (B, n, 8):
    row b is the unbatched term of row b."""
    spline = _spline()
    times, pts = _data(12, seed=7)
    meas = ref_pixels(spline, times, pts) + 0.5
    ctrl = spline.control_points.detach()
    both = fitting.Reprojections(torch.tensor(np.stack([times, times + 0.05])),
                                 torch.tensor(pts), torch.tensor(np.stack([meas, meas + 1])),
                                 camera=CAM, sigma=SIGMA, extrinsic=E, target=T,
                                 line_delay=2e-5)
    r = both(BSpline(torch.stack([ctrl, ctrl]))).detach()
    assert r.shape == (2, 12, 2)
    for b, (t, m) in enumerate(((times, meas), (times + 0.05, meas + 1))):
        expect = (ref_pixels(spline, t + 2e-5 * m[:, 1], pts) - m) / np.array(SIGMA)
        np.testing.assert_allclose(r[b].numpy(), expect, rtol=1e-9, atol=1e-9)


def test_estimate_recovers_line_delay():
    """Noise-free rolling-shutter pixels (the row and the time solved together by fixed
    point in numpy): ``estimate`` with ``line_delay=True`` (start 0) returns the truth,
    4e-5 s per row, within 2 % of its standard deviation."""
    spline = _spline()
    rng = np.random.default_rng(8)
    n, ld = 200, 4e-5
    times = np.sort(rng.uniform(0.1, 0.9, n))
    pts = np.concatenate([rng.uniform(-0.3, 0.3, (n, 2)), np.zeros((n, 1))], -1)
    meas = ref_pixels(spline, times, pts)
    for _ in range(6):
        meas = ref_pixels(spline, times + ld * meas[:, 1], pts)
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(meas),
                                 camera=CAM, sigma=0.5, extrinsic=E, target=T,
                                 line_delay=True)
    start = BSpline(spline.control_points.detach().clone())
    est = fitting.estimate(start, [term], verbose=False)
    with pytest.warns(RuntimeWarning, match="chi2"):  # noise-free: chi2 / dof far below 1
        std = float(est.std(term, "line_delay"))
    assert 0 < std < 1e-5
    assert abs(float(term.line_delay) - ld) < 0.02 * std


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_nonfinite_data_raise_unless_masked(bad):
    spline = _spline()
    times, pts = _data(10, seed=9)
    meas = torch.tensor(ref_pixels(spline, times, pts))
    meas[3, 1] = bad  # a row: it would also move the rolling shutter's time
    with pytest.raises(ValueError, match="finite"):
        fitting.Reprojections(torch.tensor(times), torch.tensor(pts), meas, camera=CAM,
                              sigma=1.0, extrinsic=E, target=T)
    mask = torch.ones(10, dtype=torch.bool)
    mask[3] = False
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), meas, camera=CAM,
                                 sigma=1.0, extrinsic=E, target=T, mask=mask,
                                 line_delay=1e-5)
    r = term(spline).detach()
    assert bool(torch.isfinite(r).all()) and r[3].tolist() == [0.0, 0.0]
    t = torch.tensor(times)
    t[2] = bad
    with pytest.raises(ValueError, match="times"):
        fitting.Reprojections(t, torch.tensor(pts), meas, camera=CAM, sigma=1.0, mask=mask)


def test_estimate_excludes_points_without_image_and_reports_shapes():
    """A point behind the camera at the solution: excluded, counted in ``term.invalid``
    and named in a warning; the truth (noise-free) is kept; std shapes as documented."""
    spline = _spline()
    times, pts = _data(120, seed=11)
    meas = ref_pixels(spline, times, pts)
    pts[7] = [0.0, 0.0, -3.0]  # target z = -3: about 2 m behind the camera
    meas[7] = [300.0, 200.0]
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(meas),
                                 camera=CAM, sigma=0.5, extrinsic=E, target=T,
                                 intrinsics=True, line_delay=True)
    start = BSpline(spline.control_points.detach().clone())
    with pytest.warns(RuntimeWarning, match="Reprojections"):
        est = fitting.estimate(start, [term], verbose=False)
    assert int(term.invalid) == 1
    assert float(est.final_loss) < 1e-12
    with pytest.warns(RuntimeWarning):
        assert est.std(term, "intrinsics").shape == (8,)
        assert est.std(term, "line_delay").shape == ()

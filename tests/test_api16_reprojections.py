"""The API contract (docs/api_contract.md), torch_dq.fitting: cameras, audited line by line
(session 16): what the earlier reprojection tests did not pin. References: the pinhole formula
in numpy on the body poses, pytransform3d's exponential coordinates, central differences."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import pytransform3d.transformations as ptr
import torch

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.camera import Camera
from torch_dq.nn import BSpline

F64 = torch.float64
K = (400.0, 410.0, 320.0, 240.0)
CAM = Camera("pinhole", torch.tensor(K, dtype=F64), (640, 480))
SIGMA = 0.5
EYE = np.eye(4)


def _pixels(spline, times, pts, *, extrinsic=EYE, target=EYE, k=K, shift=0.0):
    """numpy pinhole pixels of target points for the camera at ``T^-1 x(t + shift) e``."""
    x = dq.to_matrix(spline(times + shift)).detach().numpy()
    c = np.linalg.inv(target) @ x @ extrinsic  # the camera's poses in the target frame
    pc = np.einsum("nji,nj->ni", c[:, :3, :3], pts - c[:, :3, 3])
    return np.stack([k[0] * pc[:, 0] / pc[:, 2] + k[2], k[1] * pc[:, 1] / pc[:, 2] + k[3]], -1)


def _scene(n_behind_every: int | None = None):
    """A camera (the body, extrinsic identity) swaying slowly in front of a 5 x 6 grid 2 m
    ahead; every ``n_behind_every``-th observation's point (None: none) is moved 4 m behind
    the camera (no image). Pixels from the numpy pinhole of the spline's poses, seeded noise."""
    g = torch.Generator().manual_seed(4)
    ctrl = dq.exp(torch.randn(8, 6, generator=g, dtype=F64) * 0.02)
    spline = BSpline(ctrl)
    frames = np.linspace(0.1, 0.9, 20)
    y, x = np.meshgrid(np.linspace(-0.3, 0.3, 5), np.linspace(-0.4, 0.4, 6), indexing="ij")
    grid = np.stack([x.ravel(), y.ravel(), np.full(x.size, 2.0)], -1)
    times = np.repeat(frames, len(grid))
    pts = np.tile(grid, (len(frames), 1))
    noise = SIGMA * np.random.default_rng(5).standard_normal((len(times), 2))
    pix = _pixels(spline, torch.tensor(times), pts) + noise
    behind = np.zeros(len(times), dtype=bool)
    if n_behind_every:
        behind[::n_behind_every] = True
    pts = np.where(behind[:, None], pts - [0.0, 0.0, 6.0], pts)
    return spline, torch.tensor(times), torch.tensor(pts), torch.tensor(pix), behind


def test_observations_without_image_are_left_out_of_chi2_and_dof():
    """"Observations that project invalid at the solution are excluded": they carry no
    residual, so they carry no degrees of freedom either; ``dof`` is at most the residual
    components of the observations used (2 per valid one), and ``chi2 / dof`` about 1 for
    sigmas that describe the noise (with them counted it reads ~0.8 at 20 % excluded)."""
    spline, times, pts, pix, behind = _scene(5)
    term = fitting.Reprojections(times, pts, pix, camera=CAM, sigma=SIGMA)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fitting.estimate(spline, [term], steps=10, verbose=False)
    used = int((~behind).sum())
    assert int(term.invalid) == int(behind.sum())
    assert float(est.dof[term]) <= 2 * used
    # the cameras' 6 pose dof per control point are all the data determine: dof = 2 N - 48
    assert float(est.dof[term]) == pytest.approx(2 * used - 48, abs=1e-3)
    assert 0.85 < float(est.chi2[term] / est.dof[term]) < 1.15
    weights = est.weights[term]  # no kernel: 1 where used, 0 where excluded (was 1)
    assert torch.equal(weights, torch.tensor(~behind, dtype=weights.dtype))


@pytest.mark.parametrize("line_delay", [-1e-5, torch.tensor(-2e-6, dtype=F64),
                                        fitting.Free(start=-1e-5),
                                        fitting.Free(start=torch.tensor(-1e-6, dtype=F64))])
def test_negative_line_delay_raises_at_construction(line_delay):
    """``line_delay`` (seconds per row, ``>= 0``): a fixed value or a ``Free``'s start below
    zero is a ValueError naming it when the term is made (a Free's start was only refused
    at ``estimate``, and ``term(trajectory)`` predicted with the negative delay meanwhile)."""
    _, times, pts, pix, _ = _scene()
    with pytest.raises(ValueError, match="line_delay must be >= 0"):
        fitting.Reprojections(times, pts, pix, camera=CAM, sigma=SIGMA, line_delay=line_delay)


@pytest.mark.parametrize("line_delay", [0.0, 3e-5, fitting.Free(start=0.0), fitting.Free()])
def test_nonnegative_line_delay_accepted(line_delay):
    """The boundary 0 and a Free without a start (default 0) are fine; the residual of a
    fixed delay moves the samples to ``t + line_delay * v`` (numpy reference at those times:
    rows of the measured pixels)."""
    spline, times, pts, pix, _ = _scene()
    term = fitting.Reprojections(times, pts, pix, camera=CAM, sigma=SIGMA, line_delay=line_delay)
    ell = line_delay if isinstance(line_delay, float) else 0.0
    ref = _pixels(spline, times, pts.numpy(), shift=ell * pix[:, 1])
    np.testing.assert_allclose(term(spline).detach().numpy(), (ref - pix.numpy()) / SIGMA,
                               rtol=1e-9, atol=1e-9)


def test_one_free_for_intrinsics_of_two_models_raises_naming_both():
    """"One ``Free`` given to parameters of different kinds ... is a ValueError naming both":
    a radtan's and an equidistant camera's 8 parameters are different quantities (k1..k4
    mean other things), though both are (8,) vectors; two cameras of one model may share."""
    _, times, pts, pix, _ = _scene()
    p8 = [*K, 0.0, 0.0, 0.0, 0.0]
    radtan = Camera("pinhole-radtan", p8, (640, 480))
    fisheye = Camera("pinhole-equidistant", p8, (640, 480))
    shared = fitting.Free()
    first = fitting.Reprojections(times, pts, pix, camera=radtan, sigma=SIGMA,
                                  intrinsics=shared)
    again = fitting.Reprojections(times, pts, pix, camera=radtan, sigma=SIGMA,
                                  intrinsics=shared)  # a stereo pair of one lens: fine
    with pytest.raises(ValueError, match=r"pinhole-equidistant intrinsics.*pinhole-radtan "
                                         r"intrinsics"):
        fitting.Reprojections(times, pts, pix, camera=fisheye, sigma=SIGMA, intrinsics=shared)
    assert first.intrinsics is None and again.intrinsics is None  # before estimate


# ------------------------------------------------- standard deviations in the stated charts

def _fd_std(residual, steps):
    """Gauss-Newton marginal standard deviations from central differences of ``residual``."""
    jac = np.stack([(residual(h * e) - residual(-h * e)) / (2 * h)
                    for e, h in zip(np.eye(len(steps)), steps, strict=True)], -1)
    return np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)))


def _pinned(spline):
    """A ``Poses`` term at 1e-7 that fixes the trajectory: the nuisance parameters' marginal
    standard deviations are then those of the reprojections alone."""
    tp = torch.linspace(0.02, 0.98, 300, dtype=F64)
    return fitting.Poses(tp, spline(tp).detach(), rot_sigma=1e-7, trans_sigma=1e-7)


def test_std_of_extrinsic_and_intrinsics_in_their_charts():
    """``std(term, "extrinsic")`` ``(6,)`` in the chart ``e exp(delta)`` (a body-frame twist,
    pytransform3d's exponential coordinates: rotation then translation) and ``std(term,
    "intrinsics")`` ``(P,)`` in ``params + delta``, against the Gauss-Newton inverse of a
    numpy projection's central differences."""
    spline, times, pts, _, _ = _scene()
    e = ptr.transform_from_exponential_coordinates([0.02, -0.03, 0.01, 0.05, -0.02, 0.03])
    noise = SIGMA * np.random.default_rng(1).standard_normal((len(times), 2))
    pix = _pixels(spline, times, pts.numpy(), extrinsic=e) + noise
    term = fitting.Reprojections(
        times, pts, torch.tensor(pix), camera=CAM, sigma=SIGMA, intrinsics=True,
        extrinsic=fitting.Free(start=torch.tensor(ptr.dual_quaternion_from_transform(e))))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the pinning Poses' chi2/dof far below 1
        est = fitting.estimate(spline, [_pinned(spline), term], steps=20, verbose=False)
        got = np.concatenate([est.std(term, "extrinsic").numpy(),
                              est.std(term, "intrinsics").numpy()])
    e_hat = ptr.transform_from_dual_quaternion(term.extrinsic.detach().numpy())
    k_hat = term.intrinsics.detach().numpy()

    def residual(d):
        e_d = e_hat @ ptr.transform_from_exponential_coordinates(d[:6])
        return ((_pixels(spline, times, pts.numpy(), extrinsic=e_d, k=k_hat + d[6:]) - pix)
                / SIGMA).ravel()

    np.testing.assert_allclose(got, _fd_std(residual, [1e-6] * 10), rtol=1e-4)


def test_std_of_target_time_offset_and_line_delay_in_their_charts():
    """``std(term, "target")`` ``(6,)`` in ``T exp(delta)``, ``std(term, "time_offset")`` and
    ``std(term, "line_delay")`` ``()`` in seconds and seconds per row, ``t' = t + dt + l v``
    with ``v`` the measured row: against the Gauss-Newton inverse of central differences."""
    g = torch.Generator().manual_seed(7)
    spline = BSpline(dq.exp(torch.randn(8, 6, generator=g, dtype=F64) * 0.06))
    _, times, pts, _, _ = _scene()
    p = pts.numpy()
    target = ptr.transform_from_exponential_coordinates([0.01, 0.02, -0.01, 0.03, 0.02, -0.01])
    rows = np.full(len(p), 240.0)
    for _ in range(6):  # the row seen at t + dt + l v (fixed point)
        rows = _pixels(spline, times, p, target=target, shift=0.004 + 2e-5 * torch.tensor(
            rows))[:, 1]
    pix = _pixels(spline, times, p, target=target, shift=0.004 + 2e-5 * torch.tensor(rows))
    pix = pix + SIGMA * np.random.default_rng(1).standard_normal(pix.shape)
    term = fitting.Reprojections(
        times, pts, torch.tensor(pix), camera=CAM, sigma=SIGMA, time_offset=True,
        line_delay=True, max_time_offset=0.05,
        target=fitting.Free(start=torch.tensor(ptr.dual_quaternion_from_transform(target))))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fitting.estimate(spline, [_pinned(spline), term], steps=20, verbose=False)
        got = np.concatenate([est.std(term, "target").numpy(),
                              [float(est.std(term, "time_offset")),
                               float(est.std(term, "line_delay"))]])
    assert est.std(term, "time_offset").shape == est.std(term, "line_delay").shape == ()
    t_hat = ptr.transform_from_dual_quaternion(term.target.detach().numpy())
    dt, ell, v = float(term.time_offset), float(term.line_delay), torch.tensor(pix[:, 1])

    def residual(d):
        shift = dt + d[6] + (ell + d[7]) * v
        t_d = t_hat @ ptr.transform_from_exponential_coordinates(d[:6])
        return ((_pixels(spline, times, p, target=t_d, shift=shift) - pix) / SIGMA).ravel()

    np.testing.assert_allclose(got, _fd_std(residual, [1e-6] * 7 + [1e-9]), rtol=1e-4)


def test_std_of_intrinsics_next_to_a_pinned_trajectory_is_finite():
    """The nuisance parameters' "no information" floor was relative to the control points'
    largest information, a matter of units: 1e-7 m poses put it 1e13 above a camera's
    intrinsics, and their well-determined std (0.15 px) came back inf with a warning (lead,
    api16's finding 4). Against the Gauss-Newton inverse of a numpy projection's central
    differences."""
    spline, times, pts, _, _ = _scene()
    noise = SIGMA * np.random.default_rng(1).standard_normal((len(times), 2))
    pix = _pixels(spline, times, pts.numpy()) + noise
    term = fitting.Reprojections(times, pts, torch.tensor(pix), camera=CAM, sigma=SIGMA,
                                 intrinsics=True)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*chi2/dof far below 1")  # the pinning
        warnings.filterwarnings("error", message=".*no information")
        est = fitting.estimate(spline, [_pinned(spline), term], steps=20, verbose=False)
        got = est.std(term, "intrinsics").numpy()
    k_hat = term.intrinsics.detach().numpy()

    def residual(d):
        return ((_pixels(spline, times, pts.numpy(), k=k_hat + d) - pix) / SIGMA).ravel()

    np.testing.assert_allclose(got, _fd_std(residual, [1e-6] * 4), rtol=1e-4)

"""The API contract's estimation with data a user gets wrong (session 17): a camera whose
every observation projects invalid (it was reported converged with loss 0, its term
ignored), and the uncertainties of a float32 trajectory (float64 came back; the Conventions:
"Output dtype/device follow the inputs"). References: the pinhole formula in numpy, the
gyroscope bias' standard deviation ``sigma / sqrt(N)`` of a mean."""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.camera import Camera
from torch_dq.nn import BSpline

F64 = torch.float64
K = (400.0, 410.0, 320.0, 240.0)
CAM = Camera("pinhole", torch.tensor(K, dtype=F64), (640, 480))


def _scene(batch: int | None = None):
    """A camera (the body) swaying slowly 2 m in front of a 5 x 6 grid: spline, times, the
    grid's points and their numpy pinhole pixels (no noise)."""
    g = torch.Generator().manual_seed(4)
    ctrl = dq.exp(torch.randn(8, 6, generator=g, dtype=F64) * 0.02)
    spline = BSpline(ctrl if batch is None else ctrl.expand(batch, 8, 8).clone())
    y, x = np.meshgrid(np.linspace(-0.3, 0.3, 5), np.linspace(-0.4, 0.4, 6), indexing="ij")
    grid = np.stack([x.ravel(), y.ravel(), np.full(x.size, 2.0)], -1)
    frames = np.linspace(0.1, 0.9, 10)
    times = torch.tensor(np.repeat(frames, len(grid)))
    pts = np.tile(grid, (len(frames), 1))
    m = dq.to_matrix(BSpline(ctrl)(times)).detach().numpy()  # camera poses in the target
    pc = np.einsum("nji,nj->ni", m[:, :3, :3], pts - m[:, :3, 3])
    pix = np.stack([K[0] * pc[:, 0] / pc[:, 2] + K[2], K[1] * pc[:, 1] / pc[:, 2] + K[3]], -1)
    return spline, times, torch.tensor(pts), torch.tensor(pix)


def test_every_observation_invalid_raises():
    """Every point 4 m behind the camera (a target pose or an extrinsic inverted): the term
    has no residual, no gradient, nothing to move it; ``estimate`` reported converged with
    loss 0 (and dof NaN). It raises, naming the term and what to check."""
    spline, times, pts, pix = _scene()
    behind = pts - torch.tensor([0.0, 0.0, 6.0], dtype=F64)
    term = fitting.Reprojections(times, behind, pix, camera=CAM, sigma=0.5)
    with pytest.raises(ValueError, match=r"every observation of Reprojections \(camera "
                                         r"'pinhole'\) projects invalid.*T_imu_cam"):
        fitting.estimate(spline, [term], steps=5, verbose=False)


def test_every_observation_invalid_beside_other_terms_raises():
    """Poses fix the trajectory; the camera sees nothing: the result would ignore its data
    (its intrinsics' estimate its start) behind one warning; it raises."""
    spline, times, pts, pix = _scene()
    behind = pts - torch.tensor([0.0, 0.0, 6.0], dtype=F64)
    poses = fitting.Poses(times[::30], spline(times[::30]).detach(), rot_sigma=0.01,
                          trans_sigma=0.01)
    cam = fitting.Reprojections(times, behind, pix, camera=CAM, sigma=0.5, intrinsics=True)
    with pytest.raises(ValueError, match="every observation of Reprojections"):
        fitting.estimate(spline, [poses, cam], steps=5, verbose=False)


def test_one_blind_batch_element_is_named():
    """Two problems: the first camera sees the grid, the second sees it from behind; the
    error names batch element [1]."""
    spline, times, pts, pix = _scene(batch=2)
    both = torch.stack([pts, pts - torch.tensor([0.0, 0.0, 6.0], dtype=F64)])
    term = fitting.Reprojections(times, both, pix.expand(2, -1, 2), camera=CAM, sigma=0.5)
    with pytest.raises(ValueError, match=r"\(batch element \[1\]\) projects invalid"):
        fitting.estimate(spline, [term], steps=5, verbose=False)


def test_some_observations_invalid_still_estimate():
    """Some observations behind the camera, the others seen: excluded and warned of, as
    before (the error is for a term that sees nothing)."""
    spline, times, pts, pix = _scene()
    behind = torch.zeros(len(times), dtype=torch.bool)
    behind[::7] = True
    pts = torch.where(behind[:, None], pts - torch.tensor([0.0, 0.0, 6.0], dtype=F64), pts)
    term = fitting.Reprojections(times, pts, pix, camera=CAM, sigma=0.5)
    with pytest.warns(RuntimeWarning, match="project invalid at the solution"):
        est = fitting.estimate(spline, [term], steps=5, verbose=False)
    assert int(term.invalid) == int(behind.sum())
    assert float(est.final_loss) < 1e-12


@pytest.mark.parametrize("dtype", [torch.float32, F64])
def test_uncertainties_follow_the_trajectory_dtype(dtype):
    """A gyroscope bias with the rotation pinned by tight poses: its std is the mean's
    ``sigma / sqrt(N)`` per axis; ``std``, ``cov``, ``pose_std`` and ``kinematics_std`` come
    back in the trajectory's dtype (float64 for a float32 trajectory before), with float64
    times for pose_std (wide time) as well."""
    xi = torch.tensor([0.0, 0.3, 1.0, 0.5, 0.0, 0.1], dtype=F64)
    tc = torch.linspace(0.0, 4.0, 81, dtype=F64)
    ti = torch.linspace(0.0, 4.0, 801, dtype=F64)
    truth = dq.exp(tc[:, None] * xi)
    spline = BSpline.from_dualquats(truth.to(dtype), tc, n_ctrl=23)
    poses = fitting.Poses(tc, truth, rot_sigma=1e-5, trans_sigma=1e-5)
    sigma = 1e-2
    gyro = fitting.Gyro(ti, xi[:3].expand(801, 3), sigma=sigma, bias=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # chi2/dof far below 1: exact data
        est = fitting.estimate(spline, [poses, gyro], verbose=False)
        std = est.std(gyro, "bias")
        cov = est.cov((gyro, "bias"))
        pose = est.pose_std(tc[:5])
        kin = est.kinematics_std(tc[:5].to(dtype))
    for out in (std, cov, pose, kin):
        assert out.dtype == dtype
    assert std.shape == (3,) and cov.shape == (3, 3) and pose.shape == (5, 6)
    assert kin.shape == (5, 12)
    ref = sigma / math.sqrt(len(ti))
    np.testing.assert_allclose(std.double().numpy(), ref, rtol=0.01)
    np.testing.assert_allclose(cov.diagonal().double().numpy(), ref ** 2, rtol=0.02)
    assert bool(torch.isfinite(pose).all()) and bool((pose > 0).all())


def test_scaled_uncertainties_without_redundancy_are_inf():
    """Four noisy poses and a cubic of four control points: 24 residual components for 24
    parameters, no degree of freedom left, so the residuals' scatter says nothing of the
    sigmas: ``scaled=True`` has no variance factor to scale by. It scaled by
    ``chi2 / max(dof, 1)``, a number of roundoff (4e-14 of the unscaled std); now inf, as
    scipy's ``curve_fit`` (``absolute_sigma=False``) gives for a fit without redundancy."""
    from scipy.optimize import OptimizeWarning, curve_fit

    with pytest.warns(OptimizeWarning):  # the reference: a line through two points
        _, pcov = curve_fit(lambda x, a, b: a + b * x, [0.0, 1.0], [0.3, 1.1])
    assert np.isinf(pcov).all()
    xi = torch.tensor([0.0, 0.3, 1.0, 0.5, 0.0, 0.1], dtype=F64)
    t = torch.linspace(0.0, 4.0, 4, dtype=F64)
    noise = torch.randn(4, 6, generator=torch.Generator().manual_seed(0), dtype=F64) * 1e-3
    noisy = dq.mul(dq.exp(t[:, None] * xi), dq.exp(noise))
    spline = BSpline.from_dualquats(dq.exp(t[:, None] * xi), t, n_ctrl=4)
    term = fitting.Poses(t, noisy, rot_sigma=1e-3, trans_sigma=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fitting.estimate(spline, [term], verbose=False)
        assert float(est.dof[term]) < 1e-6
        plain = est.pose_std(t)
        scaled = est.pose_std(t, scaled=True)
    assert bool(torch.isfinite(plain).all())
    assert bool(torch.isinf(scaled).all())


def test_batch_summary_shows_the_numbers():
    """A batch of two problems: ``summary()`` and ``repr`` printed ``<(2,) tensor>`` for the
    final loss and each term's chi2 and dof; they print the batch's range, the chi2 equal
    to the whitened residuals' sum of squares computed with scipy's rotations."""
    from scipy.spatial.transform import Rotation

    xi = torch.tensor([0.0, 0.3, 1.0, 0.5, 0.0, 0.1], dtype=F64)
    t = torch.linspace(0.0, 4.0, 81, dtype=F64)
    truth = dq.exp(t[:, None] * xi)
    g = torch.Generator().manual_seed(1)
    noisy = torch.stack([dq.mul(truth, dq.exp(torch.randn(81, 6, generator=g, dtype=F64) * s))
                         for s in (1e-3, 1e-2)])
    one = BSpline.from_dualquats(truth, t, n_ctrl=23)
    spline = BSpline(one.control_points.detach().expand(2, 23, 8).clone(), knots=one.knots)
    term = fitting.Poses(t, noisy, rot_sigma=1e-3, trans_sigma=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fitting.estimate(spline, [term], verbose=False)
        text = est.summary() + repr(est)
    assert "tensor>" not in text
    chi2 = []
    for b in range(2):
        m = dq.to_matrix(spline(t)[b]).detach().numpy()
        mm = dq.to_matrix(noisy[b]).numpy()
        rot = (Rotation.from_matrix(mm[:, :3, :3]).inv()
               * Rotation.from_matrix(m[:, :3, :3])).as_rotvec()
        chi2.append(float(((rot / 1e-3) ** 2).sum() + (((m - mm)[:, :3, 3] / 1e-3) ** 2).sum()))
    for what in ("chi2", "final loss"):
        found = re.search(rf"{what} (\S+) to (\S+) \(2,\)", text)
        assert found is not None, text
        assert [float(v) for v in found.groups()] == pytest.approx(sorted(chi2), rel=1e-5)


def test_cov_of_nothing_estimated_is_empty():
    """``cov()`` is "every estimated parameter, in the order of ``parameters``": with none
    (``parameters == []``) that is the ``(0, 0)`` matrix, not torch's error."""
    t = torch.linspace(0.0, 1.0, 11, dtype=F64)
    poses = dq.identity((11,), dtype=F64)
    spline = BSpline.from_dualquats(poses, t, n_ctrl=4)
    term = fitting.Poses(t, poses, rot_sigma=1e-3, trans_sigma=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = fitting.estimate(spline, [term], verbose=False)
        assert est.parameters == []
        assert est.cov().shape == (0, 0)

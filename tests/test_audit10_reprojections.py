"""Audit 10: estimated intrinsics must not leave the camera model's domain to empty the
reprojection term.

A double-sphere lens whose ``alpha`` is near 1 (the true 0.9995, started at 0.95): the
Levenberg-Marquardt step pushed ``alpha`` past 1, where the camera sees nothing; every
observation then had a zero residual, the cost fell to the pose term's alone and the
estimate reported convergence with ``alpha = 1.14`` and 2520 observations "invalid". The
pixels are simulated here with the paper's projection written in numpy (Usenko, Demmel,
Cremers 2018, eqs. 40-42), the truth is what the estimate must come back to.
"""

import warnings

import numpy as np
import pytest
import torch
from references import double_sphere_np

import torch_dq.dualquat as dq
from torch_dq import camera, fitting, nn, quat

F64 = torch.float64
TRUE = [300.0, 300.0, 320.0, 240.0, 0.0, 0.9995]


def _scene(frames=30, seed=0):
    """A camera (the body) turning and moving in front of a wide grid of points 0.8 m
    ahead (up to 85 degrees off its axis); noisy pixels (0.5 px)."""
    rng = np.random.default_rng(seed)
    times = torch.linspace(0.0, 2.0, frames, dtype=F64)
    q = quat.from_axis_angle(torch.tensor([0.0, 1.0, 0.0], dtype=F64), 0.3 * torch.sin(times))
    p = torch.stack([0.2 * torch.sin(times), 0.1 * torch.cos(times), 0.05 * times], -1)
    gx, gy = np.meshgrid(np.linspace(-1.5, 1.5, 9), np.linspace(-1.2, 1.2, 7), indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.8)], -1)
    R, t = quat.to_matrix(q).numpy(), p.numpy()
    cam = np.einsum("fji,fpj->fpi", R, pts[None] - t[:, None])  # R^T (p - t) per frame
    pixels = double_sphere_np(TRUE, cam.reshape(-1, 3)) + 0.5 * rng.normal(size=(cam.size // 3, 2))
    n = len(pts)
    return (times, q, p, times.repeat_interleave(n), torch.tensor(np.tile(pts, (frames, 1))),
            torch.tensor(pixels))


def test_estimated_double_sphere_alpha_stays_in_its_domain():
    times, q, p, t_obs, points, pixels = _scene()
    start = torch.tensor(TRUE, dtype=F64)
    start[0], start[5] = 310.0, 0.95
    cam = camera.Camera("double-sphere", start, (2000, 2000))
    spline = nn.BSpline.from_poses(q, p, times, n_ctrl=8, form="cumulative")
    term = fitting.Reprojections(t_obs, points, pixels, camera=cam, sigma=0.5, intrinsics=True)
    poses = fitting.Poses(times, dq.from_rt(q, p), rot_sigma=1e-3, trans_sigma=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no observation may end invalid
        est = fitting.estimate(spline, [term, poses], steps=30, verbose=False)
    k = term.intrinsics
    assert int(term.invalid) == 0
    assert 0.0 <= float(k[5]) <= 1.0 and abs(float(k[5]) - TRUE[5]) < 5e-3
    assert np.abs(k[:4].numpy() - TRUE[:4]).max() < 1.0
    n = 2 * len(t_obs)  # the pixels' chi2 is the noise's: 2 per observation
    assert 0.8 < float(est.chi2[term]) / n < 1.2


def test_intrinsics_given_or_started_outside_the_domain_raise():
    *_, t_obs, points, pixels = _scene(frames=3)
    cam = camera.Camera("double-sphere", torch.tensor(TRUE, dtype=F64), (2000, 2000))
    for bad in ([300.0, 300.0, 320.0, 240.0, 0.0, 1.2], [0.0, 300.0, 320.0, 240.0, 0.0, 0.5],
                [300.0, 300.0, 320.0, 240.0, -1.0, 0.5]):
        for given in (torch.tensor(bad, dtype=F64), fitting.Free(start=torch.tensor(bad))):
            # a Free started there stayed there: no Jacobian, "converged" at alpha = 1.2
            with pytest.raises(ValueError, match="intrinsics outside the 'double-sphere'"):
                fitting.Reprojections(t_obs, points, pixels, camera=cam, sigma=0.5,
                                      intrinsics=given)

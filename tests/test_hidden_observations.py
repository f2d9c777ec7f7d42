"""Levenberg-Marquardt never buys a lower cost by hiding observations: a Reprojections
observation without an image (behind the camera) has a zero residual, so a step that turned
the camera away from the target lowered the cost by every residual it hid. From a far start
(0.35 rad, 0.3 m off, 0.5 m above a 3 m target) ``estimate`` turned all 219 observations
behind the camera and reported a zero loss; it now rejects such steps (as
``torch_dq.calibration``'s own loop does) and ends at the truth."""

from __future__ import annotations

import math
import warnings

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from torch_dq import camera, fitting
from torch_dq import dualquat as dq
from torch_dq import nn as tnn

FU, CU, CV = 400.0, 320.0, 240.0
T, GRID = 20, 13


def _truth() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Times, camera rotations (scipy) as matrices and positions: the camera looks down
    (its z along the world's -z) from 0.5-0.6 m above a target in the plane z = 0."""
    t = np.linspace(0.0, 1.0, T)
    R = np.repeat(Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_matrix()[None], T, 0)
    p = np.stack([0.2 * np.sin(t), 0.1 * t, 0.5 + 0.1 * t], -1)
    return t, R, p


def _observations(g: torch.Generator):
    """Pinhole pixels of the target's grid (numpy: ``K R^T (P - p)``), inside the 640 x 480
    image, with 1 px noise (drawn from ``g``)."""
    t, R, p = _truth()
    g1 = np.linspace(-1.5, 1.5, GRID)
    P = np.stack([*np.meshgrid(g1, g1, indexing="ij"), np.zeros((GRID, GRID))], -1)
    P = P.reshape(-1, 3)
    cam = np.einsum("tji,tnj->tni", R, P[None] - p[:, None])
    uv = FU * cam[..., :2] / cam[..., 2:] + [CU, CV]
    keep = (cam[..., 2] > 0) & (uv[..., 0] > 0) & (uv[..., 0] < 640) & (uv[..., 1] > 0) & (
        uv[..., 1] < 480)
    noisy = uv + torch.randn(uv.shape, generator=g, dtype=torch.float64).numpy()
    times = np.broadcast_to(t[:, None], keep.shape)
    pts = np.broadcast_to(P[None], (T, *P.shape))
    return (torch.tensor(times[keep]), torch.tensor(pts[keep]), torch.tensor(noisy[keep]))


def test_far_start_keeps_every_observation():
    g = torch.Generator().manual_seed(8)
    times, pts, pix = _observations(g)
    term = fitting.Reprojections(times, pts, pix, sigma=1.0, camera=camera.Camera(
        "pinhole", torch.tensor([FU, FU, CU, CV], dtype=torch.float64), (640, 480)))
    t, R, p = _truth()
    ang = (torch.randn(3, generator=g, dtype=torch.float64) * 0.6).numpy()
    off = (torch.randn(3, generator=g, dtype=torch.float64) * 0.3).numpy()
    R0 = R @ Rotation.from_rotvec(ang).as_matrix()
    p0 = p + np.einsum("tij,j->ti", R, off)
    spline = tnn.BSpline.from_poses(torch.tensor(Rotation.from_matrix(R0).as_quat(
        scalar_first=True)), torch.tensor(p0), torch.tensor(t))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no observation may end invalid
        est = fitting.estimate(spline, [term], verbose=False)
    assert int(term.invalid) == 0 and bool(est.converged)
    assert float(est.final_loss) > 0.5 * pix.numel()  # 1 px noise: the residuals remain
    q, tr = dq.to_rt(spline(torch.tensor(t)).detach())
    err = Rotation.from_quat(q.numpy(), scalar_first=True) * Rotation.from_matrix(R).inv()
    assert np.abs(tr.numpy() - p).max() < 5e-3
    assert err.magnitude().max() < 2e-2  # 1 px at 400 px per radian, spline ends


def test_batch_elements_keep_their_own_observations():
    """Two problems solved together (the far start above and a near one): each keeps its
    observations and ends where its solo solve does."""
    gens = [torch.Generator().manual_seed(s) for s in (8, 1)]
    data = [_observations(g) for g in gens]
    t, R, p = _truth()
    starts = []
    for g, scale in zip(gens, (1.0, 0.1), strict=True):
        ang = (torch.randn(3, generator=g, dtype=torch.float64) * 0.6 * scale).numpy()
        off = (torch.randn(3, generator=g, dtype=torch.float64) * 0.3 * scale).numpy()
        starts.append((R @ Rotation.from_rotvec(ang).as_matrix(),
                       p + np.einsum("tij,j->ti", R, off)))
    q0 = torch.tensor(np.stack([Rotation.from_matrix(r).as_quat(scalar_first=True)
                                for r, _ in starts]))
    spline = tnn.BSpline.from_poses(q0, torch.tensor(np.stack([x for _, x in starts])),
                                    torch.tensor(t), n_ctrl=10)
    cam = camera.Camera("pinhole", torch.tensor([FU, FU, CU, CV], dtype=torch.float64),
                        (640, 480))
    term = fitting.Reprojections(torch.stack([d[0] for d in data]),
                                 torch.stack([d[1] for d in data]),
                                 torch.stack([d[2] for d in data]), sigma=1.0, camera=cam)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        est = fitting.estimate(spline, [term], verbose=False)
    assert term.invalid.tolist() == [0, 0] and bool(est.converged.all())
    _, tr = dq.to_rt(spline(torch.tensor(t)).detach())
    assert np.abs(tr.numpy() - p).max() < 1e-2

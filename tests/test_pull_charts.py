"""The numerical prior's pulls in the step charts (``torch_dq.fitting._lm``).

Without nuisance parameters the pulls stay anchored at the start: their cost is ``d^T P d``
with ``d = Log(s^-1 c)``. A step ``c Exp(delta)`` moves ``d`` by ``J_r^-1(d) delta``; the
damped steps took the pulls' information as ``P`` (the anchor's chart), which along the
weakly determined directions they hold (where they weigh as much as the data) misjudged a far
start's curvature by a third: a camera trajectory started 0.35 rad and 0.3 m off crept to its
optimum at a rate of 0.46 per step and stopped unconverged after 21 steps. With ``J^T P J``
it converges quadratically to the same optimum."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytransform3d.transformations as pt
import torch
from scipy.spatial.transform import Rotation

from torch_dq import camera, fitting
from torch_dq import dualquat as dq
from torch_dq import nn as tnn
from torch_dq.fitting._lm import _log_jacobians

sys.path.insert(0, str(Path(__file__).resolve().parent))

import test_hidden_observations as hidden


def _log_pt(T: np.ndarray) -> np.ndarray:
    """pytransform3d's exponential coordinates ``(omega, v)`` of a 4 x 4 transform."""
    return pt.exponential_coordinates_from_transform(T)


def test_log_jacobians_against_pytransform3d_differences():
    gen = torch.Generator().manual_seed(3)
    xi = torch.randn(7, 6, generator=gen, dtype=torch.float64)
    xi[:, :3] *= torch.tensor([0.0, 1e-9, 0.3, 1.0, 2.0, 2.8, 3.0], dtype=torch.float64)[:, None]
    start = dq.exp(torch.randn(7, 6, generator=gen, dtype=torch.float64))
    ctrl = dq.mul(start, dq.exp(xi))
    J = _log_jacobians(start, ctrl).numpy()
    h = 1e-6
    for i in range(7):
        rel = np.linalg.inv(dq.to_matrix(start[i]).numpy()) @ dq.to_matrix(ctrl[i]).numpy()
        for j in range(6):
            e = np.zeros(6)
            e[j] = h
            up = _log_pt(rel @ pt.transform_from_exponential_coordinates(e))
            down = _log_pt(rel @ pt.transform_from_exponential_coordinates(-e))
            np.testing.assert_allclose(J[i, :, j], (up - down) / (2 * h), atol=2e-8)


def test_far_start_without_nuisance_converges_quadratically():
    """20 control points for 20 frames: weakly determined directions that the pulls hold at
    the far start."""
    g = torch.Generator().manual_seed(8)
    times, pts, pix = hidden._observations(g)
    t, R, p = hidden._truth()
    ang = (torch.randn(3, generator=g, dtype=torch.float64) * 0.6).numpy()
    off = (torch.randn(3, generator=g, dtype=torch.float64) * 0.3).numpy()
    R0 = R @ Rotation.from_rotvec(ang).as_matrix()
    p0 = p + np.einsum("tij,j->ti", R, off)
    cam = camera.Camera("pinhole", torch.tensor([hidden.FU, hidden.FU, hidden.CU, hidden.CV],
                                                dtype=torch.float64), (640, 480))
    term = fitting.Reprojections(times, pts, pix, sigma=1.0, camera=cam)
    spline = tnn.BSpline.from_poses(torch.tensor(Rotation.from_matrix(R0).as_quat(
        scalar_first=True)), torch.tensor(p0), torch.tensor(t), n_ctrl=20)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        est = fitting.estimate(spline, [term], verbose=False)
    assert bool(est.converged) and est.steps <= 10, est
    assert int(term.invalid) == 0
    _, tr = dq.to_rt(spline(torch.tensor(t)).detach())
    assert np.abs(tr.numpy() - p).max() < 1e-2

"""API.md, torch_dq.fitting: cameras, audited line by line (session 16): what the earlier
reprojection tests did not pin. References: the pinhole formula in numpy on the body poses,
the chi-square bookkeeping of excluded observations, the contract's ``line_delay >= 0``."""

from __future__ import annotations

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
SIGMA = 0.5


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
    m = dq.to_matrix(spline(torch.tensor(times))).detach().numpy()  # body (camera) poses
    cam = np.einsum("nji,nj->ni", m[:, :3, :3], pts - m[:, :3, 3])  # R^T (p - t)
    pix = np.stack([K[0] * cam[:, 0] / cam[:, 2] + K[2], K[1] * cam[:, 1] / cam[:, 2] + K[3]],
                   -1)
    pix = pix + SIGMA * np.random.default_rng(5).standard_normal(pix.shape)
    behind = np.zeros(len(times), dtype=bool)
    if n_behind_every:
        behind[::n_behind_every] = True
    pts = np.where(behind[:, None], pts - [0.0, 0.0, 6.0], pts)
    return spline, torch.tensor(times), torch.tensor(pts), torch.tensor(pix), behind


@pytest.mark.xfail(strict=True, reason="Estimate._kept (fitting/_uncertainty.py, out of this "
                   "helper's files) counts the term's mask, not the observations that project "
                   "valid: excluded observations add 2 dof each (api16 report)")
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
    m = dq.to_matrix(spline(times + ell * pix[:, 1])).detach().numpy()
    cam = np.einsum("nji,nj->ni", m[:, :3, :3], pts.numpy() - m[:, :3, 3])
    ref = np.stack([K[0] * cam[:, 0] / cam[:, 2] + K[2], K[1] * cam[:, 1] / cam[:, 2] + K[3]], -1)
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

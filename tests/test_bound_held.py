"""A bounded scalar on its bound with the descent pointing outwards (a line delay at 0 on
global-shutter pixels) is held by the steps: the other parameters' step was computed as if it
moved, its move was clamped away, and ``estimate`` crept for 50 steps unconverged."""

import warnings

import numpy as np
import torch
from test_cam12_reprojections import CAM, E, T, _spline, ref_pixels  # OpenCV's pixels

from torch_dq import fitting
from torch_dq.nn import BSpline

F64 = torch.float64


def _global_shutter(noise: float, seed: int = 8):
    """Pixels of target points at the frame times (no line delay: a global shutter), OpenCV's
    projection of a numpy pose chain."""
    spline = _spline()
    rng = np.random.default_rng(seed)
    times = np.sort(rng.uniform(0.1, 0.9, 200))
    pts = np.concatenate([rng.uniform(-0.3, 0.3, (200, 2)), np.zeros((200, 1))], -1)
    px = ref_pixels(spline, times, pts) + noise * rng.standard_normal((200, 2))
    term = fitting.Reprojections(torch.tensor(times), torch.tensor(pts), torch.tensor(px),
                                 camera=CAM, sigma=noise or 0.5, extrinsic=E, target=T,
                                 line_delay=fitting.Free(start=5e-5))
    return spline, (times, pts, px), term


def test_line_delay_held_at_zero_converges():
    spline, (times, pts, px), term = _global_shutter(0.0)
    start = BSpline(spline.control_points.detach().clone())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no 'steps reached'
        est = fitting.estimate(start, [term], verbose=False)
    assert est.reason.startswith("the scaled gradient test passed"), est.reason
    assert est.steps <= 8
    assert float(term.line_delay) == 0.0
    fit = ref_pixels(start, times, pts)  # OpenCV's pixels of the estimated motion
    assert np.sqrt(((fit - px) ** 2).sum(-1).mean()) < 1e-3  # px


def test_line_delay_off_the_bound_unchanged():
    """With noise the optimum may lie inside the range: the estimate converges where the
    data put it, within a few standard deviations of zero."""
    spline, _, term = _global_shutter(0.3)
    start = BSpline(spline.control_points.detach().clone())
    est = fitting.estimate(start, [term], verbose=False)
    assert est.reason.startswith("the scaled gradient test passed"), est.reason
    value, std = float(term.line_delay), float(est.std(term, "line_delay"))
    assert 0.0 <= value < 4 * std

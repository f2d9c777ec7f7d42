"""Degrees of freedom per term never negative: knots finer than the samples (odometry at 20
Hz and one anchor pose on 0.05 s knots of a quartic) gave dof -17.7 and -0.29; the data
determine at most as many combinations as they have residual components."""

import warnings

import numpy as np
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Poses, RelativePoses, estimate
from torch_dq.nn import BSpline


def _poses(t: np.ndarray) -> torch.Tensor:
    R = Rotation.from_rotvec(np.stack([0.3 * np.sin(t), 0.2 * t, 0.1 * np.cos(t)], -1))
    p = np.stack([np.sin(t), np.cos(0.5 * t), 0.2 * t], -1)
    return dq.from_rt(torch.tensor(R.as_quat(scalar_first=True)), torch.tensor(p))


def _dofs(spacing: float):
    tc = np.arange(0.0, 3.0 + 1e-9, 0.05)
    cam = _poses(tc)
    rel = dq.mul(dq.conj(cam[:-1]), cam[1:])
    t = torch.tensor(tc)
    terms = [RelativePoses(t[:-1], t[1:], rel, rot_sigma=1e-3, trans_sigma=1e-3),
             Poses(t[:1], cam[:1], rot_sigma=1e-3, trans_sigma=1e-3)]
    spline = BSpline.from_dualquats(cam, t, form="cumulative", degree=4, knot_spacing=spacing)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        est = estimate(spline, terms, verbose=False)
    return [float(est.dof[term]) for term in terms], spline.control_points.shape[0]


def test_dof_is_zero_when_the_knots_are_finer_than_the_samples():
    dofs, _ = _dofs(0.05)  # 64 control points: 384 parameters for 366 residual components
    assert dofs == [0.0, 0.0]


def test_dof_is_each_terms_residuals_less_what_the_parameters_take():
    """The lone anchor pose alone places the trajectory: the parameters take all of its 6
    components (dof 0, its residual 0 at the optimum), the relative poses the rest; summed,
    the residual count less the parameters (dof14: the proportional share N_t (1 - p / sum
    N) gave the anchor 6 (1 - p / 366) > 0)."""
    dofs, n = _dofs(0.5)
    np.testing.assert_allclose(dofs, [60 * 6 - 6 * n + 6, 0.0], rtol=0, atol=1e-6)

"""``Estimate.pose_std`` at absolute (UNIX) times against the closed-form standard deviation
of linear least squares (user11).

On the split form (``form="split"``) a ``Poses`` term's translation residual is linear in the
control points' translations, ``p(t) = sum_j B_j(t) p_j``, and does not involve the rotations;
with rotations at the identity, the rotation residual's linearisation is
``sum_j B_j(t) omega_j`` too (the cumulative basis telescopes). Both marginal standard
deviations are then ``sigma sqrt(b(t)^T (B^T B)^-1 b(t))`` with ``B`` the B-spline design
matrix at the sample times: scipy's ``BSpline.design_matrix`` on the spline's own knots (in
seconds since the first sample) is the independent reference.
"""

import warnings

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline as ScipyBSpline

import torch_dq.dualquat as dq
from torch_dq import fitting, nn, quat

F64 = torch.float64
T0 = 1305031098.6659  # TUM fr1_xyz's first timestamp


def test_pose_std_is_linear_least_squares_on_the_split_form():
    s = torch.arange(301, dtype=F64) / 100  # 3 s at 100 Hz
    gen = torch.Generator().manual_seed(0)
    p = torch.stack((torch.sin(s), torch.cos(2 * s), 0.3 * s), -1)
    p = p + 1e-3 * torch.randn(p.shape, generator=gen, dtype=F64)
    q = quat.identity((301,), dtype=F64)
    spline = nn.BSpline.from_poses(q, p, T0 + s, knot_spacing=0.25, form="split")
    term = fitting.Poses(T0 + s, dq.from_rt(q, p), rot_sigma=2e-3, trans_sigma=1e-3)
    est = fitting.estimate(spline, [term], verbose=False)
    tq = T0 + torch.tensor([0.0, 0.37, 1.5, 2.93, 3.0], dtype=F64)
    with warnings.catch_warnings():  # chi2/dof: the rotations are noise-free
        warnings.simplefilter("ignore", RuntimeWarning)
        std = est.pose_std(tq).numpy()
    knots = spline.knots.numpy() - T0
    B = ScipyBSpline.design_matrix(s.numpy(), knots, 3).toarray()
    b = ScipyBSpline.design_matrix((tq - T0).numpy(), knots, 3).toarray()
    ref = np.sqrt(np.einsum("ij,jk,ik->i", b, np.linalg.inv(B.T @ B), b))
    np.testing.assert_allclose(std[:, 3:], 1e-3 * ref[:, None].repeat(3, 1), rtol=1e-5)
    np.testing.assert_allclose(std[:, :3], 2e-3 * ref[:, None].repeat(3, 1), rtol=1e-5)


def test_std_along_time_errors_name_the_method():
    """Bad times name ``Estimate.pose_std`` / ``kinematics_std`` (they named the layer's
    ``derivatives``, which the user never called)."""
    s = torch.linspace(0.0, 1.0, 40, dtype=F64)
    x = dq.exp(torch.stack((s, 0 * s, 0 * s, s, s * s, 0 * s), -1))
    spline = nn.BSpline.from_poses(*dq.to_rt(x), s, n_ctrl=8)
    est = fitting.estimate(spline, [fitting.Poses(s, x, rot_sigma=1e-3, trans_sigma=1e-3)],
                           verbose=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for name in ("pose_std", "kinematics_std"):
            with pytest.raises(ValueError, match=rf"^fitting\.Estimate\.{name}: t must lie in "
                                                 r"the module's time domain \[0, 1\]"):
                getattr(est, name)(torch.tensor([2.0], dtype=F64))
            with pytest.raises(TypeError, match=rf"^fitting\.Estimate\.{name}: .*floating"):
                getattr(est, name)(torch.tensor([0, 1]))

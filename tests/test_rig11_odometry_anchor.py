"""fitting.estimate on odometry chained from one anchor pose, started at the identity.

Odometry ``RelativePoses`` between consecutive times ``t_0 .. t_K`` with isotropic rotation
noise ``s`` (to-frame) and one ``Poses`` anchor at ``t_0`` with the same ``s``: the
rotation at ``t_k`` is the anchor composed with ``k`` measured increments, each error
turned into the body frame by a rotation, so its covariance is exactly ``(k + 1) s^2 I``
(isotropic noise stays isotropic). Truth: the closed-form motion of ``_rig11_rig``.

Found here: with ``margin=0.1`` and ``knot_spacing=0.1`` the last sample lies on a knot and
``pose_std`` there was inf ("an end without samples"): the control point whose support
starts at that knot has a zero weight at it, but the check asked only whether the window
touched an uninformed control point, not whether the output loads on it.
"""

import warnings

import numpy as np
import pytest
import torch
from _rig11_rig import position, rotation
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Poses, RelativePoses, estimate
from torch_dq.nn import BSpline

S = 1e-3
TK = np.arange(0.0, 3.0 + 1e-9, 0.05)


def _dq(R, p):
    return dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p))


@pytest.fixture(scope="module")
def solved():
    rng = np.random.default_rng(0)
    R, p = rotation(TK), position(TK)
    noise = Rotation.from_rotvec(S * rng.standard_normal((len(TK) - 1, 3)))
    rel = _dq((R[:-1].inv() * R[1:]) * noise,
              R[:-1].inv().apply(p[1:] - p[:-1]) + S * rng.standard_normal((len(TK) - 1, 3)))
    q = torch.zeros(len(TK), 4, dtype=torch.float64)
    q[:, 0] = 1.0  # the start: identity rotations at the origin
    spline = BSpline.from_poses(q, torch.zeros(len(TK), 3, dtype=torch.float64),
                                torch.from_numpy(TK), form="cumulative", degree=4,
                                margin=0.1, n_ctrl=36)  # knots every 0.1 s
    t = torch.from_numpy(TK)
    terms = [RelativePoses(t[:-1], t[1:], rel, rot_sigma=S, trans_sigma=S),
             Poses(t[:1], _dq(R[:1], p[:1]), rot_sigma=S, trans_sigma=S)]
    return spline, terms, estimate(spline, terms, verbose=False)


def test_converges_to_the_truth_within_its_std(solved):
    spline, terms, est = solved
    assert bool(est.converged), est.reason
    ratio = float(est.chi2[terms[0]] / est.dof[terms[0]])
    assert 0.8 < ratio < 1.2, ratio
    t = torch.from_numpy(TK[::10])
    q, p = dq.to_rt(spline(t).detach())
    err_r = (Rotation.from_quat(q.numpy(), scalar_first=True).inv() * rotation(t.numpy()))
    err = np.hstack([err_r.as_rotvec(), position(t.numpy()) - p.numpy()])
    z = err / est.pose_std(t).numpy()
    assert np.all(np.abs(z) < 4.0), z


def test_rotation_std_is_the_random_walk_up_to_the_last_sample_on_a_knot(solved):
    """The last time (3.0) is a knot of the margin's domain [-0.1, 3.1]: finite there, the
    closed form to 0.1 %; every sample within 2.5 % (the spline smooths the chain a little)."""
    spline, _, est = solved
    assert float((spline.knots - TK[-1]).abs().min()) < 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every pose here is determined: no warning
        std = est.pose_std(torch.from_numpy(TK)).numpy()
    walk = S * np.sqrt(np.arange(len(TK)) + 1.0)
    assert np.all(np.isfinite(std)), std[-1]
    np.testing.assert_allclose(std[:, :3], np.repeat(walk[:, None], 3, 1), rtol=2.5e-2)
    np.testing.assert_allclose(std[-1, :3], walk[-1], rtol=1e-3)
    kin = est.kinematics_std(torch.from_numpy(TK[-1:]))
    assert bool(torch.isfinite(kin).all()), kin  # degree 4: the weight's derivatives vanish


def test_a_time_past_the_last_sample_is_inf_with_a_warning(solved):
    """Inside the margin (3.0, 3.1] the pose loads on the undetermined control point."""
    _, _, est = solved
    with pytest.warns(RuntimeWarning, match="an end without samples"):
        std = est.pose_std(torch.tensor([1.0, 3.05], dtype=torch.float64))
    assert bool(torch.isfinite(std[0]).all()) and bool(torch.isinf(std[1]).all()), std


def test_the_edges_of_a_time_gap_on_knots_are_finite_inside_inf():
    """Poses every 50 ms with a masked gap (1.5, 2.5), knots every 0.1 s: the poses at the
    gap's edges (measured, on knots) have finite standard deviations, equal by the time
    reversal symmetry of the design (1.4 and 2.6 likewise); only inside the gap inf. Before,
    1.5 was inf: the point whose support starts at 1.5 has no data and a zero weight there."""
    tc = np.arange(0.0, 4.0 + 1e-9, 0.05)
    keep = torch.from_numpy((tc <= 1.5 + 1e-9) | (tc >= 2.5 - 1e-9))
    rng = np.random.default_rng(1)
    cam = _dq(rotation(tc) * Rotation.from_rotvec(S * rng.standard_normal((len(tc), 3))),
              position(tc) + S * rng.standard_normal((len(tc), 3)))
    spline = BSpline.from_dualquats(cam, torch.from_numpy(tc), form="cumulative", degree=4,
                                    n_ctrl=44)  # knots every 0.1 s
    est = estimate(spline, [Poses(torch.from_numpy(tc), cam, rot_sigma=S, trans_sigma=S,
                                  mask=keep)], verbose=False)
    with pytest.warns(RuntimeWarning, match="a time gap"):
        std = est.pose_std(torch.tensor([1.4, 1.5, 1.5005, 2.0, 2.4995, 2.5, 2.6],
                                        dtype=torch.float64)).numpy()
    assert np.all(np.isinf(std[2:5])), std
    edges = std[[0, 1, 5, 6]]
    assert np.all(np.isfinite(edges)) and np.all(edges < 1.1 * S), edges
    np.testing.assert_allclose(std[[0, 1]], std[[6, 5]], rtol=1e-3)

"""Outside testing of ``torch_dq.fitting`` with the public API (fit13): inputs that passed
without a word.

Found here: one ``Free`` shared by a lever arm and a gyroscope bias (metres and rad/s), or
by a gyroscope's and an accelerometer's bias, was taken as one parameter (the kind was the
chart's, ``v + delta`` for both): the solve then stopped "no progress", unconverged, with
nothing said; ``pose_std`` / ``kinematics_std`` at a NaN time returned 0 (perfect
certainty) instead of NaN (the contract's non-finite rule); ``cov`` given a term instead of
a ``(term, name)`` pair failed inside with "cannot unpack non-iterable Poses object".
"""

import math

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses, Positions, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
XI = torch.tensor([0.3, -0.2, 0.5, 0.4, 0.1, -0.3], dtype=F64)  # constant screw (rad/s, m/s)


def _imu(n=50):
    t = torch.linspace(0.2, 1.8, n, dtype=F64)
    return t, torch.zeros(n, 3, dtype=F64) + XI[:3], torch.zeros(n, 3, dtype=F64)


@pytest.mark.parametrize("first, second", [
    (lambda f: Positions(_imu()[0], _imu()[2], sigma=0.01, lever_arm=f),
     lambda f: Gyro(*_imu()[:2], sigma=0.01, bias=f)),
    (lambda f: Gyro(*_imu()[:2], sigma=0.01, bias=f),
     lambda f: Accel(_imu()[0], _imu()[2], sigma=0.1, bias=f)),
    (lambda f: Gyro(*_imu()[:2], sigma=0.01, bias=f),
     lambda f: Positions(_imu()[0], _imu()[2], sigma=0.01, lever_arm=f)),
], ids=["lever_arm-gyro_bias", "gyro_bias-accel_bias", "gyro_bias-lever_arm"])
def test_a_free_of_two_kinds_of_one_shape_names_both(first, second):
    shared = Free()
    a = first(shared)
    with pytest.raises(ValueError, match=r"another kind.*(lever_arm|bias).*vs.*(lever_arm|bias)"):
        second(shared)
    assert a is not None and shared.value is None


def test_a_free_of_one_kind_is_still_one_parameter():
    """Two gyroscope terms (one log in two parts) share their bias; two antenna tracks
    their lever arm; a gyroscope and an accelerometer their clock."""
    t, g, f = _imu()
    bias, lever, clock = Free(), Free(), Free()
    Gyro(t[:25], g[:25], sigma=0.01, bias=bias, time_offset=clock)
    Gyro(t[25:], g[25:], sigma=0.01, bias=bias)
    Accel(t, f, sigma=0.1, time_offset=clock)
    Positions(t, f, sigma=0.01, lever_arm=lever)
    Positions(t, f, sigma=0.02, lever_arm=lever)


def _solved(batch=()):
    """Poses of the screw motion exp(t xi) with noise, estimated with a gyroscope bias."""
    gen = torch.Generator().manual_seed(13)
    t = torch.linspace(0.0, 2.0, 21, dtype=F64)
    x = dq.exp(t[:, None] * XI)
    x = dq.mul(x, dq.exp(1e-3 * torch.randn(*batch, 21, 6, generator=gen, dtype=F64)))
    ti, g, _ = _imu()
    g = g + 0.01 + 1e-3 * torch.randn(*batch, len(ti), 3, generator=gen, dtype=F64)
    spline = BSpline.from_dualquats(x, t, n_ctrl=8, form="cumulative", degree=4)
    terms = [Poses(t, x, rot_sigma=1e-3, trans_sigma=1e-3),
             Gyro(ti, g, sigma=1e-3, bias=True)]
    return estimate(spline, terms, verbose=False), terms


def test_pose_and_kinematics_std_at_a_nan_time_are_nan():
    est, _ = _solved()
    t = torch.tensor([0.5, math.nan, 1.5], dtype=F64)
    for s, k in ((est.pose_std(t), 6), (est.kinematics_std(t), 12)):
        assert s.shape == (3, k)
        assert bool(s[1].isnan().all()), s[1]
        assert bool((torch.isfinite(s[[0, 2]]) & (s[[0, 2]] > 0)).all())


def test_a_nan_time_touches_no_other_batch_element():
    est, _ = _solved(batch=(2,))
    t = torch.tensor([[0.5, math.nan], [0.5, 1.0]], dtype=F64)
    s = est.pose_std(t)
    ref = est.pose_std(torch.tensor([[0.5, 1.0], [0.5, 1.0]], dtype=F64))
    assert bool(s[0, 1].isnan().all()) and not bool(s[0, 0].isnan().any())
    torch.testing.assert_close(s[1], ref[1], rtol=0, atol=0)
    torch.testing.assert_close(s[0, 0], ref[0, 0], rtol=0, atol=0)


def test_cov_names_an_item_that_is_not_a_pair():
    est, (poses, gyro) = _solved()
    with pytest.raises(TypeError, match=r"Estimate\.cov.*\(term, name\) pairs"):
        est.cov(gyro)
    with pytest.raises(TypeError, match=r"Estimate\.cov.*\(term, name\) pairs"):
        est.cov((gyro, "bias", 3))
    with pytest.raises(ValueError, match=r"Estimate\.cov: Poses\.extrinsic was not estimated"):
        est.cov((poses, "extrinsic"))
    assert est.cov((gyro, "bias")).shape == (3, 3)


def test_a_free_prior_std_of_the_wrong_length_names_the_chart():
    """``prior_std``: a float or one per chart axis (extrinsic 6, gravity 2: the plane
    orthogonal to it; a bias 3); other lengths failed at estimate with a RuntimeError of
    ``expand``."""
    t, g, f = _imu()
    x = dq.exp(t[:, None] * XI)
    g0 = torch.tensor([0.0, 0.0, -9.81], dtype=F64)
    with pytest.raises(ValueError, match=r"Gyro: bias's fitting\.Free has 2 prior_std values: "
                                         r"expected a float or 3"):
        Gyro(t, g, sigma=0.01, bias=Free(prior_std=[0.01, 0.01]))
    with pytest.raises(ValueError, match=r"gravity's fitting\.Free has 3 .*a float or 2"):
        Accel(t, f, sigma=0.1, gravity=Free(start=g0, prior_std=[0.1, 0.1, 0.1]))
    with pytest.raises(ValueError, match=r"extrinsic's fitting\.Free has 3 .*a float or 6"):
        Poses(t, x, rot_sigma=0.01, trans_sigma=0.01, extrinsic=Free(prior_std=[0.1] * 3))
    Accel(t, f, sigma=0.1, gravity=Free(start=g0, prior_std=[0.1, 0.1]))
    Poses(t, x, rot_sigma=0.01, trans_sigma=0.01, extrinsic=Free(prior_std=[0.1] * 6))
    Gyro(t, g, sigma=0.01, bias=Free(prior_std=0.01), time_offset=Free(prior_std=[0.01]))

"""GNSS-style positions of an antenna on a lever arm, a gyroscope and an accelerometer with
biases (the clock known), started with identity rotations: the estimate should end within
1 of the objective that the truth start reaches, or not say that it converged.

The known limitation of CHANGELOG 0.5.0 (the user trial's finding 0): the numerical prior's
pulls, re-anchored at every step, hold the directions of the IMU-free ends' control points
(seen by the positions alone) near the start, and the scaled gradient test leaves them out:
seed 0 of this rig ends at 9098.39 from the identity start, 9051.66 from the truth start,
both reported converged. Releasing the pulls once the pulled test passes (far16, far17)
brings the starts together here (far17: 9039.31 vs 9039.30) but moved converged estimates
of other rigs (``test_honest_imu_poses``: an extrinsic 5.4 standard deviations off the
truth; ``test_rig11_batch_masks``: a batch element's clock std 1.5e-5 relatively from its
solo solve), so it is not shipped: the test is a strict expected failure until a rule
passes both. The rig is ``test_gnss15_positions_imu_lever_arm``'s (readings written with
numpy and scipy); the truth start puts the curve on the true motion (the IMU's, not the
antenna's) and the lever arm and biases at their true values.
"""

import warnings

import numpy as np
import pytest
import torch
from test_gnss15_positions_imu_lever_arm import BA, BG, LEVER, _motion, _rig

from torch_dq.fitting import Free, estimate
from torch_dq.nn import BSpline


def _truth_rig(seed, duration, monkeypatch):
    """``_rig``'s data and terms, the lever arm and biases started at their true values, and
    the curve through the true motion (the IMU's, on ``_rig``'s knots)."""
    import test_gnss15_positions_imu_lever_arm as rig

    def started(cls, key, value):
        def make(*args, **kwargs):
            kwargs[key] = Free(torch.from_numpy(value))
            return cls(*args, **kwargs)
        return make

    monkeypatch.setattr(rig, "Positions", started(rig.Positions, "lever_arm", LEVER))
    monkeypatch.setattr(rig, "Gyro", started(rig.Gyro, "bias", BG))
    monkeypatch.setattr(rig, "Accel", started(rig.Accel, "bias", BA))
    spline, terms = _rig(seed, duration)
    tp = np.arange(0.0, duration + 1e-9, 0.05)
    R, p = _motion(tp)[:2]
    truth = BSpline.from_poses(torch.from_numpy(R.as_quat(scalar_first=True)),
                               torch.from_numpy(p), torch.from_numpy(tp), knot_spacing=0.1,
                               degree=4, form="cumulative", margin=0.1)
    assert truth.n_ctrl == spline.n_ctrl
    return truth, terms


def _fit(spline, terms):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a "no progress" warning is part of the verdict
        return estimate(spline, terms, steps=100, verbose=False)


@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="known limitation (CHANGELOG 0.5.0): the pulls hold the IMU-free "
                          "ends; identity start 9098.39 vs 9051.66")
def test_identity_start_ends_at_the_truth_starts_objective_or_says_not(monkeypatch):
    """8 s, seed 0: converged from the identity start only within 1 of the truth start's
    objective (on main: 9098.39 vs 9051.66, both converged)."""
    ident = _fit(*_rig(0, 8.0))
    truth = _fit(*_truth_rig(0, 8.0, monkeypatch))
    a, b = float(ident.final_loss), float(truth.final_loss)
    assert a > 8000.0 and b > 8000.0, (a, b)  # chi2 of ~9000 components: a real fit
    assert not bool(ident.converged) or a < b + 1.0, (a, b, ident.reason)

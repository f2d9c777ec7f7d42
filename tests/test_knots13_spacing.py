"""camera_imu's knot spacing chosen from the IMU readings (knot_spacing=None, the default):
the spline's approximation error against scipy's least-squares B-spline fit, the spectrum
against formulas written here, and the spacing chosen on synthetic rigs (``_calib12_rig``:
numpy / scipy / OpenCV) judged by the truth: a slow motion gets knots every 0.027 s (its
accelerometer's chi2/dof 1.02), a dance 2.5 times faster (up to 3.3 rad/s; with knots
every 0.05 s its accelerometer's chi2/dof reads about 300 and the extrinsic's translation
is 8.7 standard deviations off) the finest, 0.01 s, and a warning that they are not fine
enough (chi2/dof 2.78), every value within a few standard deviations of the truth."""

import numpy as np
import pytest
import torch
from _calib12_rig import RADTAN, Cam, Motion, make_rig, mount, rot
from scipy.interpolate import BSpline
from test_calib12_camera_imu import errors, run

from torch_dq.calibration import _knot_spacing

pytest.importorskip("cv2")

CAM = Cam("pinhole-radtan", RADTAN, rot("z", 90) @ rot("x", 2),
          np.array([-0.02, -0.065, 0.01]), 0.01)


def _rig(speed: float, duration: float, **kw):
    """The calib12 rig's motion with every frequency ``speed`` times its own."""
    m = Motion(*mount(CAM.R_bc, CAM.t_bc))
    m.rot_f, m.pos_f = m.rot_f * speed, m.pos_f * speed
    return make_rig([CAM], duration=duration, motion=m, **kw)


@pytest.mark.parametrize("order", [0, 1, 2])
def test_spline_loss_is_the_least_squares_fit_error(order):
    """The share of a sinusoid's power that the order-th derivative of a uniform cubic
    B-spline (knots 1 apart) cannot fit: scipy's B-spline basis, dense least squares."""
    knots = np.arange(-3.0, 204.0)  # 200 spans: the ends' extra freedom 1 % of the fit
    t = np.linspace(0.0, 200.0, 8001)
    spline = BSpline(knots, np.eye(knots.size - 4), 3)  # every basis function at once
    basis = (spline.derivative(order) if order else spline)(t)
    for w in (0.5, 1.0, 2.0, 2.8):
        y = np.sin(w * t + 0.3)
        r = y - basis @ np.linalg.lstsq(basis, y, rcond=None)[0]
        want = (r ** 2).mean() / (y ** 2).mean()
        got = float(_knot_spacing.spline_loss(np.array(w), order))
        assert got == pytest.approx(want, rel=0.03), (order, w)


def test_welch_white_noise_level_and_a_sine_power():
    """White noise of sigma per axis: one-sided 2 sigma^2 / rate per axis, 3 axes summed;
    a sine of amplitude A on one axis adds A^2 / 2 around its frequency."""
    rate, sigma, amp, f0 = 200.0, 0.3, 2.0, 7.0
    rng = np.random.default_rng(1)
    t = np.arange(0, 60, 1 / rate)
    x = sigma * rng.standard_normal((t.size, 3))
    x[:, 1] += amp * np.sin(2 * np.pi * f0 * t) + 5.0 + 0.1 * t  # bias, drift removed
    freq, psd = _knot_spacing.welch(_knot_spacing._segments(x, 400), rate)
    far = np.abs(freq - f0) > 2.0
    assert np.median(psd[far & (freq > 1)]) == pytest.approx(6 * sigma ** 2 / rate, rel=0.05)
    near = ~far
    df = freq[1] - freq[0]
    power = ((psd[near] - 6 * sigma ** 2 / rate) * df).sum()
    assert power == pytest.approx(amp ** 2 / 2, rel=0.03)


def test_slow_motion_coarser_fast_dance_finest_and_too_small_densities_not_finer():
    """On the readings themselves (camera_imu passes the body velocity's rate for the
    accelerometer): the slow motion 0.031 s, the fast dance the finest with its predicted
    excess above EXCESS (1.2), densities 10 times too small the slow motion's spacing."""
    slow, fast = _rig(1.0, 6.0), _rig(2.5, 6.0)
    densities = (slow.gyro_noise, slow.accel_noise)
    h_slow, _ = _knot_spacing.choose(slow.imu[0], slow.imu[1:], densities)
    h_fast, seen = _knot_spacing.choose(fast.imu[0], fast.imu[1:], densities)
    assert 0.025 <= h_slow < 0.05
    assert h_fast == pytest.approx(0.01) and seen["accel_hz"] > 5.0
    assert seen["accel"] > _knot_spacing.EXCESS
    # densities 10 times too small: the noise is not motion (the spectrum's own floor)
    h_small, _ = _knot_spacing.choose(slow.imu[0], slow.imu[1:],
                                      tuple(d / 10 for d in densities))
    assert h_small == pytest.approx(h_slow, rel=0.05)


@pytest.mark.filterwarnings("ignore:fitting.Estimate. chi2/dof far above 1")
def test_fast_dance_default_spacing_against_the_truth():
    """Knots every 0.05 s: accelerometer chi2/dof ~300, the extrinsic 8.7 std off (measured,
    not run here); the default chooses the finest knots, and warns that even they leave a
    model error: chi2/dof 2.78, the values within 3.5 std."""
    rig = _rig(2.5, 4.0)
    with pytest.warns(UserWarning, match="too fast for the finest knots"):
        res = run(rig)
    assert res.knot_spacing == pytest.approx(0.01)
    knots = res.trajectory.knots.diff()
    assert float(knots.median()) == pytest.approx(res.knot_spacing, rel=0.02)
    est = res.estimate
    imu = [float(est.chi2[t]) / float(est.dof[t]) for t in res.terms[-2:]]
    # dof14: each term's exact dof (its leverages; the IMU takes most of the fine knots'
    # parameters, beyond its share of the residual count): gyro 0.98, accel 2.78 measured
    # (the proportional share read 0.56 and 1.55)
    assert imu[0] < 1.5 and imu[1] < 3.5, imu
    err, std = errors(res, rig)
    assert np.abs(err / std).max() < 3.5, np.round(err / std, 2)


def test_explicit_spacing_is_honoured_and_checked():
    rig = _rig(1.0, 3.0, seed=2)
    res = run(rig, knot_spacing=0.04)
    assert res.knot_spacing == 0.04
    assert float(res.trajectory.knots.diff().median()) == pytest.approx(0.04, rel=0.02)
    with pytest.raises(ValueError, match="knot_spacing"):
        run(rig, knot_spacing=-0.05)
    with pytest.raises(ValueError, match="knot_spacing"):
        run(rig, knot_spacing=float("nan"))
    assert torch.isfinite(res.extrinsics).all()

"""A time offset's std from the observed information (clock16, ``fitting._observed``): on a
short GNSS + IMU rig (positions of an antenna on a lever arm, gyroscope and accelerometer
sharing an estimated clock) the Gauss-Newton std of the clock is too small; ``std`` reports
the marginal of the Hessian with exact nuisance rows, checked against an independent
reference: the public residuals' autograd Jacobian for the control-point block and central
finite differences of the public cost in the clock for its row, inverted densely."""
import warnings

import pytest
import torch

from torch_dq import dualquat, nn, quat
from torch_dq.fitting import Accel, Free, Gyro, Poses, Positions, _observed, estimate

F = dict(dtype=torch.float64)
A = torch.tensor([0.6, 0.5, 1.5], **F)
W = torch.tensor([1.1, 0.7, 0.5], **F)
PH = torch.tensor([0.0, 1.0, 0.3], **F)
DT, LEVER, END = 0.02, torch.tensor([0.3, -0.1, 0.2], **F), 1.2


def _motion(t):
    rv = A * torch.sin(W * t[:, None] + PH)
    p = torch.stack([torch.sin(0.9 * t), 0.7 * torch.cos(0.6 * t), 0.3 * torch.sin(1.3 * t)], -1)
    return quat.from_rotvec(rv), p


def _rig(kind):
    """Antenna positions (``kind="positions"``, 1 cm) or poses at 20 Hz, a 200 Hz IMU 20 ms
    late, quartic cumulative B-spline with 0.1 s knots started from the true poses."""
    g = torch.Generator().manual_seed(0)
    tf = torch.arange(-0.3, END + 0.3, 0.02, **F)
    truth = nn.BSpline.from_poses(*_motion(tf), tf, knot_spacing=0.02, degree=4,
                                  form="cumulative")
    tc = torch.arange(0.0, END + 1e-9, 0.05, **F)
    ti = torch.arange(0.1, END - 0.1, 0.005, **F)
    with torch.no_grad():
        gy, ac = truth.imu(ti + DT)
        x = truth(tc)
    gy = gy + 2e-3 * torch.randn(gy.shape, generator=g, **F)
    ac = ac + 2e-2 * torch.randn(ac.shape, generator=g, **F)
    noise = 0.01 * torch.randn(tc.shape[0], 6, generator=g, **F)
    if kind == "positions":
        first = Positions(tc, dualquat.apply(x, LEVER) + noise[:, :3], sigma=0.01,
                          lever_arm=LEVER)
    else:
        first = Poses(tc, dualquat.mul(x, dualquat.exp(noise)), rot_sigma=0.01,
                      trans_sigma=0.01)
    clock = Free(start=DT)
    terms = [first, Gyro(ti, gy, sigma=2e-3, time_offset=clock),
             Accel(ti, ac, sigma=2e-2, time_offset=clock)]
    curve = nn.BSpline.from_poses(*_motion(tc), tc, knot_spacing=0.1, degree=4,
                                  form="cumulative", margin=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = estimate(curve, terms, steps=100, tol=1e-12, verbose=False)
    return curve, terms, est


def _reference(curve, terms):
    """The clock's marginal variances, Gauss-Newton's and with the exact clock row, densely:
    ``J_c`` of the whitened residuals in body-frame steps of the control points by autograd,
    the clock's column by central differences (of the residuals: Gauss-Newton; of the cost's
    gradient and the cost: exact)."""
    ctrl0 = curve.control_points.detach().clone()
    n, tau0 = ctrl0.shape[0], float(terms[1].time_offset)
    gyro, acc = terms[1], terms[2]

    def residuals(xc, tau):
        ctrl = dualquat.mul(ctrl0, dualquat.exp(xc.reshape(n, 6)))
        ts = [terms[0], Gyro(gyro.times, gyro.readings, sigma=2e-3, time_offset=tau),
              Accel(acc.times, acc.readings, sigma=2e-2, time_offset=tau)]
        return torch.cat([t(curve, ctrl).reshape(-1) for t in ts])

    def cost(xc, tau):
        return 0.5 * (residuals(xc, tau) ** 2).sum()

    z, h = torch.zeros(n * 6, **F), 1e-6
    Jc = torch.autograd.functional.jacobian(lambda x: residuals(x, tau0), z, vectorize=True)
    Jt = (residuals(z, tau0 + h) - residuals(z, tau0 - h)) / (2 * h)
    gp = torch.autograd.functional.jacobian(lambda x: cost(x, tau0 + h), z)
    gm = torch.autograd.functional.jacobian(lambda x: cost(x, tau0 - h), z)
    htt = (cost(z, tau0 + h) + cost(z, tau0 - h) - 2 * cost(z, tau0)) / h ** 2
    used = Jc.abs().amax(0) > 0
    Acc = (Jc.T @ Jc)[used][:, used]
    out = []
    for c, t in ((Jc.T @ Jt, Jt @ Jt), ((gp - gm) / (2 * h), htt)):
        c = c[used]
        out.append(1.0 / (t - c @ torch.linalg.solve(Acc, c)))
    return float(out[0]), float(out[1])


def test_clock_on_no_minimum_is_inf():
    """Antenna positions on 1.2 s: the reference's Schur complement with the exact clock row
    is negative (the estimate is no minimum along the clock once the second-order terms are
    counted, while Gauss-Newton reports 6 ms): ``std`` stays Gauss-Newton's (the contract),
    with a warning naming the parameter; ``observed=True`` is inf, with the warning."""
    curve, terms, est = _rig("positions")
    gn_var, exact_var = _reference(curve, terms)
    assert exact_var < 0 < gn_var
    gn = float(est.cov((terms[1], "time_offset")).sqrt())
    assert gn == pytest.approx(gn_var ** 0.5, rel=0.05)  # weak ends: factored regularised
    with pytest.warns(RuntimeWarning, match=r"Gyro\.time_offset's Gauss-Newton standard "
                                            r"deviation is inf times smaller.*no minimum.*"
                                            r"observed=True"):
        assert float(est.std(terms[1], "time_offset")) == gn
    with pytest.warns(RuntimeWarning, match=r"no minimum.*observed standard deviation is inf"):
        assert float(est.std(terms[1], "time_offset", observed=True)) == float("inf")
    with pytest.raises(ValueError, match=r"observed=True is for a time_offset.*'bias'"):
        est.std(terms[1], "bias", observed=True)
    with pytest.raises(TypeError, match="observed to be a bool"):
        est.std(terms[1], "time_offset", observed=1)


def test_clock_std_against_the_reference(monkeypatch):
    """Poses (the rotation seen): the observed std 1.2 times the Gauss-Newton one. ``std``
    is Gauss-Newton's; with the factor above that ratio without the warning, with it below
    with the warning; ``observed=True`` is the Gauss-Newton one times the reference's ratio
    (and ``scaled`` times the pooled factor) without a warning."""
    curve, terms, est = _rig("poses")
    gn_var, exact_var = _reference(curve, terms)
    ratio = (exact_var / gn_var) ** 0.5
    assert 1.1 < ratio < 1.5
    gn = float(est.cov((terms[1], "time_offset")).sqrt())
    assert gn == pytest.approx(gn_var ** 0.5, rel=0.05)  # weak ends: factored regularised
    monkeypatch.setattr(_observed, "FACTOR", 1.5)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*times smaller than its observed")
        assert float(est.std(terms[1], "time_offset")) == gn
        s = float(est.std(terms[1], "time_offset", observed=True))
        scaled = float(est.std(terms[2], "time_offset", scaled=True, observed=True))
    assert s / gn == pytest.approx(ratio, rel=0.03)
    monkeypatch.setattr(_observed, "FACTOR", 1.1)
    with pytest.warns(RuntimeWarning, match=r"Gyro\.time_offset's Gauss-Newton standard"):
        assert float(est.std(terms[1], "time_offset")) == gn
    with pytest.warns(RuntimeWarning, match="Accel.time_offset"):
        scaled_gn = float(est.std(terms[2], "time_offset", scaled=True))
    factor = float(est._factor_scale()[0])  # the pooled sqrt(chi2 / dof)
    accel_gn = float(est.cov((terms[2], "time_offset")).sqrt())
    assert scaled_gn == pytest.approx(accel_gn * factor, rel=1e-9)
    assert scaled / scaled_gn == pytest.approx(float(est._ratios[
        est._param(terms[2], "time_offset").offset][0]), rel=1e-9)

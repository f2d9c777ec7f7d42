"""Per-term chi2/dof far from 1, both ways (honest8): a correct model never warns, sigmas
too large warn "far below 1", too small "far above 1", and the summary marks each; the
quantile band against scipy; ``std(..., scaled=True)`` against a numpy formula."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist

import torch_dq.dualquat as dq
from torch_dq.fitting import Gyro, Poses, estimate
from torch_dq.fitting._chi2 import band as _band
from torch_dq.nn import BSpline

F64 = torch.float64
ROT, TRANS, GYRO = 0.01, 0.01, 0.01
BIAS = np.array([0.02, -0.01, 0.03])


def _truth(t):
    """Rotation (scipy), position and body angular velocity (numpy) at times t."""
    R = (Rotation.from_euler("z", (0.8 * t)[:, None])
         * Rotation.from_euler("y", (0.5 * np.sin(t))[:, None]))
    p = np.stack((0.6 * t + 0.1 * t**2, np.sin(2 * t), 0.5 * np.cos(t)), -1)
    ey = np.stack((-np.sin(0.8 * t), np.cos(0.8 * t), 0 * t), -1)
    w = np.array([0.0, 0.0, 0.8]) + (0.5 * np.cos(t))[:, None] * ey
    return R, p, R.inv().apply(w)


def _job(seed: int, scale=(1.0, 1.0, 1.0), pose_hz=10, spacing=0.2):
    """4 s of poses (``pose_hz``) and a 50 Hz gyroscope with a bias, noises ROT, TRANS,
    GYRO; the terms declare the true sigmas times ``scale`` (poses rot, trans, gyro)."""
    rng = np.random.default_rng(seed)
    tc, ti = np.linspace(0, 4, 4 * pose_hz + 1), np.linspace(0.1, 3.9, 191)
    R, p, _ = _truth(tc)
    Rm = R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    pm = p + TRANS * rng.standard_normal(p.shape)
    gy = _truth(ti)[2] + BIAS + GYRO * rng.standard_normal((len(ti), 3))
    x = dq.from_rt(torch.from_numpy(Rm.as_quat(scalar_first=True)), torch.from_numpy(pm))
    t = torch.from_numpy(tc)
    spline = BSpline.from_dualquats(x, t, n_ctrl=math.ceil(4 / spacing) + 3, form="cumulative")
    cam = Poses(t, x, rot_sigma=ROT * scale[0], trans_sigma=TRANS * scale[1])
    gyro = Gyro(torch.from_numpy(ti), torch.from_numpy(gy), sigma=GYRO * scale[2], bias=True)
    return spline, cam, gyro


def test_band_matches_scipy_quantiles():
    """The cube-root approximation of the two-sided 99.9 % band is within 1 % of scipy's
    chi-square quantiles from 100 degrees of freedom; at 10 within 2 % above and 10 % below,
    where it errs low (a warning less likely, never more)."""
    for nu, tol in ((10, 0.1), (100, 0.01), (1000, 0.01), (20000, 0.01)):
        n = torch.tensor(float(nu), dtype=F64)
        hi, lo = chi2_dist.ppf(0.9995, nu), chi2_dist.ppf(0.0005, nu)
        assert float(_band(n, 3.2905)) == pytest.approx(hi, rel=min(tol, 0.02))
        assert float(_band(n, -3.2905)) == pytest.approx(lo, rel=tol)
        assert float(_band(n, -3.2905)) <= lo * (1 + 1e-6)


@pytest.mark.parametrize("pose_hz,spacing,seeds", [(10, 0.2, 20), (5, 0.25, 10)])
def test_correct_model_never_warns(pose_hz, spacing, seeds):
    """20 (10) noise seeds of a correct model (the terms' sigmas the true ones): no chi2 warning
    when the uncertainties are asked, also where the poses are barely more than the control
    points (their proportional share of the parameters is then far too small, their
    chi2/dof 0.4 to 0.55: the lower test uses the fewest degrees of freedom they can have)."""
    ratios = []
    for seed in range(seeds):
        spline, cam, gyro = _job(seed, pose_hz=pose_hz, spacing=spacing)
        est = estimate(spline, [cam, gyro], verbose=False)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            est.std(gyro, "bias")
        ratios.append([float(est.chi2[t] / est.dof[t]) for t in (cam, gyro)])
        assert "far" not in est.summary() and "far" not in repr(est)
    assert 0.4 < np.mean(ratios) < 1.6


@pytest.mark.parametrize("which,name", [(2, "Gyro"), (0, "Poses")])
def test_sigmas_too_large_warn_far_below(which, name):
    """A term whose sigmas are 2.5 times the truth (chi2/dof about 0.16): the first
    uncertainty warns "far below 1" naming it, the summary and the repr mark it."""
    scale = [1.0, 1.0, 1.0]
    scale[which] = 2.5
    if which == 0:
        scale[1] = 2.5
    spline, cam, gyro = _job(3, tuple(scale))
    est = estimate(spline, [cam, gyro], verbose=False)
    with pytest.warns(RuntimeWarning, match=rf"chi2/dof far below 1 \({name} 0\.1"):
        est.std(gyro, "bias")
    line = next(s for s in est.summary().splitlines() if s.strip().startswith(name))
    assert "far below 1" in line
    assert f"{name}: " in repr(est) and "(far below 1)" in repr(est)
    c, d = float(est.chi2[cam if which == 0 else gyro]), float(est.dof[cam if which == 0
                                                                       else gyro])
    assert f"chi2/dof {c / d:.3g}" in line


def test_summary_reports_both_ways():
    """Gyro sigmas too small, poses' too large: two warnings, each naming its term, and the
    summary marks one above, the other below."""
    spline, cam, gyro = _job(5, (3.0, 3.0, 0.4))
    est = estimate(spline, [cam, gyro], verbose=False)
    with pytest.warns(RuntimeWarning) as record:
        est.pose_std(torch.tensor([1.0, 2.0], dtype=F64))
    text = " ".join(str(w.message) for w in record)
    assert "far above 1 (Gyro" in text and "far below 1 (Poses" in text
    lines = est.summary().splitlines()
    assert "far above 1" in next(s for s in lines if "Gyro" in s)
    assert "far below 1" in next(s for s in lines if "Poses" in s)


def _numpy_chi2_poses(spline, cam, tc, Rm, pm):
    """The poses' chi2 by scipy: rotation vectors of R_m^T R(t) and p(t) - p_m, whitened."""
    with torch.no_grad():
        x = spline(tc)
    q, p = dq.to_rt(x)
    R = Rotation.from_quat(q.numpy(), scalar_first=True)
    rv = (Rm.inv() * R).as_rotvec()
    return float((rv**2).sum() / ROT**2 + ((p.numpy() - pm) ** 2).sum() / TRANS**2)


def test_scaled_is_the_pooled_reference_variance():
    """``scaled=True`` multiplies every standard deviation by sqrt(sum chi2 / (N - p)), N the
    residual components of every term and p = 6 n_ctrl + 3 (bias): the poses' chi2 by scipy,
    the gyro's from its whitened residuals; and sigmas all off by one common factor (3x) give
    the same scaled standard deviations as the true sigmas."""
    spline, cam, gyro = _job(11)
    est = estimate(spline, [cam, gyro], verbose=False)
    rng = np.random.default_rng(11)  # the job's poses again, for the scipy chi2
    tc = np.linspace(0, 4, 41)
    R, p, _ = _truth(tc)
    Rm = R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    pm = p + TRANS * rng.standard_normal(p.shape)
    with torch.no_grad():
        chi_g = float(gyro(spline).square().sum())
    chi_p = _numpy_chi2_poses(spline, cam, torch.from_numpy(tc), Rm, pm)
    assert chi_p == pytest.approx(float(est.chi2[cam]), rel=1e-9)
    n_res, n_par = 6 * 41 + 3 * 191, 6 * spline.n_ctrl + 3
    factor = math.sqrt((chi_p + chi_g) / (n_res - n_par))
    s, s_scaled = est.std(gyro, "bias"), est.std(gyro, "bias", scaled=True)
    np.testing.assert_allclose(s_scaled.numpy(), factor * s.numpy(), rtol=1e-10)
    t = torch.tensor([0.5, 2.0], dtype=F64)
    np.testing.assert_allclose(est.pose_std(t, scaled=True).numpy(),
                               factor * est.pose_std(t).numpy(), rtol=1e-10)
    np.testing.assert_allclose(est.cov(scaled=True).numpy(), factor**2 * est.cov().numpy(),
                               rtol=1e-10)
    spline3, cam3, gyro3 = _job(11, (3.0, 3.0, 3.0))
    est3 = estimate(spline3, [cam3, gyro3], verbose=False)
    with pytest.warns(RuntimeWarning, match="far below 1"):
        s3 = est3.std(gyro3, "bias", scaled=True)
    np.testing.assert_allclose(s3.numpy(), s_scaled.numpy(), rtol=1e-6)
    np.testing.assert_allclose(est3.std(gyro3, "bias").numpy(), 3 * s.numpy(), rtol=1e-6)

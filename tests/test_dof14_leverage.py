"""Per-term degrees of freedom: nu_t = N_t - tr(H_t H^+), each term's samples' leverages.

(a) Against a dense numpy reference: each term's whitened residuals differentiated by
central differences with respect to a local step of every control point (``c exp(delta)``)
and of the estimated biases (additive), rows weighted by the square roots of the robust
weights, and
``nu_t = N_t - trace(J_t pinv(J^T J) J_t^T)`` (the hat matrix's diagonal over the term's
rows; invariant under a change of the local charts), for several terms, a robust term
(its inliers by a fixed point written here with scipy), a masked term, a batch and a
time gap; ``BandedCholesky.trace_products`` against numpy's dense inverse.

(b) Monte Carlo: poses and an IMU with correct sigmas on a closed-form motion (scipy
rotations), the mean chi2/dof per term over seeds about 1; the proportional share of the
parameters (N_t (1 - p / sum N)) gave the poses 1.086 here (60 s benchmark job: 1.084).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi2 as chi2_dist

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Gyro, Poses, Positions, RelativePoses, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
G = np.array([0.0, 0.0, -9.81])
ROT, POS, GYR, ACC = 2e-3, 2e-3, 3e-3, 3e-2
B_G, B_A = np.array([0.01, -0.02, 0.015]), np.array([0.05, -0.08, 0.1])


def _truth(t: np.ndarray):
    """Rotation ``R0 exp(phi(t))``, position, body angular rate ``J_r(phi) phi'`` and world
    acceleration, in closed form."""
    phi = np.stack([0.3 * np.sin(t), 0.4 * t, 0.2 * np.cos(0.7 * t)], -1)
    dphi = np.stack([0.3 * np.cos(t), 0.4 + 0 * t, -0.14 * np.sin(0.7 * t)], -1)
    th = np.linalg.norm(phi, axis=-1)[:, None, None]
    hat = np.zeros((len(t), 3, 3))
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    hat = hat - hat.transpose(0, 2, 1)
    a = (1 - np.cos(th)) / th**2
    b = (th - np.sin(th)) / th**3
    jr = np.eye(3) - a * hat + b * hat @ hat
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]) * Rotation.from_rotvec(phi)
    amp, f = np.array([1.0, 0.8, 0.3]), np.array([0.5, 0.7, 0.9])
    p = amp * np.sin(t[:, None] * f)
    acc = -amp * f**2 * np.sin(t[:, None] * f)
    return R, p, np.einsum("nij,nj->ni", jr, dphi), acc


def _pose(R: Rotation, p: np.ndarray) -> torch.Tensor:
    return dq.from_rt(torch.tensor(R.as_quat(scalar_first=True)), torch.tensor(p))


def _job(seed: int, duration: float = 4.0, pose_hz: float = 20.0, imu_hz: float = 100.0,
         knot: float = 0.1, robust: str | None = None, mask: bool = False):
    """A spline from the noisy poses and the terms: poses, gyroscope and accelerometer
    with biases (``robust`` on the gyroscope, with 3 % gross outliers then; ``mask``: a
    third of the poses masked)."""
    rng = np.random.default_rng(seed)
    tc = np.arange(round(duration * pose_hz) + 1) / pose_hz
    ti = np.arange(round(duration * imu_hz) + 1) / imu_hz
    Rc, pc, _, _ = _truth(tc)
    Ri, _, w, a = _truth(ti)
    Rm = Rc * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3)))
    poses = _pose(Rm, pc + POS * rng.standard_normal((len(tc), 3)))
    gyro = w + B_G + GYR * rng.standard_normal(w.shape)
    if robust:
        out = rng.random(len(ti)) < 0.03
        gyro[out] += rng.uniform(0.1, 0.3, (out.sum(), 3)) * rng.choice([-1, 1], (out.sum(), 3))
    acc = Ri.inv().apply(a - G) + B_A + ACC * rng.standard_normal(a.shape)
    t, u = torch.tensor(tc), torch.tensor(ti)
    m = torch.tensor(np.arange(len(tc)) % 3 != 1) if mask else None
    n = int(np.ceil(duration / knot)) + 3
    spline = BSpline.from_dualquats(poses, t, n_ctrl=n, form="cumulative")
    return spline, _terms(t, u, poses, torch.tensor(gyro), torch.tensor(acc), robust, m)


def _terms(t, u, poses, gyro, acc, robust=None, mask=None):
    return [Poses(t, poses, rot_sigma=ROT, trans_sigma=POS, mask=mask),
            Gyro(u, gyro, sigma=GYR, bias=True, robust=robust),
            Accel(u, acc, sigma=ACC, bias=True, gravity=torch.tensor(G))]


def _solve(spline, terms):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return estimate(spline, terms, verbose=False)


def _leverages(spline, terms, weights) -> list[np.ndarray]:
    """Per term ``(...)``: trace(J_t pinv(J^T J) J_t^T), ``J`` the whitened residuals'
    (``term.evaluate``) central differences over a local step of the control points
    (``c exp(delta)``) and of the estimated (additive) biases, rows times sqrt(robust
    weight); a batch element's rows and columns apart."""
    ctrl = spline.control_points.detach()
    lead, n = ctrl.shape[:-2], ctrl.shape[-2]
    vals = [term.values(spline, ctrl) for term in terms]
    est = [[k for k, s in term.slots().items() if s.estimated] for term in terms]
    for names in est:
        assert set(names) <= {"bias"}
    sizes = [6 * n] + [3 for names in est for _ in names]
    P, B = sum(sizes), max(int(np.prod(lead)), 1)

    def rows(x):  # x (K, *lead, P) -> (K, B, R)
        parts = list(torch.split(x, sizes, -1))
        c = dq.mul(ctrl, dq.exp(parts[0].unflatten(-1, (n, 6))))
        out, k = [], 1
        for term, v, names, w in zip(terms, vals, est, weights, strict=True):
            v = dict(v)
            for name in names:
                v[name] = v[name] + parts[k]
                k += 1
            r = term.evaluate(spline, c, v) * w.sqrt()[..., None]
            out.append(r.reshape(x.shape[0], B, -1))
        return torch.cat(out, -1)

    h = 1e-6
    steps = h * torch.eye(P, dtype=F64).reshape(P, *(1,) * len(lead), P).expand(P, *lead, P)
    with torch.no_grad():
        J = ((rows(steps) - rows(-steps)) / (2 * h)).numpy()  # (P, B, R)
    counts = [w.shape[-1] * term.dim for term, w in zip(terms, weights, strict=True)]
    lev = np.zeros((B, J.shape[-1]))
    for b in range(B):
        Jb = J[:, b, :].T
        H = Jb.T @ Jb
        lev[b] = np.einsum("ij,jk,ik->i", Jb, np.linalg.pinv(H, rcond=1e-12, hermitian=True), Jb)
    out, a = [], 0
    for c in counts:
        out.append(lev[:, a:a + c].sum(-1).reshape(lead))
        a += c
    return out


def _inliers(s2: np.ndarray, d: int, taken: float) -> int:
    """The robust term's inliers (numpy): squared norms within the 99.9 % chi-square
    quantile times f = chi2 / (d n_in - taken) / kappa, a fixed point from the median's."""
    q = chi2_dist.ppf(0.999, d)
    kappa = chi2_dist.cdf(q, d + 2) / chi2_dist.cdf(q, d)
    f = np.median(s2) / chi2_dist.ppf(0.5, d)
    keep = np.zeros(len(s2), dtype=bool)
    for _ in range(100):
        new = s2 <= q * f
        if np.array_equal(new, keep):
            break
        keep = new
        f = s2[keep].sum() / (kappa * (d * keep.sum() - taken))
    return int(keep.sum())


def _check(est, spline, terms, tol=1e-6):
    weights = [est.weights[t].detach() for t in terms]
    lev = _leverages(spline, terms, weights)
    dof = [est.dof[t].numpy() for t in terms]
    for term, nu, x, w in zip(terms, dof, lev, weights, strict=True):
        if term.robust is None:
            count = term.mask.expand(w.shape).sum(-1).numpy() * term.dim
        else:
            r = term(spline).detach().numpy()
            count = _inliers((r * r).sum(-1)[term.mask.numpy()], term.dim, float(x)) * term.dim
        np.testing.assert_allclose(nu, count - x, rtol=0, atol=tol)
    return dof, lev


def test_poses_gyro_accel_with_biases_match_the_dense_reference():
    spline, terms = _job(0, duration=2.0, knot=0.2)
    est = _solve(spline, terms)
    dof, _ = _check(est, spline, terms)
    n = spline.control_points.shape[0]
    # summed: the residual components less the parameters (all determined here)
    total = sum(float(t.mask.sum()) * t.dim for t in terms)
    assert sum(float(x) for x in dof) == pytest.approx(total - 6 * n - 6, abs=1e-6)


def test_robust_and_masked_terms_match_the_dense_reference():
    spline, terms = _job(1, duration=2.0, knot=0.2, robust="cauchy", mask=True)
    est = _solve(spline, terms)
    _check(est, spline, terms)
    assert float(est.weights[terms[1]].min()) < 0.1  # the outliers weighed down


def test_positions_and_relative_poses_match_the_dense_reference():
    rng = np.random.default_rng(2)
    tc = np.arange(61) / 20.0
    R, p, _, _ = _truth(tc)
    poses = _pose(R * Rotation.from_rotvec(ROT * rng.standard_normal((61, 3))),
                  p + POS * rng.standard_normal((61, 3)))
    rel = dq.mul(dq.conj(poses[:-1]), poses[1:])
    t = torch.tensor(tc)
    pos = torch.tensor(p + 0.01 * rng.standard_normal((61, 3)))
    terms = [Positions(t, pos, sigma=0.01),
             RelativePoses(t[:-1], t[1:], rel, rot_sigma=2 * ROT, trans_sigma=2 * POS),
             Poses(t[::10], poses[::10], rot_sigma=ROT, trans_sigma=POS)]
    spline = BSpline.from_dualquats(poses, t, n_ctrl=14, form="cumulative")
    est = _solve(spline, terms)
    _check(est, spline, terms)


def test_a_batch_matches_the_dense_reference_per_element():
    """Two trajectories on shared times, each its own data (a third of the second's poses
    masked): each element's dof its own."""
    jobs = [_job(s, duration=2.0, knot=0.2)[1] for s in (3, 4)]
    t, u = jobs[0][0].times, jobs[0][1].times
    poses = torch.stack([dq.from_rt(ts[0].rotations, ts[0].translations) for ts in jobs])
    spline = BSpline.from_dualquats(poses, t, n_ctrl=13, form="cumulative")
    mask = torch.stack([torch.ones(len(t), dtype=torch.bool), torch.arange(len(t)) % 3 != 1])
    terms = _terms(t, u, poses, *(torch.stack([ts[k].readings for ts in jobs]) for k in (1, 2)),
                   mask=mask)
    est = _solve(spline, terms)
    dof, _ = _check(est, spline, terms)
    assert dof[0].shape == (2,) and float(dof[0][0] - dof[0][1]) > 60


def test_monte_carlo_chi2_over_dof_is_one_per_term():
    """15 seeds of 4 s, poses at 20 Hz, IMU at 100 Hz, knots every 0.08 s, correct sigmas:
    the mean chi2/dof of each term within 3 standard errors of 1 (sd of one seed's about
    sqrt(2 / nu); the poses' 3 se 0.051). Measured: poses 1.009, gyroscope 1.000,
    accelerometer 0.988; the proportional share gave 1.086 (5 se off), 0.982 and 0.975."""
    ratios = []
    for seed in range(15):
        spline, terms = _job(100 + seed, knot=0.08)
        est = _solve(spline, terms)
        ratios.append([float(est.chi2[t] / est.dof[t]) for t in terms])
        nus = [float(est.dof[t]) for t in terms]
    mean = np.mean(ratios, 0)
    se = np.sqrt(2.0 / np.array(nus) / 15)
    assert np.all(np.abs(mean - 1) < 3 * se), (mean, se)


@pytest.mark.parametrize(("n", "w"), [(7, 3), (10, 4), (5, 2), (1, 1), (4, 4)])
def test_trace_products_against_numpy(n, w):
    """``BandedCholesky.trace_products``: trace(M (A^-1 + U V^T)) of block-banded ``M``
    against numpy's dense inverse, a batch of two, with and without the update."""
    from torch_dq.fitting._banded import BandedCholesky
    rng = np.random.default_rng(n + 10 * w)
    s = 6
    block = np.arange(n * s) // s
    near = np.abs(block[:, None] - block[None, :]) < w
    J = rng.standard_normal((2, 3 * n * s, n * s))
    A = (J.transpose(0, 2, 1) @ J) * near + 5 * np.eye(n * s)
    M = rng.standard_normal((2, n * s, n * s))
    M = (M + M.transpose(0, 2, 1)) * near
    U = rng.standard_normal((2, n * s, 2))
    S = rng.standard_normal((2, 2, 2))
    V = U @ (S + S.transpose(0, 2, 1))  # U V^T symmetric

    def band(X):
        b = np.zeros((2, n, w, s, s))
        for k in range(n):
            for d in range(min(w, n - k)):
                b[:, k, d] = X[:, k * s:(k + 1) * s, (k + d) * s:(k + d + 1) * s]
        return torch.from_numpy(b)

    chol = BandedCholesky(band(A))
    plain, = chol.trace_products([band(M)])
    up, = chol.trace_products([band(M)], *(torch.from_numpy(x.reshape(2, n, s, 2))
                                           for x in (U, V)))
    inv = np.linalg.inv(A)
    np.testing.assert_allclose(plain.numpy(), np.einsum("bij,bji->b", M, inv), rtol=1e-10)
    ref = np.einsum("bij,bji->b", M, inv + U @ V.transpose(0, 2, 1))
    np.testing.assert_allclose(up.numpy(), ref, rtol=1e-10)


def test_a_time_gap_counts_its_control_points_for_no_term():
    """Poses and gyroscope with a 0.8 s gap over 0.2 s knots: the control points without
    data are no term's parameters (the dense pseudo-inverse's null space), the rest match."""
    rng = np.random.default_rng(7)
    tc, ti = np.arange(61) / 20.0, np.arange(301) / 100.0
    tc, ti = tc[(tc < 1.0) | (tc > 1.8)], ti[(ti < 1.0) | (ti > 1.8)]
    R, p, _, _ = _truth(tc)
    poses = _pose(R * Rotation.from_rotvec(ROT * rng.standard_normal((len(tc), 3))),
                  p + POS * rng.standard_normal(p.shape))
    gyro = _truth(ti)[2] + B_G + GYR * rng.standard_normal((len(ti), 3))
    t = torch.tensor(tc)
    terms = [Poses(t, poses, rot_sigma=ROT, trans_sigma=POS),
             Gyro(torch.tensor(ti), torch.tensor(gyro), sigma=GYR, bias=True)]
    spline = BSpline.from_dualquats(poses, t, n_ctrl=18, form="cumulative")
    est = _solve(spline, terms)
    _, lev = _check(est, spline, terms)
    # one control point's 6 directions without data: 105 of the 111 parameters determined
    assert sum(float(x) for x in lev) == pytest.approx(6 * 18 + 3 - 6, abs=1e-6)

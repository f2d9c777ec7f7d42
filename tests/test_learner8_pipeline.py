"""A learning-pipeline user's trial of ``torch_dq.nn.BSpline`` (learner8): BAD-Gaussians-like
camera trajectories over an exposure, in the three B-spline forms, against independent
references written here (numpy/scipy matrix formulas, pypose's ``bspline``), with finite
gradients at every degenerate point and an Adam loop that converges in float32 and float64.

pypose's parametrisation (``pypose.bspline(poses, interval)``): a uniform, unclamped cubic
cumulative B-spline on SE(3), ``T(s) = T_{i-1} prod_{j=i}^{i+2} Exp(lambda_{j-i}(u) Log(
T_{j-1}^{-1} T_j))`` with the SE(3) group Log/Exp (twists ``(rho, phi)``), knots one unit
apart, segment ``i`` covering ``s in [i, i + 1)`` with ``u = s - i``, and the end pose
appended; poses are 7-vectors ``(tx, ty, tz, qx, qy, qz, qw)``. It is torch_dq's
``form="cumulative"`` cubic on the knots ``0, 1, ..., n + 3`` at ``t = s + 3``.
"""

import math

import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
import torch_dq.quat as tq
from torch_dq import nn as tnn

F64 = torch.float64
FORMS = ("de_boor", "cumulative", "split")
KINDS = ("generic", "identical", "halfturn", "pure_translation", "tiny")


# ----------------------------------------------------------------------------- references

def basis_np(knots, p, t):
    """Cox-de Boor B-spline basis ``(T, n)`` at ``t`` (the last span closed at the end)."""
    knots, t = np.asarray(knots, float), np.asarray(t, float)
    n = len(knots) - p - 1
    hi = knots[n]
    b = np.zeros((len(t), len(knots) - 1))
    for i in range(len(knots) - 1):
        inside = (knots[i] <= t) & (t < knots[i + 1])
        if knots[i] < knots[i + 1] and knots[i + 1] == hi:
            inside |= t == hi
        if i >= n:
            inside &= t != hi
        b[:, i] = inside
    for k in range(1, p + 1):
        nb = np.zeros((len(t), len(knots) - 1 - k))
        for i in range(len(knots) - 1 - k):
            d0, d1 = knots[i + k] - knots[i], knots[i + k + 1] - knots[i + 1]
            a = (t - knots[i]) / d0 * b[:, i] if d0 > 0 else 0.0
            c = (knots[i + k + 1] - t) / d1 * b[:, i + 1] if d1 > 0 else 0.0
            nb[:, i] = a + c
        b = nb
    return b


def mats_np(x):
    """``(..., 8)`` dual quaternions -> ``(..., 4, 4)`` numpy matrices (scipy's rotation)."""
    x = x.detach().double().numpy()
    q, d = x[..., :4], x[..., 4:]
    w, v = q[..., :1], q[..., 1:]
    dw, dv = d[..., :1], d[..., 1:]
    t = 2.0 * (w * dv - dw * v + np.cross(v, dv))  # t = 2 d q*  (vector part)
    T = np.zeros((*x.shape[:-1], 4, 4))
    T[..., :3, :3] = Rotation.from_quat(np.concatenate((v, w), -1).reshape(-1, 4)
                                        ).as_matrix().reshape((*x.shape[:-1], 3, 3))
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def log_np(T):
    """Principal se(3) logarithm (rotation angle < pi: the shortest path), pytransform3d's
    closed form (scipy's ``logm`` gives the same to 1e-14, at 60 ms a call, 300 times
    theirs: the references call it per sample and level)."""
    return pt.transform_log_from_transform(T)


def cumulative_np(C, knots, p, t):
    r"""Kim-Kim-Shin: ``X = C_0 prod_{j>=1} expm(Bt_j logm(C_{j-1}^{-1} C_j))``."""
    cum = np.cumsum(basis_np(knots, p, t)[:, ::-1], 1)[:, ::-1]
    logs = [log_np(np.linalg.solve(C[j - 1], C[j])) for j in range(1, len(C))]
    out = []
    for row in cum:
        X = C[0].copy()
        for j in range(1, len(C)):
            X = X @ expm(row[j] * logs[j - 1])
        out.append(X)
    return np.stack(out)


def split_np(C, knots, p, t):
    r"""SO(3) x R^3: ``R = R_0 prod Exp(Bt_j Log(R_{j-1}^T R_j))``, ``p = sum_j B_j p_j``."""
    b = basis_np(knots, p, t)
    cum = np.cumsum(b[:, ::-1], 1)[:, ::-1]
    R = Rotation.from_matrix(C[:, :3, :3])
    rel = [(R[j - 1].inv() * R[j]).as_rotvec() for j in range(1, len(C))]
    out = np.zeros((len(t), 4, 4))
    for i, row in enumerate(cum):
        Ri = R[0]
        for j in range(1, len(C)):
            Ri = Ri * Rotation.from_rotvec(row[j] * rel[j - 1])
        out[i, :3, :3] = Ri.as_matrix()
    out[:, :3, 3] = b @ C[:, :3, 3]
    out[:, 3, 3] = 1.0
    return out


def de_boor_np(C, knots, p, t):
    """De Boor's pyramid with screw interpolation ``a expm(s logm(a^-1 b))``."""
    knots = np.asarray(knots, float)
    n = len(C)
    out = []
    for ti in np.asarray(t, float):
        k = min(max(np.searchsorted(knots, ti, side="right") - 1, p), n - 1)
        d = [C[j + k - p].copy() for j in range(p + 1)]
        for r in range(1, p + 1):
            for j in range(p, r - 1, -1):
                i = j + k - p
                s = (ti - knots[i]) / (knots[i + p + 1 - r] - knots[i])
                d[j] = d[j - 1] @ expm(s * log_np(np.linalg.solve(d[j - 1], d[j])))
        out.append(d[p])
    return np.stack(out)


REFERENCE = {"de_boor": de_boor_np, "cumulative": cumulative_np, "split": split_np}


def control_points(kind, n=6, dtype=F64, seed=0):
    """Control poses of one degenerate kind (``(n, 8)``, sign-continuous)."""
    g = torch.Generator().manual_seed(seed)
    trans = torch.randn(n, 3, generator=g, dtype=F64)
    if kind == "generic":
        rot = tq.from_rotvec(0.6 * torch.randn(n, 3, generator=g, dtype=F64))
    elif kind == "identical":
        rot = tq.from_rotvec(torch.tensor([0.3, -0.2, 0.5], dtype=F64)).expand(n, 4)
        trans = trans[:1].expand(n, 3)
    elif kind == "halfturn":  # neighbours a half turn apart (the shortest path's edge)
        axis = torch.tensor([0.0, 0.6, 0.8], dtype=F64).expand(n, 3)
        rot = tq.from_axis_angle(axis, torch.arange(n, dtype=F64) * math.pi)
    elif kind == "pure_translation":
        rot = tq.identity((n,), dtype=F64)
    elif kind == "tiny":
        rot = tq.from_rotvec(1e-8 * torch.randn(n, 3, generator=g, dtype=F64))
    else:
        raise AssertionError(kind)
    return dq.from_rt(rot.contiguous(), trans.contiguous()).to(dtype)


def knots_and_times(n=6, p=3):
    """Clamped uniform knots on [0, 1] and sub-frame times incl. every knot and both ends."""
    knots = np.concatenate((np.zeros(p), np.linspace(0.0, 1.0, n - p + 1), np.ones(p)))
    t = np.unique(np.concatenate((np.linspace(0.0, 1.0, 13), knots)))
    return torch.tensor(knots, dtype=F64), torch.tensor(t, dtype=F64)


# ----------------------------------------------------------------------------- values

@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["generic", "identical", "pure_translation", "tiny"])
def test_forms_match_matrix_references(form, kind):
    """Poses of every form at sub-frame times, at every knot and both ends, against the
    numpy/scipy matrix formula of that form (clamped and non-uniform knots)."""
    n, p = 6, 3
    ctrl = control_points(kind, n)
    knots, t = knots_and_times(n, p)
    knots_nu = torch.tensor([0.0, 0, 0, 0, 0.2, 0.7, 1, 1, 1, 1], dtype=F64)
    for k in (knots, knots_nu):
        x = tnn.BSpline(ctrl, degree=p, knots=k, form=form)(t)
        ref = REFERENCE[form](mats_np(ctrl), k.numpy(), p, t.numpy())
        assert np.abs(mats_np(x) - ref).max() <= 1e-9, (form, kind)


def test_halfturn_neighbours_stay_on_a_half_turn():
    """Neighbours exactly a half turn apart: the shortest path is ambiguous, but every form
    stays finite and on the rotation axis (any valid choice rotates about it)."""
    ctrl = control_points("halfturn")
    knots, t = knots_and_times()
    axis = np.array([0.0, 0.6, 0.8])
    for form in FORMS:
        x = tnn.BSpline(ctrl, knots=knots, form=form)(t)
        assert torch.isfinite(x).all()
        rv = Rotation.from_matrix(mats_np(x)[:, :3, :3]).as_rotvec()
        assert np.abs(np.cross(rv, axis)).max() <= 1e-9, form


# ----------------------------------------------------------------------------- pypose

def _pp_ctrl(base, xi):
    pp = pytest.importorskip("pypose")
    T = pp.SE3(dq.to_pose7(base))
    return T * pp.se3(torch.cat((xi[..., 3:], xi[..., :3]), -1)).Exp()  # (rho, phi)


@pytest.mark.parametrize("kind", ["generic", "identical", "pure_translation", "tiny"])
def test_cumulative_matches_pypose_values_and_gradients(kind):
    """The reprojection loss of 3D points through the cumulative cubic equals pypose's, and
    so does its gradient w.r.t. a twist chart ``c_j exp(xi_j)`` of every control pose; the
    poses also match the numpy formula. At 1e-8 rad rotations pypose itself is off by
    ~1.6e-8 (its SE(3) Log/Exp lose the left Jacobian's ``(1 - cos) / theta^2`` term to
    cancellation) while torch_dq matches the numpy/scipy formula to ~1e-14: the pypose
    tolerance is 1e-7 there."""
    pp = pytest.importorskip("pypose")
    n, interval = 7, 0.125
    base = control_points(kind, n)
    pts = torch.tensor([[0.3, -0.2, 5.0], [-1.0, 0.4, 6.0], [0.8, 0.9, 4.0]], dtype=F64)
    xi_pp = torch.zeros(n, 6, dtype=F64, requires_grad=True)
    poses = pp.bspline(_pp_ctrl(base, xi_pp), interval)  # (S, 7)
    s = torch.arange(poses.shape[-2], dtype=F64) * interval
    y_pp = poses[:, None].Act(pts)
    xi = torch.zeros(n, 6, dtype=F64, requires_grad=True)
    spline = tnn.BSpline(base, knots=torch.arange(n + 4, dtype=F64), form="cumulative")
    x = spline(s + 3.0, ctrl=dq.mul(base, dq.exp(xi)))
    y = dq.apply(x[:, None], pts)
    ref = cumulative_np(mats_np(base), np.arange(n + 4.0), 3, (s + 3.0).numpy())
    assert np.abs(mats_np(x) - ref).max() <= 1e-12
    tol = 1e-7 if kind == "tiny" else 1e-10
    assert float((y - y_pp).detach().abs().max()) <= tol
    loss = lambda y: ((y[..., :2] / y[..., 2:] - 0.1) ** 2).sum()  # noqa: E731
    g_pp, = torch.autograd.grad(loss(y_pp), xi_pp)
    g, = torch.autograd.grad(loss(y), xi)
    assert torch.isfinite(g).all()
    assert float((g - g_pp).abs().max()) <= 10 * tol * max(1.0, float(g_pp.abs().max()))


# ----------------------------------------------------------------------------- BAD-Gaussians

def _reprojection_loss(x, pts, target):
    y = dq.apply(x[..., None, :], pts)
    return ((y[..., :2] / y[..., 2:] - target) ** 2).mean()


@pytest.mark.parametrize("form, dtype, kind", [
    ("de_boor", torch.float32, "identical"), ("de_boor", torch.float64, "tiny"),
    ("cumulative", torch.float32, "pure_translation"), ("cumulative", torch.float64, "identical"),
    ("split", torch.float32, "tiny"), ("split", torch.float64, "pure_translation")])
def test_adam_recovers_an_exposure_trajectory(form, dtype, kind):
    """A blurred exposure: 25 sub-frame poses (ends and knots included) of a cubic camera
    trajectory whose control poses are degenerate (each kind in each form once across the
    cases, in one dtype); Adam from a perturbed start
    brings the reprojection loss down by 1e3 or more, every gradient finite on the way,
    including at the exact solution (zero loss)."""
    g = torch.Generator().manual_seed(3)
    pts = torch.randn(30, 3, generator=g, dtype=F64) + torch.tensor([0.0, 0.0, 6.0], dtype=F64)
    _, t = knots_and_times()
    for ctrl in (control_points(kind),):
        with torch.no_grad():
            target = dq.apply(tnn.BSpline(ctrl, form=form)(t)[:, None], pts)
            target = (target[..., :2] / target[..., 2:]).to(dtype)
        exact = tnn.BSpline(ctrl.to(dtype), form=form)
        _reprojection_loss(exact(t), pts.to(dtype), target).backward()
        assert torch.isfinite(exact.parametrizations.ctrl.original.grad).all(), kind
        start = dq.mul(ctrl, dq.exp(0.05 * torch.randn(6, 6, generator=g, dtype=F64)))
        spline = tnn.BSpline(start.to(dtype), form=form)
        opt = torch.optim.Adam(spline.parameters(), lr=2e-2)
        losses = []
        for _ in range(120):
            opt.zero_grad()
            loss = _reprojection_loss(spline(t), pts.to(dtype), target)
            loss.backward()
            assert torch.isfinite(spline.parametrizations.ctrl.original.grad).all(), kind
            losses.append(float(loss.detach()))
            opt.step()
        assert losses[-1] <= 1e-3 * losses[0], (kind, losses[0], losses[-1])


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("knots", [
    [0, 0, 0, 0, 0.4, 0.4, 0.7, 1, 1, 1, 1],  # a double interior knot
    [0, 0, 0, 0, 0.5, 0.5, 0.5, 1, 1, 1, 1],  # a triple one (C^0 for a cubic)
    [-1, -0.5, 0, 0.2, 0.2, 0.6, 1, 1.3, 1.6, 2, 3]], ids=["double", "triple", "unclamped"])
def test_repeated_and_unclamped_knots(form, knots):
    """Repeated interior knots and unclamped non-uniform knots: poses at every knot, both
    ends and between them match the matrix formula of the form."""
    c = control_points("generic", 7)
    k = torch.tensor(knots, dtype=F64)
    lo, hi = float(k[3]), float(k[7])
    t = torch.tensor(sorted({lo, hi, *np.linspace(lo, hi, 9).tolist(),
                             *[v for v in knots if lo <= v <= hi]}), dtype=F64)
    x = tnn.BSpline(c, knots=k, form=form)(t)
    ref = REFERENCE[form](mats_np(c), k.numpy(), 3, t.numpy())
    assert np.abs(mats_np(x) - ref).max() <= 1e-9

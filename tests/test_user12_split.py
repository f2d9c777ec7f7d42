"""A new user's checks of the split SO(3) x R^3 B-spline (user12) against independent
references: scipy's ``BSpline`` (translations, the basis), a numpy/scipy product of rotation
exponentials (rotations, any knots), ``pypose.bspline`` (its SE(3) cumulative cubic has the
split form's rotations on uniform knots), scipy's ``Slerp`` (degree 1), finite differences of
the numpy reference (time derivatives to order 3); batch shapes and float32."""

import numpy as np
import pytest
import torch
from scipy.interpolate import BSpline as ScipyBSpline
from scipy.spatial.transform import Rotation, Slerp

import torch_dq.dualquat as dq
from torch_dq import curves, nn

F64 = torch.float64
KNOTS = np.array([0.0, 0, 0, 0, 0.7, 1.1, 2.5, 3, 3, 3, 3])  # clamped, non-uniform, n = 7


def _control(n, seed=1, batch=()):
    rng = np.random.default_rng(seed)
    rotvec = np.cumsum(rng.normal(0.0, 0.6, (*batch, n, 3)), -2)
    trans = rng.normal(0.0, 1.0, (*batch, n, 3))
    return rotvec, trans


def _to_dq(rotvec, trans):
    xyzw = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_quat()
    wxyz = np.concatenate((xyzw[:, 3:], xyzw[:, :3]), -1).reshape(*rotvec.shape[:-1], 4)
    return dq.from_rt(torch.tensor(wxyz), torch.tensor(trans))


def _reference(rotvec, trans, knots, degree, t):
    """numpy: R(t) = R_0 prod_j Exp(Bt_j(t) Log(R_{j-1}^T R_j)), p(t) = sum_j B_j(t) p_j,
    Bt_j = sum_{l >= j} B_l (scipy's B-spline basis), as (T, 8) dual quaternions."""
    n = len(trans)
    basis = np.stack([np.nan_to_num(ScipyBSpline(knots, np.eye(n)[j], degree,
                                                 extrapolate=False)(t)) for j in range(n)], 1)
    basis[t == knots[-1], -1] = 1.0  # scipy leaves the closing end of a clamped basis out
    cumulative = np.cumsum(basis[:, ::-1], 1)[:, ::-1]
    R = Rotation.from_rotvec(rotvec)
    steps = [(R[j - 1].inv() * R[j]).as_rotvec() for j in range(1, n)]
    out = []
    for i in range(len(t)):
        r = R[0]
        for j in range(1, n):
            r = r * Rotation.from_rotvec(cumulative[i, j] * steps[j - 1])
        out.append(r.as_rotvec())
    return _to_dq(np.array(out), basis @ trans)


def _same(a, b):
    """Dual quaternions up to the sign of each row."""
    sign = torch.sign((a[..., :4] * b[..., :4]).sum(-1, keepdim=True))
    return (a * sign - b).abs().max().item()


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_split_matches_the_numpy_product_on_clamped_nonuniform_knots(degree):
    n = 7
    breaks = 0.78 * np.linspace(0, 3, n - degree + 1) ** 1.3  # non-uniform
    knots = np.concatenate(([breaks[0]] * degree, breaks, [breaks[-1]] * degree))
    rotvec, trans = _control(n)
    t = np.linspace(knots[0], knots[-1], 41)
    x = curves.bspline(_to_dq(rotvec, trans), torch.tensor(t), degree=degree,
                       knots=torch.tensor(knots), form="split")
    assert _same(x, _reference(rotvec, trans, knots, degree, t)) < 1e-13


def test_split_rotations_equal_pypose_bspline_and_translations_scipy():
    pp = pytest.importorskip("pypose")
    n = 8
    rotvec, trans = _control(n, seed=2)
    ctrl = _to_dq(rotvec, trans)
    knots = torch.arange(n + 4, dtype=F64)  # uniform unclamped: domain [3, n]
    s = torch.linspace(0, n - 3, 4 * (n - 3) + 1, dtype=F64)
    x = curves.bspline(ctrl, s + 3, degree=3, knots=knots, form="split")
    ours = Rotation.from_quat(torch.cat((x[:, 1:4], x[:, :1]), -1).numpy())
    theirs = pp.bspline(pp.SE3(dq.to_pose7(ctrl))[None], interval=0.25).tensor()[0].numpy()
    assert (ours * Rotation.from_quat(theirs[:, 3:]).inv()).magnitude().max() < 1e-13
    p = dq.to_rt(x)[1].numpy()
    np.testing.assert_allclose(p, ScipyBSpline(knots.numpy(), trans, 3)(s.numpy() + 3),
                               atol=1e-13)


def test_split_degree_one_is_scipy_slerp_and_linear_interpolation():
    n = 5
    rotvec, trans = _control(n, seed=3)
    rotvec[3] = rotvec[2] + [0.0, 0.0, 3.0]  # a step over 170 degrees: still the short way
    times = np.array([0.0, 0.4, 1.5, 1.7, 3.0])
    t = np.linspace(0, 3, 61)
    x = curves.bspline(_to_dq(rotvec, trans), torch.tensor(t), degree=1,
                       knots=torch.tensor(np.concatenate(([0.0], times, [3.0]))), form="split")
    r = Slerp(times, Rotation.from_rotvec(rotvec))(t)
    p = np.stack([np.interp(t, times, trans[:, k]) for k in range(3)], -1)
    assert _same(x, _to_dq(r.as_rotvec(), p)) < 1e-13


def test_split_derivatives_match_finite_differences_of_the_numpy_reference():
    rotvec, trans = _control(7, seed=4)
    t = np.array([0.3, 0.9, 1.6, 2.0, 2.8])  # inside spans (the cubic's d3 jumps at knots)
    d = curves.bspline_derivatives(_to_dq(rotvec, trans), torch.tensor(t), order=3, degree=3,
                                   knots=torch.tensor(KNOTS), form="split")
    h = 1e-3
    ref = {k: _reference(rotvec, trans, KNOTS, 3, t + k * h).numpy() for k in range(-2, 3)}
    for k in ref:
        ref[k] *= np.sign((ref[k][:, :4] * d[0][:, :4].numpy()).sum(-1, keepdims=True))
    fd = [ref[0],
          (-ref[2] + 8 * ref[1] - 8 * ref[-1] + ref[-2]) / (12 * h),
          (-ref[2] + 16 * ref[1] - 30 * ref[0] + 16 * ref[-1] - ref[-2]) / (12 * h * h),
          (ref[2] - 2 * ref[1] + 2 * ref[-1] - ref[-2]) / (2 * h ** 3)]
    for k, tol in enumerate((1e-13, 1e-9, 1e-6, 1e-4)):
        scale = max(1.0, np.abs(fd[k]).max())
        assert np.abs(d[k].numpy() - fd[k]).max() < tol * scale, k


@pytest.mark.parametrize("shape", [(), (1,), (5,), (2, 5), (3, 1, 5)])
def test_split_batches_equal_the_numpy_reference_per_element(shape):
    rotvec, trans = _control(7, seed=5, batch=shape)
    ctrl = _to_dq(rotvec, trans)
    t = np.linspace(0.0, 3.0, 9)
    for times in (torch.tensor(t), torch.tensor(t).expand(*shape, 9)):
        x = curves.bspline(ctrl, times, degree=3, knots=torch.tensor(KNOTS), form="split")
        assert x.shape == (*shape, 9, 8)
        module = nn.BSpline(ctrl, knots=torch.tensor(KNOTS), form="split")
        assert module(times).shape == (*shape, 9, 8)
        flat_r, flat_t = rotvec.reshape(-1, 7, 3), trans.reshape(-1, 7, 3)
        ref = torch.stack([_reference(flat_r[i], flat_t[i], KNOTS, 3, t)
                           for i in range(len(flat_r))]).reshape(*shape, 9, 8)
        assert _same(x, ref) < 1e-13
        assert _same(module(times).detach(), ref) < 1e-13


def test_split_float32_with_unix_times_is_float32_accurate():
    rotvec, trans = _control(7, seed=6, batch=(200,))
    ctrl = _to_dq(rotvec, trans)
    t = np.linspace(0.0, 3.0, 13)
    ref = torch.stack([_reference(rotvec[i], trans[i], KNOTS, 3, t) for i in range(200)])
    for offset in (0.0, 1.7e9):  # float64 UNIX seconds with float32 control points
        x = curves.bspline(ctrl.float(), torch.tensor(t + offset), degree=3,
                           knots=torch.tensor(KNOTS + offset), form="split")
        assert x.dtype == torch.float32
        assert _same(x.double(), ref) < 2e-6  # translations ~ 3: a few float32 ulps

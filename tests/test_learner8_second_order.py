"""learner8: second order of ``nn.BSpline`` (poses, time derivatives, IMU readings) with
respect to the control points, at generic and degenerate control poses, in the three
forms; ``torch.func`` transforms over the layer; float32 accuracy against float64.

References are independent of the library: ``gradcheck``/``gradgradcheck`` (finite
differences), central finite differences of gradients, and the numpy/scipy matrix formulas of
``test_learner8_pipeline``.
"""

import math

import numpy as np
import pytest
import torch
from torch.autograd import gradcheck, gradgradcheck
from torch.func import hessian, jacfwd, jacrev, vmap

import torch_dq.dualquat as dq
import torch_dq.quat as tq
from tests.test_learner8_pipeline import FORMS, REFERENCE, control_points, mats_np
from torch_dq import nn as tnn

F64 = torch.float64
KNOTS = torch.tensor([0.0, 0, 0, 0, 0.5, 1, 1, 1, 1], dtype=F64)  # one interior knot
TIMES = torch.tensor([0.0, 0.3, 0.5, 1.0], dtype=F64)  # both ends and the knot


def near_halfturn(n=5):
    """Neighbours 1e-3 rad short of a half turn (still differentiable: one shortest path)."""
    axis = torch.tensor([0.0, 0.6, 0.8], dtype=F64).expand(n, 3)
    rot = tq.from_axis_angle(axis, torch.arange(n, dtype=F64) * (math.pi - 1e-3))
    return dq.from_rt(rot.contiguous(), torch.randn(n, 3, dtype=F64,
                                                    generator=torch.Generator().manual_seed(2)))


def ctrl_of(kind):
    return near_halfturn() if kind == "near_halfturn" else control_points(kind, 5)


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["generic", "identical", "tiny", "pure_translation",
                                  "near_halfturn"])
def test_gradcheck_and_gradgradcheck(form, kind):
    """Poses, ``(x, dx, ddx)`` and (generic, static) IMU readings: first and second
    derivatives w.r.t. the control points agree with finite differences (fast mode), at the
    ends and the knot."""
    c = ctrl_of(kind).requires_grad_()
    m = tnn.BSpline(c.detach(), knots=KNOTS, form=form)
    fns = [lambda c: m(TIMES, ctrl=c), lambda c: torch.cat(m.derivatives(TIMES, 2, ctrl=c), -1)]
    if kind in ("generic", "identical"):
        fns.append(lambda c: torch.cat(m.imu(TIMES, ctrl=c), -1))
    for f in fns:
        assert gradcheck(f, (c,), fast_mode=True)
        assert gradgradcheck(f, (c,), fast_mode=True)


@pytest.mark.parametrize("form", FORMS)
def test_exact_halfturn_gradients_are_finite(form):
    """Exactly a half turn between neighbours the shortest path switches branch (no
    derivative there), but first and second derivatives come back finite, not NaN."""
    c = control_points("halfturn", 5).requires_grad_()
    m = tnn.BSpline(c.detach(), knots=KNOTS, form=form)
    x, _dx, ddx = m.derivatives(TIMES, 2, ctrl=c)
    g, = torch.autograd.grad((ddx.square().sum() + x.sum()), c, create_graph=True)
    h, = torch.autograd.grad(g.square().sum(), c)
    assert torch.isfinite(g).all() and torch.isfinite(h).all()


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("which", [0, 1, 2])
def test_double_backward_through_one_derivative(form, which):
    """Regression (cumulative form): double backward through one of ``(x, dx, ddx)`` alone
    (an acceleration penalty's Hessian-vector product) raised ``stack expects each tensor
    to be equal size`` in the fused rows op. The Hessian-vector product in a twist chart
    ``c_j exp(xi_j)`` matches central differences of the gradient."""
    base = control_points("generic", 5)
    m = tnn.BSpline(base, knots=KNOTS, form=form)
    v = torch.randn(5, 6, dtype=F64, generator=torch.Generator().manual_seed(4))

    def grad(xi, create_graph=False):
        out = m.derivatives(TIMES, 2, ctrl=dq.mul(base, dq.exp(xi)))[which]
        return torch.autograd.grad(out.square().sum(), xi, create_graph=create_graph)[0]

    xi = torch.zeros(5, 6, dtype=F64, requires_grad=True)
    hv, = torch.autograd.grad(grad(xi, True), xi, v)
    eps = 1e-5
    fd = (grad((eps * v).requires_grad_()) - grad((-eps * v).requires_grad_())) / (2 * eps)
    assert float((hv - fd).abs().max()) <= 1e-6 * max(1.0, float(fd.abs().max()))


@pytest.mark.parametrize("form", FORMS)
def test_torch_func_over_the_layer(form):
    """``jacrev`` == ``jacfwd`` (no fused path under transforms), ``hessian`` of a
    reprojection-like loss == central differences of its gradient, and ``vmap`` over a batch
    of predicted control points equals the batched call."""
    base = control_points("identical", 5)  # a static camera: the degenerate point
    m = tnn.BSpline(base, knots=KNOTS, form=form)
    pts = torch.tensor([[0.3, -0.2, 5.0], [1.0, 0.5, 4.0]], dtype=F64)

    def poses(xi):
        return m(TIMES, ctrl=dq.mul(base, dq.exp(xi)))

    def loss(xi):
        y = dq.apply(poses(xi)[:, None], pts)
        return (y[..., :2] / y[..., 2:]).square().sum()

    xi0 = torch.zeros(5, 6, dtype=F64)
    assert float((jacrev(poses)(xi0) - jacfwd(poses)(xi0)).abs().max()) <= 1e-12
    H = hessian(loss)(xi0).reshape(30, 30)
    g = jacrev(loss)
    eps = 1e-5
    fd = torch.stack([(g(xi0 + eps * e.view(5, 6)) - g(xi0 - eps * e.view(5, 6))).flatten()
                      for e in torch.eye(30, dtype=F64)]) / (2 * eps)
    assert float((H - fd).abs().max()) <= 1e-6 * max(1.0, float(fd.abs().max()))
    batch = torch.stack((base, control_points("generic", 5)))
    assert torch.allclose(vmap(lambda c: m(TIMES, ctrl=c))(batch), m(TIMES, ctrl=batch),
                          atol=1e-14)


@pytest.mark.parametrize("form", FORMS)
def test_float32_accuracy(form):
    """float32 poses against the float64 numpy/scipy formula, and float32 time derivatives
    (orders 1 to 3) against float64 ones, for a generic trajectory over [0, 1] (8 control
    poses, translations of unit scale), at times off the knots. Measured (2026-11-29, this
    test's data): poses <= 4e-7, derivatives <= 6e-7 of their scale in every form. At a
    knot a float32 module's knot is rounded (0.8 -> 0.80000001) so a float64 time on it
    takes the other side of a jump of the derivative the form does not keep continuous
    (de_boor's acceleration, every form's jerk): that is the one-sided limit, not an
    error, and is left out here."""
    c = control_points("generic", 8)
    t = (torch.arange(100, dtype=F64) + 0.5) / 100
    m64 = tnn.BSpline(c, form=form)
    m32 = tnn.BSpline(c.float(), form=form)
    ref = REFERENCE[form](mats_np(c), m64.knots.numpy(), 3, t.numpy())
    assert np.abs(mats_np(m32(t)) - ref).max() <= 2e-6
    with torch.no_grad():
        d64 = m64.derivatives(t, 3)
        d32 = m32.derivatives(t, 3)
    for k in (1, 2, 3):
        scale = float(d64[k].abs().max())
        assert float((d32[k].double() - d64[k]).abs().max()) <= 3e-6 * scale, k


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["generic", "identical", "tiny"])
def test_imu_against_finite_differences_of_the_matrix_formula(form, kind):
    """Visual-inertial use: gyro ``R^T w`` and accelerometer ``R^T (a - g)`` against central
    differences (step 1e-4, 4th order) of the numpy/scipy pose formula, off the knots; a
    static camera reads zero rotation rate and ``-R^T g``."""
    c = control_points(kind, 6)
    m = tnn.BSpline(c, form=form)
    t = torch.tensor([0.1, 0.45, 0.8], dtype=F64)
    gyro, accel = m.imu(t)
    h = 1e-4
    steps = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
    T = np.stack([REFERENCE[form](mats_np(c), m.knots.numpy(), 3, t.numpy() + s * h)
                  for s in steps])  # (5, T, 4, 4)
    d1 = np.tensordot(np.array([1, -8, 0, 8, -1]) / (12 * h), T, 1)
    d2 = np.tensordot(np.array([-1, 16, -30, 16, -1]) / (12 * h * h), T, 1)
    R = T[2, :, :3, :3]
    w_body = R.transpose(0, 2, 1) @ d1[:, :3, :3]  # [w_body]x = R^T dR/dt
    gyro_ref = np.stack((w_body[:, 2, 1], w_body[:, 0, 2], w_body[:, 1, 0]), -1)
    g = np.array([0.0, 0.0, -9.81])
    accel_ref = np.einsum("tji,tj->ti", R, d2[:, :3, 3] - g)
    for got, ref, tol in ((gyro, gyro_ref, 1e-6), (accel, accel_ref, 1e-5)):
        assert np.abs(got.detach().numpy() - ref).max() <= tol * max(1.0, np.abs(ref).max())


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("kind", ["generic", "identical"])
def test_time_gradients(form, kind):
    """Learning a time offset: poses, ``(x, dx, ddx)`` and IMU readings are twice
    differentiable w.r.t. ``t`` (finite differences, inside the spans), and the first
    derivative w.r.t. ``t`` by autograd is the exact velocity ``dx``."""
    m = tnn.BSpline(control_points(kind, 6), form=form)
    t = torch.tensor([0.1, 0.45, 0.8], dtype=F64, requires_grad=True)
    for f in (lambda t: m(t), lambda t: torch.cat(m.derivatives(t, 2), -1),
              lambda t: torch.cat(m.imu(t), -1)):
        assert gradcheck(f, (t,), fast_mode=True)
        assert gradgradcheck(f, (t,), fast_mode=True)
    x = m(t)
    J = torch.stack([torch.autograd.grad(x[:, k].sum(), t, retain_graph=True)[0]
                     for k in range(8)], -1)
    assert float((J - m.derivatives(t.detach(), 1)[1]).detach().abs().max()) <= 1e-12

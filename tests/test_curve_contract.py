"""The curve contract (issue 30): a curve class that fitting/ has never seen, defined here,
runs through ``torch_dq.fitting.estimate`` by :class:`torch_dq.nn.Curve`'s span contract
alone (``support``, ``local_times``, ``evaluate_span``).

The toy curve is piecewise linear in the Lie algebra: on span ``i`` (uniform knots ``h``
apart), ``x(t) = exp((1 - u) log c_i + u log c_{i+1})`` with ``u = (t - i h) / h``. Its fits
are checked against numpy's linear least squares on the hat-function design matrix (for
rotations about one axis, and for translations with the rotations pinned, the fit is linear in
the twists), and
the solver's Gauss-Newton system against finite differences of the whitened residuals
evaluated through the layer's public path.
"""

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import curves, fitting
from torch_dq._time import KnotDomain
from torch_dq.fitting import Poses
from torch_dq.fitting._problem import Problem
from torch_dq.nn import Curve

F64 = torch.float64


def _lie_linear(a, b, u):
    """``exp((1 - u) log a + u log b)`` for ``a, b (..., 8)``, ``u (...)``."""
    u = u[..., None]
    return dq.exp((1 - u) * dq.log(a) + u * dq.log(b))


class LieLinear(Curve):
    """Piecewise linear in the Lie algebra on ``[0, length]``, spans ``length / (n - 1)``."""

    _name = "LieLinear"

    def __init__(self, ctrl, length=1.0):
        super().__init__()
        self._setup(ctrl, 2, check=True, extrapolate=False)
        self._origin, self._length = 0.0, float(length)
        self._h = self._length / (self.n_ctrl - 1)

    @property
    def time_model(self):
        knots = curves.clamped_uniform_knots(self.n_ctrl, 1, dtype=F64) * self._length
        return KnotDomain(knots, 1, self._origin)

    def _curve(self, ctrl, rel):
        i = (rel / self._h).floor().clamp(0, self.n_ctrl - 2).long()
        u = rel / self._h - i
        a = ctrl.gather(-2, i[..., None].expand(*i.shape, 8))
        b = ctrl.gather(-2, (i + 1)[..., None].expand(*i.shape, 8))
        return _lie_linear(a, b, u.to(ctrl.dtype))

    def _curve_derivatives(self, ctrl, rel, order):
        if order:
            raise ValueError("LieLinear: poses only (order 0)")
        return (self._curve(ctrl, rel),)

    def evaluate_span(self, points, local, first, order):
        if order:
            raise ValueError("LieLinear: poses only (order 0)")
        u = (local / self._h).to(points.dtype).expand(points.shape[:-2])
        return (_lie_linear(points[..., 0, :], points[..., 1, :], u),)


def _hat_design(t, n, length):
    """The hat functions of ``n`` uniform nodes over ``[0, length]`` at ``t``: ``(N, n)``."""
    nodes = np.linspace(0.0, length, n)
    return np.stack([np.interp(t, nodes, np.eye(n)[j]) for j in range(n)], -1)


def _twists(kind, values):
    """Twists ``(..., 6)`` of rotations about z by ``values (...)`` or translations
    ``values (..., 3)``."""
    values = torch.as_tensor(values, dtype=F64)
    if kind == "rotation":
        zero = torch.zeros_like(values)
        return torch.stack((zero, zero, values, zero, zero, zero), -1)
    return torch.cat((torch.zeros_like(values), values), -1)


def test_contract_support_and_local_times():
    curve = LieLinear(dq.exp(0.1 * torch.randn(5, 6, dtype=F64)), length=2.0)  # h = 0.5
    t = torch.tensor([0.0, 0.2, 0.5, 1.7, 2.0], dtype=F64)
    first, w = curve.support(t)
    assert w == curve.span_size == 2
    assert first.tolist() == [0, 0, 1, 3, 3]  # the right end: the last span
    local = curve.local_times(t, first)
    torch.testing.assert_close(local, torch.tensor([0.0, 0.2, 0.0, 0.2, 0.5], dtype=F64))
    pts = curve.control_points.detach()[first[:, None] + torch.arange(2)]
    (x,) = curve.evaluate_span(pts, local, first, 0)
    torch.testing.assert_close(x, curve(t).detach())


@pytest.mark.parametrize("kind", ["rotation", "translation"])
def test_toy_curve_estimate_matches_numpy_least_squares(kind):
    gen = torch.Generator().manual_seed(3)
    n, length, N = 6, 2.0, 41
    t = torch.linspace(0.0, length, N, dtype=F64)
    shape = (n,) if kind == "rotation" else (n, 3)
    true = 0.3 * torch.randn(shape, generator=gen, dtype=F64)
    A = _hat_design(t.numpy(), n, length)
    data = torch.as_tensor(A @ true.numpy()) + 0.02 * torch.randn(
        (N, *shape[1:]), generator=gen, dtype=F64)
    ref = np.linalg.lstsq(A, data.numpy(), rcond=None)[0]
    curve = LieLinear(dq.identity((n,), dtype=F64), length)
    # translations alone: rotations pinned (rotated control points would bend the
    # interpolated translations and trade a rotation residual for a lower translation one)
    sigmas = dict(rot_sigma=0.02, trans_sigma=0.02) if kind == "rotation" else dict(
        rot_sigma=1e-7, trans_sigma=0.02)
    est = fitting.estimate(curve, [Poses(t, dq.exp(_twists(kind, data)), **sigmas)],
                           prior=0.0, verbose=False)
    assert est.converged
    twist = dq.log(curve.control_points.detach())
    if kind == "rotation":
        got, rest = twist[:, 2], torch.cat((twist[:, :2], twist[:, 3:]), -1)
    else:
        got, rest = twist[:, 3:], twist[:, :3]
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-8)
    assert float(rest.abs().max()) < 1e-8


def test_toy_curve_gauss_newton_system_against_finite_differences():
    """The band and gradient of the Gauss-Newton system (exact per-span Jacobians through
    the contract) against J^T J and J^T r of central differences of the whitened residuals
    at a generic point, each control point moved by ``c exp(delta)``."""
    gen = torch.Generator().manual_seed(5)
    n, length = 5, 2.0
    t = torch.linspace(0.0, length, 17, dtype=F64)
    curve = LieLinear(dq.exp(0.4 * torch.randn(n, 6, generator=gen, dtype=F64)), length)
    x = dq.exp(0.4 * torch.randn(17, 6, generator=gen, dtype=F64))
    term = Poses(t, x, rot_sigma=0.05, trans_sigma=0.1)
    ctrl = curve.control_points.detach()
    problem = Problem(curve, [term], ctrl.shape[:-2])
    w = problem.width([])
    assert w == 2
    system = problem.system(ctrl, [], w)

    def residuals(delta):
        return term(curve, ctrl=dq.mul(ctrl, dq.exp(delta))).detach().reshape(-1)

    eps, zero = 1e-6, torch.zeros(n * 6, dtype=F64)
    J = torch.stack([(residuals((zero + eps * e).view(n, 6))
                      - residuals((zero - eps * e).view(n, 6))) / (2 * eps)
                     for e in torch.eye(n * 6, dtype=F64)], -1)
    H, g = J.T @ J, J.T @ residuals(zero.view(n, 6))
    for k in range(n):
        for d in range(w):
            if k + d < n:
                torch.testing.assert_close(system.band[0, k, d],
                                           H[6 * k:6 * k + 6, 6 * (k + d):6 * (k + d) + 6],
                                           rtol=1e-6, atol=1e-6)
    assert H.reshape(n, 6, n, 6).abs().amax((1, 3)).triu(w).max() == 0  # the band's width
    torch.testing.assert_close(system.gc[0].reshape(-1), g, rtol=1e-6, atol=1e-6)


def test_fit_is_a_plain_re_export():
    """``torch_dq.nn.fit`` is ``torch_dq.fitting.fit`` (no lazy module ``__getattr__``)."""
    import torch_dq.nn

    assert torch_dq.nn.fit is fitting.fit and torch_dq.nn.FitHistory is fitting.FitHistory
    assert "__getattr__" not in vars(torch_dq.nn)

"""Eq. 11's dual weights, written once on jets (``torch_dq._taylor``: series, closed forms,
guarded angles) and used with one coefficient by the fused kernels
(``torch_dq._kernels.weights``).

References are independent: mpmath at 40 digits of :math:`F = \\sin(s\\theta)/\\sin\\theta`
with :math:`\\theta = \\arccos(1 - y)`, differentiated numerically in ``y`` and ``s`` (the
kernels' slopes) or along a time line (the jets' Taylor coefficients). Samples cluster at the
series/closed-form switch points of ``_numerics.THRESHOLDS["screw_series"]``, where the
truncation and cancellation errors of the two branches meet.
"""

from __future__ import annotations

import math

import mpmath as mp
import pytest
import torch

from torch_dq import _taylor
from torch_dq._kernels import jet_sclerp
from torch_dq._kernels import weights as kw
from torch_dq._numerics import threshold

F64, F32 = torch.float64, torch.float32


@pytest.fixture(autouse=True)
def _mp_precision():
    """40 digits for this module's mpmath references, restored afterwards (set globally, it
    leaked into other modules' references)."""
    with mp.workdps(40):
        yield


def _F(s, y):
    theta = mp.acos(1 - y)
    return mp.sin(s * theta) / mp.sin(theta)


def _samples(dtype, order, n, gen):
    """``y`` spanning 1e-9 (1e-6 in float32, above its rounding) .. 1.9 with a third of them
    within 1 % of the switch point, and ``t`` in [-0.3, 1.3] (extrapolation included)."""
    switch = threshold("screw_series", dtype, order)
    low = 9.0 if dtype == F64 else 6.0
    y = 10.0 ** (torch.rand(n, generator=gen, dtype=F64) * (low + 0.28) - low)
    y[: n // 3] = switch * (1.0 + 0.02 * (torch.rand(n // 3, generator=gen, dtype=F64) - 0.5))
    t = torch.rand(n, generator=gen, dtype=F64) * 1.6 - 0.3
    c = (1.0 - y).to(dtype)
    return c, t.to(dtype)


def _rel_err(x, ref):
    return abs(float(x) - float(ref)) / max(1.0, abs(float(ref)))


@pytest.mark.parametrize("dtype, tol", [(F64, (1e-15, 1e-12, 2e-9, 1e-15, 2e-12, 2e-9)),
                                        (F32, (1e-6, 1e-5, 3e-4, 1e-6, 2e-5, 3e-4))])
def test_kernel_weights_and_slopes_against_mpmath(dtype, tol):
    """F, G = dF/dy, H = dG/dy, Fs = dF/ds, Gs = dG/ds, Hs = dH/ds of ``screw_weights``
    (both branches, the host-branch paths) against mpmath derivatives."""
    c, t = _samples(dtype, 0, 60, torch.Generator().manual_seed(0))
    w = kw.screw_weights(c, t, derivatives=True, h_slope=True)
    worst = [0.0] * 6
    for i in range(c.numel()):
        y = 1 - mp.mpf(float(c[i]))  # the rounded input's own y
        for row, s in enumerate((1 - mp.mpf(float(t[i])), mp.mpf(float(t[i])))):
            ref = (_F(s, y), mp.diff(lambda z: _F(s, z), y), mp.diff(lambda z: _F(s, z), y, 2),
                   mp.diff(lambda u: _F(u, y), s),
                   mp.diff(lambda u, z: _F(u, z), (s, y), (1, 1)),
                   mp.diff(lambda u, z: _F(u, z), (s, y), (1, 2)))
            for k, (x, r) in enumerate(zip(w, ref, strict=True)):
                worst[k] = max(worst[k], _rel_err(x[row, i], r))
    assert all(e <= b for e, b in zip(worst, tol, strict=True)), worst


def test_kernel_weights_are_the_jets_of_order_0():
    """The kernels' F, G are bit for bit the jets' order 0 (one implementation), in every
    branch path of ``piecewise`` (all series, all closed, a few series, a mix)."""
    gen = torch.Generator().manual_seed(1)
    n = 400
    for y in (torch.full((n,), 1e-6, dtype=F64), torch.rand(n, generator=gen, dtype=F64) + 0.1,
              torch.where(torch.arange(n) < 20, 1e-6, 0.5).double(),
              10.0 ** (torch.rand(n, generator=gen, dtype=F64) * 6 - 6)):
        c, t = 1.0 - y, torch.rand(n, generator=gen, dtype=F64) * 1.4 - 0.2
        w = kw.screw_weights(c, t, host_branch=True)
        F, G = jet_sclerp.weights([c], [torch.stack((1.0 - t, t))])
        assert torch.equal(w.F, F[0]) and torch.equal(w.G, G[0])
        plain = kw.screw_weights(c, t, derivatives=True, host_branch=False, h_slope=True)
        host = kw.screw_weights(c, t, derivatives=True, host_branch=True, h_slope=True)
        assert all(torch.equal(a, b) for a, b in zip(plain, host, strict=True))


def _taylor_ref(c_jet, t_jet, order):
    """mpmath Taylor coefficients of F and G along ``c(tau), t(tau)`` (polynomials)."""
    def along(row, which):
        def f(tau):
            c = sum(mp.mpf(x) * tau**k for k, x in enumerate(c_jet))
            t = sum(mp.mpf(x) * tau**k for k, x in enumerate(t_jet))
            s = 1 - t if row == 0 else t
            theta = mp.acos(c)
            F = mp.sin(s * theta) / mp.sin(theta)
            return F if which == 0 else (s * mp.cos(s * theta) - F * c) / mp.sin(theta) ** 2
        return mp.taylor(f, 0, order)
    return [[along(row, which) for row in (0, 1)] for which in (0, 1)]


@pytest.mark.parametrize("order", [1, 2, 3])
def test_jets_against_mpmath(order):
    """Jets of F and G of orders 1..3 (the curves' time derivatives) around their switch
    points: relative error <= 1e-11 (2e-12 measured for the third coefficient)."""
    gen = torch.Generator().manual_seed(2 + order)
    c, t = _samples(F64, order, 24, gen)
    # c(tau) = cos(theta + omega tau): a relative rotation turning at a rate omega
    theta, omega = torch.acos(c), torch.randn(c.shape, generator=gen, dtype=F64)
    c_jet = [c] + [torch.cos(theta + k * torch.pi / 2) * omega**k / math.factorial(k)
                   for k in range(1, order + 1)]
    t_jet = [t, torch.randn(c.shape, generator=gen, dtype=F64)] + [None] * (order - 1)
    s = _taylor._stack(zip(_taylor._rsub(1.0, t_jet), t_jet, strict=True))
    jets = jet_sclerp.weights(c_jet, s)
    worst = 0.0
    for i in range(c.numel()):
        ref = _taylor_ref([float(x[i]) for x in c_jet],
                          [float(x[i]) for x in t_jet if x is not None], order)
        for which in (0, 1):
            for row in (0, 1):
                for k in range(order + 1):
                    worst = max(worst, _rel_err(jets[which][k][row, i], ref[which][row][k]))
    assert worst <= 1e-11, worst


def test_jets_are_differentiable_twice_across_the_switch():
    """Reverse mode through both branches of the jets: gradcheck and gradgradcheck of G's
    first coefficient in c and t, on points on either side of the order-1 switch."""
    switch = threshold("screw_series", F64, 1)
    y = torch.tensor([0.5 * switch, 0.9 * switch, 1.1 * switch, 3.0 * switch, 0.4], dtype=F64)
    c0 = (1.0 - y).requires_grad_()
    t0 = torch.tensor([0.3, 0.7, 0.2, 0.9, 0.5], dtype=F64, requires_grad=True)

    def fn(c, t):
        s = torch.stack((1.0 - t, t))
        F, G = jet_sclerp.weights([c, 0.01 * torch.ones_like(c)], [s, torch.stack((-t, t))])
        return F[1], G[1]

    assert torch.autograd.gradcheck(fn, (c0, t0))
    assert torch.autograd.gradgradcheck(fn, (c0, t0))


@pytest.mark.parametrize("dtype, tol", [(F64, 4e-14), (F32, 1e-6)])
def test_angle_square_against_mpmath(dtype, tol):
    r""":math:`\theta^2 = \arccos(c)^2`, :math:`\kappa = 2\theta/\sin\theta`, its derivative in
    ``y`` and the first and
    second derivatives of :math:`\theta^2` in ``c`` (reverse mode, twice), against mpmath, on
    ``y`` from 0 (equal rotations, where ``acos`` has no derivative) to 1 (``c = 0``), a third
    within 1 % of the switch point; then the constants of the weights' equations in ``s``:
    :math:`\partial_s^2 F = -\theta^2 F` and :math:`\partial_s^2 G = -\kappa F - \theta^2 G`
    with the kernel's ``F, G`` against mpmath's second derivatives in ``s``."""
    gen = torch.Generator().manual_seed(1)
    switch = threshold("angle_square_series", dtype)
    y = torch.cat((torch.zeros(1, dtype=F64), 10.0 ** (-9.0 * torch.rand(30, generator=gen,
                                                                        dtype=F64)),
                   switch * (1.0 + 0.02 * (torch.rand(15, generator=gen, dtype=F64) - 0.5))))
    c = (1.0 - y).to(dtype).requires_grad_()
    th2, kappa, kappa_y = kw.angle_square(c)
    d1 = torch.autograd.grad(th2.sum(), c, create_graph=True)[0]
    d2 = torch.autograd.grad(d1.sum(), c)[0]
    worst = 0.0
    for i in range(c.numel()):
        ci = mp.mpf(float(c[i].detach()))

        def f(x):  # analytic through c = 1: acos(x)^2 = -acosh(x)^2 above it
            return mp.re(mp.acos(x) ** 2)

        ref_kappa = -mp.diff(f, ci)  # d theta^2 / dy
        for x, r in ((th2[i], f(ci)), (kappa[i], ref_kappa), (d1[i], mp.diff(f, ci)),
                     (d2[i], mp.diff(f, ci, 2)), (kappa_y[i], mp.diff(f, ci, 2))):
            worst = max(worst, _rel_err(x.detach(), r))
    assert worst <= tol, worst
    t = torch.rand(c.numel(), generator=gen, dtype=F64).to(dtype)
    w = kw.screw_weights(c.detach(), t)
    for row, s in enumerate((1.0 - t, t)):
        for i in range(1, c.numel(), 5):
            yi, si = 1 - mp.mpf(float(c[i].detach())), mp.mpf(float(s[i]))
            if yi == 0:  # mpmath's F is 0 / 0 there (float32 rounds small y to 0)
                continue
            ref_F = mp.diff(lambda u, yi=yi: _F(u, yi), si, 2)
            ref_G = mp.diff(lambda u, yi=yi: mp.diff(lambda z: _F(u, z), yi), si, 2)
            F_ss = -th2[i] * w.F[row, i]
            G_ss = -(kappa[i] * w.F[row, i] + th2[i] * w.G[row, i])
            assert _rel_err(F_ss.detach(), ref_F) <= 10 * tol
            assert _rel_err(G_ss.detach(), ref_G) <= 1e3 * tol

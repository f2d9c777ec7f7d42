"""Outside tests of ``camera.project`` / ``unproject`` derivatives (API.md: exact, twice
differentiable w.r.t. points, pixels and params) against mpmath's high-precision
differentiation of the models' formulas written here (OpenCV's and Usenko et al. 2018's),
at and near the degenerate points: the optical axis ``x = y = 0``, zero distortion, the
double sphere's ``xi = 0``; and torch's gradcheck / gradgradcheck there."""

from __future__ import annotations

import itertools

import mpmath as mp
import numpy as np
import pytest
import torch

from torch_dq import camera

F64 = torch.float64
mp.mp.dps = 50


def mp_project(model, p, pt):
    """``(u, v)`` in mpmath of a point: OpenCV's formulas (radtan with k3 = 0, fisheye) and
    eqs. 40-42 of the double sphere."""
    x, y, z = pt
    if model == "double-sphere":
        fu, fv, cu, cv, xi, alpha = p
        d1 = mp.sqrt(x * x + y * y + z * z)
        w = xi * d1 + z
        den = alpha * mp.sqrt(x * x + y * y + w * w) + (1 - alpha) * w
        return fu * x / den + cu, fv * y / den + cv
    a, b = x / z, y / z
    fu, fv, cu, cv = p[:4]
    if model == "pinhole-radtan":
        k1, k2, p1, p2 = p[4:]
        r2 = a * a + b * b
        rad = 1 + k1 * r2 + k2 * r2 * r2
        a, b = (a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a),
                b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b)
    elif model == "pinhole-equidistant":
        k1, k2, k3, k4 = p[4:]
        r = mp.sqrt(a * a + b * b)
        th = mp.atan(r)
        t2 = th * th
        s = 1 if r == 0 else th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) / r
        a, b = s * a, s * b
    return fu * a + cu, fv * b + cv


def _mp_jacobian_hessian(f, x0, out: int, hessian: bool, h=None):
    """Derivatives of ``f(*x) -> (out,)`` at ``x0`` by mpmath's ``diff`` (50 digits; central
    differences of step ``h``, default mpmath's)."""
    opts = {} if h is None else {"h": mp.mpf(h)}
    n = len(x0)
    x0 = [mp.mpf(v) for v in x0]
    jac = np.zeros((out, n))
    hes = np.zeros((out, n, n))
    for i in range(out):
        fi = lambda *x, i=i: f(*x)[i]  # noqa: E731
        for j in range(n):
            jac[i, j] = float(mp.diff(fi, x0, tuple(int(k == j) for k in range(n)), **opts))
        if hessian:
            for j, k in itertools.combinations_with_replacement(range(n), 2):
                order = tuple(int(m == j) + int(m == k) for m in range(n))
                hes[i, j, k] = hes[i, k, j] = float(mp.diff(fi, x0, order, **opts))
    return jac, hes


def _torch_jacobian_hessian(fn, x0):
    x = torch.tensor(x0, dtype=F64)
    jac = torch.autograd.functional.jacobian(fn, x)
    hes = torch.stack([torch.autograd.functional.hessian(lambda x, i=i: fn(x)[i], x)
                       for i in range(jac.shape[0])])
    return jac.numpy(), hes.numpy()


FISH = [0.1, -0.05, 0.01, -0.002]
CASES = [
    # model, params, point: generic, on the axis, near it, zero distortion, xi = 0
    ("pinhole", [400.0, 380.0, 320.0, 240.0], [0.3, -0.2, 1.5]),
    ("pinhole", [400.0, 380.0, 320.0, 240.0], [0.0, 0.0, 2.0]),
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, -0.28, 0.07, 2e-4, 2e-5], [0.3, -0.2, 1.5]),
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, -0.28, 0.07, 2e-4, 2e-5], [0.0, 0.0, 1.0]),
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0], [0.3, -0.2, 1.5]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, *FISH], [0.7, -0.4, 0.5]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, *FISH], [0.0, 0.0, 1.0]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, *FISH], [1e-9, -2e-9, 1.0]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, -0.2, 0.6], [0.7, -0.4, 0.5]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, 0.0, 0.6], [0.7, -0.4, -0.1]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, 0.0, 0.5], [0.0, 0.0, 1.0]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, 0.9, 0.0], [0.0, 0.0, 1.0]),
]


@pytest.mark.parametrize("model,params,point", CASES)
def test_project_derivatives_vs_mpmath(model, params, point):
    """Jacobian and Hessian w.r.t. (point, params) jointly: 1e-9 relative."""
    n = len(params)

    def f_torch(v):
        return camera.project(model, v[3:], v[:3])[0]

    def f_mp(*v):
        return mp_project(model, list(v[3:]), list(v[:3]))

    x0 = point + params
    jac, hes = _torch_jacobian_hessian(f_torch, x0)
    rjac, rhes = _mp_jacobian_hessian(f_mp, x0, 2, hessian=True)
    assert jac.shape == (2, 3 + n)
    np.testing.assert_allclose(jac, rjac, rtol=1e-10, atol=1e-10 * np.abs(rjac).max())
    np.testing.assert_allclose(hes, rhes, rtol=1e-9, atol=1e-9 * np.abs(rhes).max())


def _mp_unproject(model, p, px, start):
    """The normalised point ``(a, b)`` (ray ``(a, b, 1)``) whose image is ``px``."""
    def g(a, b):
        u, v = mp_project(model, p, [a, b, mp.mpf(1)])
        return [u - px[0], v - px[1]]

    a, b = mp.findroot(g, (mp.mpf(start[0]), mp.mpf(start[1])), tol=mp.mpf(10) ** -45)
    n = mp.sqrt(a * a + b * b + 1)
    return a / n, b / n, 1 / n


UNPROJECT_CASES = [
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, -0.28, 0.07, 2e-4, 2e-5], [600.0, 50.0]),
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, -0.28, 0.07, 2e-4, 2e-5], [320.0, 240.0]),
    ("pinhole-radtan", [400.0, 380.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0], [600.0, 50.0]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, *FISH], [700.0, 30.0]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, *FISH], [320.0, 240.0]),
    ("pinhole-equidistant", [300.0, 310.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0], [320.0, 240.0]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, -0.2, 0.6], [700.0, 30.0]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, 0.0, 0.6], [320.0, 240.0]),
    ("double-sphere", [300.0, 310.0, 320.0, 240.0, 0.0, 0.5], [500.0, 400.0]),
]


@pytest.mark.parametrize("model,params,pixel", UNPROJECT_CASES)
def test_unproject_derivatives_vs_mpmath(model, params, pixel):
    """Jacobian w.r.t. (pixel, params) and Hessian w.r.t. (pixel, fu, k1 or xi) of the ray
    against the implicit function of the reference projection (mpmath root, differentiated
    by mpmath): 1e-9 relative."""
    ray, ok = camera.unproject(model, torch.tensor(params, dtype=F64),
                               torch.tensor(pixel, dtype=F64))
    assert bool(ok)
    start = (ray[:2] / ray[2]).tolist()
    x0 = pixel + params

    def f_mp(*v):
        return _mp_unproject(model, list(v[2:]), list(v[:2]), start)

    def f_torch(v):
        return camera.unproject(model, v[2:], v[:2])[0]

    jac = torch.autograd.functional.jacobian(f_torch, torch.tensor(x0, dtype=F64)).numpy()
    rjac, _ = _mp_jacobian_hessian(f_mp, x0, 3, hessian=False, h=1e-12)
    np.testing.assert_allclose(jac, rjac, rtol=1e-9, atol=1e-9 * np.abs(rjac).max())
    # second derivatives in (u, v, fu, first distortion parameter)
    sel = [0, 1, 2, 6]
    rest = list(x0)

    def f_sub_mp(u, v, fu, k):
        w = list(rest)
        w[0], w[1], w[2], w[6] = u, v, fu, k
        return f_mp(*w)

    def f_sub_torch(s):
        w = torch.tensor(rest, dtype=F64).index_put((torch.tensor(sel),), s)
        return f_torch(w)

    _, hes = _torch_jacobian_hessian(f_sub_torch, [x0[i] for i in sel])
    _, rhes = _mp_jacobian_hessian(f_sub_mp, [x0[i] for i in sel], 3, hessian=True, h=1e-10)
    np.testing.assert_allclose(hes, rhes, rtol=1e-8, atol=1e-8 * np.abs(rhes).max())


GRADCHECK = [
    ("pinhole-radtan", [1.1, 0.9, 0.1, -0.2, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.1, -0.2]),
    ("pinhole-radtan", [1.1, 0.9, 0.1, -0.2, -0.2, 0.05, 0.01, -0.01], [0.0, 0.0, 1.0],
     [0.1, -0.2]),
    ("pinhole-equidistant", [1.1, 0.9, 0.1, -0.2, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0],
     [0.1, -0.2]),
    ("pinhole-equidistant", [1.1, 0.9, 0.1, -0.2, 0.1, -0.05, 0.01, -0.002], [0.0, 0.0, 0.7],
     [0.1, -0.2]),
    ("double-sphere", [1.1, 0.9, 0.1, -0.2, 0.0, 0.5], [0.0, 0.0, 1.0], [0.1, -0.2]),
    ("double-sphere", [1.1, 0.9, 0.1, -0.2, -0.2, 0.6], [0.0, 0.0, 1.0], [0.1, -0.2]),
    ("double-sphere", [1.1, 0.9, 0.1, -0.2, 0.0, 0.6], [0.3, 0.2, -0.1], [0.5, 0.3]),
    ("double-sphere", [1.1, 0.9, 0.1, -0.2, 1e-9, 0.3], [0.3, 0.2, 0.4], [0.5, 0.3]),
    ("pinhole", [1.1, 0.9, 0.1, -0.2], [0.0, 0.0, 1.0], [0.1, -0.2]),
]


@pytest.mark.parametrize("model,params,point,pixel", GRADCHECK)
def test_gradcheck_gradgradcheck_at_degenerate_points(model, params, point, pixel):
    """torch's finite-difference checks at x = y = 0, the principal point, zero distortion,
    ``xi = 0`` (first and second order, both arguments). (Not at ``alpha`` = 0 or 1: the
    ends of its domain, where a two-sided difference leaves it.)"""
    p = torch.tensor(params, dtype=F64, requires_grad=True)
    x = torch.tensor(point, dtype=F64, requires_grad=True)
    px = torch.tensor(pixel, dtype=F64, requires_grad=True)

    def proj(p, x):
        return camera.project(model, p, x)[0]

    def unproj(p, px):
        return camera.unproject(model, p, px)[0]

    for fn, args in ((proj, (p, x)), (unproj, (p, px))):
        assert torch.autograd.gradcheck(fn, args)
        assert torch.autograd.gradgradcheck(fn, args)


@pytest.mark.parametrize("model", list(camera.MODELS))
def test_invalid_points_second_derivatives_finite(model):
    """Behind the camera (and the double sphere's origin): the Hessian is finite."""
    p = torch.tensor([300.0, 310.0, 320.0, 240.0, 0.1, -0.05, 0.01, -0.002][
        :len(camera.MODELS[model])], dtype=F64)
    if model == "double-sphere":
        p = torch.tensor([300.0, 310.0, 320.0, 240.0, 0.3, 0.6], dtype=F64)
    for pt in ([0.3, 0.2, -1.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0]):
        x = torch.tensor(pt, dtype=F64)
        hes = torch.autograd.functional.hessian(
            lambda x: camera.project(model, p, x)[0].sum(), x)
        assert bool(torch.isfinite(hes).all())
        hes = torch.autograd.functional.hessian(
            lambda q, x=x: camera.project(model, q, x)[0].sum(), p)
        assert bool(torch.isfinite(hes).all())


PARAMS = {"pinhole": [400.0, 400.0, 320.0, 240.0],
          "pinhole-radtan": [400.0, 400.0, 320.0, 240.0, -0.28, 0.07, 2e-4, 2e-5],
          "pinhole-equidistant": [400.0, 400.0, 320.0, 240.0, *FISH],
          "double-sphere": [400.0, 400.0, 320.0, 240.0, -0.2, 0.6]}


@pytest.mark.parametrize("model", list(camera.MODELS))
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("where", ["params", "x", "cu"])
@pytest.mark.parametrize("fn", ["project", "unproject"])
def test_nonfinite_element_does_not_touch_other_gradients(model, bad, where, fn):
    """NaN / inf in one element's input: the other elements' gradients w.r.t. shared
    arguments stay finite and equal to those without the bad element (0 * NaN in the
    backward of a formula evaluated on the bad value must not leak)."""
    func = getattr(camera, fn)
    n = 3 if fn == "project" else 2
    good = torch.tensor([[0.1, 0.2, 1.0], [0.3, -0.1, 1.0], [-0.2, 0.1, 0.8]], dtype=F64)
    if fn == "unproject":
        good = torch.tensor([[300.0, 200.0], [500.0, 100.0], [100.0, 400.0]], dtype=F64)
    shared_params = where != "params" and where != "cu"
    p = torch.tensor(PARAMS[model], dtype=F64)
    if not shared_params:
        p = p.repeat(3, 1)
        p[1, 0 if where == "params" else 2] = bad
        x = good[0].clone().requires_grad_()  # shared point / pixel, per-element params
        p.requires_grad_()
    else:
        x = good.clone()
        x[1, n - 1] = bad
        x.requires_grad_()
        p.requires_grad_()
    out, ok = func(model, p, x)
    assert not bool(ok[1]) and not bool(torch.isfinite(out[1]).any())
    gp, gx = torch.autograd.grad(out[[0, 2]].sum(), (p, x))
    others = gx[[0, 2]] if shared_params else gp[[0, 2]]  # the bad element's own: any
    shared = gp if shared_params else gx
    assert bool(torch.isfinite(others).all()) and bool(torch.isfinite(shared).all()), (gp, gx)
    # and the same as without the bad element
    p2 = (p.detach() if shared_params else p.detach()[[0, 2]]).requires_grad_()
    x2 = (x.detach()[[0, 2]] if shared_params else x.detach()).requires_grad_()
    g2p, g2x = torch.autograd.grad(func(model, p2, x2)[0].sum(), (p2, x2))
    torch.testing.assert_close(gp if shared_params else gp[[0, 2]], g2p, rtol=1e-13, atol=0)
    torch.testing.assert_close(gx[[0, 2]] if shared_params else gx, g2x, rtol=1e-13, atol=0)

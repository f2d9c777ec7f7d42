"""The cumulative B-spline form (Kim-Kim-Shin, issue 20): ``torch_dq._cumulative`` (basis,
jets, the fused ``poses``) and the readable reference ``curves._kim_kim_shin``.

Independent references: scipy's B-spline basis (``BSpline`` with unit coefficient vectors)
and the 4x4-matrix product ``T_0 prod_j expm(Bt_j logm(T_{j-1}^-1 T_j))`` (closed-form
``expm``/``logm`` checked against scipy's), its exact time derivatives (Leibniz rule on
``expm(w L)``, checked against central finite differences), and pypose's ``bspline`` on
uniform knots.
"""

import math

import numpy as np
import pytest
import scipy.interpolate as si
import scipy.linalg as sl
import torch
from pytransform3d import transformations as pt
from strategies import knot_vector, unit_quat

import torch_dq.dualquat as dq
from torch_dq import _cumulative, curves
from torch_dq._core import align_chain
from torch_dq._kernels import cumulative as kcum
from torch_dq._kernels import cumulative_jets, cumulative_rows, subsets
from torch_dq._time import KnotDomain, span_bases

F64 = torch.float64


# ----------------------------------------------------------------------------- inputs

def chain(n, gen, spread=0.6, scale=1.0, dtype=F64):
    """``n`` poses, each a screw motion of moderate angle (< 2.4 rad) from the previous one,
    with random signs (not sign-aligned)."""
    xi = torch.randn(n, 6, generator=gen, dtype=F64)
    xi[:, :3] *= spread
    xi[:, :3] *= torch.clamp(2.4 / xi[:, :3].norm(dim=-1, keepdim=True), max=1.0)
    xi[:, 3:] *= scale
    start = dq.from_rt(unit_quat((), gen), torch.randn(3, generator=gen, dtype=F64))
    out = [start]
    for k in range(1, n):
        out.append(dq.mul(out[-1], dq.exp(xi[k])))
    signs = torch.where(torch.rand(n, generator=gen, dtype=F64) < 0.5, -1.0, 1.0)
    return (torch.stack(out) * signs[:, None]).to(dtype)


KNOT_KINDS = ("clamped", "uniform", "nonuniform", "repeated")


def spans(knots, t, p):
    """The span ``r`` of each time and the indices ``(..., p + 1)`` of its control points
    ``r - p .. r``."""
    r = KnotDomain(knots, p).span(t)
    return r, r[..., None] - p + torch.arange(p + 1)


def span_inputs(ctrl, knots, p, t, order):
    """Spans, weights and gathered sign-aligned control points, as the curves pass them."""
    r, idx = spans(knots, t, p)
    return align_chain(ctrl)[idx], span_bases(knots, r, t, p, order, cumulative=True)


def domain_times(knots, p, count, margin=0.0):
    n = knots.shape[0] - p - 1
    lo, hi = float(knots[p]), float(knots[n])
    return torch.linspace(lo - margin, hi + margin, count, dtype=F64)


# ----------------------------------------------------------------------------- scipy references

def cumulative_basis_np(knots, p, t, nu):
    """``(T, n)``: column ``j`` is ``sum_{l >= j} B_{l,p}`` (or its ``nu``-th derivative)
    from scipy, extrapolating the end pieces outside the domain."""
    knots = np.asarray(knots)
    n = len(knots) - p - 1
    cols = np.zeros((len(t), n))
    if nu <= p:
        for l in range(n):
            cols[:, l] = si.BSpline(knots, np.eye(n)[l], p, extrapolate=True)(t, nu)
    return np.flip(np.cumsum(np.flip(cols, 1), 1), 1)


def twist_matrix(xi):
    """The 4x4 matrix ``[[[omega]x, v], [0, 0]]`` of exponential coordinates ``(omega, v)``."""
    L = np.zeros((4, 4))
    L[:3, :3] = [[0.0, -xi[2], xi[1]], [xi[2], 0.0, -xi[0]], [-xi[1], xi[0], 0.0]]
    L[:3, 3] = xi[3:]
    return L


def matrix_jets_np(ctrl, knots, p, t, order):
    """The matrix form ``T_0 prod_j expm(w_j L_j)``, ``L_j = logm(T_{j-1}^-1 T_j)``, and its
    exact time derivatives ``0..order`` at ``t`` (Leibniz rule; ``d/dt expm(w L) =
    expm(w L) L w'``). Returns ``(order + 1, T, 4, 4)``. ``expm`` and ``logm`` of rigid
    motions in closed form (pytransform3d's exponential coordinates; the same as scipy's
    ``expm``/``logm``, checked below, and free of LAPACK calls that crawl on a busy
    machine)."""
    M = dq.to_matrix(ctrl).numpy()
    xis = [pt.exponential_coordinates_from_transform(np.linalg.solve(M[j - 1], M[j]))
           for j in range(1, len(M))]
    W = [cumulative_basis_np(knots, p, t, nu) for nu in range(order + 1)]
    out = np.zeros((order + 1, len(t), 4, 4))
    for i in range(len(t)):
        X = [M[0]] + [np.zeros((4, 4))] * order
        for j, xi in enumerate(xis, start=1):
            w = [W[nu][i, j] for nu in range(order + 1)] + [0.0] * 3
            E, L = pt.transform_from_exponential_coordinates(w[0] * xi), twist_matrix(xi)
            L2 = L @ L
            dE = [E, E @ L * w[1], E @ (L2 * w[1] ** 2 + L * w[2]),
                  E @ (L2 @ L * w[1] ** 3 + 3.0 * L2 * w[1] * w[2] + L * w[3])]
            X = [sum(math.comb(k, m) * X[m] @ dE[k - m] for m in range(k + 1))
                 for k in range(order + 1)]
        out[:, i] = X
    return out


def test_closed_form_exp_log_match_scipy(gen):
    """The reference's matrix exponential and logarithm are scipy's ``expm``/``logm``."""
    M = dq.to_matrix(chain(4, gen)).numpy()
    for j in range(1, 4):
        rel = np.linalg.solve(M[j - 1], M[j])
        xi = pt.exponential_coordinates_from_transform(rel)
        L = np.real(sl.logm(rel))
        assert np.abs(twist_matrix(xi) - L).max() <= 1e-12
        assert np.abs(pt.transform_from_exponential_coordinates(0.37 * xi)
                      - sl.expm(0.37 * L)).max() <= 1e-13


def _quadratic_matrix(x):
    """The 4x4 matrix of unit dual quaternions ``x (..., 8)`` as a homogeneous quadratic
    form (bottom row left out): ``R`` from ``w^2 + x^2 - y^2 - z^2``-type entries,
    ``t = 2 vec(d r*)``."""
    w, a, b, c, dw, da, db, dc = np.moveaxis(x, -1, 0)
    R = [[w * w + a * a - b * b - c * c, 2 * (a * b - w * c), 2 * (a * c + w * b)],
         [2 * (a * b + w * c), w * w - a * a + b * b - c * c, 2 * (b * c - w * a)],
         [2 * (a * c - w * b), 2 * (b * c + w * a), w * w - a * a - b * b + c * c]]
    t = [2 * (-dw * a + da * w - db * c + dc * b), 2 * (-dw * b + db * w - dc * a + da * c),
         2 * (-dw * c + dc * w - da * b + db * a)]
    zero = np.zeros_like(w)
    return np.stack([np.stack([*R[i], t[i]], -1) for i in range(3)]
                    + [np.stack([zero] * 4, -1)], -2)


def matrix_jets_torch(jet):
    """The time derivatives of the matrix of ``x(t)`` from those of ``x``, by the Leibniz
    rule on the quadratic form (polarised): ``(order + 1, T, 4, 4)``."""
    xs = [v.detach().numpy() for v in jet]

    def bilinear(a, b):
        return (_quadratic_matrix(a + b) - _quadratic_matrix(a - b)) / 4.0

    out = [sum(math.comb(k, i) * bilinear(xs[i], xs[k - i]) for i in range(k + 1))
           for k in range(len(xs))]
    out[0][..., 3, 3] = 1.0
    return np.stack(out)


# ----------------------------------------------------------------------------- basis

@pytest.mark.parametrize("kind", KNOT_KINDS)
@pytest.mark.parametrize("p", [1, 2, 3, 4, 5])
def test_basis_matches_scipy(gen, kind, p):
    n = p + 4
    knots = knot_vector(kind, n, p, gen)
    t = domain_times(knots, p, 41, margin=0.3)  # extrapolates beyond both ends
    r = KnotDomain(knots, p).span(t)
    got = span_bases(knots, r, t, p, 3, cumulative=True)
    cols = (r[:, None] - p + torch.arange(1, p + 1)).numpy()
    for nu in range(4):
        ref = np.take_along_axis(cumulative_basis_np(knots.numpy(), p, t.numpy(), nu), cols, 1)
        scale = max(1.0, np.abs(ref).max())
        assert got[nu].shape == (41, p)
        assert np.abs(got[nu].numpy() - ref).max() <= 1e-11 * scale, nu


def test_basis_batched_times_and_gradcheck(gen):
    p, n = 3, 7
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 6).reshape(2, 3)
    r = KnotDomain(knots, p).span(t)
    flat = span_bases(knots, r.reshape(-1), t.reshape(-1), p, 2, cumulative=True)
    for a, b in zip(span_bases(knots, r, t, p, 2, cumulative=True), flat, strict=True):
        assert a.shape == (2, 3, p) and torch.equal(a.reshape(-1, p), b)

    def f(t, knots):
        return tuple(span_bases(knots, r, t, p, 2, cumulative=True))

    inputs = (t.clone().requires_grad_(), knots.clone().requires_grad_())
    assert torch.autograd.gradcheck(f, inputs)
    assert torch.autograd.gradgradcheck(f, inputs)


# ----------------------------------------------------------------------------- the curve

@pytest.mark.parametrize("kind", KNOT_KINDS)
@pytest.mark.parametrize("p", [1, 2, 3, 4, 5])
def test_curve_matches_matrix_reference(gen, kind, p):
    n = p + 3
    ctrl = chain(n, gen)
    knots = knot_vector(kind, n, p, gen)
    t = domain_times(knots, p, 9)
    points, weights = span_inputs(ctrl, knots, p, t, 0)
    ref = matrix_jets_np(ctrl, knots.numpy(), p, t.numpy(), 0)[0]
    for x in (_cumulative.jets(points, weights, 0)[0],
              curves._kim_kim_shin(points, weights[0]),
              _cumulative.poses(align_chain(ctrl), KnotDomain(knots, p).span(t) - p, weights[0].T)):
        assert np.abs(dq.to_matrix(x).numpy() - ref).max() <= 1e-10
    # the same motion whatever the signs of the control points
    flipped = ctrl * torch.where(torch.arange(n) % 2 == 0, -1.0, 1.0).to(F64)[:, None]
    points2, _ = span_inputs(flipped, knots, p, t, 0)
    x2 = curves._kim_kim_shin(points2, weights[0])
    assert np.abs(dq.to_matrix(x2).numpy() - ref).max() <= 1e-10


@pytest.mark.parametrize("p", [2, 3, 5])
def test_derivatives_match_matrix_reference(gen, p):
    n = p + 3
    ctrl = chain(n, gen)
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 7, margin=-0.05)
    points, weights = span_inputs(ctrl, knots, p, t, 3)
    jet = _cumulative.jets(points, weights, 3)
    got = matrix_jets_torch(jet)
    ref = matrix_jets_np(ctrl, knots.numpy(), p, t.numpy(), 3)
    for k in range(4):
        assert np.abs(got[k] - ref[k]).max() <= 1e-10 * max(1.0, np.abs(ref[k]).max()), k
    # lower orders: the same leading coefficients
    for order in range(3):
        lower = _cumulative.jets(points, weights, order)
        assert all(torch.allclose(a, b, rtol=0, atol=1e-13)
                   for a, b in zip(lower, jet[:order + 1], strict=True))


def test_matrix_derivative_reference_matches_finite_differences(gen):
    """The exact matrix reference above against central differences of the matrix curve
    (a degree-8 polynomial through 9 samples)."""
    p, n = 3, 6
    ctrl = chain(n, gen)
    knots = knot_vector("nonuniform", n, p, gen).numpy()
    t0, h, steps = float(knots[p] + knots[p + 1]) / 2, 2e-3, np.arange(-4, 5)
    vals = matrix_jets_np(ctrl, knots, p, t0 + h * steps, 0)[0].reshape(9, 16)
    coef = np.linalg.solve(np.vander(steps * h, 9, increasing=True), vals)
    exact = matrix_jets_np(ctrl, knots, p, np.array([t0]), 3)[:, 0].reshape(4, 16)
    for k in range(4):
        fd = math.factorial(k) * coef[k]
        assert np.abs(fd - exact[k]).max() <= 1e-6 * max(1.0, np.abs(exact[k]).max()), k


@pytest.mark.parametrize("shape", [(4,), (2, 3)])
def test_pypose_on_uniform_knots(gen, shape):
    """pypose's cubic ``bspline`` (SE3 ``(tx, ty, tz, qx, qy, qz, qw)``, time ``s`` from 0
    per segment) is our cubic on the knots ``0, 1, ..., n + 3`` at ``t = s + 3``."""
    pp = pytest.importorskip("pypose")
    n, interval = 8, 0.25
    ctrl = align_chain(chain(math.prod(shape) * n, gen).reshape(*shape, n, 8))
    out = pp.bspline(pp.SE3(dq.to_pose7(ctrl)), interval)  # (..., (n - 3) / interval + 1, 7)
    s = torch.arange(out.shape[-2], dtype=F64) * interval
    knots = torch.arange(n + 4, dtype=F64)
    t = s + 3.0
    r = KnotDomain(knots, 3).span(t)
    weights = span_bases(knots, r, t, 3, 0, cumulative=True)[0]
    flat = ctrl.reshape(-1, n, 8)
    ours = torch.stack([curves._kim_kim_shin(c[r[:, None] - 3 + torch.arange(4)], weights)
                        for c in flat]).reshape(*shape, -1, 8)
    ref = dq.to_matrix(dq.from_pose7(out.tensor()))
    assert ref.shape == (*shape, 21, 4, 4)
    assert float((dq.to_matrix(ours) - ref).abs().max()) <= 1e-10


@pytest.mark.parametrize("kind", ["clamped", "nonuniform"])
@pytest.mark.parametrize("p", [1, 2, 3, 4, 5])
def test_public_bspline_cumulative_matches_matrix_reference(gen, kind, p):
    """``curves.bspline`` / ``bspline_derivatives`` with ``form="cumulative"``, batched
    control points, inside the domain and extrapolated beyond both ends."""
    n = p + 3
    ctrl = torch.stack((chain(n, gen), chain(n, gen)))
    knots = knot_vector(kind, n, p, gen)
    for extrapolate, margin in ((False, 0.0), (True, 0.2)):
        t = domain_times(knots, p, 7, margin)
        x = curves.bspline(ctrl, t, degree=p, knots=knots, form="cumulative",
                           extrapolate=extrapolate)
        jet = curves.bspline_derivatives(ctrl, t, order=3, degree=p, knots=knots,
                                         form="cumulative", extrapolate=extrapolate)
        for b in range(2):
            ref = matrix_jets_np(ctrl[b], knots.numpy(), p, t.numpy(), 3)
            assert np.abs(dq.to_matrix(x[b]).numpy() - ref[0]).max() <= 1e-10
            got = matrix_jets_torch([v[b] for v in jet])
            for k in range(4):
                scale = max(1.0, np.abs(ref[k]).max())
                assert np.abs(got[k] - ref[k]).max() <= 1e-10 * scale, (extrapolate, k)


# ----------------------------------------------------------------------------- smoothness

def test_continuity_across_simple_knots(gen):
    """At a simple interior knot the cumulative form's derivatives of order < p agree from
    both sides (the left limit is the left span's polynomial continuation), and the p-th
    jumps; the De Boor form's acceleration jumps."""
    n = 8
    ctrl = chain(n, gen)
    for p in (3, 4, 5):
        knots = knot_vector("nonuniform", n, p, gen)
        u = knots[p + 1:n]  # the interior knots
        r = KnotDomain(knots, p).span(u)
        for side in (r - 1, r):  # left span (continued to u) and right span
            pts = align_chain(ctrl)[side[:, None] - p + torch.arange(p + 1)]
            jet = _cumulative.jets(pts, span_bases(knots, side, u, p, 3, cumulative=True), 3)
            if side is r:
                right = jet
            else:
                left = jet
        for k in range(4):
            jump = float((left[k] - right[k]).abs().max())
            scale = float(right[k].abs().max())
            if k < p:
                assert jump <= 1e-10 * max(1.0, scale), (p, k, jump)
            else:
                assert jump >= 1e-3 * scale, (p, k, jump)  # the p-th derivative jumps


def test_de_boor_acceleration_jumps_at_knots(gen):
    """The paper's De Boor form (curves.bspline_derivatives' default) is C^1 only: its
    acceleration jumps at a simple knot by a measurable amount; the cumulative form's,
    through the same public function, does not."""
    n, p = 8, 3
    ctrl = chain(n, gen)
    knots = knot_vector("nonuniform", n, p, gen)
    u = knots[p + 1:n]

    def jumps(form):
        left, right = (curves.bspline_derivatives(ctrl, s, order=2, degree=p, knots=knots,
                                                  form=form) for s in (u - 1e-9, u))
        scale = float(right[2].norm(dim=-1).max())
        return [float((a - b).norm(dim=-1).max()) / scale for a, b in zip(left, right, strict=True)]

    de_boor, cumulative = jumps("de_boor"), jumps("cumulative")
    assert de_boor[1] <= 1e-7 and cumulative[1] <= 1e-7  # velocities continuous
    assert de_boor[2] >= 1e-3  # the acceleration jumps
    assert cumulative[2] <= 1e-7  # continuous: only jerk * 1e-9 s


# ----------------------------------------------------------------------------- autograd

def degenerate_chain(gen, kind):
    """A sign-aligned cubic chain with a static segment (equal neighbours) or a neighbour
    a half turn away (``c`` the relative motion's real part: 0 exactly, or ``1e-3``)."""
    ctrl = align_chain(chain(6, gen))
    if kind == "generic":
        return ctrl
    if kind == "static":
        ctrl[3] = ctrl[2]
    else:
        axis = torch.nn.functional.normalize(torch.randn(3, generator=gen, dtype=F64), dim=0)
        c = 0.0 if kind == "half_turn" else 1e-3
        rel = dq.from_rt(torch.cat((torch.tensor([c], dtype=F64), math.sqrt(1 - c * c) * axis)),
                         torch.randn(3, generator=gen, dtype=F64))
        ctrl[3] = dq.mul(ctrl[2], rel)
    return ctrl


@pytest.mark.parametrize("kind", ["generic", "static", "near_half_turn"])
def test_gradcheck_wrt_control_points_and_t(gen, kind):
    """First and second derivatives of the jets (order 2, then 1) and of the fused poses
    with respect to the control points and t, at generic points, at a static segment (the
    log of the identity) and next to a half turn between neighbours."""
    p = 3
    ctrl = degenerate_chain(gen, kind)[1:6]  # the degenerate pair is ctrl[1], ctrl[2]
    knots = torch.tensor([0.0, 0.1, 0.3, 0.6, 1.0, 1.2, 1.5, 1.9, 2.0], dtype=F64)
    t = torch.tensor([0.7, 1.1], dtype=F64)  # one time in each span
    r, idx = spans(knots, t, p)

    def jets(order):
        return lambda c, t: tuple(_cumulative.jets(c[idx], span_bases(
            knots, r, t, p, order, cumulative=True), order))

    def fused(c, t):
        return _cumulative.poses(c, r - p, span_bases(knots, r, t, p, 0, cumulative=True)[0].T)

    inputs = (ctrl.clone().requires_grad_(), t.clone().requires_grad_())
    assert torch.autograd.gradcheck(jets(2), inputs, fast_mode=True)
    for fn in (jets(1), fused):
        assert torch.autograd.gradgradcheck(fn, inputs, fast_mode=True)
    assert torch.autograd.gradcheck(fused, inputs)


def test_half_turn_gradients_are_finite_one_sided(gen):
    """At a half turn between neighbours the shortest path switches; the gradients there are
    finite and those of one side (a neighbour pushed by 1e-9 towards that side)."""
    p = 3
    knots = knot_vector("uniform", 6, p, gen)
    t = domain_times(knots, p, 5)
    r, idx = spans(knots, t, p)
    weights = span_bases(knots, r, t, p, 1, cumulative=True)
    base = degenerate_chain(gen, "half_turn")

    def grads(ctrl):
        c = ctrl.clone().requires_grad_()
        x, dx = _cumulative.jets(c[idx], weights, 1)
        fused = _cumulative.poses(c, r - p, weights[0].T)
        return torch.cat([torch.autograd.grad(y.square().sum(), c, retain_graph=True)[0].ravel()
                          for y in (x, dx, fused)])

    at = grads(base)
    assert torch.isfinite(at).all()
    sides = []
    rel = dq.mul(dq.conj(base[2]), base[3])
    for eps in (1e-8, -1e-8):  # a turn of ctrl[3] about the relative motion's axis
        turn = dq.exp(torch.cat((eps * rel[1:4], torch.zeros(3, dtype=F64))))
        moved = base.clone()
        moved[3] = dq.mul(base[3], turn)
        sides.append(float((grads(moved) - at).abs().max() / at.abs().max()))
    assert min(sides) <= 1e-5, sides


def test_fused_poses_match_reference_gradients(gen):
    """The fused op against the readable reference: values, gradients and second
    derivatives, with several curves in one flat control tensor; a NaN control point of
    one curve leaves the other curve's gradients finite."""
    p, n = 3, 7
    ctrl = torch.cat((align_chain(chain(n, gen)), align_chain(chain(n, gen))))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 11)
    r = KnotDomain(knots, p).span(t)
    first = torch.cat((r - p, r - p + n))
    w = span_bases(knots, r, t, p, 0, cumulative=True)[0].T.repeat(1, 2).requires_grad_()
    c = ctrl.clone().requires_grad_()
    fused = _cumulative.poses(c, first, w)
    ref = curves._kim_kim_shin(c[first[:, None] + torch.arange(p + 1)], w.T)
    assert float((fused - ref).detach().abs().max()) <= 1e-14
    g = torch.randn(fused.shape, generator=gen, dtype=F64)
    a = torch.autograd.grad(fused, (c, w), g, create_graph=True)
    b = torch.autograd.grad(ref, (c, w), g, create_graph=True)
    assert all(float((x - y).detach().abs().max()) <= 1e-12 for x, y in zip(a, b, strict=True))
    v = torch.randn(c.shape, generator=gen, dtype=F64)
    a2 = torch.autograd.grad((a[0] * v).sum() + a[1].sum(), (c, w))
    b2 = torch.autograd.grad((b[0] * v).sum() + b[1].sum(), (c, w))
    assert all(float((x - y).abs().max()) <= 1e-10 for x, y in zip(a2, b2, strict=True))

    bad = ctrl.clone()
    bad[n + 2] = float("nan")
    bad.requires_grad_()
    out = _cumulative.poses(bad, first, w.detach())
    assert torch.isfinite(out[: t.shape[0]]).all() and torch.isnan(out[t.shape[0]:]).any()
    grad = torch.autograd.grad(out[: t.shape[0]].sum(), bad)[0]
    assert torch.isfinite(grad[:n]).all()


@pytest.mark.parametrize("count", [3, 45, 400])
def test_fused_poses_unsorted_times_match_reference(gen, count):
    """The fused op sums each span's table cotangent with one matrix product per span for
    non-decreasing spans holding many times (400 times on 5 spans), by scattering otherwise
    (shuffled or repeated times, 45 times), and with fewer times than twice the span starts
    (3 times) runs the product of powers per time: every path gives the reference's values
    and gradients."""
    p, n = 3, 8
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, count)
    t = torch.cat((t, t[:2]))[torch.randperm(count + 2, generator=gen)]
    r = KnotDomain(knots, p).span(t)
    w = span_bases(knots, r, t, p, 0, cumulative=True)[0].T
    g = torch.randn(count + 2, 8, generator=gen, dtype=F64)
    for order in (torch.randperm(count + 2, generator=gen), torch.argsort(r)):  # scattered, sorted
        c = ctrl.clone().requires_grad_()
        first = r[order] - p
        fused = _cumulative.poses(c, first, w[:, order])
        ref = curves._kim_kim_shin(c[first[:, None] + torch.arange(p + 1)], w[:, order].T)
        assert float((fused - ref).detach().abs().max()) <= 1e-14
        a, b = (torch.autograd.grad(x, c, g[order])[0] for x in (fused, ref))
        assert float((a - b).abs().max()) <= 1e-12


def test_fused_poses_runs_across_chunks_match_reference(gen, monkeypatch):
    """Sorted times run per span (one matrix product per run of a span start) with chunk
    boundaries inside runs (chunks of 37 times): values and gradients with respect to the
    control points and the weights (first and second order) equal the reference's."""
    monkeypatch.setattr(cumulative_rows, "POSES_CHUNK", 37)
    p, n = 3, 7
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 200)
    r = KnotDomain(knots, p).span(t)
    first = r - p
    runs = cumulative_rows.sorted_runs(first)
    assert runs is not None and len(runs) == 6  # chunks of 37 times
    spans = [f for _, rs in runs for *_, f in rs]
    assert len(spans) > len(set(spans))  # some span's run is split between two chunks
    w = span_bases(knots, r, t, p, 0, cumulative=True)[0].T.contiguous().requires_grad_()
    c = ctrl.clone().requires_grad_()
    fused = _cumulative.poses(c, first, w)
    ref = curves._kim_kim_shin(c[first[:, None] + torch.arange(p + 1)], w.T)
    assert float((fused - ref).detach().abs().max()) <= 1e-14
    g = torch.randn(fused.shape, generator=gen, dtype=F64)
    for create_graph in (False, True):
        a = torch.autograd.grad(fused, (c, w), g, retain_graph=True, create_graph=create_graph)
        b = torch.autograd.grad(ref, (c, w), g, retain_graph=True, create_graph=create_graph)
        assert all(float((x - y).detach().abs().max()) <= 1e-12
                   for x, y in zip(a, b, strict=True))
    a = torch.autograd.grad(fused, c, g)[0]  # the first-order backward from saved weights
    assert float((a - b[0]).detach().abs().max()) <= 1e-12


def test_fused_poses_build_tables_of_starts_in_use(gen, monkeypatch):
    """Eager, the span tables are built only for the span starts that some time reads (3 of
    the 18 of three flattened curves, with more than twice as many times): values and
    gradients equal the reference's, and a NaN control point that no span in use reads
    changes nothing."""
    built = []

    def spy(ctrl, starts, p, used=None):
        built.append(starts.tolist())
        return span_tables(ctrl, starts, p, used)

    span_tables = kcum._span_tables
    monkeypatch.setattr(kcum, "_span_tables", spy)
    p, n = 3, 7
    ctrl = torch.cat([align_chain(chain(n, gen)) for _ in range(3)])
    ctrl[9] = float("nan")  # curve 1, read by no time
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 200)
    r = KnotDomain(knots, p).span(t)
    keep = (r == p) | (r == n - 1)
    first = torch.cat((r[keep] - p, r[keep][:5] - p + 2 * n))
    assert len(set(first.tolist())) == 3 and first.shape[0] >= 2 * 18
    w = span_bases(knots, r[keep], t[keep], p, 0, cumulative=True)[0].T
    w = torch.cat((w, w[:, :5]), 1)
    c = ctrl.clone().requires_grad_()
    fused = _cumulative.poses(c, first, w)
    assert built == [sorted(set(first.tolist()))]
    ref = curves._kim_kim_shin(c[first[:, None] + torch.arange(p + 1)], w.T)
    assert float((fused - ref).detach().abs().max()) <= 1e-14
    g = torch.randn(fused.shape, generator=gen, dtype=F64)
    a, b = (torch.autograd.grad(x, c, g)[0] for x in (fused, ref))
    assert torch.isfinite(a).all() and float((a - b).abs().max()) <= 1e-12


def test_fused_poses_vectorized_jacobian(gen):
    """The fused op's backward under ``vmap`` (``jacobian(vectorize=True)``, after the forward
    took the tables' path: 6 times on one span) equals the loop of plain backwards."""
    p = 3
    ctrl = align_chain(chain(p + 1, gen))
    first = torch.zeros(6, dtype=torch.long)
    w = torch.rand(p, 6, generator=gen, dtype=F64).sort(0, descending=True)[0]

    def f(c, w):
        return _cumulative.poses(c, first, w)
    for vec, loop in zip(torch.autograd.functional.jacobian(f, (ctrl, w), vectorize=True),
                         torch.autograd.functional.jacobian(f, (ctrl, w)), strict=True):
        assert float(loop.abs().max()) > 0 and float((vec - loop).abs().max()) <= 1e-12


def _fused_and_jets(ctrl, knots, p, t, order, perm=None):
    """The fused derivatives (span tables, weight jets) and the plain jets of the same
    times (reordered by ``perm``), from leaf control points and weights."""
    r = KnotDomain(knots, p).span(t)
    r = r if perm is None else r[perm]
    t = t if perm is None else t[perm]
    w = [x.T.contiguous().requires_grad_()
         for x in span_bases(knots, r, t, p, order, cumulative=True)]
    c = ctrl.clone().requires_grad_()
    first = r - p
    fused = _cumulative.derivatives(c, first, w)
    ref = _cumulative.jets(c[first[:, None] + torch.arange(p + 1)], [x.T for x in w], order)
    return c, w, fused, ref


@pytest.mark.parametrize("p", [1, 2, 3, 5])
@pytest.mark.parametrize("count", [3, 45, 400])
def test_fused_derivatives_match_jets(gen, p, count):
    """The fused derivatives (time derivatives on the scalar dual weights of the span
    tables' expansion, one weighted sum of table rows per order) against the plain
    Leibniz/eq.-11 jets: values, gradients with respect to the control points and the
    weights, and second derivatives, on sorted times (runs per span: 400 times), scattered
    or repeated ones (45) and too few for the tables (3: the jets themselves), orders 1-3."""
    n = p + 5
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, count)
    perm = None if count == 400 else torch.randperm(count, generator=gen).repeat(2)
    for order in (1, 2, 3):
        c, w, fused, ref = _fused_and_jets(ctrl, knots, p, t, order, perm)
        assert len(fused) == order + 1
        for k, (a, b) in enumerate(zip(fused, ref, strict=True)):
            scale = max(1.0, float(b.detach().abs().max()))
            assert float((a - b).detach().abs().max()) <= 1e-13 * scale, (order, k)
        g = [torch.randn(x.shape, generator=gen, dtype=F64) for x in fused]
        # first order: the written-out backwards; with create_graph: their plain-op VJPs
        first = torch.autograd.grad(fused, (c, *w), g, retain_graph=True)
        a = torch.autograd.grad(fused, (c, *w), g, create_graph=True)
        b = torch.autograd.grad(ref, (c, *w), g, create_graph=True)
        for x, y in (*zip(first, b, strict=True), *zip(a, b, strict=True)):
            x, y = x.detach(), y.detach()
            assert float((x - y).abs().max()) <= 1e-11 * max(1.0, float(y.abs().max()))
        v = torch.randn(c.shape, generator=gen, dtype=F64)
        a2 = torch.autograd.grad((a[0] * v).sum() + a[-1].sum(), (c, w[0]))
        b2 = torch.autograd.grad((b[0] * v).sum() + b[-1].sum(), (c, w[0]))
        for x, y in zip(a2, b2, strict=True):
            assert float((x - y).abs().max()) <= 1e-10 * max(1.0, float(y.abs().max()))


@pytest.mark.parametrize("p", [1, 2, 3, 5])
def test_bag_jets_backward_is_autograds(gen, monkeypatch, p):
    """The fused derivatives' written-out backward of the weight jets (``_BagJets``: the
    derivatives in ``y`` by the weights' equations, the subsets' cotangents transposed)
    gives autograd's cotangents through the same ops, to rounding, and the plain jets'
    (another algorithm) to 1e-11, on a chain with equal, sign-flipped, nearly equal (1e-9,
    1e-6 rad) and nearly opposite (pi - 1e-3) neighbours, sorted and scattered times,
    orders 1-3."""
    ran = []
    monkeypatch.setattr(cumulative_jets._BagJets, "backward",
                        staticmethod(lambda ctx, g, f=cumulative_jets._BagJets.backward:
                                     ran.append(1) or f(ctx, g)))
    n = p + 8
    steps = [dq.exp(torch.tensor([0.0, 0.0, 0.0, 0.1, 0.0, 0.2], dtype=F64)),
             dq.exp(torch.tensor([1e-9, 0.0, 0.0, 0.0, 0.3, 0.0], dtype=F64)),
             dq.exp(torch.tensor([0.0, 1e-6, 0.0, 0.0, 0.0, 0.4], dtype=F64)),
             dq.exp(torch.tensor([0.0, 0.0, math.pi - 1e-3, 0.5, 0.0, 0.0], dtype=F64))]
    ctrl = chain(n, gen)
    for k, step in enumerate(steps, start=2):
        ctrl[k] = dq.mul(ctrl[k - 1], step)
    ctrl[7] = -ctrl[6]
    ctrl = align_chain(ctrl)
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 500)
    for perm in (None, torch.randperm(500, generator=gen)):
        tt = t if perm is None else t[perm]
        r = KnotDomain(knots, p).span(tt)
        for order in (1, 2, 3):
            w = [x.T.contiguous() for x in span_bases(knots, r, tt, p, order, cumulative=True)]
            c = ctrl.clone().requires_grad_()
            out = _cumulative.derivatives(c, r - p, w)
            g = [torch.randn(x.shape, generator=gen, dtype=F64) for x in out]
            ran.clear()
            (written,) = torch.autograd.grad(out, c, g)
            assert ran
            with monkeypatch.context() as m:
                m.setattr(cumulative_jets._BagJets, "applies", staticmethod(lambda *a: False))
                (plain,) = torch.autograd.grad(_cumulative.derivatives(c, r - p, w), c, g)
            scale = float(plain.abs().max())
            assert float((written - plain).abs().max()) <= 1e-13 * scale
            ref = _cumulative.jets(c[(r - p)[:, None] + torch.arange(p + 1)],
                                   [x.T for x in w], order)
            (jets,) = torch.autograd.grad(ref, c, g)
            assert float((written - jets).abs().max()) <= 1e-11 * scale


def test_fused_derivatives_static_segment_and_gradcheck(gen):
    """Equal neighbouring control points (a robot standing still: the relative motion is the
    identity, the weights' series branch) give finite derivatives and gradients equal to the
    jets'; ``gradcheck`` and ``gradgradcheck`` of the fused op with respect to the control
    points there and elsewhere."""
    p, n = 3, 7
    ctrl = align_chain(chain(n, gen))
    ctrl[3] = ctrl[2]
    ctrl[4] = ctrl[2]
    knots = knot_vector("uniform", n, p, gen)
    t = domain_times(knots, p, 60)
    c, w, fused, ref = _fused_and_jets(ctrl, knots, p, t, 2)
    g = [torch.randn(x.shape, generator=gen, dtype=F64) for x in fused]
    a = torch.autograd.grad(fused, c, g)[0]
    assert torch.isfinite(a).all()
    assert float((a - torch.autograd.grad(ref, c, g)[0]).abs().max()) <= 1e-11
    r = KnotDomain(knots, p).span(t[::6])
    first = r - p
    w = [x.T.contiguous() for x in span_bases(knots, r, t[::6], p, 2, cumulative=True)]
    ctrl = ctrl.clone().requires_grad_()
    assert first.shape[0] >= 2 * (n - p)  # the tables' path, not the jets'

    def f(c):
        return torch.cat(_cumulative.derivatives(c, first, w))

    assert torch.autograd.gradcheck(f, (ctrl,))  # every row: the written-out backward
    # second order (the plain VJP, differentiated): a random projection of the 56 x 296
    # Jacobian against finite differences, as elsewhere in this file (a detached VJP fails)
    assert torch.autograd.gradgradcheck(f, (ctrl,), fast_mode=True)


def test_fused_derivatives_vectorized_jacobian(gen):
    """The weighted table rows' backward under ``vmap`` (``jacobian(vectorize=True)`` after
    the fused forward) equals the loop of plain backwards."""
    p = 3
    ctrl = align_chain(chain(p + 2, gen))
    knots = knot_vector("uniform", p + 2, p, gen)
    t = domain_times(knots, p, 8)
    r = KnotDomain(knots, p).span(t)
    w = [x.T.contiguous() for x in span_bases(knots, r, t, p, 2, cumulative=True)]

    def f(c):
        return torch.stack(_cumulative.derivatives(c, r - p, w))

    vec = torch.autograd.functional.jacobian(f, ctrl, vectorize=True)
    loop = torch.autograd.functional.jacobian(f, ctrl)
    assert float(loop.abs().max()) > 0 and float((vec - loop).abs().max()) <= 1e-12


def test_fused_derivatives_compile_fullgraph(gen):
    """The fused derivatives under ``torch.compile(fullgraph=True)`` with inductor (a table
    per span start, the weighted rows as a gather and a sum written out term by term, the
    table cotangents through the opaque segment sums): the eager values and gradients."""
    p, n = 3, 6
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 20)
    r = KnotDomain(knots, p).span(t)
    w = [x.T.contiguous() for x in span_bases(knots, r, t, p, 2, cumulative=True)]

    def f(c):
        return torch.stack(_cumulative.derivatives(c, r - p, w))

    compiled = torch.compile(f, fullgraph=True)  # inductor: the term-by-term weighted sums
    c1, c2 = ctrl.clone().requires_grad_(), ctrl.clone().requires_grad_()
    a, b = compiled(c1), f(c2)
    assert float((a - b).detach().abs().max()) <= 1e-12
    g = torch.randn(a.shape, generator=gen, dtype=F64)
    ga, gb = torch.autograd.grad(a, c1, g)[0], torch.autograd.grad(b, c2, g)[0]
    assert float((ga - gb).abs().max()) <= 1e-12


def test_forward_mode_and_transforms_match_reverse(gen):
    p, n = 3, 6
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("nonuniform", n, p, gen)
    t = domain_times(knots, p, 4)
    r, idx = spans(knots, t, p)

    def f(ctrl, t):
        weights = span_bases(knots, r, t, p, 2, cumulative=True)
        return torch.cat(_cumulative.jets(ctrl[idx], weights, 2))

    fwd = torch.func.jacfwd(f, argnums=(0, 1))(ctrl, t)
    rev = torch.autograd.functional.jacobian(f, (ctrl, t))
    assert all(float((a - b).abs().max()) <= 1e-12 for a, b in zip(fwd, rev, strict=True))
    tangent = torch.randn(ctrl.shape, generator=gen, dtype=F64)
    with torch.autograd.forward_ad.dual_level():
        dual = torch.autograd.forward_ad.make_dual(ctrl, tangent)
        jvp = torch.autograd.forward_ad.unpack_dual(f(dual, t)).tangent
    assert float((jvp - (rev[0] * tangent).sum((-2, -1))).abs().max()) <= 1e-12
    batch = torch.stack((ctrl, align_chain(chain(n, gen))))
    mapped = torch.func.vmap(f, in_dims=(0, None))(batch, t)
    assert torch.equal(mapped, torch.stack([f(c, t) for c in batch]))


def test_unix_time_knots_with_float32_control_points(gen):
    """float64 UNIX-second knots and times with float32 control points: the weights are
    computed in float64 and rounded, so the float32 curve is the float64 one to float32
    rounding (local times computed in float32 would be off by whole knot intervals)."""
    p, n = 3, 8
    ctrl = align_chain(chain(n, gen))
    base = 1.7e9
    knots = base + knot_vector("nonuniform", n, p, gen) * 0.05
    t = domain_times(knots, p, 13)
    r, idx = spans(knots, t, p)
    points = ctrl[idx]
    weights = span_bases(knots, r, t, p, 2, cumulative=True)
    ref = _cumulative.jets(points, weights, 2)
    low = _cumulative.jets(points.float(), [w.float() for w in weights], 2)
    fused = _cumulative.poses(ctrl.float(), r - p, weights[0].T.float())
    for k, (a, b) in enumerate(zip(low, ref, strict=True)):
        assert a.dtype == torch.float32
        assert float((a.double() - b).abs().max()) <= 2e-5 * max(1.0, float(b.abs().max())), k
    assert float((fused.double() - ref[0]).abs().max()) <= 2e-5


def test_jets_compile_fullgraph(gen):
    p, n = 2, 4
    ctrl = align_chain(chain(n, gen))
    knots = knot_vector("uniform", n, p, gen)
    t = domain_times(knots, p, 3)
    r, idx = spans(knots, t, p)

    def f(ctrl, t):
        return _cumulative.jets(ctrl[idx], span_bases(knots, r, t, p, 1, cumulative=True), 1)

    compiled = torch.compile(f, fullgraph=True, backend="aot_eager")
    for a, b in zip(compiled(ctrl, t), f(ctrl, t), strict=True):
        assert float((a - b).abs().max()) <= 1e-13


def test_no_times_give_empty_results():
    """Empty time batches: empty poses and derivatives of the right shapes, batched too."""
    gen = torch.Generator().manual_seed(0)
    ctrl = dq.from_rt(unit_quat((8,), gen), torch.randn(8, 3, generator=gen, dtype=F64))
    knots = torch.arange(12, dtype=F64)
    none = torch.zeros(0, dtype=F64)
    assert curves.bspline(ctrl, none, 3, knots, form="cumulative").shape == (0, 8)
    assert [x.shape for x in curves.bspline_derivatives(
        ctrl, none, 2, 3, knots, form="cumulative")] == [(0, 8)] * 3
    out = curves.bspline(ctrl.expand(2, 8, 8), none.expand(2, 0), 3, knots, form="cumulative")
    assert out.shape == (2, 0, 8)


def test_basis_knot_gradients_ignore_unread_nan_knots():
    """A NaN knot that no span reads (here trajectory 0's last knot, in flattened rows of
    two trajectories' knots) leaves the knot gradients of the read knots finite and equal
    to those of clean knots; the unread ones get 0."""
    p = 3
    clean = torch.tensor([0.0, 0, 0, 0, 1, 2, 3, 3, 3, 3], dtype=F64)
    K = clean.shape[0]
    t = torch.tensor([0.5, 1.5, 2.5], dtype=F64)
    g = torch.linspace(-1.0, 1.0, 3 * p, dtype=F64).view(3, p)
    grads = []
    for bad in (float("nan"), 3.0):
        knots = torch.cat((torch.cat((clean[:-1], clean.new_tensor([bad]))), clean))
        knots.requires_grad_()
        r = torch.tensor([3, 4, 5]) + K
        v = span_bases(knots, r, t, p, 1, cumulative=True)
        grads.append(torch.autograd.grad((v[0] * g).sum() + (v[1] * g).sum(), knots)[0])
    assert torch.equal(grads[0][:K], torch.zeros(K, dtype=F64))
    assert torch.isfinite(grads[0]).all() and torch.equal(grads[0], grads[1])
    assert grads[0][K:].abs().max() > 0.1


def test_segment_outer_op_matches_scatter(gen):
    """The compiled path's per-start matrix products (times sorted by start inside the op)
    equal the scatter of outer products, on unsorted starts with empty ones, and the
    compiled fused poses' gradients (which call it) equal the eager ones."""
    n, k, F = 300, 16, 9
    W = torch.randn(n, k, generator=gen, dtype=F64)
    G = torch.randn(n, 8, generator=gen, dtype=F64)
    f = torch.randint(0, F - 2, (n,), generator=gen)  # the last two starts unread
    ref = torch.zeros(F, k, 8, dtype=F64).index_add(0, f, W[:, :, None] * G[:, None, :])
    out = cumulative_rows._segment_outer_op(W, G, f, F)
    assert float((out - ref).abs().max()) <= 1e-12 and not out[-2:].any()
    p, m = 3, 8
    ctrl = align_chain(chain(m, gen))
    knots = knot_vector("nonuniform", m, p, gen)
    t = domain_times(knots, p, 50)[torch.randperm(50, generator=gen)]
    r = KnotDomain(knots, p).span(t)
    w = span_bases(knots, r, t, p, 0, cumulative=True)[0].T.contiguous()

    def f_poses(c):
        return _cumulative.poses(c, r - p, w)

    compiled = torch.compile(f_poses, fullgraph=True, backend="aot_eager")
    c1, c2 = ctrl.clone().requires_grad_(), ctrl.clone().requires_grad_()
    g = torch.randn(50, 8, generator=gen, dtype=F64)
    a = torch.autograd.grad(compiled(c1), c1, g)[0]
    b = torch.autograd.grad(f_poses(c2), c2, g)[0]
    assert float((a - b).abs().max()) <= 1e-12


@pytest.mark.parametrize("p, L", [(1, 2), (2, 3), (3, 3), (4, 4)])
def test_subset_jets_backward_is_autograds(gen, p, L):
    """The written-out backward of the subset weights on jets equals autograd through its
    plain ops, and the products equal a direct evaluation of one subset's dual weight jet
    (a product of p dual-number polynomials, truncated)."""
    b_r = torch.randn(L, 2, p, 7, generator=gen, dtype=F64, requires_grad=True)
    b_d = torch.randn(L, 2, p, 7, generator=gen, dtype=F64, requires_grad=True)
    out = subsets.SubsetJets.apply(b_r, b_d)
    ref = subsets.subset_jets(b_r, b_d)  # the same ops, recorded by autograd
    assert out.shape == (L, 2 ** (p + 1), 7)
    S = torch.randint(0, 2 ** p, (), generator=gen).item()
    bits = [(S >> j) & 1 for j in range(p)]
    poly = np.polynomial.polynomial
    r = [1.0]
    d = [0.0]
    for j, b in enumerate(bits):  # (r + eps d)(x_r + eps x_d), coefficients in tau, at time 0
        x_r, x_d = b_r[:, b, j, 0].tolist(), b_d[:, b, j, 0].tolist()
        r, d = poly.polymul(r, x_r), poly.polyadd(poly.polymul(r, x_d), poly.polymul(d, x_r))
    assert np.allclose(out[:, S, 0].detach().numpy(), np.pad(r, (0, 2 * L))[:L], atol=1e-12)
    assert np.allclose(out[:, 2 ** p + S, 0].detach().numpy(), np.pad(d, (0, 2 * L))[:L],
                       atol=1e-12)
    g = torch.randn(out.shape, generator=gen, dtype=F64)
    a = torch.autograd.grad(out, (b_r, b_d), g)
    b = torch.autograd.grad(ref, (b_r, b_d), g)
    assert all(float((x - y).abs().max()) <= 1e-12 for x, y in zip(a, b, strict=True))
    small = (b_r[..., :2].detach().requires_grad_(), b_d[..., :2].detach().requires_grad_())
    # second order through the plain VJP: a random projection (fast mode) of the Jacobian
    assert torch.autograd.gradgradcheck(subsets.SubsetJets.apply, small, fast_mode=True)


@pytest.mark.parametrize("compiled", [False, True])
def test_derivatives_nan_control_point_stays_in_its_curve(gen, compiled):
    """A NaN control point of one curve of a batch (the fused derivatives flatten the curves
    into one table of span starts) leaves the other curve's derivatives and gradients
    finite, eagerly and compiled, and makes its own curve's NaN."""
    n, p = 9, 3
    ctrl = torch.stack([align_chain(chain(n, gen)) for _ in range(2)])
    ctrl[1, 4] = float("nan")
    ctrl.requires_grad_()
    knots = torch.arange(n + p + 1, dtype=F64)
    t = torch.linspace(3.0, float(n), 200, dtype=F64)

    def f(c):
        return curves.bspline_derivatives(c, t, order=2, knots=knots, form="cumulative",
                                          check=not compiled)

    out = (torch.compile(f, fullgraph=True, backend="aot_eager") if compiled else f)(ctrl)
    assert all(torch.isfinite(x[0]).all() and torch.isnan(x[1]).any() for x in out)
    grad = torch.autograd.grad(sum(x[0].sum() for x in out), ctrl)[0]
    assert torch.isfinite(grad[0]).all() and grad[0].abs().sum() > 0


@pytest.mark.parametrize("spread, tol", [(0.0, 1e-6), (1e-6, 1e-6), (1e-4, 1e-4), (1e-2, 5e-3)])
def test_fused_derivatives_float32_slow_motion_far_from_origin(gen, spread, tol):
    """float32 control points 100 m from the origin, standing still, creeping or moving
    (screw steps of ``spread`` per control point, 34 ms knots): the fused derivatives'
    linear and angular accelerations and velocities against a float64 evaluation of the
    same rounded control points. Summed as they are, the tables' large cancelling weights
    times the 100 m translation gave 6e-2 m/s^2 at every spread; now (measured) 0, 7e-8,
    6e-6 and 5e-4 m/s^2, where the plain float32 jets give 0, 1.5e-2, 1.2e-2 and 5e-2: the
    empty subset weighs the total weight, whose slope is taken in closed form, and the
    tables, angles and ``y = 1 - c`` of the pairs are computed in float64."""
    p, n = 3, 12
    xi = torch.randn(n, 6, generator=gen, dtype=F64) * spread
    start = dq.from_rt(torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=F64),
                       torch.tensor([100.0, -100.0, 100.0], dtype=F64))
    ctrl = dq.mul(start, dq.exp(xi.cumsum(0))).float()
    knots = torch.arange(n + p + 1, dtype=F64) * 0.034
    t = torch.linspace(float(knots[p]), float(knots[n]) - 1e-9, 2000, dtype=F64)
    ref = curves.kinematics(*curves.bspline_derivatives(ctrl.double(), t, order=2, knots=knots,
                                                        form="cumulative"))
    low = curves.kinematics(*(x.double() for x in curves.bspline_derivatives(
        ctrl, t, order=2, knots=knots, form="cumulative")))
    for name in ("linear_acceleration", "angular_acceleration", "linear_velocity"):
        err = float((getattr(low, name) - getattr(ref, name)).abs().max())
        assert err <= tol, (name, err)

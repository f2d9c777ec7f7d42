"""The split B-spline form (issue 35): ``form="split"`` of ``curves.bspline``,
``curves.bspline_derivatives``, ``nn.BSpline`` and the estimation.

Independent references, written here: the basis from scipy (``scipy.interpolate.BSpline``
with unit coefficient vectors), the rotation as scipy ``Rotation`` products
``R_0 prod_j Exp(Bt_j Log(R_{j-1}^T R_j))`` over ALL control points (not only a span's: the
telescoping of the whole factors is checked with it), the translation as a numpy basis
product; the derivatives against central finite differences of that reference; degree 1
against scipy's ``Slerp`` and numpy's linear interpolation. The drop-in check against
BAD-Gaussians' ``spline_functor`` (linear and cubic SO(3) x R^3 interpolation) runs on our
own rewrite of it in pypose (``badgs_linear`` / ``badgs_cubic``, also used by
``benchmarks/bench_split.py``).
"""

import math

import numpy as np
import pytest
import scipy.interpolate as si
import torch
from scipy.spatial.transform import Rotation, Slerp
from strategies import knot_vector, unit_dq, unit_quat

import torch_dq.dualquat as dq
from torch_dq import curves, fitting
from torch_dq._core import align_chain
from torch_dq.nn import BSpline

F64 = torch.float64
KNOT_KINDS = ("clamped", "uniform", "nonuniform", "repeated")


# ----------------------------------------------------------------------------- inputs

def chain(n, gen, spread=0.6, scale=1.0, dtype=F64):
    """``n`` poses, each turned by less than 2.4 rad from the previous, random signs."""
    rv = spread * torch.randn(n, 3, generator=gen, dtype=F64)
    rv *= torch.clamp(2.4 / rv.norm(dim=-1, keepdim=True), max=1.0)
    q = [unit_quat((), gen)]
    for k in range(1, n):
        step = torch.from_numpy(Rotation.from_rotvec(rv[k].numpy()).as_quat(scalar_first=True))
        q.append(torch.from_numpy((Rotation.from_quat(q[-1].numpy(), scalar_first=True)
                                   * Rotation.from_quat(step.numpy(), scalar_first=True))
                                  .as_quat(scalar_first=True)))
    signs = torch.where(torch.rand(n, generator=gen, dtype=F64) < 0.5, -1.0, 1.0)
    q = torch.stack(q) * signs[:, None]
    p = scale * torch.randn(n, 3, generator=gen, dtype=F64)
    return dq.from_rt(q, p).to(dtype)


def inner_times(knots, p, count, gen, margin=0.0):
    """``count`` sorted times in the domain, at least ``margin`` away from every knot."""
    n = knots.shape[0] - p - 1
    t0, t1 = float(knots[p]), float(knots[n])
    t = t0 + (t1 - t0) * torch.rand(4 * count, generator=gen, dtype=F64)
    if margin:
        t = t[(t[:, None] - knots).abs().min(-1).values > margin]
    return t[:count].sort().values


# ----------------------------------------------------------------------------- reference

def reference(ctrl, knots, p, t):
    """numpy/scipy: the split B-spline at times ``t`` -> (scipy ``Rotation``, ``(T, 3)``).

    Basis: scipy's ``BSpline`` on unit coefficients (end polynomials continued outside);
    rotation: ``R_0 prod_{j=1}^{n-1} Exp(Bt_j Log(R_{j-1}^T R_j))`` (scipy's rotation vector:
    the shortest path); translation: ``sum_j B_j p_j``.
    """
    c = ctrl.detach().double().numpy()
    n = c.shape[0]
    qs = c[:, :4]
    d = c[:, 4:]
    conj = qs * np.array([1.0, -1.0, -1.0, -1.0])
    # translation 2 vec(d q*) by a numpy Hamilton product
    w1, x1, y1, z1 = d.T
    w2, x2, y2, z2 = conj.T
    trans = 2.0 * np.stack((w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2), -1)
    tt = np.asarray(t, dtype=float)
    B = si.BSpline(knots.numpy(), np.eye(n), p, extrapolate=True)(tt)  # (T, n)
    Bt = np.cumsum(B[:, ::-1], -1)[:, ::-1]
    R = [Rotation.from_quat(q, scalar_first=True) for q in qs]
    out = Rotation.from_quat(np.repeat(qs[:1], len(tt), 0), scalar_first=True)
    for j in range(1, n):
        step = (R[j - 1].inv() * R[j]).as_rotvec()
        out = out * Rotation.from_rotvec(Bt[:, j:j + 1] * step[None])
    return out, B @ trans


def reference_dq(ctrl, knots, p, t, like):
    """The reference as ``(T, 8)`` dual quaternions, each signed as ``like (T, 8)``."""
    R, pos = reference(ctrl, knots, p, t)
    x = dq.from_rt(torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(pos))
    sign = torch.where((x[:, :4] * like[:, :4].double()).sum(-1) < 0, -1.0, 1.0)
    return x * sign[:, None]


def assert_poses(x, R, pos, atol):
    q, tr = dq.to_rt(x.detach().double())
    ang = (Rotation.from_quat(q.numpy(), scalar_first=True).inv() * R).magnitude()
    assert ang.max() <= atol, ang.max()
    np.testing.assert_allclose(tr.numpy(), pos, rtol=0, atol=atol)


# ----------------------------------------------------------------------------- values

@pytest.mark.parametrize("kind", KNOT_KINDS)
@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_matches_scipy_reference(gen, kind, p):
    """Poses of every knot layout and degree equal the scipy/numpy reference (float64),
    the readable ``curves._split`` and the jets' order 0 included."""
    n = 8
    ctrl, knots = chain(n, gen), knot_vector(kind, n, p, gen)
    t = torch.cat((inner_times(knots, p, 40, gen), knots[[p, n]]))
    x = curves.bspline(ctrl, t, degree=p, knots=knots, form="split")
    assert_poses(x, *reference(ctrl, knots, p, t.numpy()), atol=1e-12)
    x0 = curves.bspline_derivatives(ctrl, t, order=0, degree=p, knots=knots, form="split")[0]
    torch.testing.assert_close(x0, x, rtol=0, atol=1e-13)
    # the readable reference on the span points as the curves gather them
    from torch_dq._time import KnotDomain, span_bases
    r = KnotDomain(knots, p).span(t)
    points = align_chain(ctrl)[r[:, None] - p + torch.arange(p + 1)]
    weights = span_bases(knots, r, t, p, 0, cumulative=True)[0]
    torch.testing.assert_close(curves._split(points, weights), x, rtol=0, atol=1e-13)
    assert torch.allclose(dq.norm(x).real, torch.ones((), dtype=F64), atol=1e-13)


def test_degree_one_is_slerp_and_linear_interpolation(gen):
    """Degree 1 on clamped knots = scipy's Slerp of the rotations and numpy's linear
    interpolation of the translations at the knots' times (BAD-Gaussians' "linear")."""
    n = 6
    ctrl = chain(n, gen)
    knots = torch.cat((torch.zeros(1, dtype=F64), torch.rand(n, generator=gen,
                                                               dtype=F64).cumsum(0)))
    knots = torch.cat((knots[:1], knots, knots[-1:]))[:n + 2]  # clamped, non-uniform
    grid = knots[1:n + 1].numpy()
    t = torch.linspace(float(knots[1]), float(knots[n]), 57, dtype=F64)
    x = curves.bspline(ctrl, t, degree=1, knots=knots, form="split")
    q, pos = dq.to_rt(ctrl)
    rots = Slerp(grid, Rotation.from_quat(q.numpy(), scalar_first=True))(t.numpy())
    lin = np.stack([np.interp(t.numpy(), grid, pos[:, k].numpy()) for k in range(3)], -1)
    assert_poses(x, rots, lin, atol=1e-12)


def test_forms_agree_where_they_must(gen):
    """Pure rotations: split = cumulative (the same SO(3) product); pure translations: split
    = the Euclidean B-spline = de_boor = cumulative. And in general the forms differ."""
    n, p = 7, 3
    knots = knot_vector("nonuniform", n, p, gen)
    t = inner_times(knots, p, 30, gen)
    rot = dq.from_rt(unit_quat((n,), gen), torch.zeros(n, 3, dtype=F64))
    trans = dq.from_rt(torch.tensor([1.0, 0, 0, 0], dtype=F64).expand(n, 4),
                       torch.randn(n, 3, generator=gen, dtype=F64))
    kw = dict(degree=p, knots=knots)
    for a, b in ((curves.bspline(rot, t, form="split", **kw),
                  curves.bspline(rot, t, form="cumulative", **kw)),
                 (curves.bspline(trans, t, form="split", **kw),
                  curves.bspline(trans, t, form="de_boor", **kw))):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
    ctrl = chain(n, gen)
    assert (curves.bspline(ctrl, t, form="split", **kw)
            - curves.bspline(ctrl, t, form="cumulative", **kw)).abs().max() > 1e-3


def test_signs_of_control_points_do_not_matter(gen):
    """x and -x control points give the same motion; the output follows ctrl[0]'s sign."""
    n, p = 7, 3
    ctrl = chain(n, gen)
    knots = knot_vector("uniform", n, p, gen)
    t = inner_times(knots, p, 20, gen)
    flips = torch.where(torch.rand(n, generator=gen, dtype=F64) < 0.5, -1.0, 1.0)
    flips[0] = 1.0
    a = curves.bspline(ctrl, t, degree=p, knots=knots, form="split")
    b = curves.bspline(ctrl * flips[:, None], t, degree=p, knots=knots, form="split")
    torch.testing.assert_close(a, b, rtol=0, atol=1e-13)


# ----------------------------------------------------------------------------- derivatives

def _stencils(f, t, h):
    """Central differences of orders 1..3 of ``f (T,) -> (T, 8)`` (1, 2: fourth order;
    3: second order)."""
    fm2, fm1, f0, fp1, fp2 = (f(t + k * h) for k in (-2, -1, 0, 1, 2))
    d1 = (-fp2 + 8 * fp1 - 8 * fm1 + fm2) / (12 * h)
    d2 = (-fp2 + 16 * fp1 - 30 * f0 + 16 * fm1 - fm2) / (12 * h * h)
    d3 = (fp2 - 2 * fp1 + 2 * fm1 - fm2) / (2 * h ** 3)
    return d1, d2, d3


@pytest.mark.parametrize("kind", KNOT_KINDS)
@pytest.mark.parametrize("p", [2, 3])
def test_derivatives_against_finite_differences_of_the_reference(gen, kind, p):
    """Exact velocities, accelerations and jerks (dual quaternions) against central finite
    differences of the scipy reference, at times 1e-2 away from the knots."""
    n = 8
    ctrl, knots = chain(n, gen), knot_vector(kind, n, p, gen)
    t = inner_times(knots, p, 25, gen, margin=1e-2)
    xs = curves.bspline_derivatives(ctrl, t, order=3, degree=p, knots=knots, form="split")
    fds = _stencils(lambda s: reference_dq(ctrl, knots, p, s.numpy(), xs[0]), t, 1e-3)
    scale = [1.0] + [float(x.abs().max()) for x in xs[1:]]
    for k, (ours, fd, tol) in enumerate(zip(xs[1:], fds, (1e-9, 1e-7, 1e-4), strict=True), 1):
        err = (ours - fd).abs().max() / scale[k]
        assert err < tol, (k, float(err))


def test_accelerations_are_continuous_at_knots(gen):
    """C^(p-1): a cubic's second derivative is continuous across a simple knot (its third
    jumps)."""
    n, p = 8, 3
    ctrl, knots = chain(n, gen), knot_vector("nonuniform", n, p, gen)
    k = knots[5]
    t = torch.stack((k - 1e-9, k))
    xs = curves.bspline_derivatives(ctrl, t, order=3, degree=p, knots=knots, form="split")
    assert (xs[2][0] - xs[2][1]).abs().max() < 1e-6
    assert (xs[3][0] - xs[3][1]).abs().max() > 1e-3


# ----------------------------------------------------------------------------- gradients

def _ctrl_at(where, gen, n):
    if where == "random":
        return chain(n, gen)
    if where == "identity":
        return dq.identity((n,), dtype=F64)
    return chain(1, gen).expand(n, 8).clone()  # equal control points: a static trajectory


@pytest.mark.parametrize("where", ["random", "identity", "equal"])
@pytest.mark.parametrize("p", [1, 3])
def test_gradcheck_and_gradgradcheck(gen, where, p):
    """Poses and derivatives to order 3, w.r.t. the control points and the times, at random,
    identity and equal control points (no epsilon anywhere)."""
    n = p + 2
    knots = knot_vector("nonuniform", n, p, gen)
    t = inner_times(knots, p, 2, gen, margin=1e-2)
    c = _ctrl_at(where, gen, n).requires_grad_()
    tt = t.clone().requires_grad_()

    def pose(c, s):
        return curves.bspline(dq.normalize(c), s, degree=p, knots=knots, form="split")

    def jets(c, s):
        return torch.cat(curves.bspline_derivatives(dq.normalize(c), s, order=3, degree=p,
                                                    knots=knots, form="split"), -1)
    assert torch.autograd.gradcheck(pose, (c, tt))
    for f in (pose, jets):  # fast mode: random projections (the full Jacobians take minutes)
        assert torch.autograd.gradgradcheck(f, (c, tt), fast_mode=True)
    assert torch.autograd.gradcheck(jets, (c, tt), fast_mode=True)


@pytest.mark.parametrize("where", ["identity", "equal"])
def test_gradients_finite_at_rest_in_float32(gen, where):
    """float32, many times, local parameters 0 and 1 included: gradients and second-order
    gradients finite at identity and equal control points."""
    n, p = 6, 3
    knots = curves.clamped_uniform_knots(n, p)
    t = torch.cat((torch.linspace(0.0, 1.0, 101), knots[p:n + 1]))
    c = _ctrl_at(where, gen, n).float().requires_grad_()
    xs = curves.bspline_derivatives(c, t, order=3, degree=p, knots=knots, form="split")
    loss = sum((x * torch.linspace(-1.0, 1.0, x.numel()).view(x.shape)).sum() for x in xs)
    (g,) = torch.autograd.grad(loss, c, create_graph=True)
    (gg,) = torch.autograd.grad((g * g).sum(), c)
    assert torch.isfinite(g).all() and torch.isfinite(gg).all()


# ----------------------------------------------------------------------------- shapes

@pytest.mark.parametrize("batch", [(), (1,), (5,), (2, 5), (3, 1, 5)])
def test_batch_shapes(gen, batch):
    """Control points (*batch, n, 8) with (T,) and (*batch, T) times: every element equals
    its own unbatched curve, poses and derivatives."""
    n, p, T = 6, 3, 4
    knots = knot_vector("nonuniform", n, p, gen)
    ctrl = unit_dq((*batch, n), gen)
    t_shared = inner_times(knots, p, T, gen)
    lo, hi = float(knots[p]), float(knots[n])
    t_rows = lo + (hi - lo) * torch.rand(*batch, T, generator=gen, dtype=F64)
    for t in (t_shared, t_rows):
        x = curves.bspline(ctrl, t, degree=p, knots=knots, form="split")
        xs = curves.bspline_derivatives(ctrl, t, order=2, degree=p, knots=knots, form="split")
        assert x.shape == (*batch, T, 8) and all(d.shape == (*batch, T, 8) for d in xs)
        flat_c = ctrl.reshape(-1, n, 8)
        flat_t = t.expand(*batch, T).reshape(-1, T)
        for b in range(flat_c.shape[0]):
            one = curves.bspline_derivatives(flat_c[b], flat_t[b], order=2, degree=p,
                                             knots=knots, form="split")
            torch.testing.assert_close(x.reshape(-1, T, 8)[b], one[0], rtol=0, atol=1e-13)
            for d, o in zip(xs, one, strict=True):
                torch.testing.assert_close(d.reshape(-1, T, 8)[b], o, rtol=0, atol=1e-12)


def test_float32_accuracy(gen):
    """float32 against float64 on 64 random chains of unit-scale poses, 200 times each
    (non-uniform knots): poses within 1.5e-6, velocities, accelerations and jerks within 3e-6
    of each derivative's largest entry (measured 6.6e-7, 9.5e-7, 9.6e-7, 1.1e-6 of maxima
    1.2, 2.8, 13, 81)."""
    n, p = 8, 3
    knots = knot_vector("nonuniform", n, p, gen)
    ctrl = torch.stack([chain(n, gen) for _ in range(64)])
    t = inner_times(knots, p, 200, gen)
    x64 = curves.bspline_derivatives(ctrl, t, order=3, degree=p, knots=knots, form="split")
    x32 = curves.bspline_derivatives(ctrl.float(), t.float(), order=3, degree=p,
                                     knots=knots.float(), form="split")
    errs = [float((a.double() - b).abs().max() / max(1.0, float(b.abs().max())))
            for a, b in zip(x32, x64, strict=True)]
    for err, bound in zip(errs, (1.5e-6, 3e-6, 3e-6, 3e-6), strict=True):
        assert err < bound, errs


def test_wide_time(gen):
    """float64 UNIX seconds with float32 control points lose nothing beyond float32
    rounding of the local parameter: equal to the float64 curve on times relative to the
    origin."""
    n, p = 7, 3
    ctrl = chain(n, gen)
    rel_knots = knot_vector("nonuniform", n, p, gen)
    origin = 1.7e9
    t_rel = inner_times(rel_knots, p, 50, gen)
    wide = curves.bspline_derivatives(ctrl.float(), origin + t_rel, order=2, degree=p,
                                      knots=origin + rel_knots, form="split")
    ref = curves.bspline_derivatives(ctrl, t_rel, order=2, degree=p, knots=rel_knots,
                                     form="split")
    for a, b, tol in zip(wide, ref, (2e-6, 1e-5, 1e-4), strict=True):
        assert a.dtype == torch.float32
        assert float((a.double() - b).abs().max() / max(1.0, float(b.abs().max()))) < tol


def test_domain_rules_and_extrapolation(gen):
    """Outside the domain: ValueError naming it; extrapolate=True continues the end spans
    (the scipy reference's end polynomials); check=False gives NaN there."""
    n, p = 6, 3
    ctrl, knots = chain(n, gen), knot_vector("nonuniform", n, p, gen)
    t0, t1 = float(knots[p]), float(knots[n])
    out = torch.tensor([t0 - 0.1, t1 + 0.05], dtype=F64)
    with pytest.raises(ValueError, match=r"^curves\.bspline: .*domain"):
        curves.bspline(ctrl, out, degree=p, knots=knots, form="split")
    with pytest.raises(ValueError, match=r"^curves\.bspline_derivatives: .*domain"):
        curves.bspline_derivatives(ctrl, out, degree=p, knots=knots, form="split")
    x = curves.bspline(ctrl, out, degree=p, knots=knots, form="split", extrapolate=True)
    assert_poses(x, *reference(ctrl, knots, p, out.numpy()), atol=1e-12)
    nan = curves.bspline(ctrl, out, degree=p, knots=knots, form="split", check=False)
    assert torch.isnan(nan).all()


def test_batched_knots_per_trajectory(gen):
    """A row of knots per trajectory (B, K) with (B, T) times: each row its own curve."""
    B, n, p = 3, 6, 3
    ctrl = unit_dq((B, n), gen)
    knots = torch.stack([knot_vector("nonuniform", n, p, gen) + 10.0 * b for b in range(B)])
    t = torch.stack([inner_times(knots[b], p, 5, gen) for b in range(B)])
    xs = curves.bspline_derivatives(ctrl, t, order=3, degree=p, knots=knots, form="split")
    for b in range(B):
        assert_poses(xs[0][b], *reference(ctrl[b], knots[b], p, t[b].numpy()), atol=1e-12)
        one = curves.bspline_derivatives(ctrl[b], t[b], order=3, degree=p, knots=knots[b],
                                         form="split")
        for a, o in zip(xs, one, strict=True):
            torch.testing.assert_close(a[b], o, rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- layers

def test_layer_state_dict_round_trip(gen):
    """nn.BSpline(form="split") evaluates the split curve; from_state_dict rebuilds it
    (form, degree, per-row knots and origins) and gives the same poses and kinematics."""
    B, n, p = 2, 6, 2
    knots = torch.stack([1.7e9 + knot_vector("nonuniform", n, p, gen) for _ in range(B)])
    src = BSpline(unit_dq((B, n), gen).float(), degree=p, knots=knots, form="split")
    t = torch.stack([inner_times(knots[b], p, 7, gen) for b in range(B)])
    ref = curves.bspline(src.control_points, t, degree=p, knots=knots, form="split")
    torch.testing.assert_close(src(t), ref, rtol=0, atol=0)
    dst = BSpline.from_state_dict(src.state_dict())
    assert (dst.form, dst.degree, dst.n_ctrl) == ("split", p, n)
    torch.testing.assert_close(dst(t), src(t), rtol=0, atol=0)
    for a, b in zip(dst.kinematics(t), src.kinematics(t), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    other = BSpline(dq.identity((B, n)), degree=p, knots=knots)
    other.load_state_dict(src.state_dict())
    assert other.form == "split"


def _split_truth(gen, n=9, p=3, duration=4.0):
    ctrl = chain(n, gen, spread=0.3)
    knots = curves.clamped_uniform_knots(n, p, dtype=F64, domain=(0.0, duration))
    return ctrl, knots


def test_from_poses_and_estimate_recover_a_split_spline(gen):
    """from_poses(form="split") on 81 noise-free samples of a split spline starts close to
    it; fitting.estimate (Poses term) then recovers it to 1e-7 at held-out times."""
    ctrl, knots = _split_truth(gen)
    times = torch.linspace(0.0, 4.0, 81, dtype=F64)
    x = curves.bspline(ctrl, times, knots=knots, form="split")
    q, pos = dq.to_rt(x)
    spline = BSpline.from_poses(q, pos, times, n_ctrl=9, form="split")
    assert spline.form == "split"
    held = times[:-1] + 0.025
    truth = curves.bspline(ctrl, held, knots=knots, form="split")
    from torch_dq import losses
    with torch.no_grad():
        start = spline(held)
    assert float(losses.rotation_angle(start, truth).max()) < 1e-2
    assert float(losses.translation_error(start, truth).max()) < 1e-2
    est = fitting.estimate(spline, [fitting.Poses(times, x, rot_sigma=0.01, trans_sigma=0.01)],
                           prior=0.0, verbose=False)
    assert bool(est.converged) and spline.form == "split"
    with torch.no_grad():
        fitted = spline(held)
    assert float(losses.rotation_angle(fitted, truth).max()) < 1e-7
    assert float(losses.translation_error(fitted, truth).max()) < 1e-7


# ----------------------------------------------------------------------------- BAD-Gaussians

pp = pytest.importorskip("pypose")
from bad_gaussians import badgs_cubic, badgs_linear, to_pypose  # noqa: E402  (needs pypose)


def split_cubic(ctrl, u):
    """torch_dq's split cubic on 4 control points ``(B, 4, 8)`` at BAD-Gaussians' local
    parameters ``u (B, V)``: uniform unclamped knots 0..7, the one span [3, 4], t = 3 + u."""
    knots = torch.arange(8, dtype=u.dtype)
    return curves.bspline(ctrl, 3.0 + u, degree=3, knots=knots, form="split")


def split_linear(ctrl, u):
    knots = torch.tensor([0.0, 0.0, 1.0, 1.0], dtype=u.dtype)
    return curves.bspline(ctrl, u, degree=1, knots=knots, form="split")


def same_pose(a7, b7, atol):
    """pypose poses (..., 7) equal up to the quaternion's sign: quaternions within ``atol``,
    translations within ``atol`` times their scale ``max(1, |t|)``."""
    sign = torch.where((a7[..., 3:] * b7[..., 3:]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    scale = max(1.0, float(b7[..., :3].abs().max()))
    return (float((a7[..., :3] - b7[..., :3]).abs().max()) <= atol * scale
            and float((a7[..., 3:] - sign * b7[..., 3:]).abs().max()) <= atol)


@pytest.mark.parametrize("which", ["linear", "cubic"])
def test_drop_in_for_bad_gaussians_functor(gen, which):
    """Random control poses (rotations about 0.5 rad apart, translations of unit scale, up
    to 3.5) and u in [0, 1] with both ends: the split forms equal our rewrite of
    BAD-Gaussians' functor in float64 (1e-12) and float32 (quaternions 1e-6, translations
    1e-6 max(1, |t|): absolute 1e-6 in a scene normalised to the unit cube). Measured in
    float32: quaternions 3.6e-7, translations 1.4e-6 at |t| = 2.9 (against float64: ours
    1.4e-6, the functor's 3.0e-7; the dual quaternion's from_rt / to_rt round trip costs
    about 5 ulp of |t|)."""
    m = 2 if which == "linear" else 4
    ctrl = torch.stack([chain(m, gen, spread=0.5) for _ in range(64)])
    u = torch.cat((torch.tensor([0.0, 1.0], dtype=F64),
                   torch.rand(10, generator=gen, dtype=F64))).expand(64, 12)
    ours_f, theirs_f = ((split_linear, badgs_linear) if which == "linear"
                        else (split_cubic, badgs_cubic))
    for dtype, atol in ((F64, 1e-12), (torch.float32, 1e-6)):
        c, uu = ctrl.to(dtype), u.to(dtype)
        ours = to_pypose(ours_f(c, uu))
        theirs = theirs_f(to_pypose(c), uu)
        assert ours.dtype == dtype and same_pose(ours, theirs, atol)


@pytest.mark.parametrize("which", ["linear", "cubic"])
@pytest.mark.parametrize("where", ["identity", "equal"])
def test_drop_in_gradients_at_rest(gen, which, where):
    """At identity / equal control poses (the start of a BAD-Gaussians training: every
    image's trajectory at rest) with u = 0, 1 included: torch_dq's first and second-order
    gradients are finite without any epsilon. pypose 0.9.5's first gradients are finite
    there too (pypose #172 is fixed), but its second-order gradients at the identity are
    NaN (measured here: the reason BAD-Gaussians keep "initial noise ... non-zero")."""
    m = 2 if which == "linear" else 4
    ours_f, theirs_f = ((split_linear, badgs_linear) if which == "linear"
                        else (split_cubic, badgs_cubic))
    base = (dq.identity((8, m), dtype=torch.float32) if where == "identity"
            else chain(1, gen).float().expand(8, m, 8).clone())
    u = torch.linspace(0.0, 1.0, 11).expand(8, 11)
    c = base.clone().requires_grad_()
    out = to_pypose(ours_f(c, u))
    weight = torch.linspace(-1.0, 1.0, out.numel()).view(out.shape)
    (g,) = torch.autograd.grad((out * weight).sum(), c, create_graph=True)
    (gg,) = torch.autograd.grad((g * g).sum(), c)
    assert torch.isfinite(g).all() and torch.isfinite(gg).all()
    c7 = to_pypose(base).requires_grad_()
    out7 = theirs_f(c7, u)
    (g7,) = torch.autograd.grad((out7 * weight).sum(), c7, create_graph=True)
    assert torch.isfinite(g7).all()
    if where == "identity":
        (gg7,) = torch.autograd.grad((g7 * g7).sum(), c7)
        assert not torch.isfinite(gg7).all()  # pypose: NaN second-order gradients at rest


def test_cubic_matches_pypose_bspline_rotation(gen):
    """Rotation-only poses: the split cubic equals pypose's SE(3) ``bspline`` (cumulative
    SE(3) on uniform knots; with zero translations the same SO(3) product)."""
    ctrl = dq.from_rt(torch.stack([dq.to_rt(chain(4, gen, spread=0.5))[0] for _ in range(5)]),
                      torch.zeros(5, 4, 3, dtype=F64))
    ref = pp.bspline(pp.SE3(to_pypose(ctrl)), interval=0.25).tensor()  # (5, 5, 7): u 0..1
    ours = to_pypose(split_cubic(ctrl, torch.linspace(0.0, 1.0, 5, dtype=F64).expand(5, 5)))
    assert same_pose(ours, ref, 1e-10)
    assert math.isfinite(float(ours.abs().max()))

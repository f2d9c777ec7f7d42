"""The time model's domain rules (docs/api_contract.md, nn and curves): the tolerance at the ends,
extrapolate=True, NaN where checks are skipped, torch.compile with the default arguments,
meta tensors; and saving whole modules (from_state_dict, torch.save).

References are independent: numpy De Boor / De Casteljau over screw interpolation of 4x4
matrices (tests/references.py, pytransform3d's exponential coordinates)."""

import io
import math
import re

import numpy as np
import pytest
import torch
from references import casteljau_np, deboor_np, sclerp_mat
from strategies import unit_dq

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq.nn import Bezier, BSpline, Curve

F64 = torch.float64


def knots_on(n, degree, t0, t1):
    return t0 + (t1 - t0) * curves.clamped_uniform_knots(n, degree, dtype=F64)


def near_chain(n, gen, step=0.4):
    """Control points whose neighbours differ by moderate screw motions (no half turns)."""
    xi = torch.randn(n, 6, generator=gen, dtype=F64) * step
    return dq.normalize(torch.stack([dq.exp(xi[: i + 1].sum(0)) for i in range(n)]))


def tol(t0, t1, dtype):
    """The contract's tolerance (docs/api_contract.md), written out."""
    return max(1e-9 * (t1 - t0), 4 * torch.finfo(dtype).eps * max(abs(t0), abs(t1)))


# ----------------------------------------------------------------------------- the tolerance

@pytest.mark.parametrize("t0, t1", [(10.0, 12.0), (1.7e9, 1.7e9 + 30.0), (-3.0, -1.0)])
def test_a_rounding_outside_is_evaluated_at_the_end(gen, t0, t1):
    """0.2 raised on t = 12.000000000001 for [10, 12]: times within the tolerance now give
    the end pose; beyond it the error names the domain and extrapolate=True."""
    spline = BSpline(near_chain(6, gen), knots=knots_on(6, 3, t0, t1))
    bez = Bezier(near_chain(4, gen), domain=(t0, t1))
    eps = tol(t0, t1, F64)
    for module in (spline, bez):
        ends = torch.tensor([t0, t1], dtype=F64)
        ref = module(ends)
        inside = torch.tensor([t0 - 0.5 * eps, t1 + 0.5 * eps], dtype=F64)
        torch.testing.assert_close(module(inside), ref, rtol=0, atol=0)
        for bad in (t0 - 3 * eps, t1 + 3 * eps):
            with pytest.raises(ValueError, match=r"module's time domain.*extrapolate=True"):
                module(torch.tensor([bad], dtype=F64))
    k = knots_on(6, 3, t0, t1)
    ctrl = near_chain(6, gen)
    x = curves.bspline(ctrl, torch.tensor([t1 + 0.5 * eps], dtype=F64), knots=k)
    torch.testing.assert_close(x, curves.bspline(ctrl, k[-1:], knots=k), rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"^curves\.bspline_derivatives: t must lie in the "
                                         r"domain .*or pass extrapolate=True"):
        curves.bspline_derivatives(ctrl, torch.tensor([t1 + 3 * eps], dtype=F64), knots=k)


def test_float32_times_use_their_own_eps():
    """A float32 t on [10, 12]: 4 float32 ulps of 12 are accepted, 1e-3 is not."""
    spline = BSpline(dq.identity((5,)), knots=knots_on(5, 2, 10.0, 12.0).float(), degree=2)
    step = 4 * torch.finfo(torch.float32).eps * 12.0
    t = torch.tensor([12.0 + 0.9 * step, 10.0 - 0.9 * step])
    assert t[0] > 12.0 and t[1] < 10.0  # representable, really outside
    assert torch.isfinite(spline(t)).all()
    with pytest.raises(ValueError, match="extrapolate"):
        spline(torch.tensor([12.001]))


def test_gradient_with_respect_to_t_passes_at_the_clamped_ends(gen):
    """Times moved onto an end keep d/dt (the value is the end's, the derivative flows)."""
    spline = BSpline(near_chain(6, gen), knots=knots_on(6, 3, 0.0, 2.0))
    t = torch.tensor([2.0 + 1e-12], dtype=F64, requires_grad=True)
    (g,) = torch.autograd.grad(spline(t)[..., 5].sum(), t)
    t_end = torch.tensor([2.0], dtype=F64, requires_grad=True)
    (g_end,) = torch.autograd.grad(spline(t_end)[..., 5].sum(), t_end)
    torch.testing.assert_close(g, g_end)
    assert g.abs() > 0


# ----------------------------------------------------------------------------- extrapolate

def _mats(ctrl):
    return dq.to_matrix(ctrl).numpy()


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_extrapolate_continues_the_end_spans(gen, degree):
    """extrapolate=True evaluates De Boor's scheme of the end spans outside the domain: the
    numpy scheme over 4x4 screw interpolation (alphas outside [0, 1])."""
    n = 6
    ctrl = near_chain(n, gen)
    k = knots_on(n, degree, 1.0, 3.0)
    t = torch.tensor([0.7, 0.95, 3.05, 3.4], dtype=F64)
    ref = np.stack([deboor_np(_mats(ctrl), k.numpy(), degree, s, sclerp_mat) for s in t.tolist()])
    got = curves.bspline(ctrl, t, degree, k, extrapolate=True)
    np.testing.assert_allclose(dq.to_matrix(got).numpy(), ref, atol=1e-10)
    spline = BSpline(ctrl, degree, k, extrapolate=True)
    np.testing.assert_allclose(dq.to_matrix(spline(t)).detach().numpy(), ref, atol=1e-10)
    strict = BSpline(ctrl, degree, k)
    np.testing.assert_allclose(dq.to_matrix(strict(t, extrapolate=True)).detach().numpy(), ref,
                               atol=1e-10)
    with pytest.raises(ValueError, match="extrapolate=True"):
        strict(t)
    # derivatives continue the same polynomial pieces: finite differences of the reference
    h = 1e-5
    x, dx = strict.derivatives(t, order=1, extrapolate=True)
    fd = [(deboor_np(_mats(ctrl), k.numpy(), degree, s + h, sclerp_mat)
           - deboor_np(_mats(ctrl), k.numpy(), degree, s - h, sclerp_mat)) / (2 * h)
          for s in t.tolist()]
    dT = _dmatrix(x, dx)
    np.testing.assert_allclose(dT, np.stack(fd), atol=1e-7)


def _dmatrix(x, dx):
    """d/dt of the 4x4 matrix of x(t) from x and dx (forward mode of dq.to_matrix)."""
    _, out = torch.func.jvp(dq.to_matrix, (x.detach(),), (dx.detach(),))
    return out.numpy()


def test_bezier_extrapolate_is_de_casteljau_outside(gen):
    ctrl = near_chain(4, gen)
    t = torch.tensor([-0.5, 2.5], dtype=F64)
    got = curves.bezier(ctrl, t, domain=(0.0, 2.0), extrapolate=True)
    ref = np.stack([casteljau_np(_mats(ctrl), s / 2.0, sclerp_mat) for s in t.tolist()])
    np.testing.assert_allclose(dq.to_matrix(got).numpy(), ref, atol=1e-10)
    bez = Bezier(ctrl, domain=(0.0, 2.0))
    np.testing.assert_allclose(dq.to_matrix(bez(t, extrapolate=True)).detach().numpy(), ref,
                               atol=1e-10)


# ----------------------------------------------------------------------------- skipped checks

def test_unchecked_times_outside_give_nan_per_element(gen):
    """check=False: 0.2 extrapolated silently; now NaN for those times only, the others
    unchanged (and times within the tolerance at the ends)."""
    ctrl = near_chain(6, gen)
    k = knots_on(6, 3, 0.0, 2.0)
    t = torch.tensor([-0.1, 0.0, 1.0, 2.0 + 1e-12, 2.5], dtype=F64)
    ref = curves.bspline(ctrl, torch.tensor([0.0, 1.0, 2.0], dtype=F64), knots=k)
    for x in (curves.bspline(ctrl, t, knots=k, check=False),
              curves.bspline_derivatives(ctrl, t, order=1, knots=k, check=False)[0],
              BSpline(ctrl, knots=k, check=False)(t),
              BSpline(ctrl, knots=k, check=False, form="cumulative")(t),
              BSpline(ctrl, knots=k, check=False, form="split")(t)):
        nan = torch.isnan(x).all(-1)
        assert nan.tolist() == [True, False, False, False, True]
    x = BSpline(ctrl, knots=k, check=False)(t)
    torch.testing.assert_close(x[1:4], ref, rtol=0, atol=1e-15)
    b = Bezier(ctrl[:3], domain=(0.0, 2.0), check=False)(t)
    assert torch.isnan(b).all(-1).tolist() == [True, False, False, False, True]


@pytest.mark.parametrize("knots", [True, False])
def test_meta_tensors(knots):
    """0.2: "Cannot copy out of meta tensor" with meta knots, "Tensor.item() cannot be
    called on meta tensors" without; check=True on meta blamed "this transform"."""
    ctrl = dq.identity((5,)).to("meta")
    kw = {"knots": curves.clamped_uniform_knots(5, 3).to("meta")} if knots else {}
    spline = BSpline(ctrl, **kw)
    t = torch.empty(7, device="meta")
    assert spline(t).shape == (7, 8) and spline(t).device.type == "meta"
    assert all(x.shape == (7, 8) for x in spline.derivatives(t, order=3))
    assert Bezier(ctrl)(t).shape == (7, 8)
    assert curves.bspline(ctrl, t).shape == (7, 8)


# ----------------------------------------------------------------------------- saving

@pytest.mark.parametrize("form", ["de_boor", "cumulative", "split"])
def test_from_state_dict_rebuilds_without_knowing_the_shape(gen, form):
    k = torch.tensor([0.0, 0.0, 0.0, 0.4, 0.5, 1.3, 2.0, 2.0, 2.0], dtype=F64) + 1.7e9
    src = BSpline(unit_dq((2, 6), gen, scale=2.0).float(), degree=2, knots=k, form=form)
    with torch.no_grad():  # a raw tensor off the manifold, as after training
        src.parametrizations.ctrl.original.mul_(1.3)
    state = src.state_dict()
    dst = BSpline.from_state_dict(state)
    assert isinstance(dst, Curve)
    assert (dst.degree, dst.form, dst.n_ctrl, dst.domain) == (2, form, 6, src.domain)
    assert dst.control_points.dtype == torch.float32
    t = 1.7e9 + torch.linspace(0.0, 2.0, 9, dtype=F64)
    assert torch.equal(dst(t), src(t))
    assert torch.equal(dst.knots, src.knots)
    bez = Bezier(unit_dq((5,), gen), domain=(3.0, 4.5))
    assert torch.equal(Bezier.from_state_dict(bez.state_dict())(t[:1] * 0 + 4.0),
                       bez(t[:1] * 0 + 4.0))
    with pytest.raises(ValueError, match=r"from_state_dict: expected a state_dict of "
                                         r"nn.BSpline"):
        BSpline.from_state_dict({"weight": torch.zeros(3)})
    with pytest.raises(TypeError, match="mapping"):
        BSpline.from_state_dict([1, 2])
    with pytest.raises(ValueError, match="degree-2 spline.*from_state_dict"):
        BSpline(dq.identity((6,)), degree=3).load_state_dict(state)


def test_torch_save_of_a_whole_module(gen):
    """torch.save(module) was refused (parametrized modules do not pickle)."""
    for src in (BSpline(near_chain(6, gen), knots=knots_on(6, 3, 2.0, 5.0), form="cumulative",
                        check=False),
                Bezier(near_chain(4, gen), domain=(2.0, 5.0), extrapolate=True)):
        buf = io.BytesIO()
        torch.save(src, buf)
        buf.seek(0)
        dst = torch.load(buf, weights_only=False)
        assert type(dst).__name__ == type(src).__name__
        assert (dst.check, dst.extrapolate, dst.domain) == (src.check, src.extrapolate,
                                                           src.domain)
        t = torch.linspace(2.0, 5.0, 7, dtype=F64)
        assert torch.equal(dst(t), src(t))


# ----------------------------------------------------------------------------- forms

@pytest.mark.parametrize("form", ["cumulative", "split"])
def test_form_is_state_and_every_evaluation_follows_it(gen, form):
    """BSpline(form=...) evaluates, differentiates and accepts ctrl= in its form; the form
    is saved and loaded; an unknown form is a clear ValueError."""
    ctrl, k = near_chain(7, gen), knots_on(7, 3, 0.0, 3.0)
    t = torch.linspace(0.0, 3.0, 11, dtype=F64)
    spline = BSpline(ctrl, knots=k, form=form)
    ref = curves.bspline_derivatives(ctrl, t, order=2, knots=k, form=form)
    other = curves.bspline(ctrl, t, knots=k)
    assert (ref[0] - other).abs().max() > 1e-4  # the forms differ
    torch.testing.assert_close(spline(t), ref[0], rtol=0, atol=1e-12)
    for a, b in zip(spline.derivatives(t, order=2), ref, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-10)
    moved = near_chain(7, gen)
    torch.testing.assert_close(spline(t, ctrl=moved),
                               curves.bspline(moved, t, knots=k, form=form),
                               rtol=0, atol=1e-12)
    gyro, _ = spline.imu(t)
    torch.testing.assert_close(gyro, curves.imu(*ref)[0], rtol=0, atol=1e-10)
    dst = BSpline(dq.identity((7,), dtype=F64))
    dst.load_state_dict(spline.state_dict())
    assert dst.form == form
    with pytest.raises(ValueError, match=r"^nn\.BSpline: form must be 'de_boor'.*got 'kkS'"):
        BSpline(ctrl, form="kkS")
    with pytest.raises(ValueError, match=r"^curves\.bspline: form must be"):
        curves.bspline(ctrl, t, form=None)
    with pytest.raises(ValueError, match=r"from_poses: form must be"):
        BSpline.from_poses(*dq.to_rt(ctrl), torch.arange(7.0, dtype=F64), n_ctrl=4,
                           form="x")


@pytest.mark.parametrize("form", ["de_boor", "cumulative"])
def test_from_poses_is_exact_on_a_constant_screw_motion(form):
    """Both forms linearize to the Euclidean B-spline in a chart: the least-squares start
    reproduces a constant screw motion exp(t xi) (pytransform3d's exponential) exactly."""
    import pytransform3d.transformations as pt

    xi = np.array([0.3, -0.2, 0.5, 1.0, 0.4, -0.3])
    times = torch.linspace(0.0, 4.0, 41, dtype=F64)
    T = np.stack([pt.transform_from_exponential_coordinates(s * xi) for s in times.tolist()])
    spline = BSpline.from_matrices(torch.from_numpy(T), times, n_ctrl=9, form=form)
    assert spline.form == form
    s = torch.linspace(0.0, 4.0, 17, dtype=F64)
    ref = np.stack([pt.transform_from_exponential_coordinates(v * xi) for v in s.tolist()])
    np.testing.assert_allclose(dq.to_matrix(spline(s)).detach().numpy(), ref, atol=1e-9)


def test_time_model_is_one_object(gen):
    """The layers' time lives in one object: origin, relative knots, domain and Greville
    abscissae agree with the absolute knots."""
    k = knots_on(6, 2, 1.7e9, 1.7e9 + 10.0)
    spline = BSpline(dq.identity((6,), dtype=F64), degree=2, knots=k)
    tm = spline.time_model
    assert tm.origin == 1.7e9 and tm.degree == 2
    assert tm.domain() == spline.domain == (1.7e9, 1.7e9 + 10.0)
    ref = np.array([k[j + 1:j + 3].mean().item() for j in range(6)])
    np.testing.assert_allclose(spline.greville().numpy(), ref, rtol=0, atol=1e-6)
    assert math.isclose(Bezier(dq.identity((3,)), domain=(2.0, 6.0)).greville()[1].item(), 4.0)


def test_time_model_holds_per_trajectory_origins_and_knots():
    """The time model is built for batches of trajectories with their own times: (B, K)
    knots and (B, 1) origins give, row by row, the spans, local parameters, De Boor levels
    and checks of each trajectory's own time model; the spans agree with numpy's
    searchsorted on each row's knots."""
    from torch_dq._time import KnotDomain

    rows = [curves.clamped_uniform_knots(6, 3, dtype=F64),
            3.0 * torch.tensor([0, 0, 0, 0, 0.2, 0.7, 1, 1, 1, 1], dtype=F64)]
    origin = torch.tensor([[10.0], [1.7e9]], dtype=F64)
    batched = KnotDomain(torch.stack(rows), 3, origin)
    t = torch.tensor([[10.1, 10.5, 11.0], [1.7e9, 1.7e9 + 1.0, 1.7e9 + 3.0]], dtype=F64)
    rel = batched.prepare("test", t, F64, check=True, extrapolate=False, knots="knots",
                          fix="inside")
    r = batched.span(rel)
    for i, k in enumerate(rows):
        one = KnotDomain(k, 3, float(origin[i]))
        rel_i = one.relative(t[i], F64)
        torch.testing.assert_close(rel[i], rel_i, rtol=0, atol=0)
        kn = k.numpy()
        ref = np.minimum(np.searchsorted(kn, rel_i.numpy(), side="right") - 1,
                         np.searchsorted(kn, kn[-4], side="left") - 1)
        assert r[i].tolist() == ref.tolist()
        _, u, slope = batched.locate(rel, F64)
        _, u_i, slope_i = one.locate(rel_i, F64)
        torch.testing.assert_close(u[i], u_i, rtol=0, atol=0)
        for (a, s), (a_i, s_i) in zip(batched.de_boor_levels(rel, r, F64),
                                      one.de_boor_levels(rel_i, one.span(rel_i), F64),
                                      strict=True):
            torch.testing.assert_close(a[i], a_i, rtol=0, atol=0)
            torch.testing.assert_close(s[i], s_i, rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"domain of trajectory \(0,\) \[10, 11\], got values "
                                         r"in \[15\.1, 16\]; inside$"):
        batched.prepare("test", t + 5.0, F64, check=True, extrapolate=False, knots=None,
                        fix="inside")


def test_times_whose_dtype_cannot_resolve_the_domain_raise():
    """float32 UNIX seconds (steps of 128 s on a 30 s domain) were accepted silently (all
    rounded onto one end); now a ValueError says to pass float64."""
    k = knots_on(5, 3, 1.7e9, 1.7e9 + 30.0)
    spline = BSpline(dq.identity((5,)), knots=k)
    t64 = torch.tensor([1.7e9 + 3.0], dtype=F64)
    assert spline(t64).shape == (1, 8)
    for call in (lambda: spline(t64.float()), lambda: spline.derivatives(t64.float()),
                 lambda: curves.bspline(dq.identity((5,)), t64.float(), knots=k)):
        with pytest.raises(ValueError, match=r"t is torch\.float32, whose values near "
                                             r"1700000030 are 128 apart.*pass t as "
                                             r"torch\.float64"):
            call()
    # narrow dtypes near 0 are the caller's choice of precision: accepted
    for low in (torch.float16, torch.bfloat16):
        assert curves.bspline(dq.identity((5,)).to(low), torch.rand(4).to(low)).shape == (4, 8)


def test_repr_names_the_layer():
    assert repr(BSpline(dq.identity((5,)))).startswith("BSpline(\n  n_ctrl=5, degree=3")
    assert repr(Bezier(dq.identity((3,)))).startswith("Bezier(")


def test_from_poses_chooses_n_ctrl_from_the_data(gen):
    """n_ctrl=None (the default) asks the knot chooser instead of a silent 8: a motion with
    detail every ~0.5 s over 20 s gets more than 8 control points, and the fit is close."""
    s = torch.linspace(0.0, 20.0, 401, dtype=F64)
    xi = torch.stack((0.3 * torch.sin(3 * s), 0.2 * torch.cos(2 * s), 0.1 * s,
                      torch.sin(s), 0.5 * s, torch.cos(4 * s)), -1)
    x = dq.exp(xi)
    spline = BSpline.from_dualquats(x, s)
    assert 8 < spline.n_ctrl <= 401
    with torch.no_grad():
        err = (dq.to_rt(spline(s))[1] - dq.to_rt(x)[1]).norm(dim=-1).max()
    assert err < 0.05
    with pytest.raises(ValueError, match="n_ctrl=None chooses the knots from one trajectory"):
        BSpline.from_dualquats(torch.stack((x, x)), s)


@pytest.mark.parametrize("bad, message", [
    ((2.0, 1.0), r"domain must be two finite times t0 < t1, got \(2\.0, 1\.0\)$"),
    ((0.0, math.nan), r"domain must be two finite times t0 < t1, got \(0\.0, nan\)$"),
    ((0.0, 1.0, 2.0), r"expected domain to be \(t0, t1\), two real numbers or a \(2,\) tensor"),
    ("ab", r"expected domain to be \(t0, t1\), two real numbers or a \(2,\) tensor, got 'ab'"),
    ((0.0, True), r"expected domain to be \(t0, t1\)"),
    (torch.zeros(3, dtype=F64), r"expected a \(2,\) tensor for domain, got shape \(3,\)$"),
])
def test_one_parser_of_time_spans(bad, message):
    """curves.bezier's domain, the layers' domain and clamped_uniform_knots' domain go through
    one parser (_time.time_pair): the same input gives the same message everywhere."""
    c = dq.identity((3,), dtype=F64)
    t = torch.tensor([0.5], dtype=F64)
    calls = {"curves.bezier": lambda: curves.bezier(c, t, domain=bad),
             "nn.Bezier": lambda: Bezier(c, domain=bad),
             "curves.clamped_uniform_knots": lambda: curves.clamped_uniform_knots(
                 4, 3, domain=bad)}
    for fn, call in calls.items():
        with pytest.raises(ValueError, match="^" + re.escape(fn) + ": " + message):
            call()
    with pytest.raises(ValueError, match=r"^nn\.BSpline: time_range must be two finite times"), \
            pytest.warns(DeprecationWarning):
        BSpline(c, degree=2, time_range=(1.0, 1.0))
    with pytest.raises(TypeError, match=r"^nn\.Bezier: expected a floating-point tensor for "
                                        r"domain"):
        Bezier(c, domain=torch.tensor([0, 1]))


def test_local_times_against_numpy():
    """KnotDomain.local_times is t - origin - u_r (numpy, float64), clamped to the span,
    for shared and per-trajectory knots, with leading copies of the samples."""
    from torch_dq._time import KnotDomain
    k = np.array([0.0, 0, 0, 0, 1.5, 2.0, 4.0, 5.0, 5, 5, 5])
    origin = 1.7e9
    t = origin + np.array([0.0, 0.7, 1.5, 3.9, 5.0, 5.0 + 1e-6])
    r = np.minimum(np.searchsorted(k, t - origin, side="right") - 1, 6)
    ref = np.clip((t - origin) - k[r], 0.0, k[r + 1] - k[r])
    one = KnotDomain(torch.from_numpy(k), 3, origin)
    got = one.local_times(torch.from_numpy(t), torch.from_numpy(r))
    np.testing.assert_allclose(got.numpy(), ref, rtol=0, atol=1e-15)
    assert got[-1] == k[7] - k[6]  # a time past the end: clamped onto its span
    rows = torch.from_numpy(np.stack([k, 2.0 * k]))
    both = KnotDomain(rows, 3, torch.tensor([[origin], [origin - 1.0]], dtype=F64))
    tt = torch.from_numpy(t[:4]).expand(3, 2, 4)  # 3 copies of 2 trajectories' samples
    rr = torch.tensor([[3, 3, 4, 5], [3, 3, 3, 4]])
    got = both.local_times(tt, rr)
    rel = np.stack([t[:4] - origin, t[:4] - origin + 1.0])
    ref = np.clip(rel - np.take_along_axis(rows.numpy(), rr.numpy(), 1), 0.0,
                  np.diff(rows.numpy(), axis=1)[np.arange(2)[:, None], rr.numpy()])
    assert got.shape == (3, 2, 4)
    np.testing.assert_allclose(got.numpy(), np.broadcast_to(ref, (3, 2, 4)), rtol=0, atol=1e-15)


def test_resolution_rule_against_numpy_spacing():
    """time_step is numpy's spacing of the dtype at |t|; unresolved refuses float32 UNIX
    seconds and coarse float32 times far from 0, never float64 nor narrow dtypes near 0."""
    from torch_dq._time import MIN_RESOLUTION, time_step, unresolved
    for dtype, np_dtype in ((torch.float32, np.float32), (torch.float16, np.float16)):
        for x in (1.0, 3.0, 1000.5, 6.0e4):
            assert float(time_step(dtype, x)) == float(np.spacing(np_dtype(x)))
    assert float(time_step(torch.float32, 0.0)) == 0.0
    assert bool(unresolved(torch.float32, 1.7e9 + 30.0, 30.0))  # steps of 128 s
    assert not bool(unresolved(torch.float64, 1.7e9 + 30.0, 1e-3))
    assert not bool(unresolved(torch.bfloat16, 1.0, 1.0))  # near 0: the caller's choice
    step = float(np.spacing(np.float32(1e4)))  # 9.8e-4
    assert bool(unresolved(torch.float32, 1e4, 0.99 * step / MIN_RESOLUTION))
    assert not bool(unresolved(torch.float32, 1e4, 1.01 * step / MIN_RESOLUTION))


def test_outside_is_the_domain_check():
    """KnotDomain.outside flags exactly the times that check refuses (tolerance included)."""
    from torch_dq._time import KnotDomain
    dom = KnotDomain(torch.tensor([0.0, 0, 1, 2, 2], dtype=F64), 1, 100.0)
    tol = float(dom.tolerance(F64))
    t = torch.tensor([100.0 - 2 * tol, 100.0 - 0.5 * tol, 101.0, 102.0 + 0.5 * tol,
                      102.0 + 2 * tol], dtype=F64)
    assert dom.outside(t).tolist() == [True, False, False, False, True]
    for ti, out in zip(t, dom.outside(t).tolist(), strict=True):
        rel = dom.relative(ti[None], F64)
        if out:
            with pytest.raises(ValueError, match="must lie in"):
                dom.check("f", rel, knots=None, extrapolate=False, fix="x")
        else:
            dom.check("f", rel, knots=None, extrapolate=False, fix="x")

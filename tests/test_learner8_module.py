"""learner8: ``nn.BSpline`` / ``nn.Bezier`` as a learning pipeline uses them: batch shapes
and broadcasting between control-point and time batches (against element-by-element
calls), ``nn.Module`` behaviour (state_dict, dtype moves, parameters, deepcopy, pickling,
CUDA), and bad inputs (a clear error naming the argument, never garbage; inputs unchanged).
"""

import copy
import io
import itertools
import pickle

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from tests.test_learner8_pipeline import FORMS, REFERENCE, mats_np
from torch_dq import nn as tnn

F64 = torch.float64
SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


def poses(*shape, seed=0, dtype=F64):
    g = torch.Generator().manual_seed(seed)
    return dq.exp(0.5 * torch.randn(*shape, 6, generator=g, dtype=F64)).to(dtype)


def time_shapes(cs):
    """Time batches against control batch ``cs``: shared, equal, and broadcasting ones."""
    out = [(), cs]
    if len(cs) >= 2:
        out.append((1,) * (len(cs) - 1) + cs[-1:])  # broadcast over the leading dims
        out.append((4,) + (1,) * len(cs))  # one more leading dim than the control points
    return out


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("cs", SHAPES, ids=str)
def test_batches_broadcast_like_elementwise_calls(form, cs):
    """``module(t)``, ``derivatives`` and ``imu`` with control points ``cs + (n, 8)`` and
    times ``ts + (T,)``: shape ``broadcast(cs, ts) + (T, ...)``, each element equal to the
    call on that element alone (checked against the numpy formula for the poses)."""
    n, T = 6, 3
    ctrl = poses(*cs, n)
    for ts in time_shapes(cs):
        g = torch.Generator().manual_seed(len(ts))
        t = torch.rand(*ts, T, generator=g, dtype=F64)
        m = tnn.BSpline(ctrl, form=form)
        batch = torch.broadcast_shapes(cs, ts)
        x = m(t)
        _, dx = m.derivatives(t, 1)
        gyro, _ = m.imu(t)
        assert x.shape == (*batch, T, 8) and dx.shape == x.shape
        assert gyro.shape == (*batch, T, 3)
        c_all, t_all = ctrl.expand((*batch, n, 8)), t.expand((*batch, T))
        for idx in itertools.islice(np.ndindex(*batch), 0, None, 3):
            one = tnn.BSpline(c_all[idx], form=form)
            ref = REFERENCE[form](mats_np(c_all[idx]), one.knots.numpy(), 3,
                                  t_all[idx].numpy())
            assert np.abs(mats_np(x[idx]) - ref).max() <= 1e-9
            assert torch.allclose(dx[idx], one.derivatives(t_all[idx], 1)[1], atol=1e-12)
            assert torch.allclose(gyro[idx], one.imu(t_all[idx])[0], atol=1e-12)


@pytest.mark.parametrize("cs", SHAPES, ids=str)
def test_bezier_batches(cs):
    ctrl = poses(*cs, 4)
    t = torch.rand((4,) + (1,) * len(cs) + (7,), dtype=F64)
    m = tnn.Bezier(ctrl, domain=(2.0, 3.0))
    x = m(t + 2.0)
    assert x.shape == (4, *cs, 7, 8)
    assert bool(dq.is_unit(x).all())


# ----------------------------------------------------------------------------- nn.Module

@pytest.mark.parametrize("form", FORMS)
def test_module_round_trips(form):
    """state_dict -> from_state_dict / load_state_dict (form, degree, knots and a UNIX-time
    origin restored), deepcopy, pickle, torch.save, .double() / .to(float32), parameters."""
    knots = 1.7e9 + torch.tensor([0.0, 0, 0, 0, 0.3, 0.6, 1, 1, 1, 1], dtype=F64) * 10
    m = tnn.BSpline(poses(2, 6, dtype=torch.float32), knots=knots, form=form)
    t = 1.7e9 + torch.tensor([0.0, 2.5, 6.0, 10.0], dtype=F64)
    x = m(t)
    back = tnn.BSpline.from_state_dict(m.state_dict())
    assert back.form == form and back.degree == 3 and torch.equal(back(t), x)
    other = tnn.BSpline(poses(2, 6, seed=1, dtype=torch.float32), form="de_boor")
    other.load_state_dict(m.state_dict())
    assert other.form == form and torch.equal(other(t), x)
    for copied in (copy.deepcopy(m), pickle.loads(pickle.dumps(m))):
        assert torch.equal(copied(t), x)
    buf = io.BytesIO()
    torch.save(m, buf)
    buf.seek(0)
    assert torch.equal(torch.load(buf, weights_only=False)(t), x)
    m64 = copy.deepcopy(m).double()
    assert m64(t).dtype == F64 and torch.equal(m64.knots, m.knots)
    assert float((m64(t) - x.double()).detach().abs().max()) <= 1e-6
    assert copy.deepcopy(m64).to(torch.float32)(t).dtype == torch.float32
    params = list(m.parameters())
    assert len(params) == 1 and params[0].shape == (2, 6, 8)
    opt = torch.optim.SGD(m.parameters(), lr=0.1)
    m(t).sum().backward()
    opt.step()
    assert not torch.equal(m(t), x)
    assert bool(dq.is_unit(m.control_points).all())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("form", FORMS)
def test_cuda_matches_cpu(form):
    m = tnn.BSpline(poses(6), form=form)
    t = torch.rand(9, dtype=F64)
    assert torch.allclose(copy.deepcopy(m).cuda()(t.cuda()).cpu(), m(t), atol=1e-12)


# ----------------------------------------------------------------------------- bad inputs

BAD_CTOR = [
    (lambda: torch.randn(6, 7), {}, ValueError, r"nn\.BSpline: .*ctrl"),
    (lambda: torch.zeros(6, 8, dtype=torch.int64), {}, TypeError, r"nn\.BSpline: .*ctrl"),
    (lambda: poses(3), {}, ValueError, r"degree must be < the number of control points"),
    (lambda: poses(6), {"degree": 0}, ValueError, r"degree"),
    (lambda: poses(6), {"degree": 2.0}, ValueError, r"degree"),
    (lambda: poses(6), {"form": "bspline"}, ValueError, r"form must be"),
    (lambda: poses(6), {"knots": torch.linspace(0, 1, 9)}, ValueError, r"knots"),
    (lambda: poses(6), {"knots": torch.linspace(1, 0, 10)}, ValueError, r"non-decreasing"),
    (lambda: poses(6), {"knots": torch.arange(10)}, TypeError, r"knots"),
]


@pytest.mark.parametrize("make, kwargs, kind, match", BAD_CTOR)
def test_constructor_rejects_bad_arguments(make, kwargs, kind, match):
    with pytest.raises(kind, match=match):
        tnn.BSpline(make(), **kwargs)


@pytest.mark.parametrize("cls", [tnn.BSpline, tnn.Bezier])
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "zero"])
def test_constructor_rejects_non_poses(cls, bad):
    """Regression: a NaN/inf control point, or one with a zero real part, was accepted and
    turned the module's poses and every later gradient into NaN; now a ValueError names the
    control point, at construction and on assignment to ``control_points``."""
    c = poses(2, 6)
    if bad == "zero":
        c[1, 3, :4] = 0.0
    else:
        c[1, 3, 6] = bad
    with pytest.raises(ValueError, match=r"nn\.(BSpline|Bezier): ctrl\[1, 3\]"):
        cls(c)
    m = cls(poses(2, 6))
    with pytest.raises(ValueError, match=r"control_points\[1, 3\]"):
        m.control_points = c


@pytest.mark.parametrize("form", FORMS)
def test_calls_reject_bad_arguments(form):
    m = tnn.BSpline(poses(6), form=form)
    t = torch.tensor([0.2, 0.7], dtype=F64)
    cases = [
        (lambda: m(torch.tensor([0, 1])), TypeError, r"forward: .*t"),
        (lambda: m(torch.tensor(0.5)), ValueError, r"forward: .*t"),
        (lambda: m([0.5]), TypeError, r"forward: .*t"),
        (lambda: m(torch.tensor([1.1])), ValueError, r"domain"),
        (lambda: m(torch.tensor([-0.1]), extrapolate=False), ValueError, r"domain"),
        (lambda: m(t, ctrl=poses(7)), ValueError, r"forward: .*ctrl"),
        (lambda: m(t, ctrl=torch.randn(6, 7)), ValueError, r"forward: .*ctrl"),
        (lambda: m(t.view(2, 1), ctrl=poses(3, 6)), ValueError, r"shape|broadcast"),
        (lambda: m.derivatives(t, 4), ValueError, r"order"),
        (lambda: m.kinematics(t, frame="Body"), ValueError, r"frame"),
        (lambda: m.imu(t, gravity=(0.0, 0.0)), ValueError, r"gravity"),
    ]
    for call, kind, match in cases:
        with pytest.raises(kind, match=match):
            call()


@pytest.mark.parametrize("form", FORMS)
def test_no_input_modified_and_non_finite_stay_local(form):
    """Inputs are never written; a NaN time or a NaN predicted control point makes its own
    outputs NaN (never finite garbage) and leaves the other trajectories of the batch
    finite, values and gradients; a non-unit predicted control point is projected."""
    c = poses(2, 6)
    t = torch.tensor([0.0, 0.4, 1.0], dtype=F64)
    c0, t0 = c.clone(), t.clone()
    m = tnn.BSpline(c, form=form)
    m(t), m.derivatives(t, 3), m.imu(t), m(t, ctrl=3.0 * c)
    assert torch.equal(c, c0) and torch.equal(t, t0)
    assert torch.allclose(m(t, ctrl=3.0 * c), m(t), atol=1e-12)
    x = m(torch.tensor([0.2, float("nan"), 0.7], dtype=F64))
    assert torch.isfinite(x[:, [0, 2]]).all() and torch.isnan(x[:, 1]).all()
    bad = c.clone()
    bad[1, 2, 0] = float("nan")
    bad.requires_grad_()
    y = m(t, ctrl=bad)
    assert torch.isfinite(y[0]).all() and torch.isnan(y[1]).any()
    y[0].sum().backward()
    assert torch.isfinite(bad.grad[0]).all()


@pytest.mark.parametrize("form", FORMS)
def test_unchecked_times_outside_give_nan(form):
    """With ``check=False`` times beyond the domain give NaN poses and derivatives (never a
    silent extrapolation); times within the rounding tolerance of a UNIX-time domain are
    evaluated at its ends, in a float32 module."""
    m = tnn.BSpline(poses(7), form=form, check=False)
    t = torch.tensor([-0.5, 0.5, 1.5], dtype=F64)
    for out in (m(t), *m.derivatives(t, 2)):
        assert torch.isnan(out[[0, 2]]).all(-1).all() and torch.isfinite(out[1]).all()
    knots = 1.7e9 + torch.tensor([0.0, 0, 0, 0, 2.5, 5, 7.5, 10, 10, 10, 10], dtype=F64)
    m32 = tnn.BSpline(poses(7, dtype=torch.float32), knots=knots, form=form)
    ends = torch.tensor([1.7e9, 1.7e9 + 10], dtype=F64)
    assert torch.equal(m32(ends + torch.tensor([-1e-7, 1e-7], dtype=F64)), m32(ends))
    with pytest.raises(ValueError, match="domain"):
        m32(ends - 1e-3)

"""Audit of torch_dq.curves (API.md, "Non-finite values"): a NaN time, or one beyond the
domain with ``check=False``, gives NaN at its own sample and must not touch the others. Their
values are checked against pytransform3d's sclerp (De Casteljau written in the test), and the
gradient of a loss over the finite samples against the same loss with the bad sample absent:
evaluating the NaN time sent ``0 * NaN`` into the gradients of the shared control points."""

import itertools
import math

import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch

import torch_dq.dualquat as dq
from torch_dq import curves
from torch_dq.nn import BSpline

F64 = torch.float64
FORMS = ["de_boor", "cumulative", "split"]


def _ctrl(n):
    gen = torch.Generator().manual_seed(5)
    return dq.exp(0.6 * torch.randn(n, 6, generator=gen, dtype=F64))


def _ref_bezier(ctrl, s):
    """De Casteljau with pytransform3d's sclerp, each pair sign-aligned first."""
    pts = list(ctrl.numpy())
    while len(pts) > 1:
        pts = [pt.dual_quaternion_sclerp(a, b if a[:4] @ b[:4] >= 0 else -b, s)
               for a, b in itertools.pairwise(pts)]
    return pts[0]


def _grads(fn, ctrl, t, keep):
    c = ctrl.clone().requires_grad_(True)
    outs = fn(c, t)
    outs = outs if isinstance(outs, tuple) else (outs,)
    loss = sum((o[keep] * torch.linspace(0.5, 1.5, 8, dtype=F64)).sum() for o in outs)
    return outs, torch.autograd.grad(loss, c)[0]


CASES = [(f"bspline-{f}", lambda c, t, f=f: curves.bspline(c, t, form=f), 6) for f in FORMS]
CASES += [(f"bspline_derivatives-{f}",
           lambda c, t, f=f: curves.bspline_derivatives(c, t, order=2, form=f), 6)
          for f in FORMS]
CASES += [("bezier", curves.bezier, 3),
          ("bezier_derivatives", lambda c, t: curves.bezier_derivatives(c, t, order=3), 3),
          ("BSpline.forward", lambda c, t: BSpline(c.detach())(t, ctrl=c), 6)]


@pytest.mark.parametrize(("name", "fn", "n"), CASES, ids=[c[0] for c in CASES])
def test_nan_time_does_not_poison_other_samples(name, fn, n):
    ctrl = _ctrl(n)
    t = torch.tensor([0.2, math.nan, 0.7], dtype=F64)
    keep = torch.tensor([True, False, True])
    outs, grad = _grads(fn, ctrl, t, keep)
    _, ref_grad = _grads(fn, ctrl, t[keep], torch.tensor([True, True]))
    for o in outs:
        assert torch.isnan(o[1]).all() and torch.isfinite(o[keep]).all()
    assert torch.isfinite(grad).all()  # NaN in the span's control points before the fix
    torch.testing.assert_close(grad, ref_grad, rtol=1e-12, atol=1e-12)
    if name == "bezier":
        for k in (0, 2):
            ref = _ref_bezier(ctrl, float(t[k]))
            got = outs[0][k].detach().numpy()
            assert min(np.abs(got - ref).max(), np.abs(got + ref).max()) < 1e-14


@pytest.mark.parametrize("form", FORMS)
def test_time_beyond_domain_without_checks_is_nan_alone(form):
    ctrl = _ctrl(6)
    t = torch.tensor([0.2, 1.5, 0.7], dtype=F64)
    keep = torch.tensor([True, False, True])
    outs, grad = _grads(lambda c, s: curves.bspline(c, s, form=form, check=False), ctrl, t,
                        keep)
    assert torch.isnan(outs[0][1]).all() and torch.isfinite(grad).all()

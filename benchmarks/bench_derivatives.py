"""Section ``derivatives``: order-2 time derivatives of the cubic B-spline of each form
against the pose alone of the same form."""

from __future__ import annotations

import functools

import torch
from _bench import CURVES_ERROR, N_CTRL, Bench, curves, err, grad
from bench_bspline import FORMS, form_inputs


def run(b: Bench, dtype):
    """Order-2 time derivatives of the cubic B-spline (both forms) against the pose alone."""
    T = b.sizes["bspline"]
    if curves is None or not hasattr(curves, "bspline_derivatives"):
        b.add("bspline derivatives", dtype, T, "not available", 0, 0,
              note=CURVES_ERROR or "curves.bspline_derivatives not available")
        return
    for form in FORMS:
        _rows(b, dtype, T, form)


def _rows(b: Bench, dtype, T: int, form: str):
    label = FORMS[form][0]
    ctrl, t, knots = form_inputs(T, dtype, b.device, form)
    cg = ctrl.clone().requires_grad_()
    size = torch.finfo(dtype).bits // 8
    pose_fn = functools.partial(curves.bspline, knots=knots, form=form)
    der_fn = functools.partial(curves.bspline_derivatives, order=2, knots=knots, form=form)

    def derivatives_loss(c):
        return sum(x.sum() for x in der_fn(c, t))

    try:
        pose = b.time(lambda: pose_fn(ctrl, t))
        pose_fb = b.time(lambda: grad(pose_fn(cg, t), (cg,)))
        der = b.time(lambda: der_fn(ctrl, t))
        der_fb = b.time(lambda: torch.autograd.grad(derivatives_loss(cg), (cg,)))
    except Exception as exc:
        b.add(f"{label} order-2 derivatives", dtype, T, err(exc), 0, T)
        return
    out_bytes = 3 * 8 * T * size
    for kind, ms, ref, bwd in (("fwd", der, pose, False), ("fwd+bwd", der_fb, pose_fb, True)):
        note = (f"(x, dx/dt, d2x/dt2), {N_CTRL} control poses, cubic; "
                f"{ms / ref:.2f} x the pose-only time" + (" (goal <= 4)" if bwd else "")
                + ("; grad of the sum of all three wrt control points" if bwd else ""))
        b.add(f"{label} order-2 derivatives {kind}", dtype, T, ms,
              out_bytes * (2 if bwd else 1), T, "torch_dq pose only", ref, note=note)

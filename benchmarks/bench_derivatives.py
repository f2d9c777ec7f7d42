"""Section ``derivatives``: order-2 time derivatives of the cubic B-spline against the pose
alone."""

from __future__ import annotations

import torch

from _bench import Bench, CURVES_ERROR, N_CTRL, bspline_inputs, curves, err, grad



def run(b: Bench, dtype):
    """Order-2 time derivatives of the cubic B-spline against the pose alone."""
    T = b.sizes["bspline"]
    if curves is None or not hasattr(curves, "bspline_derivatives"):
        b.add("bspline derivatives", dtype, T, "not available", 0, 0,
              note=CURVES_ERROR or "curves.bspline_derivatives not available")
        return
    ctrl, t = bspline_inputs(T, dtype, b.device)
    cg = ctrl.clone().requires_grad_()
    size = torch.finfo(dtype).bits // 8

    def derivatives_loss(c):
        return sum(x.sum() for x in curves.bspline_derivatives(c, t, order=2))

    try:
        pose = b.time(lambda: curves.bspline(ctrl, t))
        pose_fb = b.time(lambda: grad(curves.bspline(cg, t), (cg,)))
        der = b.time(lambda: curves.bspline_derivatives(ctrl, t, order=2))
        der_fb = b.time(lambda: torch.autograd.grad(derivatives_loss(cg), (cg,)))
    except Exception as exc:
        b.add("bspline derivatives", dtype, T, err(exc), 0, T)
        return
    out_bytes = 3 * 8 * T * size
    for label, ms, ref, bwd in (("bspline order-2 derivatives fwd", der, pose, False),
                                ("bspline order-2 derivatives fwd+bwd", der_fb, pose_fb, True)):
        note = (f"(x, dx/dt, d2x/dt2), {N_CTRL} control poses, cubic; "
                f"{ms / ref:.2f} x the pose-only time" + (" (goal <= 4)" if bwd else "")
                + ("; grad of the sum of all three wrt control points" if bwd else ""))
        b.add(label, dtype, T, ms, out_bytes * (2 if bwd else 1), T,
              "torch_dq pose only", ref, note=note)

"""Section ``bezier``: De Casteljau of degrees 3 and 7 (no peer: the copy-limit column)."""

from __future__ import annotations

import torch

from _bench import BEZIER_TIMES, Bench, CURVES_ERROR, curves, err, fit_size, grad, rand_dq, seeded



def run(b: Bench, dtype):
    C = b.sizes["bezier"]
    if curves is None:
        b.add("bezier", dtype, C * BEZIER_TIMES, "not available", 0, 0, note=CURVES_ERROR)
        return
    dev = b.device
    size = torch.finfo(dtype).bits // 8
    t = torch.linspace(0.0, 1.0, BEZIER_TIMES, dtype=dtype, device=dev)
    for degree in (3, 7):
        def inputs(m, degree=degree):
            g = seeded(dev, 4 + degree)
            return rand_dq(m * (degree + 1), dtype, dev, g).reshape(m, degree + 1, 8)

        def fwdbwd_probe(m, degree=degree):
            ctrl = inputs(m).requires_grad_()
            grad(curves.bezier(ctrl, t), (ctrl,))

        Cd = fit_size(b, C, 1024, fwdbwd_probe)
        ctrl = inputs(Cd)
        n_out = Cd * BEZIER_TIMES
        cbytes = Cd * (degree + 1) * 8 * size
        fwd_bytes = cbytes + BEZIER_TIMES * size + 8 * n_out * size
        fb_bytes = fwd_bytes + 8 * n_out * size + cbytes
        note = f"{Cd} curves x {BEZIER_TIMES} times; no peer has Bezier: see copy-limit fraction"
        try:
            ours = b.time(lambda ctrl=ctrl: curves.bezier(ctrl, t))
            b.add(f"bezier deg {degree} fwd", dtype, n_out, ours, fwd_bytes, n_out, note=note)
            cg = ctrl.clone().requires_grad_()
            ours_fb = b.time(lambda cg=cg: grad(curves.bezier(cg, t), (cg,)))
            b.add(f"bezier deg {degree} fwd+bwd", dtype, n_out, ours_fb, fb_bytes, n_out,
                  note=note + "; grad wrt control points")
        except Exception as exc:
            b.add(f"bezier deg {degree}", dtype, n_out, err(exc), 0, n_out)

"""Section ``sclerp``: ``dualquat.sclerp`` against pytransform3d and pypose, eager and compiled."""

from __future__ import annotations

import torch

import _peers
from _bench import (
    Bench, compiled_rows, fit_size, grad, max_diff_up_to_sign, peer_time, rand_dq, rand_t, seeded,
    skip_compile,
)

import torch_dq.dualquat as dq


def run(b: Bench, dtype):
    dev = b.device

    def inputs(m, seed=1):
        g = seeded(dev, seed)
        return rand_dq(m, dtype, dev, g), rand_dq(m, dtype, dev, g), rand_t(m, dtype, dev, g)

    def fwdbwd_probe(m):
        a, c, t = (x.requires_grad_() for x in inputs(m))
        grad(dq.sclerp(a, c, t), (a, c, t))

    n = fit_size(b, b.sizes["sclerp"], 1_000_000, fwdbwd_probe)
    a, c, t = inputs(n)
    size = torch.finfo(dtype).bits // 8
    fwd_bytes, fb_bytes = 25 * n * size, 50 * n * size

    # forward, eager
    ours = b.time(lambda: dq.sclerp(a, c, t))
    ptr_ms, ptr_note, ptr_made, _ = peer_time(
        b, "pytransform3d", lambda m: _peers.pytransform3d_sclerp(a[:m], c[:m], t[:m]), n,
        cpu_only=True)
    pp_ms, pp_note, pp_made, _ = peer_time(
        b, "pypose", lambda m: _peers.pypose_sclerp(a[:m], c[:m], t[:m], False), n)
    k = min(n, 2000)
    ref = dq.sclerp(a[:k], c[:k], t[:k])
    for peer, ms, note, made, extra in (
            ("pytransform3d (numpy f64)", ptr_ms, ptr_note, ptr_made, "peer in float64"),
            ("pypose", pp_ms, pp_note, pp_made, "")):
        if made is not None:
            diff = max_diff_up_to_sign(ref, made[1]()[:k])
            note = "; ".join(x for x in (note, extra, f"max|diff| {diff:.1e}") if x)
        b.add("sclerp fwd", dtype, n, ours, fwd_bytes, n, peer, ms, note)

    # forward + backward, eager
    ag, cg, tg = (x.clone().requires_grad_() for x in (a, c, t))
    ours_fb = b.time(lambda: grad(dq.sclerp(ag, cg, tg), (ag, cg, tg)))
    pp_fb, pp_note, _, _ = peer_time(
        b, "pypose", lambda m: _peers.pypose_sclerp(a[:m], c[:m], t[:m], True), n)
    b.add("sclerp fwd+bwd", dtype, n, ours_fb, fb_bytes, n, "pypose", pp_fb, pp_note,
          "grad of sum wrt a, b, t")

    # torch.compile (the documented compiled path), default inductor backend
    if skip_compile(b, dtype, "sclerp [compiled]", n):
        return
    compiled = torch.compile(dq.sclerp)
    compiled_rows(b, dtype, n, "pypose", (
        ("sclerp fwd [compiled]", lambda: compiled(a, c, t), ours, pp_ms, fwd_bytes),
        ("sclerp fwd+bwd [compiled]", lambda: grad(compiled(ag, cg, tg), (ag, cg, tg)),
         ours_fb, pp_fb, fb_bytes)))

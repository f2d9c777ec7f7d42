"""Section ``slerp``: ``quat.slerp`` against roma and scipy."""

from __future__ import annotations

import torch

import _peers
from _bench import Bench, fit_size, grad, max_diff_up_to_sign, peer_time, rand_q, rand_t, seeded

from torch_dq import quat


def run(b: Bench, dtype):
    dev = b.device

    def inputs(m, seed=2):
        g = seeded(dev, seed)
        return rand_q(m, dtype, dev, g), rand_q(m, dtype, dev, g), rand_t(m, dtype, dev, g)

    def fwdbwd_probe(m):
        q0, q1, t = (x.requires_grad_() for x in inputs(m))
        grad(quat.slerp(q0, q1, t), (q0, q1, t))

    n = fit_size(b, b.sizes["slerp"], 1_000_000, fwdbwd_probe)
    q0, q1, t = inputs(n)
    size = torch.finfo(dtype).bits // 8
    ours = b.time(lambda: quat.slerp(q0, q1, t))

    roma_ms, roma_note, roma_made, _ = peer_time(
        b, "roma", lambda m: _peers.roma_slerp(q0[:m], q1[:m], t[:m], False), n)
    if roma_made is not None:
        k = min(n, 2000)
        diff = max_diff_up_to_sign(quat.slerp(q0[:k], q1[:k], roma_made[2]), roma_made[1]()[:k])
        roma_note = "; ".join(x for x in (roma_note, "roma: one t shared by all pairs "
                                          "(0-d steps; see README)", f"max|diff| {diff:.1e}") if x)
    b.add("slerp fwd", dtype, n, ours, 13 * n * size, n, "roma", roma_ms, roma_note)

    sp_ms, sp_note, sp_made, _ = peer_time(
        b, "scipy", lambda m: _peers.scipy_slerp(q0[:m], q1[:m], t[:m]), n, cpu_only=True)
    if sp_made is not None:
        k = min(n, 2000)
        diff = max_diff_up_to_sign(quat.slerp(q0[:k], q1[:k], t[:k]), sp_made[1]()[:k])
        sp_note = "; ".join(x for x in (sp_note, "peer in float64", f"max|diff| {diff:.1e}") if x)
    b.add("slerp fwd", dtype, n, ours, 13 * n * size, n, "scipy Rotation (f64)", sp_ms, sp_note)

    q0g, q1g, tg = (x.clone().requires_grad_() for x in (q0, q1, t))
    ours_fb = b.time(lambda: grad(quat.slerp(q0g, q1g, tg), (q0g, q1g, tg)))
    roma_fb, roma_note, _, _ = peer_time(
        b, "roma", lambda m: _peers.roma_slerp(q0[:m], q1[:m], t[:m], True), n)
    b.add("slerp fwd+bwd", dtype, n, ours_fb, 26 * n * size, n, "roma", roma_fb, roma_note,
          "grad of sum wrt q0, q1, t")

    # The work roma does: one t shared by all pairs (0-d), forward and forward+backward.
    s0 = t[0].clone()
    ours_common = b.time(lambda: quat.slerp(q0, q1, s0))
    b.add("slerp fwd (common t)", dtype, n, ours_common, 12 * n * size, n, "roma", roma_ms,
          roma_note)
    s0g = s0.clone().requires_grad_()
    ours_common_fb = b.time(lambda: grad(quat.slerp(q0g, q1g, s0g), (q0g, q1g, s0g)))
    b.add("slerp fwd+bwd (common t)", dtype, n, ours_common_fb, 24 * n * size, n, "roma",
          roma_fb, roma_note, "grad of sum wrt q0, q1, t")

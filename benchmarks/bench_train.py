"""Section ``train``: one Adam step of a B-spline layer against the same loop on pypose."""

from __future__ import annotations

import torch

import _peers
from _bench import (
    Bench, CURVES_ERROR, N_TRAIN_CTRL, compiled_rows, curves, dqnn, err, peer_time, seeded,
    skip_compile,
)

import torch_dq.dualquat as dq
from torch_dq import losses


def _smooth_motion(n: int, dtype, device, gen) -> torch.Tensor:
    """``n`` control poses of a smooth motion: a random walk of small screw steps."""
    steps = 0.05 * torch.randn(n, 6, generator=gen, dtype=dtype, device=device)
    x = dq.identity(dtype=dtype, device=device)
    out = []
    for xi in dq.exp(steps):
        x = dq.mul(x, xi)
        out.append(x)
    return torch.stack(out)


def run(b: Bench, dtype):
    """One Adam step of a 512-control-point B-spline layer fitted to T timestamped poses."""
    T = b.sizes["train"]
    if curves is None:
        b.add("train step", dtype, T, "not available", 0, 0, note=CURVES_ERROR)
        return
    dev = b.device
    g = seeded(dev, 7)
    truth = _smooth_motion(N_TRAIN_CTRL, dtype, dev, g)
    times = torch.linspace(0.0, 1.0, T, dtype=dtype, device=dev)
    with torch.no_grad():
        target = curves.bspline(truth, times, check=False)
        # start: the true control poses, each moved by a small random screw
        noise = dq.exp(0.02 * torch.randn(N_TRAIN_CTRL, 6, generator=g, dtype=dtype,
                                          device=dev))
        init = dq.mul(truth, noise)

    def make_step(model, loss_fn):
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)

        def step():
            opt.zero_grad(set_to_none=True)
            loss = loss_fn()
            loss.backward()
            opt.step()
        return step

    model = dqnn.BSpline(init.clone(), degree=3, check=False)
    eager_step = make_step(model, lambda: losses.pose_loss(model(times), target))
    note = (f"{N_TRAIN_CTRL} control poses, cubic, {T} timestamped target poses; "
            "losses.pose_loss; Adam lr 1e-3; zero_grad + forward + backward + step")
    try:
        ours = b.time(eager_step)
    except Exception as exc:
        b.add("train step (Adam)", dtype, T, err(exc), 0, T)
        return

    def target_at(count):
        with torch.no_grad():
            grid = torch.linspace(0.0, 1.0, count, dtype=dtype, device=dev)
            return curves.bspline(truth, grid, check=False)

    def make_pp(m):
        k = -(-(m - 1) // (N_TRAIN_CTRL - 3))
        fn, counts["m"] = _peers.pypose_train_step(init, target_at, 1.0 / k)
        return fn, None

    counts = {}
    pp_ms, pp_note, made, m_req = peer_time(b, "pypose", make_pp, T)
    if made is not None:
        pp_ms *= m_req / counts["m"]
        pp_note = "; ".join(x for x in (pp_note, f"pypose fits {counts['m']} poses for "
                                        f"{m_req} asked, time scaled per pose") if x)
    b.add("train step (Adam)", dtype, T, ours, 0, T, "pypose bspline loop", pp_ms,
          pp_note, note)
    if skip_compile(b, dtype, "train step (Adam) [compiled]", T):
        return
    model_c = dqnn.BSpline(init.clone(), degree=3, check=False)
    compiled_loss = torch.compile(lambda: losses.pose_loss(model_c(times), target))
    compiled_rows(b, dtype, T, "pypose bspline loop", (
        ("train step (Adam) [compiled]", make_step(model_c, compiled_loss), ours, pp_ms, 0),))

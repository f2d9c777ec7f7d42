"""torch_dq benchmarks: side-by-side throughput against peers and against a plain copy.

Usage (see benchmarks/README.md)::

    python benchmarks/run.py                 # full CPU run, float32 and float64 (~4 min)
    python benchmarks/run.py --quick         # smoke run, small sizes (< 1 min)
    python benchmarks/run.py --device cuda   # sizes that fill the GPU, HBM bandwidth
    python benchmarks/run.py --sizes sclerp=1e5,bspline=2e4 --json out.json

Every time is the median of ``--repeats`` (>= 5) runs after ``--warmup`` runs, with
``torch.set_num_threads(--threads)`` (default 2), ``time.perf_counter`` and, on CUDA,
``torch.cuda.synchronize()`` around each run.
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import os
import platform
import statistics
import subprocess
import sys
import time
import traceback
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _peers
from _peers import PeerMissing

import torch_dq
import torch_dq.dualquat as dq
from torch_dq import losses, quat

try:
    from torch_dq import curves
    from torch_dq import nn as dqnn
    CURVES_ERROR = None
except ImportError as exc:  # curves.py may not exist yet
    curves = dqnn = None
    CURVES_ERROR = f"torch_dq.curves not available ({exc})"

CPU_SIZES = {"sclerp": 1_000_000, "slerp": 1_000_000, "bspline": 100_000, "bezier": 4096,
             "train": 100_000}
QUICK_SIZES = {"sclerp": 20_000, "slerp": 20_000, "bspline": 5_000, "bezier": 128,
               "train": 5_000}
CUDA_TARGETS = {"sclerp": 100_000_000, "slerp": 100_000_000, "bspline": 10_000_000,
                "bezier": 262_144, "train": 10_000_000}
# Slow peers are timed on at most this many items and scaled linearly (said in the note).
PEER_CAP = {"pypose": 100_000, "pytransform3d": 100_000, "scipy": 100_000}
QUICK_PEER_CAP = 5_000
CUDA_PEER_CAP = {"pypose": 10_000_000}
N_CTRL = 64        # B-spline control points
N_TRAIN_CTRL = 512  # control points of the trained B-spline layer
BEZIER_TIMES = 64  # Bezier times per curve


# ----------------------------------------------------------------------------- helpers

class Bench:
    """Timing, copy-limit and row bookkeeping for one run."""

    def __init__(self, args):
        self.args = args
        self.device = torch.device(args.device)
        self.cuda = self.device.type == "cuda"
        self.rows: list[dict] = []
        self._copy_cache: dict[int, tuple[float, float]] = {}
        self.peak_bw = None
        if self.cuda:
            try:
                from torch.cuda._device_limits import GPULimits
                self.peak_bw = GPULimits(self.device).get_memory_bandwidth_Bps()
            except Exception:
                p = torch.cuda.get_device_properties(self.device)
                rate, width = getattr(p, "memory_clock_rate", 0), getattr(p, "memory_bus_width", 0)
                self.peak_bw = 2 * rate * 1000 * width / 8 or None

    def sync(self):
        if self.cuda:
            torch.cuda.synchronize(self.device)

    def time(self, fn, repeats=None, warmup=None) -> float:
        """Median wall time of ``fn()`` in ms."""
        repeats = repeats or self.args.repeats
        warmup = self.args.warmup if warmup is None else warmup
        for _ in range(warmup):
            fn()
        self.sync()
        clock = time.process_time if self.args.clock == "cpu" else time.perf_counter
        times = []
        for _ in range(repeats):
            self.sync()
            t0 = clock()
            fn()
            self.sync()
            times.append(clock() - t0)
        return statistics.median(times) * 1e3

    def copy_ms(self, nbytes: int) -> tuple[float, float]:
        """Time of a plain copy moving ``nbytes`` (nbytes / 2 read + nbytes / 2 written).

        Returns ``(fresh, prealloc)``: the copy into a newly allocated buffer
        (``torch.empty(...).copy_(src)``, the limit line: every torch_dq call returns a new
        tensor, page faults included) and into an existing buffer (the bare bandwidth).
        """
        if nbytes not in self._copy_cache:
            numel = max(1, nbytes // 2 // 4)
            src = torch.rand(numel, device=self.device)
            dst = torch.empty_like(src)
            fresh = self.time(lambda: torch.empty_like(src).copy_(src), warmup=1)
            pre = self.time(lambda: dst.copy_(src), warmup=1)
            self._copy_cache[nbytes] = (fresh, pre)
            del src, dst
        return self._copy_cache[nbytes]

    def add(self, name, dtype, n, ours_ms, nbytes, items, peer="—", peer_ms=None,
            peer_note="", note=""):
        row = {"name": name, "dtype": _dname(dtype), "n": n, "ours_ms": ours_ms,
               "peer": peer, "peer_ms": peer_ms, "bytes": nbytes, "items": items,
               "note": "; ".join(x for x in (note, peer_note) if x)}
        if isinstance(ours_ms, float):
            row["throughput"] = items / (ours_ms * 1e-3)
            if isinstance(peer_ms, float):
                row["ratio"] = peer_ms / ours_ms
            if nbytes:
                fresh, pre = self.copy_ms(nbytes)
                row["copy_ms"], row["copy_prealloc_ms"] = fresh, pre
                row["copy_fraction"] = fresh / ours_ms
                row["achieved_GBps"] = nbytes / (ours_ms * 1e-3) / 1e9
                if self.peak_bw:
                    row["peak_fraction"] = nbytes / (ours_ms * 1e-3) / self.peak_bw
        self.rows.append(row)
        print(_fmt_row(row, self.cuda), flush=True)
        return row


def _dname(dtype) -> str:
    return str(dtype).replace("torch.", "") if isinstance(dtype, torch.dtype) else str(dtype)


def _num(x, digits=3) -> str:
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if x == 0:
        return "0"
    if abs(x) >= 1e5 or abs(x) < 1e-2:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}" if abs(x) < 1000 else f"{x:.0f}"


HEADER = ["name", "dtype", "n", "ours ms", "peer", "peer ms", "throughput (items/s)",
          "ratio (peer/ours)", "copy ms", "copy-limit fraction", "note"]
CUDA_HEADER = [*HEADER[:-1], "GB/s", "of peak HBM", "note"]


def _fmt_row(r, cuda) -> str:
    cells = [r["name"], r["dtype"], _num(float(r["n"]), 2) if r["n"] else "—",
             _num(r["ours_ms"]), r["peer"], _num(r.get("peer_ms")),
             _num(r.get("throughput")), _num(r.get("ratio")), _num(r.get("copy_ms")),
             _num(r.get("copy_fraction"))]
    if cuda:
        cells += [_num(r.get("achieved_GBps")),
                  f"{100 * r['peak_fraction']:.1f}%" if "peak_fraction" in r else "—"]
    cells.append(r["note"])
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _header(cuda) -> str:
    h = CUDA_HEADER if cuda else HEADER
    return "| " + " | ".join(h) + " |\n|" + "---|" * len(h)


def _err(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    return f"error: {type(exc).__name__}: {msg[0][:160] if msg else ''}"


def _max_diff_up_to_sign(x: torch.Tensor, y: torch.Tensor) -> float:
    """Max abs difference of rows of x and y, each row compared to +y and -y."""
    x, y = x.detach().double().cpu(), y.detach().double().cpu()
    return float(torch.minimum((x - y).abs().amax(-1), (x + y).abs().amax(-1)).max())


def _rand_dq(n, dtype, device, gen):
    """``n`` random unit dual quaternions: uniform rotations, translations ~ N(0, 1)."""
    q = quat.normalize(torch.randn(n, 4, generator=gen, dtype=dtype, device=device))
    return dq.from_rt(q, torch.randn(n, 3, generator=gen, dtype=dtype, device=device))


def _rand_q(n, dtype, device, gen):
    return quat.normalize(torch.randn(n, 4, generator=gen, dtype=dtype, device=device))


def _rand_t(n, dtype, device, gen):
    return torch.rand(n, generator=gen, dtype=dtype, device=device)


def _grad(fn_out, leaves):
    torch.autograd.grad(fn_out.sum(), leaves)


def _gen(device, seed=0):
    return torch.Generator(device=device).manual_seed(seed)


def _peer_time(b: Bench, peer: str, make, n: int, cpu_only=False):
    """Time a peer with linear scaling from a capped size.

    ``make(m)`` builds the peer for the first ``m`` items and returns ``(fn, check)`` or
    ``(fn, check, extra)``. Returns ``(ms scaled to n, note, made)`` or
    ``(None, reason, None)``.
    """
    if cpu_only and b.cuda:
        return None, f"{peer}: numpy/CPU only, not timed on cuda", None, 0
    if b.args.quick:
        cap = QUICK_PEER_CAP
    elif b.cuda:
        cap = CUDA_PEER_CAP.get(peer, n)
    else:
        cap = PEER_CAP.get(peer, n)
    m = min(n, cap)
    while True:
        try:
            made = make(m)
            ms = b.time(made[0], warmup=1)
            break
        except PeerMissing:
            return None, "not installed", None, 0
        except torch.OutOfMemoryError:
            gc.collect()
            if b.cuda:
                torch.cuda.empty_cache()
            if m <= 1000:
                return None, f"{peer}: out of memory", None, 0
            m //= 10
        except Exception as exc:
            return None, f"{peer} {_err(exc)}", None, 0
    note = "" if m == n else f"{peer} timed on {m:.0e} items, x{n / m:g} linear"
    return ms * n / m, note, made, m


def _fit(b: Bench, target: int, probe: int, run_probe) -> int:
    """On CUDA, the largest size <= target whose fwd+bwd fits in ~70% of free memory."""
    if not b.cuda:
        return target
    gc.collect()
    torch.cuda.empty_cache()
    free = torch.cuda.mem_get_info(b.device)[0]
    base = torch.cuda.memory_allocated(b.device)
    torch.cuda.reset_peak_memory_stats(b.device)
    run_probe(probe)
    b.sync()
    per_item = (torch.cuda.max_memory_allocated(b.device) - base) / probe
    gc.collect()
    torch.cuda.empty_cache()
    n = int(min(target, 0.7 * free / max(per_item, 1.0)))
    return max(probe, n // probe * probe)


# ----------------------------------------------------------------------------- sections

def bench_sclerp(b: Bench, dtype):
    dev = b.device

    def inputs(m, seed=1):
        g = _gen(dev, seed)
        return _rand_dq(m, dtype, dev, g), _rand_dq(m, dtype, dev, g), _rand_t(m, dtype, dev, g)

    def fwdbwd_probe(m):
        a, c, t = (x.requires_grad_() for x in inputs(m))
        _grad(dq.sclerp(a, c, t), (a, c, t))

    n = _fit(b, b.sizes["sclerp"], 1_000_000, fwdbwd_probe)
    a, c, t = inputs(n)
    size = torch.finfo(dtype).bits // 8
    fwd_bytes, fb_bytes = 25 * n * size, 50 * n * size

    # forward, eager
    ours = b.time(lambda: dq.sclerp(a, c, t))
    ptr_ms, ptr_note, ptr_made, _ = _peer_time(
        b, "pytransform3d", lambda m: _peers.pytransform3d_sclerp(a[:m], c[:m], t[:m]), n,
        cpu_only=True)
    pp_ms, pp_note, pp_made, _ = _peer_time(
        b, "pypose", lambda m: _peers.pypose_sclerp(a[:m], c[:m], t[:m], False), n)
    k = min(n, 2000)
    ref = dq.sclerp(a[:k], c[:k], t[:k])
    for peer, ms, note, made, extra in (
            ("pytransform3d (numpy f64)", ptr_ms, ptr_note, ptr_made, "peer in float64"),
            ("pypose", pp_ms, pp_note, pp_made, "")):
        if made is not None:
            diff = _max_diff_up_to_sign(ref, made[1]()[:k])
            note = "; ".join(x for x in (note, extra, f"max|diff| {diff:.1e}") if x)
        b.add("sclerp fwd", dtype, n, ours, fwd_bytes, n, peer, ms, note)

    # forward + backward, eager
    ag, cg, tg = (x.clone().requires_grad_() for x in (a, c, t))
    ours_fb = b.time(lambda: _grad(dq.sclerp(ag, cg, tg), (ag, cg, tg)))
    pp_fb, pp_note, _, _ = _peer_time(
        b, "pypose", lambda m: _peers.pypose_sclerp(a[:m], c[:m], t[:m], True), n)
    b.add("sclerp fwd+bwd", dtype, n, ours_fb, fb_bytes, n, "pypose", pp_fb, pp_note,
          "grad of sum wrt a, b, t")

    # torch.compile (the documented compiled path), default inductor backend
    if _skip_compile(b, dtype, "sclerp [compiled]", n):
        return
    compiled = torch.compile(dq.sclerp)
    _compiled_rows(b, dtype, n, "pypose", (
        ("sclerp fwd [compiled]", lambda: compiled(a, c, t), ours, pp_ms, fwd_bytes),
        ("sclerp fwd+bwd [compiled]", lambda: _grad(compiled(ag, cg, tg), (ag, cg, tg)),
         ours_fb, pp_fb, fb_bytes)))


def _skip_compile(b: Bench, dtype, label: str, n: int) -> bool:
    """Adds a 'skipped' row and returns True where compiled rows are not wanted."""
    if b.args.no_compile:
        b.add(label, dtype, n, "skipped (--no-compile)", 0, n)
        return True
    if b.args.quick and dtype != b.dtypes[0]:
        b.add(label, dtype, n, "skipped (--quick: first dtype only)", 0, n)
        return True
    return False


def _compiled_rows(b: Bench, dtype, n: int, peer: str, cases):
    """Rows ``(label, fn, eager_ms, peer_ms, bytes)`` of compiled callables: the first call
    compiles (its time is printed in the note), then the usual median."""
    for label, fn, eager, peer_ms, bytes_ in cases:
        try:
            t0 = time.perf_counter()
            fn()
            b.sync()
            compile_s = time.perf_counter() - t0
            ms = b.time(fn)
        except Exception as exc:
            b.add(label, dtype, n, _err(exc), 0, n, peer)
            continue
        b.add(label, dtype, n, ms, bytes_, n, peer, peer_ms,
              note=f"compile speed-up vs eager x{eager / ms:.2f}; first call {compile_s:.1f} s")


def bench_slerp(b: Bench, dtype):
    dev = b.device

    def inputs(m, seed=2):
        g = _gen(dev, seed)
        return _rand_q(m, dtype, dev, g), _rand_q(m, dtype, dev, g), _rand_t(m, dtype, dev, g)

    def fwdbwd_probe(m):
        q0, q1, t = (x.requires_grad_() for x in inputs(m))
        _grad(quat.slerp(q0, q1, t), (q0, q1, t))

    n = _fit(b, b.sizes["slerp"], 1_000_000, fwdbwd_probe)
    q0, q1, t = inputs(n)
    size = torch.finfo(dtype).bits // 8
    ours = b.time(lambda: quat.slerp(q0, q1, t))

    roma_ms, roma_note, roma_made, _ = _peer_time(
        b, "roma", lambda m: _peers.roma_slerp(q0[:m], q1[:m], t[:m], False), n)
    if roma_made is not None:
        k = min(n, 2000)
        diff = _max_diff_up_to_sign(quat.slerp(q0[:k], q1[:k], roma_made[2]), roma_made[1]()[:k])
        roma_note = "; ".join(x for x in (roma_note, "roma: one t shared by all pairs "
                                          "(0-d steps; see README)", f"max|diff| {diff:.1e}") if x)
    b.add("slerp fwd", dtype, n, ours, 13 * n * size, n, "roma", roma_ms, roma_note)

    sp_ms, sp_note, sp_made, _ = _peer_time(
        b, "scipy", lambda m: _peers.scipy_slerp(q0[:m], q1[:m], t[:m]), n, cpu_only=True)
    if sp_made is not None:
        k = min(n, 2000)
        diff = _max_diff_up_to_sign(quat.slerp(q0[:k], q1[:k], t[:k]), sp_made[1]()[:k])
        sp_note = "; ".join(x for x in (sp_note, "peer in float64", f"max|diff| {diff:.1e}") if x)
    b.add("slerp fwd", dtype, n, ours, 13 * n * size, n, "scipy Rotation (f64)", sp_ms, sp_note)

    q0g, q1g, tg = (x.clone().requires_grad_() for x in (q0, q1, t))
    ours_fb = b.time(lambda: _grad(quat.slerp(q0g, q1g, tg), (q0g, q1g, tg)))
    roma_fb, roma_note, _, _ = _peer_time(
        b, "roma", lambda m: _peers.roma_slerp(q0[:m], q1[:m], t[:m], True), n)
    b.add("slerp fwd+bwd", dtype, n, ours_fb, 26 * n * size, n, "roma", roma_fb, roma_note,
          "grad of sum wrt q0, q1, t")


def _bspline_inputs(T, dtype, device, seed=3):
    g = _gen(device, seed)
    ctrl = _rand_dq(N_CTRL, dtype, device, g)
    t = torch.linspace(0.0, 1.0, T, dtype=dtype, device=device)
    return ctrl, t


def bench_bspline(b: Bench, dtype):
    if curves is None:
        b.add("bspline cubic fwd", dtype, b.sizes["bspline"], "not available", 0, 0,
              note=CURVES_ERROR)
        return
    dev = b.device

    def fwdbwd_probe(m):
        ctrl, t = _bspline_inputs(m, dtype, dev)
        ctrl.requires_grad_()
        _grad(curves.bspline(ctrl, t), (ctrl,))

    T = _fit(b, b.sizes["bspline"], 100_000, fwdbwd_probe)
    ctrl, t = _bspline_inputs(T, dtype, dev)
    size = torch.finfo(dtype).bits // 8
    cbytes = N_CTRL * 8 * size
    fwd_bytes = cbytes + T * size + 8 * T * size
    fb_bytes = fwd_bytes + 8 * T * size + cbytes
    match = (f"matched: {N_CTRL} control poses, cubic, same number of output poses "
             "(pypose's uniform cumulative SE3 spline vs our clamped De Boor sclerp)")
    try:
        ours = b.time(lambda: curves.bspline(ctrl, t, degree=3))
        cg = ctrl.clone().requires_grad_()
        ours_fb = b.time(lambda: _grad(curves.bspline(cg, t, degree=3), (cg,)))
    except Exception as exc:
        b.add("bspline cubic", dtype, T, _err(exc), 0, T)
        return
    pp_times = {}
    for label, ms, bytes_, bwd in (("bspline cubic fwd", ours, fwd_bytes, False),
                                   ("bspline cubic fwd+bwd", ours_fb, fb_bytes, True)):
        counts = {}

        def make(m, bwd=bwd, counts=counts):
            fn, check, count = _peers.pypose_bspline(ctrl, m, bwd)
            counts["m"] = count
            return fn, check

        pp_ms, note, made, m_req = _peer_time(b, "pypose", make, T)
        if made is not None:
            # _peer_time scaled by T / m_req, m_req the count asked for; rescale to the
            # count pypose returned ((N - 3) / interval + 1 >= m_req).
            pp_ms *= m_req / counts["m"]
            note = "; ".join(x for x in (note, f"pypose returned {counts['m']} poses for "
                                         f"{m_req} asked, time scaled per pose", match) if x)
        b.add(label, dtype, T, ms, bytes_, T, "pypose bspline", pp_ms, note,
              "grad wrt control points" if bwd else "")
        pp_times[bwd] = pp_ms

    # torch.compile of the public function (check=False: the value check reads the host)
    if _skip_compile(b, dtype, "bspline cubic [compiled]", T):
        return
    compiled = torch.compile(functools.partial(curves.bspline, degree=3, check=False))
    _compiled_rows(b, dtype, T, "pypose bspline", (
        ("bspline cubic fwd [compiled]", lambda: compiled(ctrl, t), ours, pp_times[False],
         fwd_bytes),
        ("bspline cubic fwd+bwd [compiled]", lambda: _grad(compiled(cg, t), (cg,)), ours_fb,
         pp_times[True], fb_bytes)))


def bench_derivatives(b: Bench, dtype):
    """Order-2 time derivatives of the cubic B-spline against the pose alone."""
    T = b.sizes["bspline"]
    if curves is None or not hasattr(curves, "bspline_derivatives"):
        b.add("bspline derivatives", dtype, T, "not available", 0, 0,
              note=CURVES_ERROR or "curves.bspline_derivatives not available")
        return
    ctrl, t = _bspline_inputs(T, dtype, b.device)
    cg = ctrl.clone().requires_grad_()
    size = torch.finfo(dtype).bits // 8

    def derivatives_loss(c):
        return sum(x.sum() for x in curves.bspline_derivatives(c, t, order=2))

    try:
        pose = b.time(lambda: curves.bspline(ctrl, t))
        pose_fb = b.time(lambda: _grad(curves.bspline(cg, t), (cg,)))
        der = b.time(lambda: curves.bspline_derivatives(ctrl, t, order=2))
        der_fb = b.time(lambda: torch.autograd.grad(derivatives_loss(cg), (cg,)))
    except Exception as exc:
        b.add("bspline derivatives", dtype, T, _err(exc), 0, T)
        return
    out_bytes = 3 * 8 * T * size
    for label, ms, ref, bwd in (("bspline order-2 derivatives fwd", der, pose, False),
                                ("bspline order-2 derivatives fwd+bwd", der_fb, pose_fb, True)):
        note = (f"(x, dx/dt, d2x/dt2), {N_CTRL} control poses, cubic; "
                f"{ms / ref:.2f} x the pose-only time" + (" (goal <= 4)" if bwd else "")
                + ("; grad of the sum of all three wrt control points" if bwd else ""))
        b.add(label, dtype, T, ms, out_bytes * (2 if bwd else 1), T,
              "torch_dq pose only", ref, note=note)


def _smooth_motion(n: int, dtype, device, gen) -> torch.Tensor:
    """``n`` control poses of a smooth motion: a random walk of small screw steps."""
    steps = 0.05 * torch.randn(n, 6, generator=gen, dtype=dtype, device=device)
    x = dq.identity(dtype=dtype, device=device)
    out = []
    for xi in dq.exp(steps):
        x = dq.mul(x, xi)
        out.append(x)
    return torch.stack(out)


def bench_train(b: Bench, dtype):
    """One Adam step of a 512-control-point B-spline layer fitted to T timestamped poses."""
    T = b.sizes["train"]
    if curves is None:
        b.add("train step", dtype, T, "not available", 0, 0, note=CURVES_ERROR)
        return
    dev = b.device
    g = _gen(dev, 7)
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
        b.add("train step (Adam)", dtype, T, _err(exc), 0, T)
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
    pp_ms, pp_note, made, m_req = _peer_time(b, "pypose", make_pp, T)
    if made is not None:
        pp_ms *= m_req / counts["m"]
        pp_note = "; ".join(x for x in (pp_note, f"pypose fits {counts['m']} poses for "
                                        f"{m_req} asked, time scaled per pose") if x)
    b.add("train step (Adam)", dtype, T, ours, 0, T, "pypose bspline loop", pp_ms,
          pp_note, note)
    if _skip_compile(b, dtype, "train step (Adam) [compiled]", T):
        return
    model_c = dqnn.BSpline(init.clone(), degree=3, check=False)
    compiled_loss = torch.compile(lambda: losses.pose_loss(model_c(times), target))
    _compiled_rows(b, dtype, T, "pypose bspline loop", (
        ("train step (Adam) [compiled]", make_step(model_c, compiled_loss), ours, pp_ms, 0),))


def bench_bezier(b: Bench, dtype):
    C = b.sizes["bezier"]
    if curves is None:
        b.add("bezier", dtype, C * BEZIER_TIMES, "not available", 0, 0, note=CURVES_ERROR)
        return
    dev = b.device
    size = torch.finfo(dtype).bits // 8
    t = torch.linspace(0.0, 1.0, BEZIER_TIMES, dtype=dtype, device=dev)
    for degree in (3, 7):
        def inputs(m, degree=degree):
            g = _gen(dev, 4 + degree)
            return _rand_dq(m * (degree + 1), dtype, dev, g).reshape(m, degree + 1, 8)

        def fwdbwd_probe(m, degree=degree):
            ctrl = inputs(m).requires_grad_()
            _grad(curves.bezier(ctrl, t), (ctrl,))

        Cd = _fit(b, C, 1024, fwdbwd_probe)
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
            ours_fb = b.time(lambda cg=cg: _grad(curves.bezier(cg, t), (cg,)))
            b.add(f"bezier deg {degree} fwd+bwd", dtype, n_out, ours_fb, fb_bytes, n_out,
                  note=note + "; grad wrt control points")
        except Exception as exc:
            b.add(f"bezier deg {degree}", dtype, n_out, _err(exc), 0, n_out)


# ----------------------------------------------------------------------------- memory

def _vm(field: str) -> int:
    """A ``/proc/self/status`` field in bytes."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"{field} not in /proc/self/status")


def memprobe(args) -> dict:
    """Peak extra memory of one B-spline forward+backward, run in this (fresh) process.

    CPU: the peak resident set size (``VmHWM``) is reset through ``/proc/self/clear_refs``
    after a small warm-up, and the peak minus the resident size before the call is the
    memory the call needed. ``MALLOC_MMAP_THRESHOLD_`` is fixed by the parent so that every
    large tensor is its own ``mmap`` (returned to the OS when freed), so the RSS follows
    the live tensors. CUDA: ``torch.cuda.max_memory_allocated`` minus the allocation before.
    """
    torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtypes)
    dev = torch.device(args.device)
    T = args.memprobe_n
    ctrl, t = _bspline_inputs(T, dtype, dev)
    if args.memprobe == "ours":
        if curves is None:
            return {"error": CURVES_ERROR}
        t_small = torch.linspace(0.0, 1.0, 64, dtype=dtype, device=dev)

        def run(small: bool):
            c = ctrl.clone().requires_grad_()
            out = curves.bspline(c, t_small if small else t)
            return out, torch.autograd.grad(out.sum(), (c,))
    else:
        pp = _peers._need("pypose")
        k = -(-(T - 1) // (N_CTRL - 3))
        data = pp.SE3(dq.to_pose7(ctrl).contiguous())

        def run(small: bool):
            d = data.clone().requires_grad_()
            out = pp.bspline(d, interval=0.5 if small else 1.0 / k, extrapolate=False)
            return out, torch.autograd.grad(out.tensor().sum(), (d,))

    run(True)  # warm-up: lazy initialisation at a tiny size
    gc.collect()
    if dev.type == "cuda":
        torch.cuda.synchronize()
        base = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
        out, _ = run(False)
        torch.cuda.synchronize()
        peak = torch.cuda.max_memory_allocated() - base
        method = "torch.cuda.max_memory_allocated"
    else:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")  # reset VmHWM to the current RSS
            base = _vm("VmRSS")
            out, _ = run(False)
            peak = _vm("VmHWM") - base
            method = "VmHWM after /proc/self/clear_refs, MALLOC_MMAP_THRESHOLD_=65536"
        except OSError:
            # No resettable peak (not Linux): the process peak minus the peak so far, a
            # lower bound where the call's peak is below the earlier one.
            import resource
            scale = 1 if sys.platform == "darwin" else 1024
            base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
            out, _ = run(False)
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale - base
            method = "ru_maxrss delta (lower bound)"
    out_bytes = out.numel() * out.element_size()
    return {"peak_bytes": peak, "out_bytes": out_bytes, "out_shape": list(out.shape),
            "method": method}


def bench_memory(b: Bench, dtype):
    """Run ``memprobe`` in fresh subprocesses for torch_dq and pypose."""
    T = b.sizes["bspline"]
    res = {}
    for who in ("ours", "pypose"):
        if who == "pypose" and _peers.version("pypose") is None:
            res[who] = {"error": "not installed"}
            continue
        env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="65536")
        cmd = [sys.executable, __file__, "--_memprobe", who, "--_memprobe-n", str(T),
               "--dtypes", _dname(dtype), "--device", b.args.device,
               "--threads", str(b.args.threads)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
        except subprocess.TimeoutExpired as exc:
            res[who] = {"error": _err(exc)}
            continue
        try:
            res[who] = json.loads(proc.stdout.strip().splitlines()[-1])
        except (IndexError, ValueError):
            tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
            res[who] = {"error": f"memory probe failed: {tail[:160]}"}
    ours_out = None
    lines = []
    for who, r in res.items():
        if "error" in r:
            lines.append(f"| {who} | {_dname(dtype)} | {T} | {r['error']} | | |")
            continue
        ours_out = ours_out or (r["out_bytes"] if who == "ours" else None)
        mult = r["peak_bytes"] / r["out_bytes"]
        rel = f"{r['peak_bytes'] / ours_out:.1f}" if ours_out else "—"
        lines.append(f"| {'torch_dq' if who == 'ours' else 'pypose bspline'} | {_dname(dtype)} | "
                     f"{r['out_shape'][0]} | {r['peak_bytes'] / 2**20:.1f} | {mult:.1f} | {rel} |")
        r["multiple_of_output"] = mult
    b.memory[_dname(dtype)] = res
    return lines


# ----------------------------------------------------------------------------- main

def _parse_sizes(text: str, base: dict) -> dict:
    sizes = dict(base)
    for item in filter(None, (text or "").split(",")):
        key, _, val = item.partition("=")
        if key not in sizes or not val:
            raise SystemExit(f"--sizes: expected NAME=NUMBER with NAME in {sorted(sizes)}, "
                             f"got {item!r}")
        sizes[key] = int(float(val))
    return sizes


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="small sizes, smoke run (< 1 min)")
    p.add_argument("--device", default="cpu", help="cpu (default) or cuda")
    p.add_argument("--dtypes", default="float32,float64")
    p.add_argument("--sizes", default="", help="e.g. sclerp=1e6,slerp=1e6,bspline=1e5,bezier=4096 "
                   "(bspline: times; bezier: curves of 64 times)")
    p.add_argument("--repeats", type=int, default=5, help="timed repeats (>= 5), median")
    p.add_argument("--warmup", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                   help="wall (perf_counter) or cpu (process CPU time, summed over threads: "
                   "robust on a loaded machine; with --threads 1 it is the idle wall time)")
    p.add_argument("--only", default="", help="comma list of sections: "
                   "sclerp,slerp,bspline,derivatives,train,bezier,memory")
    p.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows")
    p.add_argument("--json", default=None, help="write rows and metadata as JSON here")
    p.add_argument("--_memprobe", default=None, help=argparse.SUPPRESS)
    p.add_argument("--_memprobe-n", dest="memprobe_n", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.memprobe = args._memprobe
    if args.memprobe:
        print(json.dumps(memprobe(args)))
        return
    if args.repeats < 5:
        raise SystemExit("--repeats must be >= 5")
    if args.clock == "cpu" and args.device != "cpu":
        raise SystemExit("--clock cpu measures host CPU time: use it with --device cpu")
    torch.set_num_threads(args.threads)
    b = Bench(args)
    b.memory = {}
    if b.cuda:
        base = CUDA_TARGETS
    else:
        base = QUICK_SIZES if args.quick else CPU_SIZES
    b.sizes = _parse_sizes(args.sizes, base)
    dtypes = [getattr(torch, d.strip()) for d in args.dtypes.split(",") if d.strip()]
    b.dtypes = dtypes
    default_sections = "sclerp,slerp,bspline,derivatives,train,bezier,memory"
    sections = [s for s in (args.only or default_sections).split(",") if s]

    if b.cuda:
        dev_name = torch.cuda.get_device_name(b.device)
    else:
        dev_name = platform.processor() or platform.machine()
    print(f"# torch_dq benchmarks  (torch {torch.__version__}, torch_dq "
          f"{getattr(torch_dq, '__version__', '?')}, device {args.device}: {dev_name}, "
          f"threads {torch.get_num_threads()}, {args.clock} clock, median of {args.repeats} after "
          f"{args.warmup} warm-up)")
    peers = {k: _peers.version(k) for k in ("pypose", "pytransform3d", "roma", "scipy")}
    print("# peers: " + ", ".join(f"{k} {v or 'not installed'}" for k, v in peers.items()))
    if b.cuda and b.peak_bw:
        print(f"# peak HBM bandwidth (from device properties): {b.peak_bw / 1e9:.0f} GB/s")
    print(f"# sizes: {b.sizes}")
    print()
    print(_header(b.cuda), flush=True)
    t_start = time.perf_counter()
    funcs = {"sclerp": bench_sclerp, "slerp": bench_slerp, "bspline": bench_bspline,
             "derivatives": bench_derivatives, "train": bench_train,
             "bezier": bench_bezier}
    for sec in sections:
        if sec not in funcs:
            continue
        for dtype in dtypes:
            try:
                funcs[sec](b, dtype)
            except Exception as exc:
                traceback.print_exc(file=sys.stderr)
                b.add(sec, dtype, 0, _err(exc), 0, 0)
            gc.collect()
            if b.cuda:
                torch.cuda.empty_cache()
    mem_lines = []
    if "memory" in sections:
        for dtype in dtypes[:1] if args.quick else dtypes:
            mem_lines += bench_memory(b, dtype)
        print()
        print(f"Peak memory of one cubic B-spline forward+backward ({N_CTRL} control poses, "
              f"{b.sizes['bspline']} times), fresh subprocess, above the memory held before "
              "the call:")
        print()
        print("| who | dtype | output poses | peak MiB | x own output size "
              "| x torch_dq output size |")
        print("|---|---|---|---|---|---|")
        print("\n".join(mem_lines))
    elapsed = time.perf_counter() - t_start
    print()
    print(f"# total {elapsed:.0f} s. ratio = peer ms / ours ms (> 1: torch_dq faster); "
          "copy-limit fraction = copy ms / ours ms, copy = torch.empty(k).copy_(src) moving "
          "the row's bytes (inputs read + outputs written; fwd+bwd adds the output gradient "
          "read and the input gradients written); 1 = at the copy limit.")
    if args.json:
        meta = {"torch": torch.__version__, "device": args.device, "device_name": dev_name,
                "threads": torch.get_num_threads(), "clock": args.clock, "repeats": args.repeats,
                "warmup": args.warmup, "sizes": b.sizes, "peers": peers,
                "peak_hbm_Bps": b.peak_bw, "quick": args.quick, "elapsed_s": elapsed,
                "python": platform.python_version()}
        Path(args.json).write_text(json.dumps({"meta": meta, "rows": b.rows,
                                               "memory": b.memory}, indent=1, default=str))
        print(f"# JSON written to {args.json}")


if __name__ == "__main__":
    main()

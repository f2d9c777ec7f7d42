"""Shared machinery of the benchmark sections: sizes, the ``Bench`` timer and row table,
random inputs, peer timing with linear scaling, CUDA size fitting and compiled rows."""

from __future__ import annotations

import gc
import statistics
import time

import torch

from _peers import PeerMissing

import torch_dq.dualquat as dq
from torch_dq import quat

try:
    from torch_dq import curves
    from torch_dq import nn as dqnn
    CURVES_ERROR = None
except ImportError as exc:  # curves.py may not exist yet
    curves = dqnn = None
    CURVES_ERROR = f"torch_dq.curves not available ({exc})"

CPU_SIZES = {"sclerp": 1_000_000, "slerp": 1_000_000, "bspline": 100_000, "bezier": 4096,
             "train": 100_000, "camera": 1_000_000}
QUICK_SIZES = {"sclerp": 20_000, "slerp": 20_000, "bspline": 5_000, "bezier": 128,
               "train": 5_000, "camera": 20_000}
CUDA_TARGETS = {"sclerp": 100_000_000, "slerp": 100_000_000, "bspline": 10_000_000,
                "bezier": 262_144, "train": 10_000_000, "camera": 10_000_000}
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
        row = {"name": name, "dtype": dname(dtype), "n": n, "ours_ms": ours_ms,
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
        print(fmt_row(row, self.cuda), flush=True)
        return row


def dname(dtype) -> str:
    return str(dtype).replace("torch.", "") if isinstance(dtype, torch.dtype) else str(dtype)


def num(x, digits=3) -> str:
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


def fmt_row(r, cuda) -> str:
    cells = [r["name"], r["dtype"], num(float(r["n"]), 2) if r["n"] else "—",
             num(r["ours_ms"]), r["peer"], num(r.get("peer_ms")),
             num(r.get("throughput")), num(r.get("ratio")), num(r.get("copy_ms")),
             num(r.get("copy_fraction"))]
    if cuda:
        cells += [num(r.get("achieved_GBps")),
                  f"{100 * r['peak_fraction']:.1f}%" if "peak_fraction" in r else "—"]
    cells.append(r["note"])
    return "| " + " | ".join(str(c) for c in cells) + " |"


def header(cuda) -> str:
    h = CUDA_HEADER if cuda else HEADER
    return "| " + " | ".join(h) + " |\n|" + "---|" * len(h)


def err(exc: BaseException) -> str:
    msg = str(exc).strip().splitlines()
    return f"error: {type(exc).__name__}: {msg[0][:160] if msg else ''}"


def max_diff_up_to_sign(x: torch.Tensor, y: torch.Tensor) -> float:
    """Max abs difference of rows of x and y, each row compared to +y and -y."""
    x, y = x.detach().double().cpu(), y.detach().double().cpu()
    return float(torch.minimum((x - y).abs().amax(-1), (x + y).abs().amax(-1)).max())


def rand_dq(n, dtype, device, gen):
    """``n`` random unit dual quaternions: uniform rotations, translations ~ N(0, 1)."""
    q = quat.normalize(torch.randn(n, 4, generator=gen, dtype=dtype, device=device))
    return dq.from_rt(q, torch.randn(n, 3, generator=gen, dtype=dtype, device=device))


def rand_q(n, dtype, device, gen):
    return quat.normalize(torch.randn(n, 4, generator=gen, dtype=dtype, device=device))


def rand_t(n, dtype, device, gen):
    return torch.rand(n, generator=gen, dtype=dtype, device=device)


def grad(fn_out, leaves):
    torch.autograd.grad(fn_out.sum(), leaves)


def seeded(device, seed=0):
    return torch.Generator(device=device).manual_seed(seed)


def peer_time(b: Bench, peer: str, make, n: int, cpu_only=False):
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
            return None, f"{peer} {err(exc)}", None, 0
    note = "" if m == n else f"{peer} timed on {m:.0e} items, x{n / m:g} linear"
    return ms * n / m, note, made, m


def fit_size(b: Bench, target: int, probe: int, run_probe) -> int:
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


def skip_compile(b: Bench, dtype, label: str, n: int) -> bool:
    """Adds a 'skipped' row and returns True where compiled rows are not wanted."""
    if b.args.no_compile:
        b.add(label, dtype, n, "skipped (--no-compile)", 0, n)
        return True
    if b.args.quick and dtype != b.dtypes[0]:
        b.add(label, dtype, n, "skipped (--quick: first dtype only)", 0, n)
        return True
    return False


def compiled_rows(b: Bench, dtype, n: int, peer: str, cases):
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
            b.add(label, dtype, n, err(exc), 0, n, peer)
            continue
        b.add(label, dtype, n, ms, bytes_, n, peer, peer_ms,
              note=f"compile speed-up vs eager x{eager / ms:.2f}; first call {compile_s:.1f} s")


def bspline_inputs(T, dtype, device, seed=3):
    g = seeded(device, seed)
    ctrl = rand_dq(N_CTRL, dtype, device, g)
    t = torch.linspace(0.0, 1.0, T, dtype=dtype, device=device)
    return ctrl, t

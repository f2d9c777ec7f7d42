"""Section ``memory``: peak memory of one B-spline forward+backward, torch_dq and pypose,
each in a fresh subprocess (``run.py --_memprobe``)."""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
from pathlib import Path

import torch

import _peers
from _bench import Bench, CURVES_ERROR, N_CTRL, bspline_inputs, curves, dname, err

import torch_dq.dualquat as dq


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
    ctrl, t = bspline_inputs(T, dtype, dev)
    if args.memprobe == "ours":
        if curves is None:
            return {"error": CURVES_ERROR}
        t_small = torch.linspace(0.0, 1.0, 64, dtype=dtype, device=dev)

        def once(small: bool):
            c = ctrl.clone().requires_grad_()
            out = curves.bspline(c, t_small if small else t)
            return out, torch.autograd.grad(out.sum(), (c,))
    else:
        pp = _peers._need("pypose")
        k = -(-(T - 1) // (N_CTRL - 3))
        data = pp.SE3(dq.to_pose7(ctrl).contiguous())

        def once(small: bool):
            d = data.clone().requires_grad_()
            out = pp.bspline(d, interval=0.5 if small else 1.0 / k, extrapolate=False)
            return out, torch.autograd.grad(out.tensor().sum(), (d,))

    once(True)  # warm-up: lazy initialisation at a tiny size
    gc.collect()
    if dev.type == "cuda":
        torch.cuda.synchronize()
        base = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
        out, _ = once(False)
        torch.cuda.synchronize()
        peak = torch.cuda.max_memory_allocated() - base
        method = "torch.cuda.max_memory_allocated"
    else:
        try:
            with open("/proc/self/clear_refs", "w") as f:
                f.write("5")  # reset VmHWM to the current RSS
            base = _vm("VmRSS")
            out, _ = once(False)
            peak = _vm("VmHWM") - base
            method = "VmHWM after /proc/self/clear_refs, MALLOC_MMAP_THRESHOLD_=65536"
        except OSError:
            # No resettable peak (not Linux): the process peak minus the peak so far, a
            # lower bound where the call's peak is below the earlier one.
            import resource
            scale = 1 if sys.platform == "darwin" else 1024
            base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale
            out, _ = once(False)
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * scale - base
            method = "ru_maxrss delta (lower bound)"
    out_bytes = out.numel() * out.element_size()
    return {"peak_bytes": peak, "out_bytes": out_bytes, "out_shape": list(out.shape),
            "method": method}


def run(b: Bench, dtype):
    """Run ``memprobe`` in fresh subprocesses for torch_dq and pypose."""
    T = b.sizes["bspline"]
    res = {}
    for who in ("ours", "pypose"):
        if who == "pypose" and _peers.version("pypose") is None:
            res[who] = {"error": "not installed"}
            continue
        env = dict(os.environ, MALLOC_MMAP_THRESHOLD_="65536")
        cmd = [sys.executable, str(Path(__file__).with_name("run.py")), "--_memprobe", who,
               "--_memprobe-n", str(T),
               "--dtypes", dname(dtype), "--device", b.args.device,
               "--threads", str(b.args.threads)]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=300)
        except subprocess.TimeoutExpired as exc:
            res[who] = {"error": err(exc)}
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
            lines.append(f"| {who} | {dname(dtype)} | {T} | {r['error']} | | |")
            continue
        ours_out = ours_out or (r["out_bytes"] if who == "ours" else None)
        mult = r["peak_bytes"] / r["out_bytes"]
        rel = f"{r['peak_bytes'] / ours_out:.1f}" if ours_out else "—"
        lines.append(f"| {'torch_dq' if who == 'ours' else 'pypose bspline'} | {dname(dtype)} | "
                     f"{r['out_shape'][0]} | {r['peak_bytes'] / 2**20:.1f} | {mult:.1f} | {rel} |")
        r["multiple_of_output"] = mult
    b.memory[dname(dtype)] = res
    return lines

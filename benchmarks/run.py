"""torch_dq benchmarks: side-by-side throughput against peers and against a plain copy.

Usage (see benchmarks/README.md)::

    python benchmarks/run.py                 # full CPU run, float32 and float64 (~4 min)
    python benchmarks/run.py --quick         # smoke run, small sizes on any device (< 1 min)
    python benchmarks/run.py --device cuda   # sizes that fill the GPU, HBM bandwidth
    python benchmarks/run.py --sizes sclerp=1e5,bspline=2e4 --json out.json

Every time is the median of ``--repeats`` (>= 5) runs after ``--warmup`` runs, with
``torch.set_num_threads(--threads)`` (default 2), ``time.perf_counter`` and, on CUDA,
``torch.cuda.synchronize()`` around each run. This file is the driver: each section is a
module ``bench_<section>.py`` with a ``run(bench, dtype)``; ``_bench.py`` holds the timer,
the row table and the shared helpers, ``_peers.py`` the peers' matched work.
"""

from __future__ import annotations

import argparse
import gc
import json
import platform
import sys
import time
import traceback
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _peers
import bench_bezier
import bench_bspline
import bench_camera
import bench_cumulative
import bench_derivatives
import bench_memory
import bench_sclerp
import bench_slerp
import bench_train
from _bench import CPU_SIZES, CUDA_TARGETS, N_CTRL, QUICK_SIZES, Bench, err, header

import torch_dq

# section name -> its run(bench, dtype); "memory" prints its own table after the rows.
SECTIONS = {"sclerp": bench_sclerp.run, "slerp": bench_slerp.run, "bspline": bench_bspline.run,
            "cumulative": bench_cumulative.run, "derivatives": bench_derivatives.run,
            "train": bench_train.run, "bezier": bench_bezier.run, "camera": bench_camera.run}
DEFAULT_SECTIONS = "sclerp,slerp,bspline,cumulative,derivatives,train,bezier,camera,memory"


def _parse_sizes(text: str, base: dict) -> dict:
    sizes = dict(base)
    for item in filter(None, (text or "").split(",")):
        key, _, val = item.partition("=")
        if key not in sizes or not val:
            raise SystemExit(f"--sizes: expected NAME=NUMBER with NAME in {sorted(sizes)}, "
                             f"got {item!r}")
        sizes[key] = int(float(val))
    return sizes


def _parser() -> argparse.ArgumentParser:
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
    p.add_argument("--only", default="", help="comma list of sections: " + DEFAULT_SECTIONS)
    p.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows")
    p.add_argument("--json", default=None, help="write rows and metadata as JSON here")
    p.add_argument("--_memprobe", default=None, help=argparse.SUPPRESS)
    p.add_argument("--_memprobe-n", dest="memprobe_n", type=int, default=0, help=argparse.SUPPRESS)
    return p


def _bench(args) -> Bench:
    """The run's ``Bench``: threads, sizes and dtypes set from the arguments."""
    if args.repeats < 5:
        raise SystemExit("--repeats must be >= 5")
    if args.clock == "cpu" and args.device != "cpu":
        raise SystemExit("--clock cpu measures host CPU time: use it with --device cpu")
    torch.set_num_threads(args.threads)
    b = Bench(args)
    b.memory = {}
    base = QUICK_SIZES if args.quick else CUDA_TARGETS if b.cuda else CPU_SIZES
    b.sizes = _parse_sizes(args.sizes, base)
    b.dtypes = [getattr(torch, d.strip()) for d in args.dtypes.split(",") if d.strip()]
    return b


def _device_name(b: Bench) -> str:
    if b.cuda:
        return torch.cuda.get_device_name(b.device)
    return platform.processor() or platform.machine()


def _print_header(b: Bench, peers: dict) -> None:
    a = b.args
    print(f"# torch_dq benchmarks  (torch {torch.__version__}, torch_dq "
          f"{getattr(torch_dq, '__version__', '?')}, device {a.device}: {_device_name(b)}, "
          f"threads {torch.get_num_threads()}, {a.clock} clock, median of {a.repeats} after "
          f"{a.warmup} warm-up)")
    print("# peers: " + ", ".join(f"{k} {v or 'not installed'}" for k, v in peers.items()))
    if b.cuda and b.peak_bw:
        print(f"# peak HBM bandwidth (from device properties): {b.peak_bw / 1e9:.0f} GB/s")
    print(f"# sizes: {b.sizes}")
    print()
    print(header(b.cuda), flush=True)


def _run_sections(b: Bench, sections: list[str]) -> None:
    for sec in sections:
        if sec not in SECTIONS:
            continue
        for dtype in b.dtypes:
            try:
                SECTIONS[sec](b, dtype)
            except Exception as exc:
                traceback.print_exc(file=sys.stderr)
                b.add(sec, dtype, 0, err(exc), 0, 0)
            gc.collect()
            if b.cuda:
                torch.cuda.empty_cache()


def _print_memory(b: Bench) -> None:
    lines = []
    for dtype in b.dtypes[:1] if b.args.quick else b.dtypes:
        lines += bench_memory.run(b, dtype)
    print()
    print(f"Peak memory of one cubic B-spline forward+backward ({N_CTRL} control poses, "
          f"{b.sizes['bspline']} times), fresh subprocess, above the memory held before "
          "the call:")
    print()
    print("| who | dtype | output poses | peak MiB | x own output size "
          "| x torch_dq output size |")
    print("|---|---|---|---|---|---|")
    print("\n".join(lines))


def _write_json(b: Bench, peers: dict, elapsed: float) -> None:
    a = b.args
    meta = {"torch": torch.__version__, "device": a.device, "device_name": _device_name(b),
            "threads": torch.get_num_threads(), "clock": a.clock, "repeats": a.repeats,
            "warmup": a.warmup, "sizes": b.sizes, "peers": peers,
            "peak_hbm_Bps": b.peak_bw, "quick": a.quick, "elapsed_s": elapsed,
            "python": platform.python_version()}
    Path(a.json).write_text(json.dumps({"meta": meta, "rows": b.rows, "memory": b.memory},
                                       indent=1, default=str))
    print(f"# JSON written to {a.json}")


def main(argv=None):
    args = _parser().parse_args(argv)
    args.memprobe = args._memprobe
    if args.memprobe:
        print(json.dumps(bench_memory.memprobe(args)))
        return
    b = _bench(args)
    peers = {k: _peers.version(k) for k in ("pypose", "pytransform3d", "roma", "scipy")}
    _print_header(b, peers)
    sections = [s for s in (args.only or DEFAULT_SECTIONS).split(",") if s]
    t_start = time.perf_counter()
    _run_sections(b, sections)
    if "memory" in sections:
        _print_memory(b)
    elapsed = time.perf_counter() - t_start
    print()
    print(f"# total {elapsed:.0f} s. ratio = peer ms / ours ms (> 1: torch_dq faster); "
          "copy-limit fraction = copy ms / ours ms, copy = torch.empty(k).copy_(src) moving "
          "the row's bytes (inputs read + outputs written; fwd+bwd adds the output gradient "
          "read and the input gradients written); 1 = at the copy limit.")
    if args.json:
        _write_json(b, peers, elapsed)


if __name__ == "__main__":
    main()

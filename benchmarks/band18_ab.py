"""The compiled banded Cholesky (``csrc/banded.c``) on and off alternating in one process, the
other compiled kernels on: ``BandedCholesky``'s calls of ``bench_gtsam.py``'s 60 s IMU + poses
job (count, shapes, CPU time), each operation on the job's band (min of ``--repeats``), and
a whole ``estimate`` + ``std`` of both biases (min of ``--repeats``, with the largest
relative differences of the biases and their standard deviations). One thread, process CPU.

    python benchmarks/band18_ab.py --repeats 6
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time
import types

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_gtsam as bg
import native_ab as nab

from torch_dq._kernels import native
from torch_dq.fitting import _banded

OFF = types.SimpleNamespace(enabled=lambda *tensors: False)
METHODS = ("__init__", "solve", "selected_inverse", "trace_products")


def _switch(on: bool) -> None:
    _banded.native = native if on else OFF  # type: ignore[assignment]


def _counted(stats: dict[str, collections.Counter]) -> None:
    """Count and time ``BandedCholesky``'s public calls per method and matrix shape into
    ``stats[flag]`` and ``stats["n" + flag]`` (``flag`` the current setting: ``stats["on"]``;
    a call inside another counted call left out)."""
    cls = _banded.BandedCholesky
    for name in METHODS:
        fn = getattr(cls, name)

        def timed(self, *a, _fn=fn, _name=name, **k):
            t = time.process_time()
            stats["depth"] += 1
            try:
                out = _fn(self, *a, **k)
            finally:
                stats["depth"] -= 1
            if stats["depth"]:  # inside another counted call (trace_products' selected
                return out  # inverse): its time is the caller's
            if _name == "__init__":
                shift = a[1] if len(a) > 1 else k.get("shift")
                self._key = (tuple(a[0].shape), "shift" if shift is not None else "")
            key = (_name, *self._key, *(("r", a[0].shape[-1]) if _name == "solve" else ()))
            stats[stats["on"]][key] += time.process_time() - t
            stats["n" + stats["on"]][key] += 1
            return out
        setattr(cls, name, timed)


def _best(fn, repeats: int) -> float:
    out = []
    for _ in range(repeats):
        t = time.process_time()
        fn()
        out.append(time.process_time() - t)
    return 1e3 * min(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=6)
    args = ap.parse_args()
    torch.set_num_threads(1)
    job = bg._job(60.0)
    bands: list = []
    init = _banded.BandedCholesky.__init__

    def keep(self, band, shift=None):
        bands.append(band)
        init(self, band, shift)
    _banded.BandedCholesky.__init__ = keep  # type: ignore[method-assign]
    bg.torch_dq_run(job)
    _banded.BandedCholesky.__init__ = init  # type: ignore[method-assign]
    band = bands[0]
    rhs = torch.randn(*band.shape[:-3], band.shape[-1], 7, dtype=torch.float64)
    ops: dict[str, collections.defaultdict] = {f: collections.defaultdict(list) for f in "10"}
    for it in range(2 * args.repeats):
        flag = "10"[it % 2]
        _switch(flag == "1")
        c = _banded.BandedCholesky(band)
        for name, fn in (("factor", lambda: _banded.BandedCholesky(band)),
                         ("solve r=1", lambda c=c: c.solve(rhs[..., :1])),
                         ("solve r=7", lambda c=c: c.solve(rhs)),
                         ("selected_inverse", c.selected_inverse),
                         ("trace_products", lambda c=c: c.trace_products([band]))):
            ops[flag][name].append(_best(fn, 3))
    print(f"the job's band {tuple(band.shape)}, ms (min of {args.repeats} x 3):")
    for name in ops["1"]:
        print(f"  {name:17s} compiled {min(ops['1'][name]):6.2f}  reduction "
              f"{min(ops['0'][name]):6.2f}")
    stats: dict = {k: collections.Counter() for k in ("1", "0", "n1", "n0")}
    stats["on"], stats["depth"] = "1", 0
    _counted(stats)
    kept = nab.recorded()
    total: dict[str, list] = {"1": [], "0": []}
    out: dict[str, list] = {}
    bg.torch_dq_run(bg.make_job(10.0))
    for it in range(2 * args.repeats + 2):  # the first pair warms both
        flag = stats["on"] = "10"[it % 2]
        _switch(flag == "1")
        for k in (flag, "n" + flag):
            stats[k].clear()
        _, solve, unc, _, _ = bg.torch_dq_run(job)
        if it >= 2:
            total[flag].append(float(solve[1] + unc[1]))
        out[flag] = kept[-2:]
    print("BandedCholesky in one estimate + std (the last run), calls / CPU ms compiled, "
          "reduction:")
    for key in sorted(stats["n1"], key=str):
        print(f"  {key}: {stats['n1'][key]} / {1e3 * stats['1'][key]:.1f}, "
              f"{stats['n0'][key]} / {1e3 * stats['0'][key]:.1f}")
    print(f"  all: {1e3 * sum(stats['1'].values()):.1f} ms, "
          f"{1e3 * sum(stats['0'].values()):.1f} ms")
    for flag in "10":
        print(f"banded compiled={flag}: estimate + std min {min(total[flag]):.3f} s, "
              f"mean {np.mean(total[flag]):.3f} s of {args.repeats}")
    for name, (e1, d1), (e0, d0) in zip(("gyro", "accel"), out["1"], out["0"], strict=True):
        print(f"{name} bias: relative difference {_rel(e1, e0):.1e}, its std's {_rel(d1, d0):.1e}")


def _rel(a, b) -> float:
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


if __name__ == "__main__":
    main()

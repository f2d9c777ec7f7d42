"""rest18's changes off and on, alternating in one process, on ``bench_gtsam.py``'s 60 s IMU
+ poses job (one thread, process CPU time, the minimum over ``--repeats``): one Gauss-Newton
system and one trial cost at the start, and a whole ``estimate`` + ``std`` of both biases;
then the largest relative differences of the systems' blocks and of the biases and their
standard deviations between the two. ``--change``: ``memo`` (the samples' bases kept per
estimate, ``KnotDomain.bases(memo=)``), ``rows`` (the inertial rows whitened as the row
builders write them, into the group's stacked rows), ``tables`` (the span tables from each
pair of control points once), ``residuals`` (the inertial residuals compiled) or ``all``.
Off is the code before rest18, restored by patching the functions it replaced.

    python benchmarks/rest18_ab.py --repeats 10 --change all
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import bench_gtsam as bg
import native_ab as nab

from torch_dq import _time, nn
from torch_dq._curve import aligned_chain
from torch_dq.fitting import _imu, _linearize


def _patches(change: str) -> list[tuple[object, str, object, object]]:
    """``(owner, name, off, on)`` per function patched off."""
    bases = _time.KnotDomain.bases

    def bases_off(self, *args, memo=None, **kw):
        return bases(self, *args, **kw)

    def whitened_off(self, rows, event):  # before rest18: scaled in place for the rows
        scale = self.mask[..., None].to(rows.dtype) / self.sigma.to(rows.dtype)
        scale = scale.reshape(*scale.shape, *[1] * event)
        return rows.mul_(scale) if event == 2 else rows * scale

    def tables_off(self, ctrl):  # before rest18: per span and step
        p = self.degree
        spans = aligned_chain(ctrl).unfold(-2, p + 1, 1).movedim(-1, -2)
        return nn._span_parts(spans.reshape(-1, p + 1, 8)).unflatten(-1, spans.shape[:-2])

    out = []
    if change in ("residuals", "all"):
        out.append((_imu, "imu_residuals", lambda *args: None, _imu.imu_residuals))
    if change in ("tables", "all"):
        out.append((nn.BSpline, "span_vjp_tables", tables_off, nn.BSpline.span_vjp_tables))
    if change in ("memo", "all"):
        out.append((_time.KnotDomain, "bases", bases_off, bases))
    if change in ("rows", "all"):
        out += [(_imu._Imu, "_scale", lambda self, x: None, _imu._Imu._scale),
                (_imu._Imu, "_whitened", whitened_off, _imu._Imu._whitened),
                (_linearize, "_row_buffer", lambda terms, O, derivs: (None, [None] * len(terms)),
                 _linearize._row_buffer)]
    return out


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)) if b.size else 0.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--change", default="all",
                    choices=("memo", "rows", "tables", "residuals", "all"))
    args = ap.parse_args()
    torch.set_num_threads(1)
    bg.CLOCK = 1
    job = bg._job(60.0)
    problem, ctrl, values, w = nab._system_inputs(job)
    patches = _patches(args.change)
    kept = nab.recorded()
    bg.torch_dq_run(bg.make_job(10.0))  # warm
    times = {m: {"system": [], "cost": [], "estimate": []} for m in ("off", "on")}
    out: dict[str, tuple] = {}
    for it in range(2 * args.repeats + 2):  # the first pair warms both
        mode = ("off", "on")[it % 2]
        for owner, name, off, on in patches:
            setattr(owner, name, off if mode == "off" else on)
        t = time.process_time()
        system = problem.system(ctrl, values, w)
        ds = time.process_time() - t
        t = time.process_time()
        problem.data_cost(ctrl, values)
        dc = time.process_time() - t
        _, solve, unc, _, _ = bg.torch_dq_run(job)
        if it >= 2:
            for key, v in (("system", ds), ("cost", dc), ("estimate", solve[1] + unc[1])):
                times[mode][key].append(float(v))
        out[mode] = (system, kept[-2:])
    for mode in ("off", "on"):
        s, c, e = (min(times[mode][k]) for k in ("system", "cost", "estimate"))
        print(f"{args.change} {mode}: one system {1e3 * s:.1f} ms, one trial cost "
              f"{1e3 * c:.1f} ms, estimate + std {e:.3f} s (min of {args.repeats}, process "
              f"CPU, one thread)")
    (s1, k1), (s0, k0) = out["on"], out["off"]
    blocks = [(getattr(s1, f), getattr(s0, f)) for f in nab.FIELDS]
    print(f"system blocks: largest relative difference {max(_rel(a, b) for a, b in blocks):.1e}")
    for name, (e1, d1), (e0, d0) in zip(("gyro", "accel"), k1, k0, strict=True):
        print(f"{name} bias: relative difference {_rel(e1, e0):.1e}, its std's {_rel(d1, d0):.1e}")


if __name__ == "__main__":
    main()

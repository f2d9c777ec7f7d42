"""Paired ratios of the cumulative cubic B-spline's forward+backward (64 control points, 1e5
times, float32, 2 threads), eager and compiled, against ``pypose.bspline`` (the same curve on
uniform knots): each pair times ours and pypose back to back, so a drift of the machine's
speed between runs (up to 1.8x on the shared 2-core machine) cancels in the ratio; prints
the median and quartiles of the per-pair ratios.

    python benchmarks/paired_cumulative.py [PAIRS]     # default 21 pairs
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

import _peers  # noqa: E402
from bench_bspline import form_inputs  # noqa: E402

from torch_dq import curves  # noqa: E402


def _ms(fn) -> float:
    start = time.perf_counter()
    fn()
    return (time.perf_counter() - start) * 1e3


def main(pairs: int = 21) -> None:
    torch.set_num_threads(2)
    T = 100_000
    ctrl, t, knots = form_inputs(T, torch.float32, "cpu", "cumulative")
    cg = ctrl.clone().requires_grad_()
    theirs, _, count = _peers.pypose_bspline(ctrl, T, True)
    compiled = torch.compile(
        lambda c: curves.bspline(c, t, knots=knots, form="cumulative", check=False))

    def eager():
        torch.autograd.grad(curves.bspline(cg, t, knots=knots, form="cumulative").sum(), cg)

    def traced():
        torch.autograd.grad(compiled(cg).sum(), cg)

    for fn in (eager, traced, theirs, eager, traced, theirs):  # compile, warm up
        fn()
    ratios: dict[str, list[float]] = {"eager": [], "compiled": []}
    for _ in range(pairs):
        ours_eager, ours_compiled = _ms(eager), _ms(traced)
        peer = _ms(theirs) * T / count  # pypose returns `count` poses: scaled per pose
        ratios["eager"].append(peer / ours_eager)
        ratios["compiled"].append(peer / ours_compiled)
    for name, r in ratios.items():
        q1, med, q3 = statistics.quantiles(r, n=4)
        print(f"cumulative cubic fwd+bwd, {name}, vs pypose bspline: median {med:.1f}x "
              f"(quartiles {q1:.1f}x, {q3:.1f}x; {pairs} pairs)")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 21)

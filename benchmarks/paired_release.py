"""Paired timings of this tree against another checkout of torch_dq (a release), alternated.

Each round runs one subprocess per tree (``PYTHONPATH`` switching, the order alternating
between rounds), and each subprocess times the same cases in process CPU time, one thread:

- layer forward+backward (``nn.BSpline`` in both forms, ``nn.Bezier``; 32 control points,
  2e4 times, float32), CPU seconds per call, the mean of ``--reps`` calls (Bezier: one)
  after a warm-up call;
- ``BSpline.derivatives`` of order 2, forward+backward (de Boor form, same sizes);
- ``dualquat.sclerp`` on 1e5 pairs, forward+backward (float32);
- ``fitting.estimate`` to convergence, poses + IMU (the ``poses + IMU`` case of
  ``bench_estimate.py``, small sizes: 2000 poses, 40 control points, 5000 IMU samples).

Prints the per-round ratios (this tree / the other) and their medians. The machine may be
shared: the alternation makes a drift of its speed affect both trees alike, not cancel.

    python benchmarks/paired_release.py OTHER_TREE [--rounds 5] [--reps 10]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _cpu(fn, reps: int) -> float:
    fn()  # warm-up
    start = time.process_time()
    for _ in range(reps):
        fn()
    return time.process_time() - start


def _layer_cases(reps: int) -> dict[str, float]:
    import torch

    import torch_dq.dualquat as dq
    from torch_dq.nn import Bezier, BSpline

    gen = torch.Generator().manual_seed(0)
    ctrl = dq.exp(0.3 * torch.randn(32, 6, generator=gen))
    t = torch.rand(20_000, generator=gen)
    layers = {"BSpline de_boor": BSpline(ctrl), "BSpline cumulative": BSpline(
        ctrl, form="cumulative"), "Bezier": Bezier(ctrl)}
    out = {}
    for name, layer in layers.items():
        n = 1 if name == "Bezier" else reps  # degree 31: ~1 s a call
        out[f"{name} fwd+bwd"] = _cpu(lambda m=layer: m(t).sum().backward(), n) / n
    spline = layers["BSpline de_boor"]
    out["derivatives order 2 fwd+bwd"] = _cpu(
        lambda: sum(d.sum() for d in spline.derivatives(t, 2)).backward(), reps) / reps
    a = dq.exp(0.5 * torch.randn(100_000, 6, generator=gen)).requires_grad_()
    b = dq.exp(0.5 * torch.randn(100_000, 6, generator=gen))
    s = torch.rand(100_000, generator=gen)
    out["sclerp 1e5 fwd+bwd"] = _cpu(lambda: dq.sclerp(a, b, s).sum().backward(), reps) / reps
    return out


def _estimate_case() -> dict[str, float]:
    import torch

    sys.path.insert(0, str(HERE))
    import bench_estimate as be

    import torch_dq.dualquat as dq
    from torch_dq import fitting
    from torch_dq.nn import BSpline

    F64, N, n, M = torch.float64, 2000, 40, 5000
    gen = torch.Generator().manual_seed(0)
    t = torch.linspace(0.0, N / 100.0, N, dtype=F64)
    meas = dq.mul(be.chained(t), dq.exp(1e-3 * torch.randn(N, 6, generator=gen, dtype=F64)))
    ti = torch.linspace(0.15, N / 100.0 - 0.15, M, dtype=F64)
    with torch.no_grad():
        gyro, acc = BSpline.from_dualquats(meas, t, n_ctrl=n).imu(ti)
    gyro = gyro + 0.01 + 1e-3 * torch.randn(M, 3, generator=gen, dtype=F64)
    acc = acc - 0.05 + 1e-2 * torch.randn(M, 3, generator=gen, dtype=F64)
    clock = fitting.Free()
    terms = [fitting.Poses(t, meas, rot_sigma=1e-3, trans_sigma=1e-3),
             fitting.Gyro(ti, gyro, sigma=1e-3, bias=True, time_offset=clock),
             fitting.Accel(ti, acc, sigma=1e-2, bias=True, time_offset=clock, gravity=9.81)]
    spline = BSpline.from_dualquats(meas, t, n_ctrl=n, form="cumulative")
    start = time.process_time()
    est = fitting.estimate(spline, terms, verbose=False)
    return {f"estimate poses+IMU (steps {est.steps})": time.process_time() - start}


def _one(reps: int) -> None:
    import torch

    torch.set_num_threads(1)
    print(json.dumps({**_layer_cases(reps), **_estimate_case()}))


def _run(tree: str, reps: int) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": tree, "OMP_NUM_THREADS": "1"}
    got = subprocess.run([sys.executable, __file__, "--one", "--reps", str(reps)], env=env,
                         check=True, capture_output=True, text=True, cwd=tree)
    return json.loads(got.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("other", nargs="?")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--one", action="store_true", help="time the tree on PYTHONPATH")
    args = parser.parse_args()
    if args.one:
        return _one(args.reps)
    ours, theirs = str(HERE.parent), str(Path(args.other).resolve())
    rows: dict[str, list[tuple[float, float]]] = {}
    for r in range(args.rounds):
        order = (ours, theirs) if r % 2 == 0 else (theirs, ours)
        got = {tree: _run(tree, args.reps) for tree in order}
        for key in got[ours]:
            other = next(k for k in got[theirs] if k.split(" (")[0] == key.split(" (")[0])
            rows.setdefault(key, []).append((got[ours][key], got[theirs][other]))
        print(f"round {r + 1} done", file=sys.stderr, flush=True)
    print("| case | this tree, median s | other, median s | ratio per round | median |")
    print("|---|---|---|---|---|")
    for key, pairs in rows.items():
        ratios = [a / b for a, b in pairs]
        print(f"| {key} | {statistics.median(a for a, _ in pairs):.3f} | "
              f"{statistics.median(b for _, b in pairs):.3f} | "
              f"{', '.join(f'{x:.2f}' for x in ratios)} | {statistics.median(ratios):.2f} |")


if __name__ == "__main__":
    main()

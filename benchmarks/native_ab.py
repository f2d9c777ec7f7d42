"""The compiled kernels against the PyTorch code in one process: ``fitting.estimate`` + the
biases' ``std`` on ``bench_gtsam.py``'s job, one thread, ``TORCH_DQ_NATIVE=0`` and ``1``
alternating (A/B, B/A, ...), process CPU seconds, the min of ``--repeats`` each, and the
largest relative difference of the results (biases, their stds, the control points).

    python benchmarks/native_ab.py --repeats 6 [--duration 60]
"""

from __future__ import annotations

import argparse
import math
import os
import time

import bench_gtsam as bg
import torch

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline


def run(job: dict) -> tuple[float, int, torch.Tensor]:
    """One solve as ``bench_gtsam.torch_dq_run``: (CPU s of estimate + std, steps, results)."""
    tc, ti, R, p, w, a = (torch.from_numpy(job[k]) for k in ("tc", "ti", "R", "p", "gyro", "acc"))
    poses = dq.from_rt(quat.from_matrix(R), p)
    n_ctrl = min(math.ceil(float(tc[-1] - tc[0]) / bg.KNOT - 1e-9) + 3, len(tc))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
    cam = fitting.Poses(tc, poses, rot_sigma=bg.SIGMA_ROT, trans_sigma=bg.SIGMA_POS)
    gyro = fitting.Gyro(ti, w, sigma=bg.SIGMA_GYRO, bias=True)
    acc = fitting.Accel(ti, a, sigma=bg.SIGMA_ACC, bias=True,
                        gravity=torch.tensor([0.0, 0.0, -bg.G], dtype=torch.float64))
    t0 = time.process_time()
    est = fitting.estimate(spline, [cam, gyro, acc], verbose=False)
    sg, sa = est.std(gyro, "bias"), est.std(acc, "bias")
    cpu = time.process_time() - t0
    out = torch.cat([gyro.bias.detach(), acc.bias.detach(), sg, sa,
                     spline.control_points.detach().flatten()])
    return cpu, est.steps, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    job = bg.make_job(args.duration)
    times: dict[str, list[float]] = {"0": [], "1": []}
    results = {}
    for m in ("0", "1"):  # warm-up, both paths
        os.environ["TORCH_DQ_NATIVE"] = m
        run(bg.make_job(10.0))
    for i in range(args.repeats):
        for m in ("0", "1") if i % 2 == 0 else ("1", "0"):
            os.environ["TORCH_DQ_NATIVE"] = m
            cpu, steps, out = run(job)
            times[m].append(cpu)
            results[m] = (steps, out)
    for m, name in (("0", "torch"), ("1", "compiled")):
        print(f"{name:9s} estimate + std, process CPU s: min {min(times[m]):.3f}, all "
              + " ".join(f"{t:.3f}" for t in times[m]))
    (s0, r0), (s1, r1) = results["0"], results["1"]
    rel = (r1 - r0).abs() / r0.abs().clamp_min(1e-300)
    print(f"steps {s0} / {s1}; biases and stds: max relative difference "
          f"{float(rel[:12].max()):.1e}; control points: max difference "
          f"{float((r1 - r0)[12:].abs().max()):.1e}")


if __name__ == "__main__":
    main()

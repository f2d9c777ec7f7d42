"""The compiled kernels on and off (``TORCH_DQ_NATIVE=1`` / ``0``) alternating in one process
on ``bench_gtsam.py``'s 60 s IMU + poses job, one thread, process CPU time: one
Gauss-Newton system (``Problem.system`` at the start) and a whole ``estimate`` + ``std``
of both biases, the minimum over ``--repeats`` of each; then the largest relative
differences of the systems' blocks and of the estimated biases and their standard
deviations between the two. ``--alone``: ``estimate`` + ``std`` only, as the environment
sets ``TORCH_DQ_NATIVE`` (one process per setting: no heap shared by the two paths).

    python benchmarks/native_ab.py --repeats 6
    for f in 1 0 1 0; do TORCH_DQ_NATIVE=$f python benchmarks/native_ab.py --alone; done
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

FIELDS = ("band", "cn", "nn", "gc", "gn")


def _system_inputs(job: dict):
    """The job's problem, start and band width (as ``bench_gtsam.profile`` builds them)."""
    import torch_dq.dualquat as dq
    from torch_dq import fitting, quat
    from torch_dq.fitting import _estimate, _problem
    from torch_dq.nn import BSpline
    tc, ti = (torch.from_numpy(job[k]) for k in ("tc", "ti"))
    poses = dq.from_rt(quat.from_matrix(torch.from_numpy(job["R"])), torch.from_numpy(job["p"]))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=len(tc), form="cumulative")
    terms = [fitting.Poses(tc, poses, rot_sigma=bg.SIGMA_ROT, trans_sigma=bg.SIGMA_POS),
             fitting.Gyro(ti, torch.from_numpy(job["gyro"]), sigma=bg.SIGMA_GYRO, bias=True),
             fitting.Accel(ti, torch.from_numpy(job["acc"]), sigma=bg.SIGMA_ACC, bias=True,
                           gravity=torch.tensor([0.0, 0.0, -bg.G], dtype=torch.float64))]
    problem = _problem.Problem(spline, terms, torch.Size([]))
    ctrl = spline.control_points.detach().to(torch.float64)
    values = _estimate._starts("native_ab", problem, ctrl)
    return problem, ctrl, values, problem.width(values)


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300)) if b.size else 0.0


def _alone(job: dict, repeats: int) -> None:
    """``estimate`` + ``std`` ``repeats`` times, warm: their mean and least CPU time."""
    bg.torch_dq_run(bg.make_job(10.0))
    bg.torch_dq_run(job)
    cpu = [float(solve[1] + unc[1]) for _, solve, unc, _, _ in
           (bg.torch_dq_run(job) for _ in range(repeats))]
    print(f"TORCH_DQ_NATIVE={os.environ.get('TORCH_DQ_NATIVE', '1')}: estimate + std "
          f"mean {np.mean(cpu):.3f} s, min {min(cpu):.3f} s of {repeats} (process CPU)")


def recorded() -> list:
    """A list that every later ``bench_gtsam`` run appends its ``(estimates, stds)`` to
    (``bench_gtsam._sigmas`` wrapped; shared by the session's A/B scripts)."""
    kept: list = []
    sigmas = bg._sigmas

    def record(est, std, truth):
        kept.append((np.array(est), np.array(std)))
        return sigmas(est, std, truth)
    bg._sigmas = record
    return kept


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--alone", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    bg.CLOCK = 1
    job = bg._job(60.0)
    if args.alone:
        _alone(job, args.repeats)
        return
    problem, ctrl, values, w = _system_inputs(job)
    kept = recorded()
    bg.torch_dq_run(bg.make_job(10.0))  # warm
    times: dict[str, dict[str, list[float]]] = {f: {"system": [], "estimate": []} for f in "10"}
    out: dict[str, tuple] = {}
    for it in range(2 * args.repeats + 2):  # the first pair warms both paths
        flag = "10"[it % 2]
        os.environ["TORCH_DQ_NATIVE"] = flag
        t = time.process_time()
        system = problem.system(ctrl, values, w)
        dt = time.process_time() - t
        _, solve, unc, _, _ = bg.torch_dq_run(job)
        if it >= 2:
            times[flag]["system"].append(dt)
            times[flag]["estimate"].append(float(solve[1] + unc[1]))
        out[flag] = (system, kept[-2:])
    for flag in "10":
        s, e = (min(times[flag][k]) for k in ("system", "estimate"))
        print(f"TORCH_DQ_NATIVE={flag}: one system {1e3 * s:.1f} ms, estimate + std {e:.3f} s "
              f"(min of {args.repeats}, process CPU, one thread)")
    (s1, k1), (s0, k0) = out["1"], out["0"]
    blocks = [(getattr(s1, f), getattr(s0, f)) for f in FIELDS]
    blocks += [(a, b) for o1, o0 in zip(s1.own, s0.own, strict=True)
               for a, b in zip(o1, o0, strict=True)]
    print(f"system blocks: largest relative difference {max(_rel(a, b) for a, b in blocks):.1e}")
    for name, (e1, d1), (e0, d0) in zip(("gyro", "accel"), k1, k0, strict=True):
        print(f"{name} bias: relative difference {_rel(e1, e0):.1e}, its std's {_rel(d1, d0):.1e}")


if __name__ == "__main__":
    main()

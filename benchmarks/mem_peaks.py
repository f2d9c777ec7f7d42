"""Peak resident memory of ``bench_gtsam.py``'s IMU + poses job at ``estimate`` and after
the first ``std`` (one process, one thread, after a 10 s warm-up job, as ``--scaling``).

    PYTHONPATH=$PWD python benchmarks/mem_peaks.py 3600   # the hour (issue 34: < 1.5 GB)
    PYTHONPATH=$PWD python benchmarks/mem_peaks.py 1200 --save out.pt  # results kept

``--save`` writes the control points, biases, their standard deviations, chi2 and dof
(``torch.save``), to compare two versions' results bit for bit.
"""

import argparse
import math
import resource
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parent))
import bench_gtsam as B

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def run(job: dict) -> tuple[dict, list[float]]:
    """One estimate and both biases' std; the results and [estimate s, std s, peak MB at
    estimate, peak MB after std]."""
    tc, ti, R, p, w, a = (torch.from_numpy(job[k]) for k in ("tc", "ti", "R", "p", "gyro",
                                                              "acc"))
    poses = dq.from_rt(quat.from_matrix(R), p)
    n_ctrl = min(math.ceil(float(tc[-1] - tc[0]) / B.KNOT - 1e-9) + 3, len(tc))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
    cam = fitting.Poses(tc, poses, rot_sigma=B.SIGMA_ROT, trans_sigma=B.SIGMA_POS)
    gyro = fitting.Gyro(ti, w, sigma=B.SIGMA_GYRO, bias=True)
    acc = fitting.Accel(ti, a, sigma=B.SIGMA_ACC, bias=True,
                        gravity=torch.tensor([0.0, 0.0, -B.G], dtype=torch.float64))
    t0 = time.perf_counter()
    est = fitting.estimate(spline, [cam, gyro, acc], verbose=False)
    t1, m1 = time.perf_counter(), _peak_mb()
    sg, sa = est.std(gyro, "bias"), est.std(acc, "bias")
    t2, m2 = time.perf_counter(), _peak_mb()
    terms = (cam, gyro, acc)
    res = dict(ctrl=spline.control_points.detach(), gyro_bias=gyro.bias.detach(),
               acc_bias=acc.bias.detach(), gyro_std=sg, acc_std=sa,
               chi2=torch.stack([est.chi2[t] for t in terms]),
               dof=torch.stack([est.dof[t] for t in terms]))
    return res, [t1 - t0, t2 - t1, m1, m2]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("duration", type=float)
    ap.add_argument("--save", help="torch.save the results here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    run(B.make_job(10.0))
    res, (te, ts, m1, m2) = run(B.make_job(args.duration))
    if args.save:
        torch.save(res, args.save)
    print(f"{args.duration:.0f} s: estimate {te:.2f} s, std {ts:.2f} s; peak RSS at estimate "
          f"{m1:.0f} MB, after std {m2:.0f} MB")


if __name__ == "__main__":
    main()

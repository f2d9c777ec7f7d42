"""Cost of torch_dq.fitting.estimate to convergence, as multiples of plain spline passes.

Rows (float64, one thread, process CPU time):

1. poses only: ``estimate`` with one Poses term on N poses and n control points, divided by
   one pose-only forward+backward pass of the same spline at the pose times;
2. poses + IMU: Gyro and Accel terms (biases, a shared clock offset, gravity direction)
   with M samples added; the baseline adds one order-2 ``derivatives`` forward+backward at
   the IMU times (in chunks of 1e5 times);
3. B small problems (50 poses, 10 control points) as one batched ``estimate`` vs a loop.

Usage: ``python benchmarks/bench_estimate.py [--poses 10000] [--ctrl 200] [--imu 100000]
[--batch 256]``; the issue's sizes are ``--poses 100000 --ctrl 2000 --imu 1000000``.
"""

from __future__ import annotations

import argparse
import time

import torch

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.losses import pose_loss
from torch_dq.nn import BSpline

F64 = torch.float64


def cpu(fn):
    """Process CPU seconds of one call and its result."""
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def motion(t: torch.Tensor) -> torch.Tensor:
    """A smooth 3-D motion (turns, climbs, wobbles) at times ``t``."""
    w = torch.stack((0.3 * torch.sin(0.7 * t), 0.2 * torch.cos(0.5 * t), 0.5 + 0 * t,
                     1.0 + 0 * t, 0.2 * torch.sin(t), 0.1 * torch.cos(0.3 * t)), -1)
    step = dq.exp(w[1:] * (t[1:] - t[:-1])[:, None])
    out = [dq.identity(dtype=F64)]
    for s in step:  # a chain of small screw motions
        out.append(dq.mul(out[-1], s))
    return torch.stack(out)


def chained(t: torch.Tensor) -> torch.Tensor:
    """``motion`` for long time grids: built at 100 Hz and interpolated."""
    coarse = torch.linspace(float(t[0]), float(t[-1]), max(2, int(float(t[-1] - t[0]) * 20)),
                            dtype=F64)
    x = motion(coarse)
    spline = BSpline.from_dualquats(x, coarse, n_ctrl=min(len(coarse), 400))
    with torch.no_grad():
        return spline(t)


def pose_pass(spline, t, target) -> float:
    ctrl = spline.control_points.detach().clone().requires_grad_()

    def run():
        pose_loss(spline(t, ctrl=ctrl), target).backward()
    return cpu(run)[0]


def imu_pass(spline, t, chunk: int = 100_000) -> float:
    """One order-2 ``derivatives`` forward+backward at the times ``t``, in chunks of times
    (the gradients accumulate; memory bounded for 1e6 samples)."""
    ctrl = spline.control_points.detach().clone().requires_grad_()

    def run():
        for part in t.split(chunk):
            sum(d.sum() for d in spline.derivatives(part, 2, ctrl=ctrl)).backward()
    return cpu(run)[0]


def bench_poses(N: int, n: int, M: int) -> None:
    gen = torch.Generator().manual_seed(0)
    duration = N / 100.0
    t = torch.linspace(0.0, duration, N, dtype=F64)
    truth = chained(t)
    noise = dq.exp(1e-3 * torch.randn(N, 6, generator=gen, dtype=F64))
    meas = dq.mul(truth, noise)
    spline = BSpline.from_dualquats(meas, t, n_ctrl=n)
    base = pose_pass(spline, t, meas)
    cam = fitting.Poses(t, meas, rot_sigma=1e-3, trans_sigma=1e-3)
    secs, est = cpu(lambda: fitting.estimate(spline, [cam], verbose=False))
    print(f"poses only: N={N} n={n}: estimate {secs:.2f} s ({est.steps} steps, "
          f"{est.reason}); pose fwd+bwd {base:.3f} s; ratio {secs / base:.0f}x")
    if not M:
        return
    ti = torch.linspace(0.15, duration - 0.15, M, dtype=F64)
    with torch.no_grad():
        gyro, acc = spline.imu(ti)
    gyro = gyro + 0.01 + 1e-3 * torch.randn(M, 3, generator=gen, dtype=F64)
    acc = acc - 0.05 + 1e-2 * torch.randn(M, 3, generator=gen, dtype=F64)
    clock = fitting.Free()
    terms = [cam, fitting.Gyro(ti, gyro, sigma=1e-3, bias=True, time_offset=clock),
             fitting.Accel(ti, acc, sigma=1e-2, bias=True, time_offset=clock, gravity=9.81)]
    spline = BSpline.from_dualquats(meas, t, n_ctrl=n, form="cumulative")  # C2 for Accel
    base2 = base + imu_pass(spline, ti)
    secs, est = cpu(lambda: fitting.estimate(spline, terms, verbose=False))
    print(f"poses + IMU: N={N} M={M} n={n}: estimate {secs:.2f} s ({est.steps} steps); "
          f"baseline {base2:.3f} s; ratio {secs / base2:.0f}x")


def bench_batch(B: int) -> None:
    gen = torch.Generator().manual_seed(1)
    t = torch.linspace(0.0, 2.0, 50, dtype=F64)
    xi = 0.5 * torch.randn(B, 1, 6, generator=gen, dtype=F64)
    x = dq.mul(dq.exp(t[:, None] * xi), dq.exp(1e-3 * torch.randn(B, 50, 6, generator=gen,
                                                                    dtype=F64)))
    batched = BSpline.from_dualquats(x, t, n_ctrl=10)
    term = fitting.Poses(t, x, rot_sigma=1e-3, trans_sigma=1e-3)
    secs_b, _ = cpu(lambda: fitting.estimate(batched, [term], verbose=False))
    k = min(B, 16)

    def loop():
        for b in range(k):
            one = BSpline.from_dualquats(x[b], t, n_ctrl=10)
            fitting.estimate(one, [fitting.Poses(t, x[b], rot_sigma=1e-3, trans_sigma=1e-3)],
                             verbose=False)
    secs_l = cpu(loop)[0] * B / k
    print(f"B={B} problems (50 poses, 10 control points): batched {secs_b:.2f} s, looped "
          f"{secs_l:.2f} s (extrapolated from {k}); {secs_l / secs_b:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--poses", type=int, default=10_000)
    parser.add_argument("--ctrl", type=int, default=200)
    parser.add_argument("--imu", type=int, default=100_000)
    parser.add_argument("--batch", type=int, default=256)
    args = parser.parse_args()
    torch.set_num_threads(1)
    bench_poses(args.poses, args.ctrl, args.imu)
    if args.batch:
        bench_batch(args.batch)


if __name__ == "__main__":
    main()

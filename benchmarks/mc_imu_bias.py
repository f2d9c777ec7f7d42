"""Monte Carlo of the IMU bias standard deviations (issue 34's IMU + poses job).

    PYTHONPATH=$PWD python benchmarks/mc_imu_bias.py DURATION SEEDS [KNOT]

benchmarks/bench_gtsam.py's job (poses 20 Hz, IMU 200 Hz, knots 0.05 s): per seed the six
bias errors over their reported standard deviations; the RMS over every seed and axis with
the 95 % band of a correct standard deviation (chi-square with SEEDS * 6 dof, scipy).
"""
import math
import sys
import warnings

import numpy as np
import torch
from scipy import stats

sys.path.insert(0, "benchmarks")
import bench_gtsam as B

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline


def one(dur: float, seed: int, knot: float):
    job = B.make_job(dur, seed)
    tc, ti = (torch.from_numpy(job[k]) for k in ("tc", "ti"))
    poses = dq.from_rt(quat.from_matrix(torch.from_numpy(job["R"])),
                       torch.from_numpy(job["p"]))
    n_ctrl = min(math.ceil(dur / knot - 1e-9) + 3, len(tc))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
    cam = fitting.Poses(tc, poses, rot_sigma=B.SIGMA_ROT, trans_sigma=B.SIGMA_POS)
    gyro = fitting.Gyro(ti, torch.from_numpy(job["gyro"]), sigma=B.SIGMA_GYRO, bias=True)
    acc = fitting.Accel(ti, torch.from_numpy(job["acc"]), sigma=B.SIGMA_ACC, bias=True,
                        gravity=torch.tensor([0.0, 0.0, -B.G], dtype=torch.float64))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = fitting.estimate(spline, [cam, gyro, acc], verbose=False)
        sg, sa = est.std(gyro, "bias"), est.std(acc, "bias")
    z = np.concatenate([(gyro.bias.numpy() - B.B_GYRO) / sg.numpy(),
                        (acc.bias.numpy() - B.B_ACC) / sa.numpy()])
    ratios = [float(est.chi2[t]) / float(est.dof[t]) for t in (cam, gyro, acc)]
    print(seed, est.steps, np.round(z, 2), np.round(ratios, 3),
          [str(w.message)[:80] for w in caught], flush=True)
    return z, ratios


def main() -> None:
    torch.set_num_threads(1)
    dur, seeds = float(sys.argv[1]), int(sys.argv[2])
    knot = float(sys.argv[3]) if len(sys.argv) > 3 else B.KNOT
    runs = [one(dur, seed, knot) for seed in range(seeds)]
    Z = np.array([z for z, _ in runs])
    n = Z.size
    rms = math.sqrt((Z**2).mean())
    lo, hi = (math.sqrt(stats.chi2.ppf(p, n) / n) for p in (0.025, 0.975))
    print(f"{dur} s, {seeds} seeds, knots {knot} s: RMS of error/std {rms:.3f} (n = {n}; "
          f"95 % band of a correct std [{lo:.3f}, {hi:.3f}])")
    print("gyro RMS", math.sqrt((Z[:, :3]**2).mean()), "accel RMS",
          math.sqrt((Z[:, 3:]**2).mean()))
    print("per-axis RMS", np.sqrt((Z**2).mean(0)).round(3))
    print("mean chi2/dof (poses, gyro, accel)", np.array([r for _, r in runs]).mean(0).round(4))


if __name__ == "__main__":
    main()

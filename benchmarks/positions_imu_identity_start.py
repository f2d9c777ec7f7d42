"""Positions + Gyro + Accel, the curve started on the positions with identity rotations (what a
GNSS + IMU user has), 10 s of benchmarks/bench_gtsam.py's job: once a known limitation, now
the case of fitting._align's IMU start.

    GRAV=free PYTHONPATH=$PWD python benchmarks/positions_imu_identity_start.py 10 0.001 identity
        gravity's direction estimated (gravity=9.81). Before the IMU start: 50 steps ended at
        cost 1.97e5 (the optimum is 11345.5), converged False (STEPS=300 reached it after
        ~240 steps: a crawl). With it (2026-11-29): 17 steps, converged, at the optimum; 60 s
        of the job: 4 steps.
    (fixed gravity vector) ... 10 0.001 identity: 15 steps before, 5 with it.
    ARM=1 GRAV=free ... 10 0.001 identity: a lever arm estimated: 50 steps unconverged
        before, 17 converged with it.
    ... 10 0 truth: from the true rotations (kept: the aligned start costs more).
"""
import math
import sys
import warnings

import torch

sys.path.insert(0, "benchmarks")
import bench_gtsam as B

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline

torch.set_num_threads(1)
import os  # noqa: E402

dur = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
knot = float(os.environ.get("KNOT", B.KNOT))
gravity = (9.81 if os.environ.get("GRAV") == "free" else
           torch.tensor([0.0, 0.0, -B.G], dtype=torch.float64))
arm = True if os.environ.get("ARM") else None
prior = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
job = B.make_job(dur, 0)
tc, ti = (torch.from_numpy(job[k]) for k in ("tc", "ti"))
poses = dq.from_rt(quat.from_matrix(torch.from_numpy(job["R"])), torch.from_numpy(job["p"]))
n_ctrl = min(math.ceil(dur / knot - 1e-9) + 3, len(tc))
start = sys.argv[3] if len(sys.argv) > 3 else "identity"
if start == "identity":  # positions only: no rotation known at the start
    ident = dq.from_rt(quat.identity(dtype=torch.float64).expand(len(tc), 4),
                       torch.from_numpy(job["p"]))
    spline = BSpline.from_dualquats(ident, tc, n_ctrl=n_ctrl, form="cumulative")
else:
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
pos = fitting.Positions(tc, torch.from_numpy(job["p"]), sigma=B.SIGMA_POS, lever_arm=arm)
gyro = fitting.Gyro(ti, torch.from_numpy(job["gyro"]), sigma=B.SIGMA_GYRO, bias=True)
acc = fitting.Accel(ti, torch.from_numpy(job["acc"]), sigma=B.SIGMA_ACC, bias=True,
                    gravity=gravity)
with warnings.catch_warnings(record=True) as w:
    warnings.simplefilter("always")
    est = fitting.estimate(spline, [pos, gyro, acc], prior=prior, verbose=True,
                           steps=int(os.environ.get("STEPS", 50)))
print(est.summary())
print("converged", bool(est.converged))
print("gyro bias err", (gyro.bias.numpy() - B.B_GYRO), "acc bias err", acc.bias.numpy() - B.B_ACC)
print("loss", est.loss.tolist()[:8], "...", est.loss.tolist()[-3:])
for x in w:
    print("warning:", str(x.message)[:300])

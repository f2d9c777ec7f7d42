"""Monte Carlo of the IMU bias standard deviations (honest8 item 6)."""
import math, sys, warnings
import numpy as np, torch
sys.path.insert(0, "benchmarks")
import bench_gtsam as B
import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline
from scipy import stats
torch.set_num_threads(1)
dur = float(sys.argv[1]); seeds = int(sys.argv[2]); knot = float(sys.argv[3]) if len(sys.argv) > 3 else B.KNOT
zs, zsc, chis = [], [], []
for seed in range(seeds):
    job = B.make_job(dur, seed)
    tc, ti = (torch.from_numpy(job[k]) for k in ("tc", "ti"))
    poses = dq.from_rt(quat.from_matrix(torch.from_numpy(job["R"])), torch.from_numpy(job["p"]))
    n_ctrl = min(math.ceil(dur / knot - 1e-9) + 3, len(tc))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
    cam = fitting.Poses(tc, poses, rot_sigma=B.SIGMA_ROT, trans_sigma=B.SIGMA_POS)
    gyro = fitting.Gyro(ti, torch.from_numpy(job["gyro"]), sigma=B.SIGMA_GYRO, bias=True)
    acc = fitting.Accel(ti, torch.from_numpy(job["acc"]), sigma=B.SIGMA_ACC, bias=True,
                        gravity=torch.tensor([0.0, 0.0, -B.G], dtype=torch.float64))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        est = fitting.estimate(spline, [cam, gyro, acc], verbose=False)
        sg, sa = est.std(gyro, "bias"), est.std(acc, "bias")
    z = np.concatenate([(gyro.bias.numpy() - B.B_GYRO) / sg.numpy(), (acc.bias.numpy() - B.B_ACC) / sa.numpy()])
    zs.append(z)
    chis.append([float(est.chi2[t]) / float(est.dof[t]) for t in (cam, gyro, acc)])
    print(seed, est.steps, est.reason[:30], np.round(z, 2), np.round(chis[-1], 3), [str(x.message)[:80] for x in w], flush=True)
Z = np.array(zs)
n = Z.size
rms = math.sqrt((Z**2).mean())
lo, hi = (math.sqrt(stats.chi2.ppf(p, n) / n) for p in (0.025, 0.975))
print(f"dur {dur} seeds {seeds} knot {knot}: RMS z {rms:.3f} (n={n}, 95% band for a correct std [{lo:.3f}, {hi:.3f}])")
print("gyro RMS", math.sqrt((Z[:, :3]**2).mean()), "acc RMS", math.sqrt((Z[:, 3:]**2).mean()))
print("per-axis RMS", np.sqrt((Z**2).mean(0)).round(3))
print("chi2/dof mean", np.array(chis).mean(0).round(4))

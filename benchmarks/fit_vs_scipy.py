"""Held-out errors of `python -m torch_dq fit FILE` (defaults) against scipy's CubicSpline +
RotationSpline through the same fitted poses, on the same held-out poses, for TUM files as
they are and subsampled to 10 Hz (car-like rates).

    python benchmarks/fit_vs_scipy.py ../shared/data/tum_fr1_xyz_groundtruth.txt \
        ../shared/data/tum_fr2_desk_groundtruth.txt

A file with a repeated timestamp (fr2_desk) is read with ``--duplicates first``.
"""
import contextlib, io as stdio, json, sys, tempfile, os
import numpy as np, torch
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline
from torch_dq import io
from torch_dq.__main__ import main

def subsample(traj, step):
    keep, last = [], -np.inf
    for i, t in enumerate(traj.times.tolist()):
        if t - last >= step - 1e-3:
            keep.append(i); last = t
    return traj.select(torch.tensor(keep))

for path in sys.argv[1:]:
    try:
        traj, dup = io.read_trajectory(path), "error"
    except ValueError:
        traj, dup = io.read_trajectory(path, duplicates="first"), "first"
    for step in (None, 0.1):
        d = tempfile.mkdtemp()
        src = path if step is None else os.path.join(d, "sub10hz.txt")
        t_ = traj if step is None else subsample(traj, step)
        if step is not None:
            io.write_trajectory(src, t_)
        args = ["fit", src, "--out", os.path.join(d, "o"), "--no-plots", "--quiet"]
        if dup == "first" and step is None:
            args += ["--duplicates", "first"]
        assert main(args) == 0
        s = json.load(open(os.path.join(d, "o", "summary.json")))
        t, p = t_.times.numpy(), t_.translations.numpy()
        rot = Rotation.from_quat(t_.rotations.numpy()[:, [1, 2, 3, 0]])
        fit = np.zeros(len(t), bool); fit[::2] = True; fit[-1] = True
        mm = 1e3 * np.linalg.norm(CubicSpline(t[fit], p[fit])(t[~fit]) - p[~fit], axis=1)
        deg = np.rad2deg((RotationSpline(t[fit], rot[fit])(t[~fit]).inv() * rot[~fit]).magnitude())
        h = s["heldout_errors"]
        print(f"{os.path.basename(path)} {'as is' if step is None else '10 Hz'}: {len(t)} poses, "
              f"knots {s['model']['knot_spacing_s']:.4g} s ({s['model']['n_ctrl']} ctrl), "
              f"steps {s['fit']['steps']}")
        for key, ref in (("translation_mm", mm), ("rotation_deg", deg)):
            print(f"   {key:15s} ours mean {h[key]['mean']:.4f} median {h[key]['median']:.4f} | "
                  f"scipy mean {ref.mean():.4f} median {np.median(ref):.4f} | ratio mean "
                  f"{h[key]['mean'] / ref.mean():.2f} median "
                  f"{h[key]['median'] / np.median(ref):.2f}",
                  flush=True)

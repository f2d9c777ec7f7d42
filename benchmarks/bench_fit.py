"""Stage-by-stage time of ``python -m torch_dq fit`` on a 10,000-pose TUM file.

The file: the repository's real hand-held motion (``tests/data/tum_fr2_desk_sub.txt``, every
5th pose of TUM RGB-D freiburg2_desk's motion capture, 4192 poses over 99 s with its gaps)
resampled at 10,000 times spread uniformly over the stretches between poses at most 0.5 s
apart (``sclerp`` between the neighbouring poses), written as TUM to a temporary folder.
``--file`` times another file instead (e.g. the first 10,000 lines of the full 200 Hz
ground truth, which keeps the motion capture's own noise).

Stages, as the command runs them (``torch_dq.cli.fit_file``; holdout 2, degree 3, De Boor,
LM up to 50 steps, ``refine="auto"``): read, knot search (``choose_knot_spacing`` on the
fitted poses), the least-squares start (``BSpline.from_poses``), the refinement test
(``torch_dq.cli._refine.predicted_gain``: does one Gauss-Newton step gain more than
``fit_file.REFINE_GAIN`` of a part of the cost?), Levenberg-Marquardt (``nn.fit``, timed
where the test asks for it, or with ``--always-lm``), held-out evaluation; then the whole
``run_fit`` in process and the command in a fresh process.
Each stage: process CPU seconds (summed over threads) and wall seconds, best of
``--repeats``. Prints the machine, the date, torch's version and the threads.

    python benchmarks/bench_fit.py [--poses 10000] [--file PATH] [--threads 1] [--repeats 3]
        [--stages-only] [--always-lm]

``--stages-only`` skips the whole ``run_fit`` and the fresh process (for paired A/B runs);
``--always-lm`` times LM (and its held-out errors) where the test would skip it too.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings

import torch

from torch_dq import dualquat, io
from torch_dq import nn as dqnn
from torch_dq._report import evaluate, pose_errors
from torch_dq.cli import _refine, fit_file
from torch_dq.fitting import _knots

SOURCE = os.path.join(os.path.dirname(__file__), "..", "tests", "data", "tum_fr2_desk_sub.txt")


def resampled(count: int, path: str) -> None:
    """Write ``count`` poses of the source's motion, uniform in time over its stretches
    without gaps longer than 0.5 s, to the TUM file ``path``."""
    src = io.read_trajectory(SOURCE, duplicates="first")
    t, x = src.times, src.poses()
    ok = torch.diff(t) <= 0.5  # intervals kept
    length = torch.where(ok, torch.diff(t), 0.0)
    s = torch.linspace(0.0, float(length.sum()), count, dtype=torch.float64)
    ends = torch.cumsum(length, 0)
    i = torch.searchsorted(ends, s, right=True).clamp(max=len(ends) - 1)
    i = torch.where(ok[i], i, i - 1)  # a point at a gap's start belongs to the interval before
    u = ((s - (ends[i] - length[i])) / torch.diff(t)[i]).clamp(0.0, 1.0)
    times = t[i] + u * torch.diff(t)[i]
    keep = torch.cat((torch.tensor([True]), torch.diff(times) > 0))
    poses = dualquat.sclerp(x[i], x[i + 1], u.to(x.dtype))[keep]
    q, p = dualquat.to_rt(poses)
    io.write_trajectory(path, io.Trajectory(times[keep], q, p))


def timed(fn, repeats: int):
    """Best CPU and wall seconds of ``repeats`` calls, and the last result."""
    cpu = wall = float("inf")
    for _ in range(repeats):
        c, w = time.process_time(), time.perf_counter()
        out = fn()
        cpu, wall = min(cpu, time.process_time() - c), min(wall, time.perf_counter() - w)
    return cpu, wall, out


def stages(path: str, repeats: int, always_lm: bool = False) -> list[tuple[str, float, float]]:
    """The command's stages on ``path``, each timed: ``(name, cpu, wall)`` rows."""
    rows = []
    cpu, wall, traj = timed(lambda: io.read_trajectory(path, duplicates="first"), repeats)
    rows.append(("read", cpu, wall))
    fit_idx, held_idx = fit_file._split(len(traj), 2, 3)
    train, poses = traj.select(fit_idx), traj.poses()
    cpu, wall, chosen = timed(lambda: fit_file._knot_spacing(
        train.times, train.poses(), 3, "de_boor", "auto", 50), repeats)
    rows.append(("knot search", cpu, wall))
    spacing, why, steps = chosen
    n_ctrl = _knots.n_ctrl(float(train.times[-1] - train.times[0]), spacing, 3)

    def start():
        return dqnn.BSpline.from_poses(train.rotations, train.translations, train.times,
                                       n_ctrl=n_ctrl, degree=3, form="de_boor")

    cpu, wall, spline = timed(start, repeats)
    rows.append(("least-squares start", cpu, wall))
    gain = None
    if steps:
        cpu, wall, gain = timed(lambda: _refine.predicted_gain(spline, train.times,
                                                               poses[fit_idx]), repeats)
        rows.append(("refinement test", cpu, wall))
        print(f"predicted gain of one Gauss-Newton step: rotation {100 * gain[0]:.3g} %, "
              f"translation {100 * gain[1]:.3g} % (LM where either > "
              f"{100 * fit_file.REFINE_GAIN:g} %)")
    pays = bool(steps) and max(gain) > fit_file.REFINE_GAIN
    refined = None
    if pays or (steps and always_lm):
        def lm():
            s = start()
            return s, dqnn.fit(s, train.times, poses[fit_idx], steps=steps, verbose=False,
                               tol=fit_file.REFINE_TOL)  # as the command

        cpu, wall, (refined, history) = timed(lm, repeats)
        rows.append((f"LM ({history.steps} steps, start incl.)" + ("" if pays else " [x]"),
                     cpu, wall))
        spline = refined if pays else spline

    def heldout():
        return pose_errors(evaluate(spline, traj.times[held_idx]), poses[held_idx])

    cpu, wall, (rot, trans) = timed(heldout, repeats)
    rows.append(("held-out evaluation", cpu, wall))
    print(f"file {path}: {len(traj)} poses, knot spacing {spacing:g} s ({n_ctrl} control "
          f"points; the search {why.split(' from ')[0]}; {'LM' if pays else 'no LM'}), "
          f"held-out {_errors(rot, trans)}")
    if refined is not None:  # what LM buys on the held-out poses
        other = start() if pays else refined
        rot0, trans0 = pose_errors(evaluate(other, traj.times[held_idx]), poses[held_idx])
        what = "the least-squares start alone (no LM)" if pays else "refined by LM (--always-lm)"
        print(f"{what}: held-out {_errors(rot0, trans0)}")
    return rows


def _errors(rot, trans) -> str:
    """Mean and median held-out errors, mm and degrees."""
    return (f"mean {1e3 * float(trans.mean()):.4f} mm, {float(rot.mean()):.4f} deg, median "
            f"{1e3 * float(trans.median()):.4f} mm, {float(rot.median()):.4f} deg")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=10_000)
    parser.add_argument("--file", default=None, help="time this file instead")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--stages-only", action="store_true",
                        help="skip run_fit in process and the command's process")
    parser.add_argument("--always-lm", action="store_true",
                        help="time LM where the refinement test skips it too (not in "
                             "the fitting sum then)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    warnings.simplefilter("ignore")
    load = os.getloadavg() if hasattr(os, "getloadavg") else ("?",)
    print(f"{platform.platform()}, {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load {load[0]:.2f}; "
          f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC; "
          f"torch {torch.__version__}, {torch.get_num_threads()} thread(s)")
    with tempfile.TemporaryDirectory() as tmp:
        path = args.file or os.path.join(tmp, f"tum_{args.poses}.txt")
        if args.file is None:
            resampled(args.poses, path)
        rows = stages(path, args.repeats, args.always_lm)
        lm = any(r[0].startswith("LM") and "[x]" not in r[0] for r in rows)
        fit_rows = [r for r in rows[1:] if not (lm and r[0] == "least-squares start")
                    and "[x]" not in r[0]]
        print(f"{'stage':<34}{'CPU s':>8}{'wall s':>8}")
        for name, cpu, wall in rows:
            print(f"{name:<34}{cpu:8.3f}{wall:8.3f}")
        if not lm and any("[x]" in r[0] for r in rows):
            print("[x]: --always-lm, not in the fitting sum (the command skips it here)")
        print(f"{'fitting (search, start, LM, held-out)':<34}{sum(r[1] for r in fit_rows):8.3f}"
              f"{sum(r[2] for r in fit_rows):8.3f}")
        if args.stages_only:
            return
        cpu, wall, _ = timed(lambda: fit_file.run_fit(
            path, duplicates="first", out=os.path.join(tmp, "out"), overwrite=True,
            plots=False, verbose=False), 1)
        print(f"{'run_fit in process (writes incl.)':<34}{cpu:8.3f}{wall:8.3f}")
        begin = time.perf_counter()
        subprocess.run([sys.executable, "-m", "torch_dq", "fit", path, "--duplicates", "first",
                        "--out", os.path.join(tmp, "cli"), "--no-plots", "--quiet",
                        "--threads", str(args.threads)], check=True)
        print(f"{'python -m torch_dq fit (process)':<34}{'':>8}{time.perf_counter() - begin:8.3f}")


if __name__ == "__main__":
    main()

"""Camera-IMU calibration end to end on a stand-in for EuRoC's 72 s calib_imu recording:
time per stage and the issue's acceptance thresholds, checked.

The rig is ``EUROC`` of ``tests/_camera_imu_sim.py``: two cameras with EuRoC's published
intrinsics (pinhole-radtan, 752 x 480, 20 Hz) and ``T_BS`` seeing an aprilgrid(6, 6,
0.088, 0.3), corners by OpenCV with 0.3 px noise, an ADIS16448-like IMU at 200 Hz (EuRoC's
``imu.yaml``: noise densities, biases drifting by its random walks), a calibration dance
(rotation about every axis, accelerations), a hardware-synchronised clock (offset 0 unless
``--offset``). 72 s give about 185,000 corners per camera, the size of a EuRoC
``calib_imu`` recording. :func:`torch_dq.calibration.camera_imu` runs with its defaults (no
start given, constant biases unless ``--random-walk``); the script prints the seconds of
each stage (start: per-frame target poses, offsets, orientations; trajectory: the start
spline; estimate; uncertainties) and PASS/FAIL per threshold of issue 33 (each camera's
extrinsic within 0.3 deg / 15 mm, the clock offset within 1 ms, reprojection RMS below
0.8 px, the cameras' relative pose within 0.1 deg / 1.5 mm, the whole run under 10
minutes and under the speed goal's minute), errors in numpy against the simulated truth.
Exit status 1 when a threshold fails.

Usage::

    python benchmarks/bench_calibration.py                  # 72 s, 2 threads
    python benchmarks/bench_calibration.py --rolling-shutter --duration 24
    python benchmarks/bench_calibration.py --duration 12 --speed 2.5 --knot-spacing 0.05
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import _camera_imu_sim as sim

from torch_dq import calibration, dualquat
from torch_dq.camera import Camera

LINE_DELAY = 3e-5  # seconds per row, with --rolling-shutter


def _f64(x):
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def _arguments():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=72.0, help="seconds of motion")
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    parser.add_argument("--offset", type=float, default=0.0,
                        help="the simulated clock offset (seconds)")
    parser.add_argument("--rolling-shutter", action="store_true",
                        help="simulate and estimate a 30 us/row line delay")
    parser.add_argument("--random-walk", action="store_true",
                        help="estimate random-walk biases (bias_walk: imu.yaml's walks)")
    parser.add_argument("--speed", type=float, default=1.0,
                        help="the dance's frequencies times this (2.5: up to 6.9 rad/s)")
    parser.add_argument("--knot-spacing", default="auto", metavar="SECONDS|auto",
                        help="camera_imu's knot_spacing (auto: chosen from the IMU readings)")
    parser.add_argument("--verbose", action="store_true", help="the estimate's progress")
    return parser.parse_args()


def main() -> int:
    args = _arguments()
    torch.set_num_threads(args.threads)
    delay = LINE_DELAY if args.rolling_shutter else 0.0
    t0 = time.perf_counter()
    spec = dataclasses.replace(sim.EUROC, freq_scale=args.speed)
    imu, cams = sim.rig(duration=args.duration, offset=args.offset, line_delay=delay, spec=spec)
    t_sim = time.perf_counter() - t0
    cameras = [Camera("pinhole-radtan", _f64(sim.intrinsics(i, sim.EUROC)), sim.RESOLUTION)
               for i in range(2)]
    obs = [tuple(_f64(x) for x in c) for c in cams]
    print(f"torch_dq camera-IMU calibration benchmark (EuRoC stand-in): {args.duration:g} s, "
          f"{[int(o[0].numel()) for o in obs]} corners per camera, {imu[0].size} IMU "
          f"samples, {'rolling' if delay else 'global'} shutter; torch {torch.__version__}, "
          f"{args.threads} thread(s), {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}; simulated in "
          f"{t_sim:.1f} s")
    t0 = time.perf_counter()
    res = calibration.camera_imu(
        cameras, obs, tuple(_f64(x) for x in imu), gyro_noise=sim.GYRO_DENSITY,
        accel_noise=sim.ACCEL_DENSITY, pixel_sigma=0.3, rolling_shutter=args.rolling_shutter,
        bias_walk=sim.EUROC_WALK if args.random_walk else None, verbose=args.verbose,
        knot_spacing=None if args.knot_spacing == "auto" else float(args.knot_spacing))
    total = time.perf_counter() - t0
    for stage, seconds in res.timings.items():
        print(f"  {stage:<14s} {seconds:8.2f} s")
    print(f"  {'total':<14s} {total:8.2f} s  ({res.estimate.steps} LM steps)")
    est = res.estimate
    chi2 = ", ".join(f"{type(t).__name__} {float(est.chi2[t]) / float(est.dof[t]):.3g}"
                     for t in res.terms[-2:])
    print(f"  knots every {res.knot_spacing:.4g} s; chi2/dof {chi2}")
    if delay:
        err = 1e9 * (res.line_delays.numpy() - delay)
        print(f"  line delay errors {err.round(3).tolist()} ns/row (truth "
              f"{1e6 * delay:g} us/row)")
    checks = sim.euroc_checks(dualquat.to_matrix(res.extrinsics).numpy(),
                              res.time_offsets.numpy(), res.reprojection_rms.numpy(),
                              truth_offset=args.offset)
    checks += [("total time (s), well under 10 min", total, 600.0, total < 600.0),
               ("total time (s), the speed goal", total, 60.0, total < 60.0)]
    for name, value, limit, ok in checks:
        print(f"  {'PASS' if ok else 'FAIL'}  {name:<36s} {value:10.4f}  (< {limit:g})")
    return 0 if all(c[3] for c in checks) else 1


if __name__ == "__main__":
    sys.exit(main())

"""Camera-IMU calibration end to end on a synthetic rig of EuRoC's size, time per stage.

The rig of ``tests/_camera_imu_sim.py`` (two EuRoC-like pinhole-radtan cameras at 20 Hz
seeing an aprilgrid(6, 6, 0.088, 0.3), corners by OpenCV with 0.3 px noise, an IMU at
200 Hz with EuRoC's noise densities and biases, a 4 ms clock offset): 72 s give about
180,000 corners per camera, the size of a EuRoC ``calib_imu`` recording. Prints the seconds
of each stage of :func:`torch_dq.calibration.camera_imu` (start: per-frame target poses,
offsets, orientations; trajectory: the start spline; estimate; uncertainties) and the
errors against the truth.

Usage::

    python benchmarks/bench_calibration.py                  # 72 s, 2 threads
    python benchmarks/bench_calibration.py --duration 12 --rolling-shutter
"""

from __future__ import annotations

import argparse
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=72.0, help="seconds of motion")
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads")
    parser.add_argument("--rolling-shutter", action="store_true",
                        help="simulate and estimate a 30 us/row line delay")
    parser.add_argument("--verbose", action="store_true", help="the estimate's progress")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    delay = 3e-5 if args.rolling_shutter else 0.0
    t0 = time.perf_counter()
    imu, cams = sim.rig(duration=args.duration, offset=0.004, line_delay=delay)
    t_sim = time.perf_counter() - t0

    def f64(x):
        return torch.as_tensor(np.asarray(x), dtype=torch.float64)

    k = sim.K
    cam = Camera("pinhole-radtan", f64([k[0, 0], k[1, 1], k[0, 2], k[1, 2], *sim.DIST]),
                 sim.RESOLUTION)
    obs = [tuple(f64(x) for x in c) for c in cams]
    print(f"torch_dq camera-IMU calibration benchmark: {args.duration:g} s, "
          f"{[int(o[0].numel()) for o in obs]} corners per camera, {imu[0].size} IMU "
          f"samples; torch {torch.__version__}, {args.threads} thread(s), "
          f"{platform.processor() or platform.machine()}; simulated in {t_sim:.1f} s")
    t0 = time.perf_counter()
    res = calibration.camera_imu([cam, cam], obs, tuple(f64(x) for x in imu),
                                 gyro_noise=sim.GYRO_DENSITY, accel_noise=sim.ACCEL_DENSITY,
                                 pixel_sigma=0.3, rolling_shutter=args.rolling_shutter,
                                 verbose=args.verbose)
    total = time.perf_counter() - t0
    for stage, seconds in res.timings.items():
        print(f"  {stage:<14s} {seconds:8.2f} s")
    print(f"  {'total':<14s} {total:8.2f} s  ({res.estimate.steps} LM steps)")
    for i in range(2):
        E = dualquat.to_matrix(res.extrinsics[i]).numpy()
        T = sim.extrinsic_matrix(i)
        ang = np.degrees(np.arccos(np.clip((np.trace(E[:3, :3].T @ T[:3, :3]) - 1) / 2, -1, 1)))
        print(f"  cam{i}: rotation error {ang:.4f} deg, translation error "
              f"{1e3 * np.linalg.norm(E[:3, 3] - T[:3, 3]):.3f} mm, offset error "
              f"{1e6 * (float(res.time_offsets[i]) - 0.004):.1f} us, reprojection RMS "
              f"{float(res.reprojection_rms[i]):.3f} px")


if __name__ == "__main__":
    main()

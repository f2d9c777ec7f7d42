"""The score tests of ``torch_dq.fitting._score`` on ``tests/_rig16_sim``'s 4 s rigs through
``calibration.camera_imu`` (defaults: a global shutter): ``z`` and the suggested value of
each test per seed, the CPU time of the tests against the whole call (``time.process_time``).

Run: ``PYTHONPATH=$PWD python benchmarks/trust17_score_null.py [--rolling] [--pinhole]
[--undistorted] SEED...`` (``--rolling``: a 1e-5 s/row readout; ``--pinhole``: the camera
fitted as ``"pinhole"``; ``--undistorted``: the simulated lens without distortion)."""

import argparse
import pathlib
import sys
import time
import warnings

import numpy as np
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tests"))
import _rig16_sim

from torch_dq.calibration import camera_imu
from torch_dq.camera import Camera
from torch_dq.fitting import _score, _uncertainty


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("seeds", type=int, nargs="+")
    ap.add_argument("--rolling", action="store_true")
    ap.add_argument("--pinhole", action="store_true")
    ap.add_argument("--undistorted", action="store_true")
    a = ap.parse_args()
    if a.undistorted:
        _rig16_sim.PARAMS = np.r_[_rig16_sim.PARAMS[:4], 0.0, 0.0, 0.0, 0.0]
    params = _rig16_sim.PARAMS[:4] if a.pinhole else _rig16_sim.PARAMS
    cam = Camera("pinhole" if a.pinhole else "pinhole-radtan", torch.from_numpy(params),
                 (_rig16_sim.WIDTH, _rig16_sim.HEIGHT))
    seen: list[str] = []
    spent: list[float] = []
    score, warn = _score._score, _uncertainty.warn_omitted

    def spy(est, i, d):
        z, step = score(est, i, d)
        seen.append(f"z {float(z[0]):+.3g} step {float(step[0]):.3g}")
        return z, step

    def timed(est, found):
        t0 = time.process_time()
        warn(est, found)
        spent.append(time.process_time() - t0)

    _score._score, _uncertainty.warn_omitted = spy, timed
    for seed in a.seeds:
        rig = _rig16_sim.make_rig(seed=seed, duration=4.0, line_delay=1e-5 if a.rolling else 0)
        seen.clear()
        t0 = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            camera_imu([cam], [tuple(torch.from_numpy(x) for x in rig.obs)],
                       tuple(torch.from_numpy(x) for x in rig.imu), gyro_noise=rig.gyro_noise,
                       accel_noise=rig.accel_noise, pixel_sigma=rig.pixel_sigma)
        print(f"seed {seed}: {'; '.join(seen)}  (tests {spent[-1]:.2f} s of "
              f"{time.process_time() - t0:.2f} s CPU)", flush=True)


if __name__ == "__main__":
    main()

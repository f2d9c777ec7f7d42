"""A known defect found by calib13, kept as a strict xfail for whoever fixes it: on a real
recording's stamps (UNIX seconds, ~1.4e9: float64 spacing 2.4e-7 s) ``camera_imu``'s
estimate ends "not converged" (no progress while the scaled gradient test fails), where the
same data on stamps near 1000 s converge. The clock offsets enter as ``t + dt``, rounded to
2.4e-7 s: the cost is a staircase in ``dt`` whose steps (1.2e-7 s / std 2e-5 s, squared: a
decrease of 3e-5) exceed the test's ``tol * cost`` (2e-5). The values are not hurt (the
offsets agree to 2e-8 s), but ``python -m torch_dq calibrate`` writes ``"converged": false``
and a warning that the estimate may be off the optimum on every EuRoC recording, and it
costs time: on the 100 s EuRoC stand-in (``benchmarks/bench_calibration.py``'s rig written
with stamps from 1403715273 s instead of 1000 s) 7 LM steps instead of 4, the estimate 161 s
instead of 92 s (the same machine, load 1 to 4)."""

import warnings

import numpy as np
import pytest
import torch
from _calib12_rig import RADTAN, Cam, make_rig, rot

from torch_dq import calibration
from torch_dq.camera import Camera

pytest.importorskip("cv2")

CAM = Cam("pinhole-radtan", RADTAN, rot("z", 90) @ rot("x", 2), np.array([-0.02, -0.065, 0.01]),
          0.01)


@pytest.mark.xfail(strict=True, reason="t + time_offset rounded at UNIX-epoch stamps "
                   "(fitting: times relative to the trajectory's origin would fix it)")
def test_unix_epoch_stamps_converge():
    rig = make_rig([CAM], seed=5, duration=3.0, t0=1403715273.262143)

    def f64(x):
        return torch.as_tensor(x, dtype=torch.float64)

    with warnings.catch_warnings():  # today: the convergence warning
        warnings.simplefilter("ignore")
        res = calibration.camera_imu([Camera(CAM.model, f64(CAM.params), (752, 480))],
                                     [tuple(map(f64, rig.observations[0]))],
                                     tuple(map(f64, rig.imu)), gyro_noise=rig.gyro_noise,
                                     accel_noise=rig.accel_noise, pixel_sigma=0.3)
    assert abs(float(res.time_offsets[0]) - CAM.dt) < 4 * float(res.std["time_offsets"][0])
    assert bool(res.estimate.converged.all()), res.estimate.reason

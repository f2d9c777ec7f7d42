"""Found by calib13: on a real recording's stamps (UNIX seconds, ~1.4e9: float64 spacing
2.4e-7 s) ``camera_imu``'s estimate ended "not converged", where the same data on stamps
near 1000 s converged: the clock offsets entered as ``t + dt``, rounded to 2.4e-7 s, a
staircase cost in ``dt`` (on the 100 s EuRoC stand-in 7 LM steps instead of 4, the estimate
161 s instead of 92 s). The estimation reads ``(t - origin) + dt`` now
(``tests/test_unix_time_offset.py``)."""

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


def test_unix_epoch_stamps_converge():
    rig = make_rig([CAM], seed=5, duration=3.0, t0=1403715273.262143)

    def f64(x):
        return torch.as_tensor(x, dtype=torch.float64)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibration.camera_imu([Camera(CAM.model, f64(CAM.params), (752, 480))],
                                     [tuple(map(f64, rig.observations[0]))],
                                     tuple(map(f64, rig.imu)), gyro_noise=rig.gyro_noise,
                                     accel_noise=rig.accel_noise, pixel_sigma=0.3)
    assert abs(float(res.time_offsets[0]) - CAM.dt) < 4 * float(res.std["time_offsets"][0])
    assert bool(res.estimate.converged.all()), res.estimate.reason

"""Device moves that the CPU can check (the CUDA comparisons are ``test_dev14_cuda.py``):
``CameraImuCalibration.to`` moves a copy of the trajectory, so that the result's
``estimate`` keeps the trajectory it was computed with and stays usable, here moved onto
the ``meta`` device (no values: any use of the moved trajectory by the estimate would fail)."""

import numpy as np
import torch

from torch_dq import calibration, camera

F64 = torch.float64


def test_camera_imu_result_moved_keeps_its_estimate_usable():
    import _camera_imu_sim as sim
    imu, cams = sim.rig(duration=5.0, offset=0.004, seed=2)
    obs = [tuple(torch.as_tensor(np.asarray(x)) for x in c) for c in cams]
    cam = camera.Camera("pinhole-radtan", torch.tensor(sim.intrinsics(0)), sim.RESOLUTION)
    res = calibration.camera_imu([cam, cam], obs, tuple(torch.as_tensor(np.asarray(x))
                                                        for x in imu),
                                 gyro_noise=sim.GYRO_DENSITY, accel_noise=sim.ACCEL_DENSITY,
                                 pixel_sigma=0.3, knot_spacing=0.05)
    t = torch.linspace(1.0, 4.0, 7, dtype=F64)
    before = res.estimate.pose_std(t)
    ctrl = res.trajectory.control_points.detach().clone()
    assert res.to("cpu").trajectory.control_points.device.type == "cpu"
    moved = res.to("meta")
    assert moved.trajectory.control_points.device.type == "meta"
    assert moved.gyro_bias.device.type == "meta" and moved.std["extrinsics"].is_meta
    after = res.estimate.pose_std(t)  # the estimate's own trajectory, on the CPU
    assert torch.equal(after, before) and bool(torch.isfinite(before).all())
    assert torch.equal(res.estimate._problem.trajectory.control_points.detach(), ctrl)

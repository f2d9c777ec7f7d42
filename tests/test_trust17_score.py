"""The score tests of what a camera model leaves out (``torch_dq.fitting._score``), through
``calibration.camera_imu`` on ``_rig16_sim``'s rigs (4 s records): a rolling shutter fitted
as global and a pinhole model on a distorted lens warn, with the value a Gauss-Newton step
suggests close to the simulator's truth (the line delay, Kalibr's k1 of the lens); global
shutters and undistorted lenses do not warn (the null: |z| measured 0.1 to 2.1 over 12
seeds, the threshold 5)."""

import re
import warnings

import _rig16_sim
import numpy as np
import pytest
import torch
from _rig16_sim import HEIGHT, PARAMS, WIDTH, make_rig
from scipy.spatial.transform import Rotation

from torch_dq import calibration, dualquat, fitting
from torch_dq.calibration import camera_imu
from torch_dq.camera import Camera
from torch_dq.nn import BSpline

pytest.importorskip("cv2")


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


def _warnings(rig, cam: Camera) -> list[str]:
    """The score tests' warnings of ``camera_imu`` with defaults (a global shutter)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        camera_imu([cam], [tuple(map(_t, rig.obs))], tuple(map(_t, rig.imu)),
                   gyro_noise=rig.gyro_noise, accel_noise=rig.accel_noise,
                   pixel_sigma=rig.pixel_sigma)
    return [str(w.message) for w in caught if "score test" in str(w.message)]


def _suggested(message: str, name: str) -> float:
    return float(re.search(rf"suggests {name} = ([-+0-9.e]+)", message).group(1))


RADTAN = Camera("pinhole-radtan", _t(PARAMS), (WIDTH, HEIGHT))
PINHOLE = Camera("pinhole", _t(PARAMS[:4]), (WIDTH, HEIGHT))


def test_rolling_shutter_fitted_as_global_is_warned():
    """test_rig16's case: a 4.8 ms readout (1e-5 s/row); the time offset ends 40 stds off."""
    rig = make_rig(seed=11, duration=4.0, line_delay=1e-5)
    found = _warnings(rig, RADTAN)
    assert len(found) == 1, found
    assert "line_delay" in found[0] and "rolling_shutter=True" in found[0]
    assert "--rolling-shutter" in found[0] and "'pinhole-radtan'" in found[0]
    assert _suggested(found[0], "line_delay") == pytest.approx(rig.line_delay, rel=0.1)


@pytest.mark.parametrize("seed", [0, 3])
def test_global_shutter_is_not_warned(seed):
    assert _warnings(make_rig(seed=seed, duration=4.0), RADTAN) == []


def test_pinhole_on_a_distorted_lens_is_warned():
    """k1 = -0.21 (the simulator's radtan lens) fitted by a pinhole model."""
    found = _warnings(make_rig(seed=0, duration=4.0), PINHOLE)
    k1 = [m for m in found if "score test of k1" in m]
    assert len(k1) == 1, found
    assert "'pinhole-radtan'" in k1[0] and "radial distortion" in k1[0]
    assert _suggested(k1[0], "k1") == pytest.approx(PARAMS[4], rel=0.1)
    # the misfit pulls the line delay too (z 10 against 128): said to be second
    assert len(found) == 1 or all("model k1, the largest |z|, first" in m for m in found)


def test_pinhole_on_an_undistorted_lens_is_not_warned(monkeypatch):
    monkeypatch.setattr(_rig16_sim, "PARAMS", np.r_[PARAMS[:4], 0.0, 0.0, 0.0, 0.0])
    assert _warnings(make_rig(seed=1, duration=4.0), PINHOLE) == []


def _cameras_warnings(rig) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        calibration.cameras([tuple(map(_t, rig.obs))], ["pinhole"], [(WIDTH, HEIGHT)])
    return [str(w.message) for w in caught if "score test" in str(w.message)]


def test_cameras_pinhole_on_a_distorted_lens_is_warned():
    """``calibration.cameras`` converges (rms 2.0 px against 0.5 px noise, fu 544 against
    420) with no other warning; the score test of k1 reads z = -112."""
    found = _cameras_warnings(make_rig(seed=0, duration=4.0))
    assert len(found) == 1 and "camera 0 ('pinhole')" in found[0], found
    assert "'pinhole-radtan'" in found[0]
    assert _suggested(found[0], "k1") < 0  # the lens's k1 is -0.21: barrel distortion


def test_cameras_pinhole_on_an_undistorted_lens_is_not_warned(monkeypatch):
    monkeypatch.setattr(_rig16_sim, "PARAMS", np.r_[PARAMS[:4], 0.0, 0.0, 0.0, 0.0])
    assert _cameras_warnings(make_rig(seed=2, duration=4.0)) == []


def _camera_alone(rig, batch: int = 1, steps: int = 50) -> list[str]:
    """The score tests' warnings of ``fitting.estimate`` of the trajectory alone (extrinsic
    fixed at the truth, started on the true poses, ``batch`` copies of the control points:
    shared data) and its first uncertainty."""
    t = np.arange(0.0, 2.5, 0.01)
    q = Rotation.from_matrix(rig.motion.rotation(t)).as_quat(scalar_first=True)
    traj = BSpline.from_poses(_t(q), _t(rig.motion.position(t)), _t(t), knot_spacing=0.05,
                              form="cumulative")
    if batch > 1:
        traj = BSpline(torch.stack([traj.control_points.detach()] * batch), knots=traj.knots,
                       form="cumulative")
    E = np.eye(4)
    E[:3, :3], E[:3, 3] = rig.R_bc, rig.t_bc
    cam = fitting.Reprojections(*map(_t, rig.obs), camera=RADTAN, sigma=rig.pixel_sigma,
                                extrinsic=dualquat.from_matrix(_t(E)))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = fitting.estimate(traj, [cam], steps=steps, verbose=False)
        est.pose_std(_t(rig.obs[0][:1]))
    return [str(w.message) for w in caught if "score test" in str(w.message)]


def test_a_batch_warns_as_its_elements_alone():
    """The rolling-shutter pixels, the trajectory alone, as one problem and as a batch of two
    (shared pixels, the control points stacked): the same warning, z and suggestion."""
    rig = make_rig(seed=11, duration=2.5, line_delay=1e-5, dt=0.0, t0=0.0)
    texts = [_camera_alone(rig, batch) for batch in (1, 2)]
    assert len(texts[0]) == 1 and texts[0] == texts[1], texts
    assert _suggested(texts[0][0], "line_delay") > 0  # 3.5e-6: the curve alone, one frame
    # per knot, takes up much of it (camera_imu's IMU holds the curve: 9.8e-6 against 1e-5)


def test_no_test_away_from_the_optimum():
    """``steps=0``: the uncertainties at the start, where the gradient is not the score."""
    rig = make_rig(seed=11, duration=2.5, line_delay=1e-5, dt=0.0, t0=0.0)
    assert _camera_alone(rig, steps=0) == []

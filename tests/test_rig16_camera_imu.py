"""``calibration.camera_imu`` and ``fitting.Reprojections`` + ``Gyro`` + ``Accel`` as an
outside suite runs them: a rig simulated from an analytic figure-eight motion (``_rig16_sim``:
numpy / scipy, the pose, body rate and specific force written by hand), defaults and starts far
from the truth (no start for ``camera_imu``; for ``estimate`` the trajectory from PnP camera
poses taken as the body's, an identity extrinsic against a ~90 deg one, zero time offset
against 25 ms, the line delay's default start); every estimate within 4 of its reported
standard deviations, all finite, ``converged`` honest; unit mistakes named."""

import math
import warnings

import numpy as np
import pytest
import torch
from _rig16_sim import GRAVITY, HEIGHT, PARAMS, WIDTH, extrinsic_error, make_rig
from scipy.spatial.transform import Rotation

from torch_dq import dualquat, fitting
from torch_dq.calibration import camera_imu
from torch_dq.camera import Camera
from torch_dq.nn import BSpline

cv2 = pytest.importorskip("cv2")
ZMAX = 4.0


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float64)


CAM = Camera("pinhole-radtan", _t(PARAMS), (WIDTH, HEIGHT))


def _calibrate(rig, **kw):
    return camera_imu([CAM], [tuple(map(_t, rig.obs))], tuple(map(_t, rig.imu)),
                      gyro_noise=rig.gyro_noise, accel_noise=rig.accel_noise, **kw)


def _across_gravity(err: np.ndarray, std: np.ndarray) -> np.ndarray:
    """z of gravity's x and z components (nearly across the true vector, which is mostly
    along -Y; its magnitude is fixed, so the component along it has no spread)."""
    return (err / std)[[0, 2]]


# (seed, line delay (s/row), motion overrides): two seeds, two motions, one rolling shutter
CASES = [(0, 0.0, {}),
         (1, 3e-5, dict(w=2 * np.pi * 0.5, amp_r=np.array([0.4, 0.25, 0.35])))]


def camera_imu_z(seed: int, line_delay: float, motion: dict) -> np.ndarray:
    """Errors over reported stds of ``camera_imu`` with defaults on one rig: extrinsic (6),
    time offset, biases (3 + 3), gravity across (2), line delay (rolling shutter)."""
    rig = make_rig(seed=seed, duration=3.5, line_delay=line_delay, motion_kw=motion)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a well-posed rig: no warning at all
        res = _calibrate(rig, pixel_sigma=rig.pixel_sigma, rolling_shutter=bool(line_delay))
    assert bool(res.estimate.converged), res.estimate.reason
    # the reprojection RMS is the norm's: sqrt(2) sigma
    assert abs(float(res.reprojection_rms[0]) / (math.sqrt(2) * rig.pixel_sigma) - 1) < 0.05
    M = dualquat.to_matrix(res.extrinsics[0]).numpy()
    z = [extrinsic_error(rig.R_bc, rig.t_bc, M[:3, :3], M[:3, 3]) / res.std["extrinsics"][0]
         .numpy(), [(float(res.time_offsets[0]) - rig.dt) / float(res.std["time_offsets"][0])],
         (res.gyro_bias.numpy() - rig.gyro_bias) / res.std["gyro_bias"].numpy(),
         (res.accel_bias.numpy() - rig.accel_bias) / res.std["accel_bias"].numpy(),
         _across_gravity(res.gravity.numpy() - GRAVITY, res.std["gravity"].numpy())]
    if line_delay:
        z.append([(float(res.line_delays[0]) - line_delay) / float(res.std["line_delays"][0])])
    return np.concatenate(z)


@pytest.mark.parametrize(("seed", "line_delay", "motion"), CASES, ids=["global", "rolling"])
def test_camera_imu_from_no_start_within_4_std(seed, line_delay, motion):
    z = camera_imu_z(seed, line_delay, motion)
    assert np.all(np.isfinite(z)), z
    assert np.abs(z).max() < ZMAX, z.round(2)


def _pnp_trajectory(rig) -> BSpline:
    """A start a user would make: each frame's camera pose from OpenCV's PnP, taken as the
    body's (an identity extrinsic), cumulative cubic with knots every 0.03 s."""
    times, points, pixels = rig.obs
    K = np.array([[PARAMS[0], 0, PARAMS[2]], [0, PARAMS[1], PARAMS[3]], [0, 0, 1.0]])
    stamps, qs, ps = np.unique(times), [], []
    for s in stamps:
        k = times == s
        _, rv, tv = cv2.solvePnP(points[k], pixels[k], K, np.r_[PARAMS[4:], 0.0])
        R = Rotation.from_rotvec(rv.ravel()).as_matrix()  # p_cam = R p_target + t
        qs.append(Rotation.from_matrix(R.T).as_quat(scalar_first=True))
        ps.append(-R.T @ tv.ravel())
    return BSpline.from_poses(_t(qs), _t(ps), _t(stamps), knot_spacing=0.03, margin=0.15,
                              form="cumulative")


def estimate_z(seed: int, line_delay: float, motion: dict) -> np.ndarray:
    """Errors over reported stds of ``Reprojections(extrinsic=True, time_offset=True,
    line_delay=True)``, ``Gyro(bias=True)``, ``Accel(bias=True, gravity=9.81)``: defaults,
    starts far from the truth; as :func:`camera_imu_z`."""
    rig = make_rig(seed=seed, duration=3.0, line_delay=line_delay, motion_kw=motion)
    traj = _pnp_trajectory(rig)
    t, gyro, accel = rig.imu
    lo, hi = float(rig.obs[0].min()) - 0.15, float(rig.obs[0].max()) + 0.15
    k = (t >= lo) & (t <= hi)
    rate = 1 / np.median(np.diff(t))
    cam = fitting.Reprojections(*map(_t, rig.obs), camera=CAM, sigma=rig.pixel_sigma,
                                extrinsic=True, time_offset=True,
                                line_delay=True if line_delay else None)
    gy = fitting.Gyro(_t(t[k]), _t(gyro[k]), sigma=rig.gyro_noise * math.sqrt(rate), bias=True)
    ac = fitting.Accel(_t(t[k]), _t(accel[k]), sigma=rig.accel_noise * math.sqrt(rate),
                       bias=True, gravity=9.81)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est = fitting.estimate(traj, [cam, gy, ac], verbose=False)
    assert bool(est.converged), est.reason
    for term in (cam, gy, ac):
        assert 0.85 < float(est.chi2[term]) / float(est.dof[term]) < 1.15, term
    M = dualquat.to_matrix(cam.extrinsic).numpy()
    z = [extrinsic_error(rig.R_bc, rig.t_bc, M[:3, :3], M[:3, 3]) / est.std(cam, "extrinsic")
         .numpy(), [(float(cam.time_offset) - rig.dt) / float(est.std(cam, "time_offset"))],
         (gy.bias.numpy() - rig.gyro_bias) / est.std(gy, "bias").numpy(),
         (ac.bias.numpy() - rig.accel_bias) / est.std(ac, "bias").numpy(),
         _across_gravity(ac.gravity.numpy() - GRAVITY, est.std(ac, "gravity").numpy())]
    if line_delay:
        z.append([(float(cam.line_delay) - line_delay) / float(est.std(cam, "line_delay"))])
    return np.concatenate(z)


@pytest.mark.parametrize(("seed", "line_delay", "motion"), CASES, ids=["global", "rolling"])
def test_estimate_from_far_starts_within_4_std(seed, line_delay, motion):
    z = estimate_z(seed + 10, line_delay, motion)
    assert np.all(np.isfinite(z)), z
    assert np.abs(z).max() < ZMAX, z.round(2)


def test_stopped_early_is_not_converged():
    """Two steps from the far start: not converged, and a warning says so."""
    rig = make_rig(seed=3, duration=3.0)
    with pytest.warns(RuntimeWarning, match="steps=2 reached"):
        res = _calibrate(rig, pixel_sigma=rig.pixel_sigma, steps=2)
    assert not bool(res.estimate.converged)


@pytest.mark.parametrize(("scale", "match"), [
    (1 / 9.80665, r"look like g, not m/s\^2: multiply them by 9\.80665"),
    (1000 / 9.80665, r"look like milli-g, not m/s\^2: multiply them by 0\.00980665"),
])
def test_accelerometer_in_another_unit_is_an_error(scale, match):
    """Readings in g were warned of by ``fitting.Accel`` only after the 30 steps (99 s on a
    4 s rig) ended unconverged; they are now a ``ValueError`` before anything is solved."""
    rig = make_rig(seed=4, duration=3.0)
    t, gyro, accel = rig.imu
    with pytest.raises(ValueError, match=r"camera_imu: the accelerometer's readings average "
                                         + r".*gravity_magnitude 9\.81 m/s\^2.*" + match):
        camera_imu([CAM], [tuple(map(_t, rig.obs))], (_t(t), _t(gyro), _t(accel * scale)),
                   gyro_noise=rig.gyro_noise, accel_noise=rig.accel_noise)


@pytest.mark.parametrize(("scale", "match"), [
    (100.0, r"centimetres or millimetres\? .*divide them by 100 or 1000"),  # 0.83 m target
    (1000.0, r"\(metres expected\): millimetres\? .*divide them by 1000$"),
])
def test_target_in_centimetres_is_named(scale, match):
    """A 0.83 m target in centimetres (83 across) was called millimetres with 'divide them by
    1000' (a target of 8 cm); the error names the units that make a 5 cm to 5 m target."""
    rig = make_rig(seed=5, duration=3.0)
    t, p, u = rig.obs
    with pytest.raises(ValueError, match=match):
        camera_imu([CAM], [(_t(t), _t(p * scale), _t(u))], tuple(map(_t, rig.imu)),
                   gyro_noise=rig.gyro_noise, accel_noise=rig.accel_noise)


def test_unmodelled_rolling_shutter_is_warned_or_within_4_std():
    """A 4.8 ms readout (1e-5 s/row) calibrated with the default global shutter: the time
    offset ends 40 of its stds off (it takes up half the readout), the extrinsic 15, reported
    converged; either the estimates hold within 4 stds or a warning says the pixel errors
    exceed their sigma (chi2/dof 1.44 / 1.21 / 1.40, not far above 1 by ``_FAR``) or that
    the pixels ask for a rolling shutter (the score test of the line delay, z = 74)."""
    rig = make_rig(seed=11, duration=4.0, line_delay=1e-5)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = _calibrate(rig, pixel_sigma=rig.pixel_sigma)
    z = (float(res.time_offsets[0]) - rig.dt) / float(res.std["time_offsets"][0])
    warned = [str(w.message) for w in caught if "chi2/dof" in str(w.message)
              or "rolling" in str(w.message)]
    assert warned or abs(z) < ZMAX, z

"""fitting.estimate with two cameras (``Reprojections``) and an IMU, from far starts, against
the closed-form truth of ``_outside8_rig`` (numpy).

Camera A is outside8's (150 deg and 0.3 m from the IMU), camera B a stereo partner 12 cm
beside it and turned 8 deg; both see the AprilGrid at 20 Hz, the IMU runs at 200 Hz with
biases and a clock 30 ms early against the cameras' (the cameras define the trajectory's
clock; the gyroscope and accelerometer share one ``Free`` started at 0). The trajectory
starts from camera A's poses taken as the body's, both extrinsics at the identity, the
biases at zero, gravity's magnitude only. Expected: converged, every value within 4 of its
reported standard deviations, chi2/dof near 1 per term.
"""

import math

import numpy as np
import pytest
import torch
from _outside8_rig import RATE_CAM, RATE_IMU, Rig, grid, radtan, simulate
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.camera import Camera
from torch_dq.fitting import Accel, Free, Gyro, Reprojections, estimate
from torch_dq.nn import BSpline

R_A = Rotation.from_rotvec(math.radians(150) * np.array([1.0, 2.0, -1.0]) / math.sqrt(6))
T_A = np.array([0.2, -0.2, 0.1])
R_AB, T_AB = Rotation.from_rotvec([0.0, math.radians(8.0), 0.0]), np.array([0.12, 0.0, 0.0])
R_B, T_B = R_A * R_AB, T_A + R_A.apply(T_AB)  # camera B in body axes
OFFSET, BG, BA = 0.03, np.array([0.05, -0.04, 0.03]), np.array([0.3, -0.2, 0.25])
GYRO, ACCEL, PIXEL = 1.7e-4, 2.0e-3, 0.3  # densities, corner noise (px)
INTR = np.array([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
                 1.76187114e-05])
RES = (752, 480)
RIG = Rig(R_A.as_matrix(), T_A)


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def _camera_b(seed, duration):
    """Camera B's corners (outside8's visibility rule), stamped ``OFFSET`` late."""
    rng = np.random.default_rng(seed + 1000)
    P = grid()
    T, X, U = [], [], []
    for s in np.arange(0.3, duration - 0.3, 1 / RATE_CAM):
        R = RIG.rotation(np.array([s]))[0] @ R_B.as_matrix()
        p = RIG.position(np.array([s]))[0] + RIG.rotation(np.array([s]))[0] @ T_B
        xc = (P - p) @ R
        uv = radtan(INTR, xc)
        ok = ((xc[:, 2] > 0.05) & (uv[:, 0] > 2) & (uv[:, 0] < RES[0] - 3) & (uv[:, 1] > 2)
              & (uv[:, 1] < RES[1] - 3))
        T.append(np.full(ok.sum(), s - OFFSET))
        X.append(P[ok])
        U.append(uv[ok] + rng.normal(0, PIXEL, (ok.sum(), 2)))
    return np.concatenate(T), np.concatenate(X), np.concatenate(U)


@pytest.fixture(scope="module")
def solved():
    duration = 3.0
    (ti, g, a), obs_a = simulate(RIG, INTR, radtan, RES, duration=duration, offset=OFFSET,
                                 line_delay=0.0, pixel_sigma=PIXEL, gyro_density=GYRO,
                                 accel_density=ACCEL, bg=BG, ba=BA, seed=0)
    obs_b = _camera_b(0, duration)
    tk = np.unique(obs_a[0])
    Rc, pc = RIG.camera_pose(tk + OFFSET)  # camera A's poses, as the body's
    x0 = dq.from_rt(_t(Rotation.from_matrix(Rc).as_quat(scalar_first=True)), _t(pc))
    spline = BSpline.from_dualquats(x0, _t(tk), form="cumulative", degree=4, margin=0.45,
                                    knot_spacing=0.05)
    cam = Camera("pinhole-radtan", _t(INTR), RES)
    clock = Free(start=0.0)
    sg, sa = GYRO * math.sqrt(RATE_IMU), ACCEL * math.sqrt(RATE_IMU)
    terms = [Reprojections(*(_t(v) for v in obs_a), camera=cam, sigma=PIXEL, extrinsic=True),
             Reprojections(*(_t(v) for v in obs_b), camera=cam, sigma=PIXEL, extrinsic=True),
             Gyro(_t(ti), _t(g), sigma=sg, bias=True, time_offset=clock),
             Accel(_t(ti), _t(a), sigma=sa, bias=True, gravity=9.81, time_offset=clock)]
    return terms, estimate(spline, terms, verbose=False)


def _extrinsic_error(e, R, t):
    """``delta`` with ``e_true = e exp(delta)``, rotation then translation in camera axes."""
    E = dq.to_matrix(e.detach()).numpy()
    return np.concatenate([Rotation.from_matrix(E[:3, :3].T @ R.as_matrix()).as_rotvec(),
                           E[:3, :3].T @ (t - E[:3, 3])])


def test_converged_with_chi2_per_dof_near_one(solved):
    terms, est = solved
    assert bool(est.converged), est.reason
    for term in terms:
        ratio = float(est.chi2[term] / est.dof[term])
        assert 0.8 < ratio < 1.25, (type(term).__name__, ratio)


def test_truth_within_four_standard_deviations(solved):
    (cam_a, cam_b, gy, ac), est = solved
    err = np.concatenate([_extrinsic_error(cam_a.extrinsic, R_A, T_A),
                          _extrinsic_error(cam_b.extrinsic, R_B, T_B),
                          [float(gy.time_offset) + OFFSET], gy.bias.detach().numpy() - BG,
                          ac.bias.detach().numpy() - BA])
    std = np.concatenate([est.std(cam_a, "extrinsic").numpy(),
                          est.std(cam_b, "extrinsic").numpy(),
                          [float(est.std(gy, "time_offset"))], est.std(gy, "bias").numpy(),
                          est.std(ac, "bias").numpy()])
    assert np.all(np.isfinite(std)) and np.all(std > 0), std
    z = err / std
    assert np.all(np.abs(z) < 4.0), z

"""A new user's TUM fit (user12): the shipped 50 Hz fr1_xyz subsample (CC BY 4.0, TUM RGB-D,
Sturm et al. 2012) fitted in its own UNIX seconds; velocities against numpy estimates from the
raw poses: a 21-sample Savitzky-Golay derivative of the positions (scipy) and the slope of a
21-sample local cubic of the rotations ``log(R_j R_i^T)`` (world angular velocity), as the
README states them for the automatic knot spacing and for a 0.1 s one."""

import os

import numpy as np
import pytest
import torch
from scipy.signal import savgol_filter
from scipy.spatial.transform import Rotation

from torch_dq import io, nn

PATH = os.path.join(os.path.dirname(__file__), "data", "tum_fr1_xyz_sub.txt")
HALF = 10  # 21-sample windows


@pytest.fixture(scope="module")
def data():
    raw = np.loadtxt(PATH)
    t, p, R = raw[:, 0], raw[:, 1:4], Rotation.from_quat(raw[:, 4:8])  # TUM: qx qy qz qw
    inner = np.arange(2 * HALF, len(t) - 2 * HALF, 3)  # away from the curve's ends
    dt = np.median(np.diff(t))
    v = savgol_filter(p, 2 * HALF + 1, 3, deriv=1, delta=dt, axis=0)[inner]
    w = np.array([np.polyfit(t[i - HALF:i + HALF + 1] - t[i],
                             (R[i - HALF:i + HALF + 1] * R[i].inv()).as_rotvec(), 3)[-2]
                  for i in inner])
    return io.read_trajectory(PATH), torch.tensor(t[inner]), v, w


def _median_error(a, b):
    return float(np.median(np.linalg.norm(a - b, axis=-1)))


@pytest.mark.parametrize("spacing", [None, 0.1])
def test_velocities_in_the_files_seconds_against_the_raw_poses(data, spacing):
    traj, t, v_ref, w_ref = data
    assert float(t[0]) > 1.3e9  # UNIX seconds, float64
    n = None if spacing is None else int(np.ceil(float(traj.times[-1] - traj.times[0])
                                                 / spacing)) + 3
    spline = nn.BSpline.from_poses(traj.rotations, traj.translations, traj.times, n_ctrl=n)
    with torch.no_grad():
        k = spline.kinematics(t)
    speed = np.median(np.linalg.norm(v_ref, axis=-1))  # 0.33 m/s
    rate = np.median(np.linalg.norm(w_ref, axis=-1))  # 0.24 rad/s
    assert _median_error(k.linear_velocity.numpy(), v_ref) < 0.05 * speed
    w_error = _median_error(k.angular_velocity.numpy(), w_ref)
    if spacing is None:  # the README: angular rates follow the noise at the automatic spacing
        assert 0.25 * rate < w_error < 0.8 * rate
    else:  # and a coarser spacing smooths them
        assert w_error < 0.25 * rate

"""``calibration.cameras`` with default settings on synthetic stereo pairs (``_calib12_rig``:
OpenCV / the double sphere's formula, 0.3 px noise): intrinsics and the relative pose
within a few returned standard deviations of the truth, RMS at the noise."""

import numpy as np
import pytest
import torch
from _calib12_rig import DS, EQUI, HEIGHT, RADTAN, WIDTH, Cam, make_rig, rot
from scipy.spatial.transform import Rotation

from torch_dq import dualquat
from torch_dq.calibration import cameras

pytest.importorskip("cv2")

RADTAN1 = np.array([457.0, 456.0, 380.0, 255.0, -0.283, 0.0745, -1e-4, -3.5e-5])


def check_pair(cams, seed):
    rig = make_rig(cams, seed=seed, duration=4.0)
    obs = [tuple(torch.as_tensor(x, dtype=torch.float64) for x in o) for o in rig.observations]
    res = cameras(obs, [c.model for c in cams], [(WIDTH, HEIGHT)] * len(cams))
    assert bool(res.converged)
    np.testing.assert_allclose(res.reprojection_rms.numpy(), np.sqrt(2) * 0.3, rtol=0.05)
    for i, c in enumerate(cams):
        p = res.cameras[i].params.numpy()
        assert res.cameras[i].model == c.model and tuple(res.cameras[i].resolution) == (
            WIDTH, HEIGHT)
        z = (p - c.params) / res.std["intrinsics"][i, :p.size].numpy()
        assert np.abs(z).max() < 4, np.round(z, 2)
    # p_cam0 = T p_cam1, from the two cameras' poses on the rig
    R = cams[0].R_bc.T @ cams[1].R_bc
    t = cams[0].R_bc.T @ (cams[1].t_bc - cams[0].t_bc)
    M = dualquat.to_matrix(res.relative_poses[0]).numpy()
    err = np.r_[Rotation.from_matrix(R.T @ M[:3, :3]).as_rotvec(), R.T @ (M[:3, 3] - t)]
    z = err / res.std["relative_poses"][0].numpy()
    assert np.abs(z).max() < 4, np.round(z, 2)
    assert np.linalg.norm(M[:3, 3] - t) < 1e-3


def test_euroc_like_radtan_pair():
    """Two radtan cameras 11 cm apart, 0.8 degrees of relative yaw (EuRoC's rig)."""
    check_pair([Cam("pinhole-radtan", RADTAN, rot("x", 90), np.zeros(3), 0.01),
                Cam("pinhole-radtan", RADTAN1, rot("x", 90) @ rot("y", 0.8),
                    np.array([0.11, 0.0, 0.001]), 0.01)], seed=5)


def test_equidistant_and_double_sphere_pair():
    check_pair([Cam("pinhole-equidistant", EQUI, rot("x", 90), np.zeros(3), 0.01),
                Cam("double-sphere", DS, rot("x", 90) @ rot("y", 3), np.array([0.12, 0, 0]),
                    0.01)], seed=6)

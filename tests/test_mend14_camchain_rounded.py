"""``calibration.read_camchain`` on a camchain whose matrices a user rounded (mend14).

Kalibr writes 16 digits; a camchain copied into a paper, a launch file or a spreadsheet keeps
4 or 6 decimals, and its rotation blocks are then orthonormal only to ~1e-4. Such a file is
read (the rotation projected onto the nearest one: scipy's ``Rotation.from_matrix`` of the
rounded block, Markley's optimal quaternion, is the reference) and agrees with the unrounded
file within the rounding; a matrix that is not a rotation (scaled, a reflection, garbage) is
refused naming the file, the camera and the key. The matrices: Kalibr's EuRoC camchain (as
kept in github.com/ethz-asl/voxblox, ``euroc_camchain.yaml``, BSD 3; also in
``test_user11_camchain.py``).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_user11_camchain import T_C0_IMU, T_C1_C0, T_C1_IMU  # Kalibr's EuRoC camchain

from torch_dq import calibration, dualquat

yaml = pytest.importorskip("yaml")


def _doc(t0, t1, t10):
    common = {"camera_model": "pinhole", "distortion_model": "none",
              "resolution": [752, 480]}
    return {"cam0": {**common, "intrinsics": [461.3, 460.1, 366.4, 248.8], "T_cam_imu": t0},
            "cam1": {**common, "intrinsics": [459.7, 458.4, 380.0, 255.6], "T_cam_imu": t1,
                     "T_cn_cnm1": t10}}


def _read(tmp_path, doc, name):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return calibration.read_camchain(path), str(path)


def _round(T, decimals):
    return np.round(np.asarray(T), decimals).tolist()


def _pose(x):
    """``(R, t)`` numpy from a unit dual quaternion (through the 4 x 4 matrix)."""
    M = dualquat.to_matrix(x).numpy()
    return M[:3, :3], M[:3, 3]


def _inverse(T):
    T = np.asarray(T)
    R, t = T[:3, :3], T[:3, 3]
    return R.T, -R.T @ t


@pytest.mark.parametrize("decimals", [4, 6])
def test_rounded_camchain_reads_within_the_rounding(tmp_path, decimals):
    full, _ = _read(tmp_path, _doc(T_C0_IMU, T_C1_IMU, T_C1_C0), "full.yaml")
    mats = [_round(T, decimals) for T in (T_C0_IMU, T_C1_IMU, T_C1_C0)]
    rounded, _ = _read(tmp_path, _doc(*mats), "rounded.yaml")
    tol = 3 * 10.0 ** -decimals  # an entry moves by 0.5e-d, a rotation by ~1e-d rad
    for i, T in enumerate(mats[:2]):
        R, t = _pose(rounded.extrinsics[i])
        Rf, tf = _pose(full.extrinsics[i])
        # the nearest rotation of the rounded block: scipy (Markley's optimal quaternion)
        Rn = Rotation.from_matrix(np.asarray(T)[:3, :3]).as_matrix()
        np.testing.assert_allclose(R, Rn.T, atol=1e-12)
        np.testing.assert_allclose(t, -Rn.T @ np.asarray(T)[:3, 3], atol=1e-12)
        angle = Rotation.from_matrix(R @ Rf.T).magnitude()
        assert angle < tol, (i, angle)
        assert np.abs(t - tf).max() < tol
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)  # a rotation, exactly
    R, t = _pose(rounded.relative_poses[0])  # cam1 in cam0: the inverse of T_cn_cnm1
    Rf, tf = _inverse(T_C1_C0)
    assert Rotation.from_matrix(R @ Rf.T).magnitude() < tol
    assert np.abs(t - tf).max() < tol


@pytest.mark.parametrize("garbage, why", [
    (np.diag([1.01, 1.0, 1.0, 1.0]), "|R^T R - I|"),            # scaled by 1 %
    (np.diag([1.0, 1.0, -1.0, 1.0]), "det R"),                   # a reflection
    (np.arange(16.0).reshape(4, 4) / 10.0, "last row"),          # garbage
    (np.asarray(T_C1_C0) + 0.01 * np.outer(np.eye(4)[0], np.eye(4)[1]), "|R^T R - I|"),
])                                                               # sheared by 1e-2
def test_matrices_that_are_not_rotations_are_refused(tmp_path, garbage, why):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_doc(T_C0_IMU, T_C1_IMU, garbage.tolist())))
    with pytest.raises(ValueError) as err:
        calibration.read_camchain(path)
    message = str(err.value)
    assert str(path) in message and "cam1.T_cn_cnm1" in message and why in message, message


def test_rounded_t_cam_imu_names_its_camera_when_refused(tmp_path):
    bad = (1.02 * np.asarray(T_C0_IMU)).tolist()
    bad[3] = [0.0, 0.0, 0.0, 1.0]
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_doc(bad, T_C1_IMU, T_C1_C0)))
    with pytest.raises(ValueError, match=r"cam0\.T_cam_imu is not a rigid transform"):
        calibration.read_camchain(path)

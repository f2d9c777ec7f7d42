"""``python -m torch_dq calibrate`` with a camchain that has intrinsics for some cameras only
(mend14): the given ones are kept as they are (fixed), only the missing ones calibrated from
their corners. Before, one camera without intrinsics made the command recalibrate every
camera, throwing the user's intrinsics away. The truth: the synthetic rig's cameras
(``tests/_calib12_rig.py``), projected by the test's own numpy models."""

from pathlib import Path

import numpy as np
import pytest
from _calib12_rig import Cam, make_rig
from scipy.spatial.transform import Rotation
from test_calib12_cli import CAM, CAM_DS, calibrate_here, write_rig

yaml = pytest.importorskip("yaml")
pytest.importorskip("cv2")


def test_given_intrinsics_kept_missing_ones_calibrated(tmp_path):
    cams = [Cam(CAM.model, CAM.params, CAM.R_bc, CAM.t_bc, 0.01),
            Cam(CAM_DS.model, CAM_DS.params, CAM_DS.R_bc, CAM_DS.t_bc, -0.004)]
    files = write_rig(tmp_path / "in", make_rig(cams, seed=5, t0=0.0, duration=5.0))
    chain = yaml.safe_load(Path(files["--cameras"]).read_text())
    given = list(chain["cam0"]["intrinsics"])
    given[2] += 0.37  # cu off by a third of a pixel: a recalibration would move it back
    chain["cam0"]["intrinsics"] = given
    given_dist = list(chain["cam0"]["distortion_coeffs"])
    del chain["cam1"]["intrinsics"]
    Path(files["--cameras"]).write_text(yaml.safe_dump(chain))
    done = calibrate_here(files, tmp_path / "out", "--pixel-sigma", "0.3", "--bias", "constant")
    assert done.returncode == 0, done.stderr
    out = yaml.safe_load((tmp_path / "out" / "camchain-imucam.yaml").read_text())
    assert out["cam0"]["intrinsics"] == given  # kept, to the bit
    assert out["cam0"]["distortion_coeffs"] == given_dist
    want = np.r_[CAM_DS.kalibr()["intrinsics"]]  # Kalibr's ds order: xi, alpha, fu, fv, cu, cv
    np.testing.assert_allclose(out["cam1"]["intrinsics"], want, rtol=0.02, atol=0.02)
    assert out["cam1"]["intrinsics"] != list(want)  # calibrated, not copied
    for i, cam in enumerate(cams):  # the extrinsics near the truth (p_cam = T p_imu)
        T = np.array(out[f"cam{i}"]["T_cam_imu"])
        assert np.degrees(Rotation.from_matrix(T[:3, :3] @ cam.R_bc).magnitude()) < 0.2
        np.testing.assert_allclose(T[:3, 3], -cam.R_bc.T @ cam.t_bc, atol=5e-3)

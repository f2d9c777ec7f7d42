"""``calibration.read_camchain`` (user11): Kalibr's camchain yaml read back.

A new user could write a camchain (``to_kalibr()``, ``python -m torch_dq calibrate``) but
not read one: only one camera at a time (``Camera.from_kalibr``), with the chain of
``T_cn_cnm1``, the ``T_cam_imu`` inverses and ``timeshift_cam_imu`` left to hand-written
code. The reference: numpy's matrix inverses and products of the file's own matrices, and
the file written by Kalibr itself for EuRoC (its ``camchain-imucam.yaml``, as kept in
github.com/ethz-asl/voxblox, ``voxblox_ros/cfg/calibrations/euroc_camchain.yaml``, BSD 3).
"""

import numpy as np
import pytest

from torch_dq import calibration, dualquat

yaml = pytest.importorskip("yaml")

T_C0_IMU = [[0.014067833389924844, 0.9996023098557362, -0.024440094001271714, 0.0657094717307726],
            [-0.9998997399258257, 0.014103075047756597, 0.0012701852087405128,
             -0.01662153508680676],
            [0.0016143605484757653, 0.0244197748817434, 0.9997004893640622,
             0.0014868599890966905],
            [0.0, 0.0, 0.0, 1.0]]
T_C1_IMU = [[0.011810542390279122, 0.9995951714398011, -0.02588444171084584,
             -0.04439379107435547],
            [-0.9998052969172723, 0.01221433647773218, 0.015497685006934178,
             -0.016235309745499065],
            [0.01580757238202092, 0.025696365864524458, 0.9995448051171812,
             0.0012030335279962774],
            [0.0, 0.0, 0.0, 1.0]]
T_C1_C0 = [[0.9999964092230391, 0.0022551294207702314, -0.0014477335121195142,
            -0.11006339056724425],
           [-0.002234380261272062, 0.9998970009983116, 0.014177268405057909,
            0.000510253673254922],
           [0.0014795559720994585, -0.014173982710466103, 0.9998984494078623,
            -0.0006164896618526655],
           [0.0, 0.0, 0.0, 1.0]]


def _kalibr_euroc():
    common = {"camera_model": "pinhole", "distortion_model": "equidistant",
              "resolution": [752, 480]}
    return {
        "cam0": {**common, "T_cam_imu": T_C0_IMU, "cam_overlaps": [1],
                 "distortion_coeffs": [-0.011602611404146694, 0.05399058892805103,
                                       -0.07542693754837938, 0.03666365316319072],
                 "intrinsics": [461.3418503026154, 460.13885656354387, 366.4281018364134,
                                248.8415565479774],
                 "rostopic": "/cam0/image_raw", "timeshift_cam_imu": -0.0016},
        "cam1": {**common, "T_cam_imu": T_C1_IMU, "T_cn_cnm1": T_C1_C0, "cam_overlaps": [0],
                 "distortion_coeffs": [0.005730625619095735, -0.009587210461496316,
                                       0.01921165649877144, -0.010717188529046507],
                 "intrinsics": [459.6820431465863, 458.37659300282706, 380.01198798196646,
                                255.55347731935623],
                 "rostopic": "/cam1/image_raw", "timeshift_cam_imu": 0.0025},
    }


def _write(tmp_path, doc, name="camchain-imucam.yaml"):
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc))
    return path


def test_kalibr_euroc_camchain(tmp_path):
    chain = calibration.read_camchain(_write(tmp_path, _kalibr_euroc()))
    assert [c.model for c in chain.cameras] == ["pinhole-equidistant"] * 2
    np.testing.assert_allclose(chain.cameras[1].params[:2].numpy(),
                               [459.6820431465863, 458.37659300282706], rtol=0, atol=0)
    rel = dualquat.to_matrix(chain.relative_poses[0]).numpy()  # p_cam0 = rel p_cam1
    np.testing.assert_allclose(rel, np.linalg.inv(T_C1_C0), atol=1e-12)
    ext = dualquat.to_matrix(chain.extrinsics).numpy()  # p_imu = e p_cam
    np.testing.assert_allclose(ext[0], np.linalg.inv(T_C0_IMU), atol=1e-12)
    np.testing.assert_allclose(ext[1], np.linalg.inv(T_C1_IMU), atol=1e-12)
    # Kalibr's T_cn_cnm1 is its T_cam_imu's chain: the two readings agree (to its rounding)
    np.testing.assert_allclose(rel, np.array(T_C0_IMU) @ np.linalg.inv(T_C1_IMU), atol=1e-6)
    np.testing.assert_allclose(chain.time_offsets.numpy(), [-0.0016, 0.0025], atol=0)
    assert chain.rostopics == ["/cam0/image_raw", "/cam1/image_raw"]


def test_three_cameras_chain_and_what_is_absent(tmp_path):
    """cam2's pose in cam0's frame is ``inv(T_c2_c1 T_c1_c0)``; a camchain without
    ``T_cam_imu`` or ``timeshift_cam_imu`` gives ``None`` for them."""
    doc = _kalibr_euroc()
    step = np.eye(4)
    step[:3, :3] = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    step[:3, 3] = [0.05, -0.02, 0.3]
    doc["cam2"] = {**doc["cam1"], "T_cn_cnm1": step.tolist()}
    for e in doc.values():
        del e["T_cam_imu"], e["timeshift_cam_imu"]
    del doc["cam2"]["rostopic"]
    chain = calibration.read_camchain(_write(tmp_path, doc, "camchain.yaml"))
    assert chain.extrinsics is None and chain.time_offsets is None
    assert chain.rostopics == ["/cam0/image_raw", "/cam1/image_raw", None]
    rel = dualquat.to_matrix(chain.relative_poses).numpy()
    np.testing.assert_allclose(rel[1], np.linalg.inv(step @ np.array(T_C1_C0)), atol=1e-12)
    del doc["cam1"]["T_cn_cnm1"]
    assert calibration.read_camchain(_write(tmp_path, doc, "c2.yaml")).relative_poses is None
    one = calibration.read_camchain(_write(tmp_path, {"cam0": doc["cam0"]}, "c1.yaml"))
    assert one.relative_poses.shape == (0, 8)


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.pop("cam0"), r"expected cameras cam0, cam1"),
    (lambda d: d.update(cam1="x"), r"cam1 must be a mapping"),
    (lambda d: d["cam1"].update(camera_model="omni"), r"cam1: .*unsupported camera_model"),
    (lambda d: d["cam1"]["T_cn_cnm1"][0].__setitem__(0, 2.0),
     r"cam1.T_cn_cnm1 is not a rigid transform"),
    (lambda d: d["cam0"].update(T_cam_imu=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]),
     r"cam0.T_cam_imu must be a 4 x 4 matrix"),
    (lambda d: d["cam0"].update(timeshift_cam_imu="soon"), r"timeshift_cam_imu must be numbers"),
])
def test_errors_name_the_file_and_the_camera(tmp_path, edit, match):
    doc = _kalibr_euroc()
    doc["cam1"]["T_cn_cnm1"] = [list(r) for r in T_C1_C0]
    edit(doc)
    path = _write(tmp_path, doc)
    with pytest.raises(ValueError, match=match) as info:
        calibration.read_camchain(path)
    assert str(info.value).startswith("calibration.read_camchain: ") and str(path) in str(
        info.value)

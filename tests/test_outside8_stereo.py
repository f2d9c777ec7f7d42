"""A new user's stereo calibration of real EuRoC AprilGrid corners (outside8), side by side
with OpenCV on the same detections, and Kalibr's camchain files written and read.

OpenCV is the independent reference: ``cv2.calibrateCamera`` (plumb bob with ``k3`` fixed at
0: our ``pinhole-radtan``), ``cv2.fisheye.calibrate`` (our ``pinhole-equidistant``) and
``cv2.stereoCalibrate`` (both cameras and their relative pose). Both minimise the same sum of
squared pixel errors, so on the same corners they must land on the same minimum: equal
reprojection RMS, intrinsics and baseline. The Kalibr file written by Kalibr itself is
EuRoC's ``camchain-imucam.yaml`` (Kannala-Brandt intrinsics), as kept in
github.com/ethz-asl/voxblox (``voxblox_ros/cfg/calibrations/euroc_camchain.yaml``, BSD 3).
"""

import os

import numpy as np
import pytest
import torch

from torch_dq import calibration, dualquat
from torch_dq.camera import Camera

cv2 = pytest.importorskip("cv2")
yaml = pytest.importorskip("yaml")

DATA = os.path.join(os.path.dirname(__file__), "data", "calibration")
RES = (752, 480)
CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 300, 1e-14)

KALIBR_EUROC = """\
cam0:
  T_cam_imu:
  - [0.014067833389924844, 0.9996023098557362, -0.024440094001271714, 0.0657094717307726]
  - [-0.9998997399258257, 0.014103075047756597, 0.0012701852087405128, -0.01662153508680676]
  - [0.0016143605484757653, 0.0244197748817434, 0.9997004893640622, 0.0014868599890966905]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.011602611404146694, 0.05399058892805103, -0.07542693754837938,
    0.03666365316319072]
  distortion_model: equidistant
  intrinsics: [461.3418503026154, 460.13885656354387, 366.4281018364134, 248.8415565479774]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  flip_camera: true
cam1:
  T_cam_imu:
  - [0.011810542390279122, 0.9995951714398011, -0.02588444171084584, -0.04439379107435547]
  - [-0.9998052969172723, 0.01221433647773218, 0.015497685006934178, -0.016235309745499065]
  - [0.01580757238202092, 0.025696365864524458, 0.9995448051171812, 0.0012030335279962774]
  - [0.0, 0.0, 0.0, 1.0]
  T_cn_cnm1:
  - [0.9999964092230391, 0.0022551294207702314, -0.0014477335121195142, -0.11006339056724425]
  - [-0.002234380261272062, 0.9998970009983116, 0.014177268405057909, 0.000510253673254922]
  - [0.0014795559720994585, -0.014173982710466103, 0.9998984494078623, -0.0006164896618526655]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [0.005730625619095735, -0.009587210461496316, 0.01921165649877144,
    -0.010717188529046507]
  distortion_model: equidistant
  intrinsics: [459.6820431465863, 458.37659300282706, 380.01198798196646, 255.55347731935623]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
  flip_camera: true
"""


def _read(i):
    return calibration.read_corners(os.path.join(DATA, f"euroc_cam_april_cam{i}_corners.csv"))


@pytest.fixture(scope="module")
def common():
    """Both cameras' observations restricted to the corners both saw in a frame (what
    ``cv2.stereoCalibrate`` needs), in the same order, and per-frame numpy lists."""
    obs = [_read(0), _read(1)]
    keys = [[(float(t), *np.round(p.numpy(), 6)) for t, p in zip(o[0], o[1], strict=True)]
            for o in obs]
    both = sorted(set(keys[0]) & set(keys[1]))
    out = []
    for o, k in zip(obs, keys, strict=True):
        index = {key: n for n, key in enumerate(k)}
        order = torch.tensor([index[key] for key in both])
        out.append(tuple(a[order] for a in o))
    return out


def _frames(obs, dtype=np.float32):
    t, p, u = (a.numpy() for a in obs)
    stamps = np.unique(t)
    return ([p[t == s].astype(dtype) for s in stamps], [u[t == s].astype(dtype) for s in stamps])


def _k(matrix, dist):
    return [matrix[0, 0], matrix[1, 1], matrix[0, 2], matrix[1, 2], *np.ravel(dist)[:4]]


def test_mono_radtan_matches_opencv_calibrate_camera():
    obs = _read(0)
    points, pixels = _frames(obs)
    rms, K, dist, _, _ = cv2.calibrateCamera(points, pixels, RES, None, None,
                                             flags=cv2.CALIB_FIX_K3, criteria=CRITERIA)
    ours = calibration.cameras([obs], ["pinhole-radtan"], [RES])
    assert abs(float(ours.reprojection_rms[0]) - rms) < 1e-5 * rms
    np.testing.assert_allclose(ours.cameras[0].params.numpy(), _k(K, dist), rtol=2e-5,
                               atol=2e-6)


def test_mono_radtan_where_opencv_diverges():
    """EuRoC's cam1 alone: ``cv2.calibrateCamera`` (default start) runs off to fu ~2500 px
    at 1.5 px RMS; ours stays near the published 458 px (a 30-frame set: 495) at 0.4 px."""
    obs = _read(1)
    ours = calibration.cameras([obs], ["pinhole-radtan"], [RES])
    rms = cv2.calibrateCamera(*_frames(obs), RES, None, None, flags=cv2.CALIB_FIX_K3)[0]
    assert float(ours.reprojection_rms[0]) < 0.45 < rms
    assert 440 < float(ours.cameras[0].params[0]) < 510


def test_mono_equidistant_matches_opencv_fisheye():
    obs = _read(0)
    points, pixels = _frames(obs, np.float64)
    guess = np.array([[450.0, 0, 376], [0, 450, 240], [0, 0, 1]])
    rms, K, dist, _, _ = cv2.fisheye.calibrate(
        [p[None] for p in points], [u[None] for u in pixels], RES, guess, np.zeros((4, 1)),
        flags=cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW | cv2.CALIB_USE_INTRINSIC_GUESS,
        criteria=CRITERIA)
    ours = calibration.cameras([obs], ["pinhole-equidistant"], [RES])
    assert abs(float(ours.reprojection_rms[0]) - rms) < 1e-6 * rms
    np.testing.assert_allclose(ours.cameras[0].params.numpy(), _k(K, dist), rtol=1e-6,
                               atol=1e-7)


@pytest.fixture(scope="module")
def stereo(common):
    return calibration.cameras(common, ["pinhole-radtan"] * 2, [RES, RES])


def test_stereo_matches_opencv_stereo_calibrate(common, stereo):
    """Same minimum as ``cv2.stereoCalibrate`` (both cameras started from OpenCV's mono
    calibration of camera 0: camera 1's alone diverges, see above): the RMS over both
    cameras, the eight intrinsics each and the relative pose."""
    (p0, u0), (_, u1) = _frames(common[0]), _frames(common[1])
    mono = cv2.calibrateCamera(p0, u0, RES, None, None, flags=cv2.CALIB_FIX_K3)[1:3]
    # copies: OpenCV refines the guesses in place, the same arrays would alias K0 and K1
    rms, K0, d0, K1, d1, R, T = cv2.stereoCalibrate(
        p0, u0, u1, *(m.copy() for m in mono), *(m.copy() for m in mono), RES,
        criteria=CRITERIA,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3)[:7]
    ours = stereo.reprojection_rms.numpy()
    assert abs(float(np.sqrt(np.mean(ours ** 2))) - rms) < 1e-5 * rms  # equal counts
    for cam, K, d in zip(stereo.cameras, (K0, K1), (d0, d1), strict=True):
        np.testing.assert_allclose(cam.params.numpy(), _k(K, d), rtol=1e-4, atol=1e-5)
    # OpenCV: x1 = R x0 + T, camera 0 to camera 1 (Kalibr's T_cn_cnm1)
    T_c1_c0 = np.linalg.inv(dualquat.to_matrix(stereo.relative_poses[0]).numpy())
    np.testing.assert_allclose(T_c1_c0[:3, :3], R, atol=1e-6)
    np.testing.assert_allclose(T_c1_c0[:3, 3], T.ravel(), atol=1e-6)  # metres
    assert abs(np.linalg.norm(T) - 0.1101) < 1e-3  # EuRoC's published baseline


def test_camchain_written_and_read_back_exactly(stereo, tmp_path):
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.safe_dump(stereo.to_kalibr()))
    chain = yaml.safe_load(path.read_text())
    assert sorted(chain) == ["cam0", "cam1"] and "T_cn_cnm1" not in chain["cam0"]
    for i, cam in enumerate(stereo.cameras):
        back = Camera.from_kalibr(chain[f"cam{i}"])
        assert back == cam  # float64 parameters bit for bit
        assert chain[f"cam{i}"]["rostopic"] == f"/cam{i}/image_raw"
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    rel = dualquat.to_matrix(stereo.relative_poses[0]).numpy()
    np.testing.assert_allclose(T @ rel, np.eye(4), atol=1e-14)
    topics = stereo.to_kalibr(["/left", "/right"])
    assert [topics[c]["rostopic"] for c in ("cam0", "cam1")] == ["/left", "/right"]
    for bad in ("/left", ["/left"], ["/left", 1]):
        with pytest.raises(ValueError, match=r"CameraCalibration\.to_kalibr: expected rostopics"):
            stereo.to_kalibr(bad)


def _kannala_brandt(k, xc):
    """OpenCV's fisheye model written out (Kannala, Brandt 2006; OpenCV fisheye docs)."""
    r = np.hypot(xc[:, 0], xc[:, 1])
    th = np.arctan2(r, xc[:, 2])
    d = th * (1 + k[4] * th ** 2 + k[5] * th ** 4 + k[6] * th ** 6 + k[7] * th ** 8)
    return np.stack([k[0] * d / r * xc[:, 0] + k[2], k[1] * d / r * xc[:, 1] + k[3]], 1)


def test_a_camchain_written_by_kalibr_reads_correctly(tmp_path):
    """EuRoC's Kalibr file: the order of the parameters (Kalibr's ``[fu, fv, pu, pv]`` then
    ``k1..k4``), its equidistant model against the formula, and our own calibration of the
    30 frames of corners within 2 mm and 0.5 deg of its ``T_cn_cnm1``."""
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(KALIBR_EUROC)
    chain = yaml.safe_load(path.read_text())
    cams = [Camera.from_kalibr(chain[f"cam{i}"]) for i in (0, 1)]
    assert cams[0].model == "pinhole-equidistant" and cams[0].resolution == RES
    entry = chain["cam0"]
    assert cams[0].params.tolist() == entry["intrinsics"] + entry["distortion_coeffs"]
    xc = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 0.8], [0.01, 0.02, 2.0]])
    for cam in cams:
        uv, ok = cam.project(torch.tensor(xc))
        np.testing.assert_allclose(uv.numpy(), _kannala_brandt(cam.params.numpy(), xc),
                                   rtol=0, atol=1e-10)
        assert bool(ok.all())
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    mine = calibration.cameras([_read(0), _read(1)], ["pinhole-equidistant"] * 2, [RES, RES])
    rel = dualquat.to_matrix(mine.relative_poses[0]).numpy()  # p_cam0 = rel p_cam1
    delta = T @ rel
    assert np.linalg.norm(delta[:3, 3]) < 2e-3
    assert np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1))) < 0.5


def test_detected_corners_of_the_raw_pair_fit_the_published_calibration():
    """``detect`` on the raw stereo pair: all 144 corners of each image, and OpenCV's own
    ``solvePnP`` with EuRoC's published radtan intrinsics fits them to 0.25 px RMS (measured
    0.16, 0.14): the corners are where a calibrated camera sees them."""
    target = calibration.Target("aprilgrid", 6, 6, 0.088, 0.3)
    published = ([458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907, 0.00019359,
                  1.76187114e-05], [457.587, 456.134, 379.999, 255.238, -0.28368365,
                                    0.07451284, -0.00010473, -3.55590700e-05])
    for c, k in enumerate(published):
        image = cv2.imread(os.path.join(DATA, f"cam{c}_1403709395937837056.png"),
                           cv2.IMREAD_GRAYSCALE)
        tags, corners, pixels, points = calibration.detect(image, target)
        assert len(tags) == 144 and sorted(set(tags.tolist())) == list(range(36))
        np.testing.assert_allclose(points.numpy(), calibration.aprilgrid(6, 6, 0.088, 0.3)[
            (tags * 4 + corners).numpy()].numpy(), atol=1e-12)
        K = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1]])
        _, rvec, tvec = cv2.solvePnP(points.numpy(), pixels.numpy(), K, np.array(k[4:]))
        fitted = cv2.projectPoints(points.numpy(), rvec, tvec, K, np.array(k[4:]))[0][:, 0]
        assert np.sqrt(np.mean(np.sum((fitted - pixels.numpy()) ** 2, 1))) < 0.25


def test_stereo_standard_deviations_are_honest_on_white_noise():
    """Corners re-projected by OpenCV's ``projectPoints`` from a calibration of the real
    frames (its target poses, intrinsics and relative pose as the truth), 0.25 px white noise:
    over 2 seeds and 22 values (16 intrinsics, the 6 of the relative pose) the RMS of
    error / std is near 1 (1.11 over 6 seeds); none beyond 4.5."""
    from scipy.spatial.transform import Rotation

    obs = [_read(0), _read(1)]
    truth = calibration.cameras(obs, ["pinhole-radtan"] * 2, [RES, RES])
    frames = dualquat.to_matrix(truth.target_poses).numpy()
    rel = dualquat.to_matrix(truth.relative_poses[0]).numpy()
    clean = []
    for c, (t, p, _) in enumerate(obs):
        k = truth.cameras[c].params.numpy()
        K = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1]])
        u = np.zeros((len(t), 2))
        for f, stamp in enumerate(truth.frame_times.tolist()):
            m = (t == stamp).numpy()
            M = frames[f] if c == 0 else np.linalg.inv(rel) @ frames[f]
            u[m] = cv2.projectPoints(p[m].numpy(), cv2.Rodrigues(M[:3, :3])[0], M[:3, 3], K,
                                     np.array([*k[4:], 0.0]))[0][:, 0]
        clean.append(u)
    z = []
    for seed in range(2):
        rng = np.random.default_rng(seed)
        noisy = [(t, p, torch.tensor(u + rng.normal(0, 0.25, u.shape)))
                 for (t, p, _), u in zip(obs, clean, strict=True)]
        r = calibration.cameras(noisy, ["pinhole-radtan"] * 2, [RES, RES])
        got = dualquat.to_matrix(r.relative_poses[0]).numpy()
        d_pose = np.r_[Rotation.from_matrix(got[:3, :3].T @ rel[:3, :3]).as_rotvec(),
                       got[:3, :3].T @ (rel[:3, 3] - got[:3, 3])]
        err = np.r_[np.concatenate([(a.params - b.params).numpy() for a, b in
                                    zip(r.cameras, truth.cameras, strict=True)]), d_pose]
        std = np.r_[r.std["intrinsics"].numpy().ravel(), r.std["relative_poses"][0].numpy()]
        z.append(err / std)
    z = np.concatenate(z)
    assert np.abs(z).max() < 4.5, z.round(2)
    assert 0.7 < float(np.sqrt(np.mean(z ** 2))) < 1.4, z.round(2)

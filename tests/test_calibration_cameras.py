"""calibration.cameras: intrinsics and relative poses from target observations alone.

References: OpenCV (``calibrateCamera``, ``stereoCalibrate``, ``projectPoints``,
``fisheye.projectPoints``), the double sphere paper's projection written here in numpy, the
published EuRoC calibration (``tests/data/calibration/README.md``).
"""

import math
import os

import numpy as np
import pytest
import torch

from torch_dq import calibration, dualquat, quat

cv2 = pytest.importorskip("cv2")

DATA = os.path.join(os.path.dirname(__file__), "data", "calibration")
RES = (752, 480)
PUBLISHED = [
    np.array([458.654, 457.296, 367.215, 248.375,
              -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]),
    np.array([457.587, 456.134, 379.999, 255.238,
              -0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]),
]
PUBLISHED_T = np.array([0.110074, -0.000157, 0.000889])


def _csv(cam):
    """(t_ns, tag_id, corner_idx, u, v, X, Y, Z) of one camera's corners, read with numpy."""
    path = os.path.join(DATA, f"euroc_cam_april_cam{cam}_corners.csv")
    ints = np.loadtxt(path, delimiter=",", comments="#", dtype=np.int64, usecols=(0, 1, 2))
    floats = np.loadtxt(path, delimiter=",", comments="#", usecols=(3, 4, 5, 6, 7))
    return ints, floats


def _observation(ints, floats):
    return (torch.tensor(ints[:, 0] * 1e-9), torch.tensor(floats[:, 2:5]),
            torch.tensor(floats[:, 0:2]))


@pytest.fixture(scope="module")
def euroc():
    return [_csv(0), _csv(1)]


@pytest.fixture(scope="module")
def euroc_result(euroc):
    obs = [_observation(*c) for c in euroc]
    return calibration.cameras(obs, ["pinhole-radtan"] * 2, [RES] * 2)


def _views(ints, floats):
    """OpenCV's per-view lists (float64 object points, float64 pixels)."""
    out = []
    for t in np.unique(ints[:, 0]):
        m = ints[:, 0] == t
        out.append((floats[m, 2:5].astype(np.float32), floats[m, 0:2].astype(np.float32)))
    return out


_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 500, 1e-15)


def test_euroc_one_camera_equals_opencv(euroc):
    """Camera 0 alone: the least-squares optimum equals OpenCV's calibrateCamera (k3 = 0),
    started by OpenCV from the published values (ours from nothing)."""
    ints, floats = euroc[0]
    res = calibration.cameras([_observation(ints, floats)], ["pinhole-radtan"], [RES])
    obj, img = zip(*_views(ints, floats), strict=True)
    p = PUBLISHED[0]
    K0 = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    rms, K, d, _, _ = cv2.calibrateCamera(
        list(obj), list(img), RES, K0, np.r_[p[4:], 0.0],
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3, criteria=_CRITERIA)
    ref = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], d.ravel()[:4]]
    got = res.cameras[0].params.numpy()
    # float32 pixels in OpenCV: its optimum moves by ~1e-3 px
    np.testing.assert_allclose(got[:4], ref[:4], atol=0.02)
    np.testing.assert_allclose(got[4:], ref[4:], atol=2e-5)
    assert abs(float(res.reprojection_rms[0]) - rms) < 1e-4
    assert res.converged and int(res.excluded[0]) == 0


def _common(euroc):
    """The corners both cameras saw in each shared frame (by tag id and corner index)."""
    (i0, f0), (i1, f1) = euroc
    key0 = {tuple(k): n for n, k in enumerate(i0)}
    rows0, rows1 = [], []
    for n, k in enumerate(i1):
        if tuple(k) in key0:
            rows0.append(key0[tuple(k)])
            rows1.append(n)
    return (i0[rows0], f0[rows0]), (i1[rows1], f1[rows1])


def test_euroc_stereo_equals_opencv(euroc):
    """Both cameras on their common corners: the joint optimum (intrinsics and relative
    pose) equals OpenCV's stereoCalibrate started from the published values."""
    c0, c1 = _common(euroc)
    res = calibration.cameras([_observation(*c0), _observation(*c1)], ["pinhole-radtan"] * 2,
                              [RES] * 2)
    v0, v1 = _views(*c0), _views(*c1)
    Ks = [np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]]) for p in PUBLISHED]
    ds = [np.r_[p[4:], 0.0] for p in PUBLISHED]
    out = cv2.stereoCalibrate(
        [o for o, _ in v0], [i for _, i in v0], [i for _, i in v1], Ks[0], ds[0], Ks[1],
        ds[1], RES, flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3,
        criteria=_CRITERIA)
    _, K0, d0, K1, d1, R, T = out[:7]
    for cam, K, d in ((0, K0, d0), (1, K1, d1)):
        got = res.cameras[cam].params.numpy()
        np.testing.assert_allclose(got[:4], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], atol=0.05)
        np.testing.assert_allclose(got[4:], d.ravel()[:4], atol=5e-5)
    # OpenCV: p_cam1 = R p_cam0 + T; ours: p_cam0 = T01 p_cam1
    M = dualquat.to_matrix(res.relative_poses[0]).numpy()
    np.testing.assert_allclose(M[:3, :3], R.T, atol=2e-5)
    np.testing.assert_allclose(M[:3, 3], -R.T @ T.ravel(), atol=2e-5)


def test_euroc_against_published(euroc_result):
    """All corners of both cameras, no guesses: what the 30 frames (1.45 s of one sweep,
    ~20 deg of tilt) give against the published calibration (made from a long sequence).

    Reached: RMS 0.27 / 0.41 px; relative translation within 8 mm, rotation within 1 deg
    of the published. NOT reached: the focal lengths are ~27 px above the published ones
    (485 / 486 px); OpenCV's calibrateCamera of each camera alone lands at 478 / 495 px, so
    this is the data's least-squares optimum (the views do not separate the focal length
    from the distance), not the solver: see the two OpenCV tests above.
    """
    res = euroc_result
    assert res.converged
    assert (res.reprojection_rms < 0.6).all()
    assert float(res.sigma) < 0.35
    for cam in (0, 1):
        got = res.cameras[cam].params.numpy()
        assert np.all(np.abs(got[2:4] - PUBLISHED[cam][2:4]) < 10.0)
        assert np.all(np.abs(got[4:6] - PUBLISHED[cam][4:6]) < 0.03)
        assert np.all(np.abs(got[:2] - PUBLISHED[cam][:2]) < 35.0)
    q, t = dualquat.to_rt(res.relative_poses[0])
    assert np.linalg.norm(t.numpy() - PUBLISHED_T) < 8e-3
    assert float(quat.to_rotvec(q).norm()) < math.radians(1.5)
    assert res.std["intrinsics"].shape == (2, 8) and res.std["relative_poses"].shape == (1, 6)
    assert torch.isfinite(res.std["intrinsics"]).all()
    assert res.target_poses.shape == (30, 8) and res.frame_times.shape == (30,)
    assert [c.model for c in res.cameras] == ["pinhole-radtan"] * 2
    assert [c.resolution for c in res.cameras] == [RES] * 2


# ----------------------------------------------------------------------------- synthetic

TRUE = {
    "pinhole-radtan": [np.array([460.0, 458.0, 370.0, 245.0, -0.28, 0.07, 2e-4, -1e-4]),
                       np.array([455.0, 456.0, 380.0, 250.0, -0.27, 0.075, -1e-4, 3e-5])],
    "pinhole-equidistant": [np.array([260.0, 259.0, 372.0, 242.0, 0.02, -0.01, 0.004, -0.001]),
                            np.array([262.0, 261.0, 378.0, 238.0, 0.015, -0.005, 0.002, 0.0])],
    "double-sphere": [np.array([240.0, 239.0, 372.0, 242.0, -0.2, 0.6]),
                      np.array([245.0, 244.0, 378.0, 238.0, -0.18, 0.58])],
}
T01 = (np.array([0.11, 0.001, -0.002]), np.array([0.005, -0.01, 0.003]))  # t, rotvec


def _rotvec_matrix(r):
    return cv2.Rodrigues(np.asarray(r, dtype=np.float64))[0]


def _project(model, p, X):
    """Pixels (N, 2) of camera-frame points X (N, 3) by OpenCV or the paper's formula."""
    K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    zero = np.zeros(3)
    if model == "pinhole-radtan":
        return cv2.projectPoints(X, zero, zero, K, np.r_[p[4:], 0.0])[0][:, 0]
    if model == "pinhole-equidistant":
        return cv2.fisheye.projectPoints(X[None], zero, zero, K, p[4:])[0][0]
    xi, alpha = p[4], p[5]  # Usenko et al. 2018, eqs. 40-41
    d1 = np.linalg.norm(X, axis=1)
    d2 = np.sqrt(X[:, 0] ** 2 + X[:, 1] ** 2 + (xi * d1 + X[:, 2]) ** 2)
    den = alpha * d2 + (1 - alpha) * (xi * d1 + X[:, 2])
    return np.stack((p[0] * X[:, 0] / den + p[2], p[1] * X[:, 1] / den + p[3]), 1)


def _scene(rng, frames, spread):
    """Checkerboard corners (9 x 7, 4 cm) and target poses in camera 0 (R, t): the board's
    centre up to ``spread`` rad off the optical axis, facing the camera within ~30 deg."""
    X, Y = np.meshgrid(np.arange(9) * 0.04, np.arange(7) * 0.04)
    pts = np.stack((X.ravel(), Y.ravel(), np.zeros(X.size)), 1)
    centre = pts.mean(0)
    poses = []
    for _ in range(frames):
        theta, phi = spread * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        direction = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                              math.cos(theta)])
        look = _rotvec_matrix(np.cross([0, 0, 1.0], direction) / max(math.sin(theta), 1e-12)
                              * theta)
        R = look @ _rotvec_matrix(rng.uniform(-0.5, 0.5, 3)) @ _rotvec_matrix([math.pi, 0, 0])
        t = rng.uniform(0.35, 0.8) * direction
        poses.append((R, t - R @ centre))
    return pts, poses


def _simulate(model, rng, frames=16, noise=0.3):
    """Observations of two cameras (p_cam0 = T01 p_cam1) with Gaussian pixel noise."""
    pts, poses = _scene(rng, frames, 0.35 if model == "pinhole-radtan" else 1.1)
    R01, t01 = _rotvec_matrix(T01[1]), T01[0]
    obs = [[], []]
    for f, (R, t) in enumerate(poses):
        for cam in (0, 1):
            Xc = pts @ R.T + t
            if cam:
                Xc = (Xc - t01) @ R01
            uv = _project(model, TRUE[model][cam], Xc)
            uv = uv + noise * rng.standard_normal(uv.shape)
            inside = ((uv[:, 0] > 0) & (uv[:, 0] < RES[0] - 1) & (uv[:, 1] > 0)
                      & (uv[:, 1] < RES[1] - 1) & (Xc[:, 2] > 0.05))
            obs[cam].append((np.full(inside.sum(), 0.05 * f), pts[inside], uv[inside]))
    return [tuple(torch.tensor(np.concatenate(x)) for x in zip(*o, strict=True)) for o in obs]


def _errors(model, res):
    """(estimate - truth) / std of every intrinsic and of the relative pose's chart."""
    z = [(res.cameras[c].params.numpy() - TRUE[model][c]) / res.std["intrinsics"][c].numpy()
         for c in (0, 1)]
    T = dualquat.from_rt(quat.from_rotvec(torch.tensor(T01[1])), torch.tensor(T01[0]))
    delta = dualquat.log(dualquat.mul(dualquat.inv(res.relative_poses[0]), T))
    return np.concatenate(z + [delta.numpy() / res.std["relative_poses"][0].numpy()])


@pytest.mark.parametrize("model", ["pinhole-radtan", "pinhole-equidistant", "double-sphere"])
def test_synthetic_within_4_std(model):
    """OpenCV-projected (the paper's formula for the double sphere) corners, 0.3 px noise:
    every intrinsic and the relative pose's chart land within 4 standard deviations."""
    rng = np.random.default_rng(7)
    res = calibration.cameras(_simulate(model, rng), [model] * 2, [RES] * 2)
    assert res.converged
    z = _errors(model, res)
    assert np.all(np.abs(z) < 4.0), z
    assert abs(res.sigma - 0.3) < 0.03
    assert (res.reprojection_rms < 0.3 * math.sqrt(2) * 1.1).all()

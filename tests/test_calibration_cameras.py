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
    """Camera 0 alone: the least-squares optimum and its standard deviations equal OpenCV's
    calibrateCameraExtended (k3 = 0), started by OpenCV from the published values (ours from
    nothing)."""
    ints, floats = euroc[0]
    res = calibration.cameras([_observation(ints, floats)], ["pinhole-radtan"], [RES])
    obj, img = zip(*_views(ints, floats), strict=True)
    p = PUBLISHED[0]
    K0 = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    rms, K, d, _, _, std = cv2.calibrateCameraExtended(
        list(obj), list(img), RES, K0, np.r_[p[4:], 0.0],
        flags=cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3, criteria=_CRITERIA)[:6]
    ref = np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], d.ravel()[:4]]
    got = res.cameras[0].params.numpy()
    np.testing.assert_allclose(res.std["intrinsics"][0].numpy(), std.ravel()[:8], rtol=1e-3)
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


def _opencv_fit(views, start, flags):
    """OpenCV's calibrateCamera (radtan, k3 = 0) of the views (float32) from ``start``: RMS,
    params, rvecs, tvecs and the intrinsics' standard deviations (its Extended form)."""
    K0 = np.array([[start[0], 0, start[2]], [0, start[1], start[3]], [0, 0, 1.0]])
    out = cv2.calibrateCameraExtended(
        [o for o, _ in views], [i for _, i in views], RES, K0, np.r_[start[4:], 0.0],
        flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_FIX_K3, criteria=_CRITERIA)
    rms, K, d, rv, tv, std = out[:6]
    return rms, np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], d.ravel()[:4]], rv, tv, std.ravel()


def _opencv_pixels(views, p, rv, tv):
    """(N, 2) cv2.projectPoints of every view's points and (N, 2, 8 + 6 V) Jacobians in the
    intrinsics (fu, fv, cu, cv, k1, k2, p1, p2) and each view's (rvec, tvec)."""
    K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    pix, jac = [], []
    for k, ((o, _), r, t) in enumerate(zip(views, rv, tv, strict=True)):
        u, J = cv2.projectPoints(o.astype(np.float64), r, t, K, np.r_[p[4:], 0.0])
        full = np.zeros((len(o), 2, 8 + 6 * len(views)))
        full[..., :8] = J[:, 6:14].reshape(-1, 2, 8)
        full[..., 8 + 6 * k:14 + 6 * k] = J[:, :6].reshape(-1, 2, 6)
        pix.append(u.reshape(-1, 2))
        jac.append(full)
    return np.concatenate(pix), np.concatenate(jac)


@pytest.mark.parametrize("cam", [0, 1])
def test_euroc_focal_length_is_not_determined_by_the_30_views(euroc, cam):
    """Why the EuRoC focal lengths miss the published ones (docs/api/camera.rst), measured with
    OpenCV alone: the 30 views (one sweep at 1.1-1.3 m, 15-30 deg of tilt) tie the focal
    length to the target's distance (correlation > 0.98), so that fixing it at the published
    value, the rest refitted, costs under 0.015 px of RMS and moves the predicted pixels by
    0.06 / 0.10 px RMS, while the white-noise standard deviation (1.0 / 1.8 px) puts the published
    value 19 / 22 standard deviations away: corner errors that are not white at the level of
    a few hundredths of a pixel decide the focal length. Measured (cam0 / cam1): RMS 0.265 /
    0.401 px free (fu 478.0 / 495.5), 0.271 / 0.413 with the published focal lengths,
    0.295 / 0.784 with every published intrinsic fixed (poses refitted)."""
    ints, floats = euroc[cam]
    views = _views(ints, floats)
    pub = PUBLISHED[cam]
    rms, free, rv, tv, std = _opencv_fit(views, pub, 0)
    start = np.r_[pub[:2], free[2:]]
    rms_f, focal, rv_f, tv_f, _ = _opencv_fit(views, start, cv2.CALIB_FIX_FOCAL_LENGTH)
    rms_p = _opencv_fit(views, pub, cv2.CALIB_FIX_FOCAL_LENGTH | cv2.CALIB_FIX_PRINCIPAL_POINT
                        | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_TANGENT_DIST)[0]
    assert rms < rms_f < rms + 0.015 and rms_p > rms_f, (rms, rms_f, rms_p)
    assert std[0] < 2.0 and abs(free[0] - pub[0]) > 10 * std[0], (free[0], std[0])
    moved = _opencv_pixels(views, free, rv, tv)[0] - _opencv_pixels(views, focal, rv_f, tv_f)[0]
    assert np.sqrt((moved ** 2).sum(-1).mean()) < 0.12
    pix, J = _opencv_pixels(views, free, rv, tv)
    J = J.reshape(-1, J.shape[-1])
    r = (pix - np.concatenate([i for _, i in views]).astype(np.float64)).ravel()
    cov = r @ r / (len(r) - J.shape[1]) * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(np.sqrt(np.diag(cov))[:8], std[:8], rtol=1e-3)  # OpenCV's
    mean_z = np.zeros(J.shape[1])
    mean_z[13::6] = 1.0 / len(views)  # the mean of the views' tz
    corr = (cov @ mean_z)[0] / np.sqrt(cov[0, 0] * (mean_z @ cov @ mean_z))
    assert corr > 0.98, corr
    dist = np.linalg.norm(np.concatenate(tv, -1), axis=0)
    tilt = np.degrees([np.arccos(abs(cv2.Rodrigues(x)[0][2, 2])) for x in rv])  # off normal
    assert 1.0 < dist.min() and dist.max() < 1.3 and 14 < tilt.min() and tilt.max() < 31


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
    if model in ("pinhole", "pinhole-radtan"):
        return cv2.projectPoints(X, zero, zero, K, np.r_[p[4:], np.zeros(9 - len(p))])[0][:, 0]
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


def _pose(t, rotvec):
    return dualquat.from_rt(quat.from_rotvec(torch.tensor(rotvec, dtype=torch.float64)),
                            torch.tensor(t, dtype=torch.float64))


def _simulate(rng, models, params, rels, frames=16, noise=0.3, spread=0.35, seen=None,
              noise_rng=None):
    """Observations of cameras (``rels[i - 1] = (t, rotvec)`` of camera i in camera 0's
    frame) with Gaussian pixel noise (drawn from ``noise_rng``, default ``rng``); camera
    ``c`` sees frame ``f`` where ``seen(c, f)``."""
    pts, poses = _scene(rng, frames, spread)
    noise_rng = rng if noise_rng is None else noise_rng
    obs = [[] for _ in models]
    for f, (R, t) in enumerate(poses):
        for c, (model, p) in enumerate(zip(models, params, strict=True)):
            if seen is not None and not seen(c, f):
                continue
            Xc = pts @ R.T + t
            if c:
                Xc = (Xc - rels[c - 1][0]) @ _rotvec_matrix(rels[c - 1][1])
            uv = _project(model, p, Xc)
            uv = uv + noise * noise_rng.standard_normal(uv.shape)
            inside = ((uv[:, 0] > 0) & (uv[:, 0] < RES[0] - 1) & (uv[:, 1] > 0)
                      & (uv[:, 1] < RES[1] - 1) & (Xc[:, 2] > 0.05))
            obs[c].append((np.full(inside.sum(), 0.05 * f), pts[inside], uv[inside]))
    return [tuple(torch.tensor(np.concatenate(x)) for x in zip(*o, strict=True)) for o in obs]


def _errors(res, params, rels):
    """(estimate - truth) / std of every intrinsic and of the relative poses' charts."""
    z = [(res.cameras[c].params.numpy() - p) / res.std["intrinsics"][c, :len(p)].numpy()
         for c, p in enumerate(params)]
    for c, (t, r) in enumerate(rels):
        delta = dualquat.log(dualquat.mul(dualquat.inv(res.relative_poses[c]), _pose(t, r)))
        z.append(delta.numpy() / res.std["relative_poses"][c].numpy())
    return np.concatenate(z)


@pytest.mark.parametrize("model", ["pinhole-radtan", "pinhole-equidistant", "double-sphere"])
def test_synthetic_within_4_std(model):
    """OpenCV-projected (the paper's formula for the double sphere) corners, 0.3 px noise:
    every intrinsic and the relative pose's chart land within 4 standard deviations."""
    rng = np.random.default_rng(7)
    spread = 0.35 if model == "pinhole-radtan" else 1.1  # the fisheyes: up to 63 deg off axis
    obs = _simulate(rng, [model] * 2, TRUE[model], [T01], spread=spread)
    res = calibration.cameras(obs, [model] * 2, [RES] * 2)
    assert res.converged
    z = _errors(res, TRUE[model], [T01])
    assert np.all(np.abs(z) < 4.0), z
    assert abs(res.sigma - 0.3) < 0.03
    assert (res.reprojection_rms < 0.3 * math.sqrt(2) * 1.1).all()


def test_three_cameras_mixed_models_chained():
    """Three cameras of three models; camera 2 shares no frame with camera 0, only with
    camera 1 (its start is chained through camera 1): all within 4 std, the std of the
    shorter models padded with NaN."""
    rng = np.random.default_rng(3)
    models = ["pinhole-radtan", "pinhole", "double-sphere"]
    params = [TRUE["pinhole-radtan"][0], np.array([450.0, 451.0, 376.0, 240.0]),
              TRUE["double-sphere"][0]]
    rels = [T01, (np.array([-0.1, 0.02, 0.01]), np.array([0.02, 0.1, -0.01]))]
    obs = _simulate(rng, models, params, rels, frames=24, spread=0.8,
                    seen=lambda c, f: (c == 0 and f < 12) or c == 1 or (c == 2 and f >= 12))
    res = calibration.cameras(obs, models, [RES] * 3)
    assert res.converged
    z = _errors(res, params, rels)
    assert np.all(np.abs(z) < 4.0), z
    std = res.std["intrinsics"]
    assert std.shape == (3, 8) and res.relative_poses.shape == (2, 8)
    assert torch.isnan(std[1, 4:]).all() and torch.isnan(std[2, 6:]).all()
    assert torch.isfinite(std[0]).all() and torch.isfinite(std[1, :4]).all()
    assert res.target_poses.shape == (res.frame_times.shape[0], 8)
    assert 20 <= res.frame_times.shape[0] <= 24  # frames without a view of >= 6 points go


def test_float32_observations():
    """float32 points and pixels (float64 times): float32 results (solved in float64), equal
    to the float64 run to float32 rounding of the inputs."""
    rng = np.random.default_rng(11)
    obs = _simulate(rng, ["pinhole-radtan"] * 2, TRUE["pinhole-radtan"], [T01], frames=10)
    r64 = calibration.cameras(obs, ["pinhole-radtan"] * 2, [RES] * 2)
    obs32 = [(t, p.float(), u.float()) for t, p, u in obs]
    r32 = calibration.cameras(obs32, ["pinhole-radtan"] * 2, [RES] * 2)
    assert r32.relative_poses.dtype == torch.float32
    assert r32.cameras[0].params.dtype == torch.float32
    assert r32.std["intrinsics"].dtype == torch.float32
    for a, b, s in zip(r32.cameras, r64.cameras, r64.std["intrinsics"], strict=True):
        assert torch.all((a.params.double() - b.params).abs() < 0.05 * s)


def test_robust_kernel_against_outliers():
    """5 % of the corners moved by 10-30 px (kept in the image): least squares puts the
    principal point 10 px off; Cauchy and Huber (k = 1 px) stay within 1 px and 4 standard
    deviations."""
    rng = np.random.default_rng(5)
    obs = _simulate(rng, ["pinhole-radtan"] * 2, TRUE["pinhole-radtan"], [T01])
    bad = []
    for t, p, u in obs:
        u = u.clone()
        idx = torch.from_numpy(rng.choice(u.shape[0], u.shape[0] // 20, replace=False))
        shift = torch.from_numpy(rng.uniform(10, 30, (idx.numel(), 1))
                                 * rng.choice([-1.0, 1.0], (idx.numel(), 2)))
        u[idx] += shift
        u = torch.minimum(u.clamp_min(0.0), torch.tensor(RES, dtype=u.dtype) - 1.0)  # in the image
        bad.append((t, p, u))
    plain = calibration.cameras(bad, ["pinhole-radtan"] * 2, [RES] * 2)
    err_plain = np.abs(plain.cameras[0].params.numpy() - TRUE["pinhole-radtan"][0])
    assert err_plain[2:4].max() > 5.0 and plain.sigma > 2.0  # pulled by 10-12 px
    for kind in ("cauchy", "huber"):
        res = calibration.cameras(bad, ["pinhole-radtan"] * 2, [RES] * 2, robust=kind,
                                  robust_k=1.0)
        z = _errors(res, TRUE["pinhole-radtan"], [T01])
        assert np.all(np.abs(z) < 4.0), (kind, z)
        err = np.abs(res.cameras[0].params.numpy() - TRUE["pinhole-radtan"][0])
        assert err[:4].max() < 1.0, (kind, err)
        if kind == "cauchy":  # the outliers' weights ~1/400: the inliers' noise
            assert abs(res.sigma - 0.3) < 0.03


def _valid_args():
    rng = np.random.default_rng(1)
    obs = _simulate(rng, ["pinhole"] * 2, [np.array([450.0, 450, 376, 240])] * 2, [T01],
                    frames=4)
    return obs, ["pinhole"] * 2, [RES] * 2


@pytest.mark.parametrize("change, match", [
    (lambda o, m, r: (o, m[:1], r), "models"),
    (lambda o, m, r: (o, m, r[:1]), "resolution"),
    (lambda o, m, r: (o, ["pinhole", "fisheye"], r), "unknown model 'fisheye' in models"),
    (lambda o, m, r: (o, m, [(752, 480), (752, 0)]), r"resolution\[1\]"),
    (lambda o, m, r: (o, m, [(752, 480), (752.0, 480)]), r"resolution\[1\]"),
    (lambda o, m, r: ([], m, r), "observations"),
    (lambda o, m, r: ([o[0], o[1][:2]], m, r), r"observations\[1\]"),
    (lambda o, m, r: ([o[0], (o[1][0], o[1][1][:-1], o[1][2])], m, r), r"observations\[1\]"),
    (lambda o, m, r: ([o[0], (o[1][0], o[1][1][:, :2], o[1][2])], m, r), r"observations\[1\]"),
    (lambda o, m, r: ([(o[0][0], o[0][1] + torch.tensor([0, 0, 0.1]), o[0][2]), o[1]], m, r),
     "planar"),
    (lambda o, m, r: ([(o[0][0], o[0][1], o[0][2] * float("nan")), o[1]], m, r),
     "non-finite"),
    (lambda o, m, r: ([(o[0][0][o[0][0] < 0.1], o[0][1][o[0][0] < 0.1],
                        o[0][2][o[0][0] < 0.1]), o[1]], m, r), "camera 0 has 2 views"),
    # the trial's case: pixels up to u = 750 with a (640, 480) resolution
    (lambda o, m, r: (o, m, [(640, 480), (752, 480)]),
     r"pixels reach u = 6[4-9]\d.*outside resolution\[0\] = \(640, 480\)"),
    (lambda o, m, r: ([o[0], (o[1][0], o[1][1], o[1][2] - torch.tensor([0.0, 500.0]))], m, r),
     r"observations\[1\] pixels reach v = -.*outside resolution\[1\]"),
])
def test_bad_arguments(change, match):
    obs, models, res = change(*_valid_args())
    with pytest.raises(ValueError, match=match) as info:
        calibration.cameras(obs, models, res)
    assert "calibration.cameras" in str(info.value)


@pytest.mark.parametrize("kwargs, match", [
    ({"robust": "tukey"}, "robust"), ({"robust_k": -1.0}, "robust_k"),
    ({"max_iterations": -1}, "max_iterations"), ({"tol": 0.0}, "tol"),
    ({"min_points": 3}, "min_points"),
])
def test_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        calibration.cameras(*_valid_args(), **kwargs)


def test_integer_observations_are_a_type_error():
    obs, models, res = _valid_args()
    with pytest.raises(TypeError, match="observations\\[0\\] pixels"):
        calibration.cameras([(obs[0][0], obs[0][1], obs[0][2].long()), obs[1]], models, res)


def test_float32_times_are_a_type_error():
    """float32 UNIX seconds are 128 s apart: the 30 EuRoC-like frames 0.05 s apart would
    merge into one or two timestamps. Required: float64 times."""
    obs, models, res = _valid_args()
    t32 = (obs[0][0] + 1.4e9).float()
    assert torch.unique(t32).numel() < torch.unique(obs[0][0]).numel()  # frames merge
    with pytest.raises(TypeError, match=r"float64 observations\[0\] times.*merges"):
        calibration.cameras([(t32, obs[0][1], obs[0][2]), obs[1]], models, res)


def test_pixels_on_the_image_border_are_accepted():
    """(0, 0) is the top-left pixel's centre: u = -0.5 and u = width - 0.5 are inside."""
    obs, models, res = _valid_args()
    t, p, u = obs[0]
    u = u.clone()
    u[0, 0], u[1, 0] = -0.5, RES[0] - 0.5
    calibration.cameras([(t, p, u), obs[1]], models, res, max_iterations=0)


def test_warns_when_the_bundle_adjustment_does_not_converge(euroc):
    """A plain pinhole on the distorted EuRoC corners ends with the principal point at about
    (647, -845) and converged False: a RuntimeWarning names the camera and the reason; the
    score test of k1 says that the lens distorts (z = 15.7)."""
    with pytest.warns(RuntimeWarning, match=r"did not converge.*camera 0 \('pinhole'\)"), \
            pytest.warns(RuntimeWarning, match=r"camera 0 \('pinhole'\) ask for radial"):
        res = calibration.cameras([_observation(*euroc[0])], ["pinhole"], [RES])
    assert not res.converged and res.reprojection_rms[0] > 1.0
    with pytest.warns(RuntimeWarning, match=r"max_iterations = 1 steps.*camera 1 \('pinhole'\)"):
        obs, models, r = _valid_args()
        obs = [obs[0], (obs[1][0], obs[1][1], obs[1][2] + 3.0 * torch.randn(
            obs[1][2].shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64))]
        res = calibration.cameras(obs, models, r, max_iterations=1)
    assert not res.converged


def test_cameras_without_a_shared_frame():
    rng = np.random.default_rng(2)
    obs = _simulate(rng, ["pinhole"] * 2, [np.array([450.0, 450, 376, 240])] * 2, [T01],
                    frames=8, seen=lambda c, f: (f < 4) == (c == 0))
    with pytest.raises(ValueError, match=r"cameras \[1\] share no frame(.|\n)*round their "
                       r"times"):  # the advice for stamps apart by trigger jitter
        calibration.cameras(obs, ["pinhole"] * 2, [RES] * 2)


@pytest.mark.slow
def test_monte_carlo_std():
    """The reported standard deviations against the scatter of 30 noise draws of one
    scene (two pinhole-radtan cameras, 10 frames, 0.3 px): the ratio of the scatter to the
    mean reported std lies in [0.6, 1.5] for all 16 intrinsics and 6 relative-pose
    coordinates."""
    models, params = ["pinhole-radtan"] * 2, TRUE["pinhole-radtan"]
    deltas, stds = [], []
    for draw in range(30):
        obs = _simulate(np.random.default_rng(21), models, params, [T01], frames=10,
                        noise_rng=np.random.default_rng(100 + draw))
        res = calibration.cameras(obs, models, [RES] * 2)
        assert res.converged
        s = torch.cat((res.std["intrinsics"].reshape(-1), res.std["relative_poses"][0]))
        z = _errors(res, params, [T01])
        deltas.append(z * s.numpy())
        stds.append(s.numpy())
    ratio = np.sqrt(np.mean(np.square(deltas), 0)) / np.mean(stds, 0)
    assert np.all((ratio > 0.6) & (ratio < 1.5)), ratio

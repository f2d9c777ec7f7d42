"""Rendered images of the simulated camera-IMU rig (``tests/_camera_imu_sim.py``) for
tests/test_calibration_render.py and notebooks/10_calibration.ipynb.

A Kalibr AprilGrid (36h11 tags with a 2-bit border from ``cv2.aruco.generateImageMarker``,
each printed turned by a half turn as Kalibr prints them, black squares between the tags'
corners) is drawn on a canvas; each frame is rendered by ray casting through the camera:
every image pixel is unprojected by OpenCV (``cv2.undistortPoints`` with criteria, of the
pinhole-radtan camera, iterated to 1e-12), its ray moved into the target frame by the
camera's true pose at the frame's IMU time, cut with the board's plane ``Z = 0`` (a
homography, ``cv2.perspectiveTransform``) and the canvas sampled there by ``cv2.remap``
(bilinear; the canvas blurred beforehand against aliasing by half a pixel of the image).
Independent of torch_dq (numpy, scipy, OpenCV). The detector finds these corners to 0.01 px
(median; 0.035 px at most) with 2 grey levels of noise.

:func:`euroc_folder` writes a whole recording in EuRoC's layout with Kalibr's files:
``mav0/cam0/data/<t_ns>.png``, ``mav0/imu0/data.csv`` and ``target.yaml``, ``imu.yaml``,
``camchain.yaml``, with the exact corners of every frame as ``cam<i>_corners.csv``.
"""

from __future__ import annotations

import pathlib

import _camera_imu_sim as sim
import numpy as np

__all__ = ["T0", "aprilgrid_canvas", "camera_pose", "euroc_folder", "pixel_rays", "render"]

T0 = 1000.0  # seconds added to every stamp of the written recording (positive nanoseconds)
_CELLS = 10  # a 36h11 tag with a 2-bit border is 10 cells wide


def aprilgrid_canvas(cv2, rows=6, cols=6, size=0.088, spacing=0.3, cell_px=8, margin=4):
    """Kalibr's AprilGrid drawn with ``cell_px`` canvas pixels per tag cell and ``margin``
    cells of white around it: the canvas (uint8) and the map ``S`` (3 x 3) from target
    metres ``(X, Y, 1)`` to canvas pixels (pixel centres at integers)."""
    tag = _CELLS * cell_px
    gap = round(spacing * tag)
    if abs(gap - spacing * tag) > 1e-9:
        raise ValueError(f"spacing {spacing} is not a whole number of canvas pixels")
    pitch, pad = tag + gap, margin * cell_px
    canvas = np.full((2 * pad + rows * pitch + gap, 2 * pad + cols * pitch + gap), 255, np.uint8)
    x0, ytop = pad + gap, pad  # canvas column of X = 0; row of Y = rows * pitch
    ppm = tag / size
    S = np.array([[ppm, 0, x0 - 0.5], [0, -ppm, ytop - 0.5 + rows * pitch], [0, 0, 1]])
    for i in range(cols + 1):  # the black squares between the tags' corners
        for j in range(rows + 1):
            top = ytop + (rows - j) * pitch
            canvas[top:top + gap, x0 + i * pitch - gap:x0 + i * pitch] = 0
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    for tag_id in range(rows * cols):
        r, c = divmod(tag_id, cols)
        marker = cv2.aruco.generateImageMarker(dictionary, tag_id, tag, borderBits=2)
        top, left = ytop + (rows - 1 - r) * pitch + gap, x0 + c * pitch
        canvas[top:top + tag, left:left + tag] = np.rot90(marker, 2)  # Kalibr's print
    return canvas, S


def pixel_rays(cv2, K=sim.K, dist=sim.DIST, resolution=sim.RESOLUTION):
    """The unprojected (undistorted, normalised) point ``(x, y)`` of every pixel,
    ``(H, W, 2)`` float64 (the ray ``(x, y, 1)`` in camera axes)."""
    w, h = resolution
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        xy = cv2.undistortPointsIter(uv, K, dist, None, None, criteria)
    else:  # OpenCV 5: undistortPoints takes the criteria
        xy = cv2.undistortPoints(uv, K, dist, criteria=criteria)
    return xy.reshape(h, w, 2)


def render(cv2, canvas, S, rays, R, t, noise=0.0, rng=None, background=128):
    """One grey image (uint8) of the board seen by a camera at pose ``(R (3, 3), t (3,))``
    in the target frame (``p_target = R p_cam + t``; a global shutter), Gaussian noise of
    ``noise`` grey levels added. The board's plane is ``Z = 0``: a pixel's ray ``(x, y, 1)``
    meets it at the homography ``(R^T [e_X, e_Y, -t])^{-1} (x, y, 1)``, which
    ``cv2.perspectiveTransform`` applies; the plane's horizon must stay out of the image
    (checked on the image's border, where the linear depth of the rays is extreme)."""
    h, w, _ = rays.shape
    G = R.T @ np.column_stack([np.eye(3)[:, :2], -t])  # plane (X, Y, 1) -> camera ray
    border = np.concatenate([rays[0], rays[-1], rays[:, 0], rays[:, -1]])
    if not np.all(-t[2] * (R[2, :2] @ border.T + R[2, 2]) > 0):
        raise ValueError("the board's plane is not in front of the camera over the image")
    uv = cv2.perspectiveTransform(rays.reshape(1, -1, 2), S @ np.linalg.inv(G))
    uv = uv.reshape(h, w, 2).astype(np.float32)
    # blur the canvas by half an image pixel, measured at the image's centre
    scale = float(np.linalg.norm(uv[h // 2, w // 2 + 1] - uv[h // 2, w // 2]))  # canvas/px
    smooth = cv2.GaussianBlur(canvas.astype(np.float32), (0, 0), max(0.5, 0.5 * scale))
    image = cv2.remap(smooth, uv[..., 0], uv[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
    if noise:
        image += noise * (rng or np.random.default_rng(0)).standard_normal(image.shape,
                                                                            np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def camera_pose(cam, times):
    """True pose ``(R (N, 3, 3), t (N, 3))`` of camera ``cam`` in the target frame at IMU
    times ``times``."""
    Rb, pb, _, _ = sim.motion(np.asarray(times, np.float64))
    E = sim.extrinsic_matrix(cam)
    return Rb @ E[:3, :3], pb + Rb @ E[:3, 3]


def _write_imu(path: pathlib.Path, t, g, a) -> None:
    ns = np.round((t + T0) * 1e9).astype(np.int64)
    with open(path, "w") as f:
        f.write("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
        for n, gi, ai in zip(ns, g, a, strict=True):
            f.write(f"{n}," + ",".join(f"{x:.12g}" for x in (*gi, *ai)) + "\n")


def _write_kalibr(root: pathlib.Path, cameras: int, spec: sim.Rig = sim.DEFAULT) -> None:
    """Kalibr's target.yaml, imu.yaml (EuRoC's ADIS16448) and camchain.yaml (the rig's
    true intrinsics) in ``root``."""
    (root / "target.yaml").write_text(
        "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n")
    (root / "imu.yaml").write_text(
        f"gyroscope_noise_density: {sim.GYRO_DENSITY}\n"
        f"gyroscope_random_walk: {sim.EUROC_WALK[0]}\n"
        f"accelerometer_noise_density: {sim.ACCEL_DENSITY}\n"
        f"accelerometer_random_walk: {sim.EUROC_WALK[1]}\nupdate_rate: 200.0\nrostopic: /imu0\n")
    chain = ""
    for i in range(cameras):
        k = sim.intrinsics(i, spec)
        chain += (f"cam{i}:\n  camera_model: pinhole\n  distortion_model: radtan\n"
                  f"  intrinsics: [{', '.join(repr(x) for x in k[:4])}]\n"
                  f"  distortion_coeffs: [{', '.join(repr(x) for x in k[4:])}]\n"
                  f"  resolution: [{sim.RESOLUTION[0]}, {sim.RESOLUTION[1]}]\n"
                  f"  rostopic: /cam{i}/image_raw\n")
    (root / "camchain.yaml").write_text(chain)


def _write_corners(path: pathlib.Path, times, points, pixels) -> None:
    ns = np.round((times + T0) * 1e9).astype(np.int64)
    with open(path, "w") as f:
        f.write("t_ns,u_px,v_px,X_m,Y_m,Z_m\n")
        for n, u, p in zip(ns, pixels, points, strict=True):
            f.write(f"{n},{u[0]:.17g},{u[1]:.17g},{p[0]:.17g},{p[1]:.17g},{p[2]:.17g}\n")


def kalibr_files(root, imu, cams, spec: sim.Rig = sim.DEFAULT) -> dict:
    """Write a simulated recording without images to ``root`` (created): the IMU readings
    ``imu`` as EuRoC's ``mav0/imu0/data.csv``, Kalibr's yamls (:func:`_write_kalibr`) and
    each camera's corners ``cams[i] = (times, points, pixels)`` as ``cam<i>_corners.csv``
    (stamps + :data:`T0`). Returns the paths as :func:`euroc_folder` does, without
    ``"images"``."""
    root = pathlib.Path(root)
    (root / "mav0" / "imu0").mkdir(parents=True, exist_ok=True)
    _write_imu(root / "mav0" / "imu0" / "data.csv", *imu)
    _write_kalibr(root, len(cams), spec)
    for i, c in enumerate(cams):
        _write_corners(root / f"cam{i}_corners.csv", *c)
    return {"corners": [root / f"cam{i}_corners.csv" for i in range(len(cams))],
            "imu": root / "mav0" / "imu0" / "data.csv", "target": root / "target.yaml",
            "imu_noise": root / "imu.yaml", "cameras": root / "camchain.yaml"}


def euroc_folder(root, duration=2.0, cameras=2, fps=20.0, offset=0.004, seed=0,
                 image_noise=2.0):
    """Write a simulated recording to ``root`` (created): EuRoC's ``mav0/cam<i>/data``
    images and ``mav0/imu0/data.csv`` (stamps + :data:`T0`), Kalibr's ``target.yaml``,
    ``imu.yaml`` and ``camchain.yaml`` (the true intrinsics) and the exact (noise-free)
    corners of every frame as ``cam<i>_corners.csv``. A frame stamped ``t`` shows the rig
    at IMU time ``t + offset``. Returns the paths as a dict (``"images"`` and ``"corners"``
    lists, ``"imu"``, ``"target"``, ``"imu_noise"``, ``"cameras"``)."""
    import cv2

    root = pathlib.Path(root)
    rng = np.random.default_rng(seed)
    (root / "mav0" / "imu0").mkdir(parents=True, exist_ok=True)
    imu, _ = sim.rig(duration=duration, offset=offset, seed=seed, fps=fps)
    _write_imu(root / "mav0" / "imu0" / "data.csv", *imu)
    _write_kalibr(root, cameras)
    canvas, S = aprilgrid_canvas(cv2)
    rays = pixel_rays(cv2)
    frames = np.arange(0.0, duration, 1.0 / fps)
    paths = {"images": [], "corners": [], "imu": root / "mav0" / "imu0" / "data.csv",
             "target": root / "target.yaml", "imu_noise": root / "imu.yaml",
             "cameras": root / "camchain.yaml"}
    for i in range(cameras):
        folder = root / "mav0" / f"cam{i}" / "data"
        folder.mkdir(parents=True, exist_ok=True)
        Rs, ts = camera_pose(i, frames + offset)
        for f, R, t in zip(frames, Rs, ts, strict=True):
            image = render(cv2, canvas, S, rays, R, t, image_noise, rng)
            cv2.imwrite(str(folder / f"{round((f + T0) * 1e9)}.png"), image)
        _write_corners(root / f"cam{i}_corners.csv",
                       *sim.corners(i, frames, offset, 0.0, 0.0, rng))
        paths["images"].append(folder)
        paths["corners"].append(root / f"cam{i}_corners.csv")
    return paths

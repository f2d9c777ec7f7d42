r"""Corner detection: AprilGrid and checkerboard corners of grey images, through OpenCV.

AprilGrid (Kalibr's): OpenCV's ArUco module with the AprilTag 36h11 dictionary and a 2-bit
marker border finds the tags; a second pass
(``ArucoDetector.refineDetectedMarkers`` with the grid's layout) looks for the tags the
first pass missed where the found ones predict them (tags of about 30 pixels, whose 3-pixel
cells the first pass misreads: on the EuRoC frames of the tests the first pass finds 29 and
30 of 36 tags, the second all 36); ids outside the grid and ids found twice are dropped.
Each tag corner is a corner of the grid's checker pattern (the tag's black border meets a
black corner square): it is pulled in with ``cv2.cornerSubPix`` (the detected quads lie
about a tenth of the tag's side inside the corners), in a window inside the tag's border and
short of the next corner, then placed at the saddle point of the smoothed image (a
quadratic fit, ``_saddle``): on the rendered grids of the tests 0.015 to 0.04 px median
error (``cornerSubPix`` alone: 0.085 px); on the real EuRoC frames the corners fit EuRoC's
published camera with a homography to 0.14 px RMS.

Corner numbering: a Kalibr AprilGrid prints each tag turned by 180 degrees with respect to
OpenCV's marker image, so OpenCV's marker corners ``(0, 1, 2, 3)`` are Kalibr's corners
``(1, 0, 3, 2)`` (Kalibr's: counter-clockwise from the tag's lower-left seen from the front;
checked on the real EuRoC frames against the grid's layout of ids).

Checkerboard: ``cv2.findChessboardCornersSB`` (sub-pixel accurate). OpenCV returns the
corners row by row in one of the board's symmetric orders; they are put in the order with
Kalibr's handedness (target ``Z`` towards the camera) and, among the half turns (and the
quarter turns of a square board), one with the black square at the inner side of corner 0,
as in Kalibr's drawing. A board with ``rows + cols`` even looks the same after a half turn
(a square one with even ``rows`` also after a quarter turn): its order is then one of those,
frame by frame (as in Kalibr).
"""

from __future__ import annotations

import functools
import numbers
import os
import pathlib
import sys
import warnings

import numpy as np
import torch
from torch import Tensor

from .. import _checks
from .._progress import progress
from ._corners import _seconds, write_corners
from ._targets import Target

__all__ = ["detect", "detect_folder"]

#: OpenCV marker corner ``j`` is Kalibr's corner ``_KALIBR_OF_OPENCV[j]`` (an involution).
_KALIBR_OF_OPENCV = (1, 0, 3, 2)
_IMAGES = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")


def cv2_module(fn: str):
    """OpenCV with its ArUco module, imported on first use, or an ImportError naming the
    ``calib`` extra."""
    try:
        import cv2
    except ImportError:
        raise ImportError(f"{fn}: detecting target corners needs OpenCV: pip install "
                          f"torch_dq[calib] (or pip install opencv-python-headless)") from None
    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "ArucoDetector"):
        raise ImportError(f"{fn}: OpenCV {cv2.__version__} has no cv2.aruco.ArucoDetector; "
                          f"install OpenCV >= 4.7: pip install torch_dq[calib]")
    return cv2


def _image(fn: str, image) -> np.ndarray:
    """A (H, W) uint8 C-contiguous numpy copy of a numpy array or a tensor."""
    if isinstance(image, Tensor):
        image = image.detach().cpu().numpy()
    if not isinstance(image, np.ndarray):
        _checks.fail(fn, f"expected a numpy array or a tensor for image, got "
                         f"{type(image).__name__}", TypeError)
    if image.dtype != np.uint8:
        _checks.fail(fn, f"expected a uint8 grey image, got dtype {image.dtype}", TypeError)
    if image.ndim != 2 or min(image.shape) < 16:
        hint = " (a colour image? convert it with cv2.cvtColor)" if image.ndim == 3 else ""
        _checks.fail(fn, f"expected a (H, W) grey image of 16 pixels or more a side, got "
                         f"shape {_checks.shape_str(image.shape)}{hint}")
    return np.ascontiguousarray(image)


@functools.lru_cache(maxsize=8)
def _aruco(cv2, target: Target):
    """The ArUco detector and the grid's board (OpenCV's layout) for an AprilGrid."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = 2  # Kalibr's tags have a 2-bit black border
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # refined below
    # The grid turned by a half turn is an OpenCV GridBoard: its k-th marker (row i from the
    # top, column j from the left) is Kalibr's tag of row i, column cols - 1 - j.
    rows, cols = target.rows, target.cols
    ids = np.array([i * cols + cols - 1 - j for i in range(rows) for j in range(cols)],
                   np.int32)
    board = cv2.aruco.GridBoard((cols, rows), target.size, target.size * target.spacing,
                                dictionary, ids)
    return cv2.aruco.ArucoDetector(dictionary, params), board


def _tags(cv2, image: np.ndarray, target: Target) -> tuple[np.ndarray, np.ndarray]:
    """Tag ids (T,) and their corners (T, 4, 2) in Kalibr's numbering, unrefined."""
    detector, board = _aruco(cv2, target)
    corners, ids, rejected = detector.detectMarkers(image)
    if ids is None or len(ids) == 0:
        return np.zeros(0, np.int64), np.zeros((0, 4, 2))
    found = np.stack([c.reshape(4, 2) for c in corners])
    side = float(np.median(np.linalg.norm(found - np.roll(found, 1, axis=1), axis=2)))
    # The second pass accepts a candidate within 40% of a tag's side of its prediction.
    detector.setRefineParameters(cv2.aruco.RefineParameters(max(3.0, 0.4 * side), 3.0, True))
    corners, ids, _, _ = detector.refineDetectedMarkers(image, board, corners, ids, rejected)
    ids = ids.ravel().astype(np.int64)
    quads = np.stack([c.reshape(4, 2) for c in corners]).astype(np.float64)
    unique, counts = np.unique(ids, return_counts=True)
    keep = (ids < target.tags) & np.isin(ids, unique[counts == 1])
    return ids[keep], quads[keep][:, list(_KALIBR_OF_OPENCV)]


def _subpixel(cv2, image: np.ndarray, pixels: np.ndarray, half: int) -> np.ndarray:
    """cornerSubPix in a (2 half + 1)^2 window; NaN where it fails (near the border, or a
    corner that moves by more than the window)."""
    h, w = image.shape
    inside = ((pixels >= half + 1) & (pixels <= np.array([w, h]) - half - 2)).all(axis=1)
    out = np.full_like(pixels, np.nan)
    if inside.any():
        start = np.ascontiguousarray(pixels[inside], np.float32).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 40, 1e-3)
        refined = cv2.cornerSubPix(image, start.copy(), (half, half), (-1, -1), criteria)
        refined = refined.reshape(-1, 2).astype(np.float64)
        moved = np.linalg.norm(refined - pixels[inside], axis=1) > half
        refined[moved] = np.nan
        out[inside] = refined
    return out


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``image`` (H, W) float sampled at ``xy`` (..., 2) (pixel centres at integers)."""
    h, w = image.shape
    x = np.clip(xy[..., 0], 0, w - 1.000001)
    y = np.clip(xy[..., 1], 0, h - 1.000001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    top = image[y0, x0] * (1 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


def _saddle(cv2, image: np.ndarray, pixels: np.ndarray, radius: int,
            steps: int = 3) -> np.ndarray:
    r"""Saddle points of the smoothed image near ``pixels`` (N, 2): the stationary point of
    the quadratic ``a x^2 + b x y + c y^2 + d x + e y + f`` fitted by least squares to the
    image (Gaussian-smoothed, sigma ``max(0.7, radius / 3)``) on a ``(2 radius + 1)^2``
    grid, Newton-like from each pixel (``steps`` times). An X-junction of a checker pattern
    is a saddle of the smoothed intensity (Lucchese and Mitra, "Using saddle points for
    subpixel feature detection in camera calibration targets", APCCAS 2002); NaN where the
    fit is no saddle (Hessian determinant >= 0) or its step leaves the grid."""
    smooth = cv2.GaussianBlur(image.astype(np.float32), (0, 0), max(0.7, radius / 3))
    d = np.arange(-radius, radius + 1, dtype=np.float64)
    dy, dx = (g.ravel() for g in np.meshgrid(d, d, indexing="ij"))
    fit = np.linalg.pinv(np.stack((dx * dx, dx * dy, dy * dy, dx, dy, np.ones_like(dx)), 1))
    out = pixels.copy()
    for _ in range(steps):
        patches = _bilinear(smooth, out[:, None, :] + np.stack((dx, dy), 1))  # (N, P)
        a, b, c, gx, gy, _ = fit @ patches.T
        det = 4 * a * c - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            step = np.stack(((b * gy - 2 * c * gx) / det, (b * gx - 2 * a * gy) / det), -1)
        bad = ~(det < 0) | ~(np.abs(step) <= radius).all(axis=1)
        out = np.where(bad[:, None], np.nan, out + step)
    return out


def _aprilgrid(cv2, image: np.ndarray, target: Target):
    ids, quads = _tags(cv2, image, target)
    if ids.size == 0:
        return ids, ids.copy(), np.zeros((0, 2))
    side = np.linalg.norm(quads - np.roll(quads, 1, axis=1), axis=2).mean()
    gap = side * target.spacing
    # The window stays inside the tag's 2-cell border (beyond it, the tag's data bits) and
    # short of the next corner of the checker pattern (a gap away); the detected quads lie
    # about a tenth of the side inside the tags' corners (the corner squares touch them).
    half = int(max(2, round(0.8 * min(gap, side / 5))))
    pixels = _subpixel(cv2, image, quads.reshape(-1, 2), half)
    ok = np.isfinite(pixels).all(axis=1)
    pixels[ok] = _saddle(cv2, image, pixels[ok], max(2, half // 2))
    tag_ids = np.repeat(ids, 4)
    corner_ids = np.tile(np.arange(4, dtype=np.int64), ids.size)
    return tag_ids, corner_ids, pixels


def _checkerboard(cv2, image: np.ndarray, target: Target):
    rows, cols = target.rows, target.cols
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(image, (cols, rows), flags=flags)
    if not found:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2))
    grid = corners.reshape(rows, cols, 2).astype(np.float64)
    along_c = (grid[:, -1] - grid[:, 0]).mean(axis=0)
    along_r = (grid[-1] - grid[0]).mean(axis=0)
    if along_c[0] * along_r[1] - along_c[1] * along_r[0] < 0:  # Kalibr's handedness
        grid = grid[:, ::-1]
    # The labellings the board's shape allows (half turns; quarter turns of a square board):
    # the first whose square inside corner 0 is the black one.
    turns = (0, 1, 2, 3) if rows == cols else (0, 2)
    for quarter in turns:
        turned = np.rot90(grid, quarter, axes=(0, 1))
        if _square(image, turned, 0, 0) < _square(image, turned, 0, 1):
            grid = turned
            break
    k = np.arange(rows * cols, dtype=np.int64)
    return np.zeros_like(k), k, grid.reshape(-1, 2)


def _square(image: np.ndarray, grid: np.ndarray, r: int, c: int) -> float:
    """Mean grey level near the centre of the square between inner corners (r, c) and
    (r + 1, c + 1)."""
    quad = grid[r:r + 2, c:c + 2].reshape(4, 2)
    centre = quad.mean(axis=0)
    samples = centre + 0.25 * (quad - centre)
    ij = np.clip(np.round(samples).astype(int), 0, np.array(image.shape[::-1]) - 1)
    return float(image[ij[:, 1], ij[:, 0]].mean())


def _check_target(fn: str, target) -> Target:
    if not isinstance(target, Target):
        _checks.fail(fn, f"expected a calibration.Target for target (Target.aprilgrid, "
                         f"Target.checkerboard or read_target), got {type(target).__name__}",
                     TypeError)
    return target


def detect(image, target: Target) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    r"""The target's corners in one grey image.

    AprilGrid through OpenCV's ArUco module (AprilTag 36h11, 2-bit border, a second pass
    with the grid's layout), checkerboard through ``cv2.findChessboardCornersSB``; corners
    refined to sub-pixel (see the module's notes for the corner numbering). Corners whose
    refinement window leaves the image or whose refinement does not converge near the
    detection are dropped, as are tag ids outside the grid and ids found twice. Needs
    OpenCV >= 4.7 (the ``calib`` extra).

    Args:
        image: ``(H, W)`` uint8 grey image, a numpy array or a tensor (pixel ``(u, v)`` is
            column ``u``, row ``v``; pixel centres at integers, OpenCV's convention).
        target: a :class:`Target`.

    Returns:
        ``(tag_ids, corner_ids, pixels, points)``: int64 ``(M,)`` and ``(M,)`` (a
        checkerboard is one tag, id 0, with corners ``0 .. rows * cols - 1``), float64
        ``(M, 2)`` pixels and ``(M, 3)`` target points
        (``target.points[tag_id * target.corners_per_tag + corner_id]``), CPU tensors
        sorted by tag then corner. Empty (``M = 0``) when the target is not seen; a
        checkerboard is found whole or not at all.

    Raises:
        TypeError: ``image`` not a uint8 array or tensor, ``target`` not a Target.
        ValueError: ``image`` not ``(H, W)``.
        ImportError: OpenCV (with ``cv2.aruco``) is not installed.

    Example:
        >>> import cv2  # doctest: +SKIP
        >>> image = cv2.imread("mav0/cam0/data/1403709395937837056.png", 0)  # doctest: +SKIP
        >>> tags, corners, pixels, points = detect(image, Target.aprilgrid(6, 6, 0.088, 0.3))
        ... # doctest: +SKIP
        >>> len(tags.unique()), pixels.shape  # doctest: +SKIP
        (36, torch.Size([144, 2]))
    """
    fn = "calibration.detect"
    target = _check_target(fn, target)
    image = _image(fn, image)
    cv2 = cv2_module(fn)
    find = _aprilgrid if target.kind == "aprilgrid" else _checkerboard
    tag_ids, corner_ids, pixels = find(cv2, image, target)
    ok = np.isfinite(pixels).all(axis=1)
    order = np.lexsort((corner_ids[ok], tag_ids[ok]))
    tag_ids, corner_ids, pixels = tag_ids[ok][order], corner_ids[ok][order], pixels[ok][order]
    points = target.points[torch.from_numpy(tag_ids * target.corners_per_tag + corner_ids)]
    return (torch.from_numpy(tag_ids), torch.from_numpy(corner_ids),
            torch.from_numpy(np.ascontiguousarray(pixels)), points)


def _frames(fn: str, path) -> list[tuple[int, pathlib.Path]]:
    """(nanoseconds, file) of the images of a folder (or of its ``data`` subfolder, EuRoC's
    ``cam0/data``), sorted by time."""
    if not isinstance(path, (str, os.PathLike)):
        _checks.fail(fn, f"expected a folder (str or os.PathLike) for path, got "
                         f"{type(path).__name__}", TypeError)
    folder = pathlib.Path(path)
    if not folder.is_dir():
        _checks.fail(fn, f"{os.fspath(path)} is not a folder")
    images = [p for p in folder.iterdir() if p.suffix.lower() in _IMAGES]
    if not images and (folder / "data").is_dir():
        return _frames(fn, folder / "data")
    bad = [p.name for p in images if not p.stem.isascii() or not p.stem.isdigit()]
    if bad:
        _checks.fail(fn, f"{folder}: image names must be their timestamps in integer "
                         f"nanoseconds (EuRoC's cam0/data/<t_ns>.png), got {bad[0]!r}")
    if not images:
        _checks.fail(fn, f"{folder}: no images ({', '.join(_IMAGES)})")
    return sorted((int(p.stem), p) for p in images)


def detect_folder(path: str | os.PathLike[str], target: Target, *,
                  min_corners: int | None = None, csv: str | os.PathLike[str] | None = None,
                  verbose: bool = False) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    r"""The target's corners in every image of a folder named by nanosecond timestamps.

    EuRoC's layout: ``cam0/data/1403709395937837056.png`` (``path`` may be ``cam0/data``
    or ``cam0``). Each image is read in grey and goes through :func:`detect`; frames with
    fewer than ``min_corners`` corners are skipped (too few for a pose of the target).

    Args:
        path: the folder.
        target: a :class:`Target`.
        min_corners: the fewest corners a frame must have to be kept; default: 16 (four
            tags) for an AprilGrid, the whole board for a checkerboard.
        csv: a file to write the corners to, in :func:`read_corners`' format
            (``t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m``, exact integer nanoseconds
            and float64 values that read back bit for bit); None (default) writes nothing.
        verbose: progress on stderr (a tqdm bar on a terminal when tqdm is installed) and a
            summary line at the end.

    Returns:
        ``(times, points, pixels, tag_ids, corner_ids)``: float64 ``(N,)`` seconds (the
        file name's nanoseconds, correctly rounded), ``(N, 3)``, ``(N, 2)`` as
        :func:`read_corners` returns them, and int64 ``(N,)`` ids as :func:`detect`
        returns them; CPU tensors, frames by time, each frame's corners by tag and corner.

    Raises:
        ValueError: ``path`` is not a folder, holds no images or an image whose name is not
            an integer; an image that cannot be read; a bad ``min_corners``; ``csv`` is
            one of the images.
        TypeError: bad argument types.
        ImportError: OpenCV is not installed.

    Warns:
        UserWarning: no frame has ``min_corners`` corners.

    Example:
        >>> target = read_target("april_6x6.yaml")  # doctest: +SKIP
        >>> times, points, pixels, tags, corners = detect_folder("mav0/cam0/data", target,
        ...                                                      csv="cam0_corners.csv")
        ... # doctest: +SKIP
    """
    fn = "calibration.detect_folder"
    target = _check_target(fn, target)
    if min_corners is None:
        min_corners = 16 if target.kind == "aprilgrid" else target.corners_per_tag
    if isinstance(min_corners, bool) or not isinstance(min_corners, numbers.Integral) or (
            min_corners < 1):
        _checks.fail(fn, f"min_corners must be an int >= 1, got {min_corners!r}")
    _checks.flag(fn, "verbose", verbose)
    frames = _frames(fn, path)
    if csv is not None and pathlib.Path(csv).resolve() in {p.resolve() for _, p in frames}:
        _checks.fail(fn, f"csv {os.fspath(csv)} is one of the images: it would be overwritten")
    cv2 = cv2_module(fn)
    found = _detect_frames(fn, cv2, frames, target, int(min_corners), verbose)
    if not found:
        warnings.warn(f"{fn}: no frame of {len(frames)} has {min_corners} corners or more",
                      UserWarning, stacklevel=2)
    ns = np.array([n for n, d in found for _ in range(d[0].shape[0])], np.int64)
    cat = lambda k, empty: torch.cat([d[k] for _, d in found]) if found else empty  # noqa: E731
    tags, corners = cat(0, torch.zeros(0, dtype=torch.int64)), cat(1, torch.zeros(
        0, dtype=torch.int64))
    pixels, points = cat(2, torch.zeros(0, 2, dtype=torch.float64)), cat(3, torch.zeros(
        0, 3, dtype=torch.float64))
    if csv is not None:
        write_corners(csv, ns, tags.numpy(), corners.numpy(), pixels.numpy(), points.numpy())
    times = torch.from_numpy(_seconds(ns)) if ns.size else torch.zeros(0, dtype=torch.float64)
    return times, points, pixels, tags, corners


def _detect_frames(fn: str, cv2, frames, target: Target, min_corners: int, verbose: bool):
    """[(ns, detect's output)] of the frames with min_corners corners or more."""
    bar = progress(len(frames), verbose and sys.stderr.isatty(), "torch_dq.detect_folder")
    found = []
    try:
        for ns, file in frames:
            image = cv2.imread(os.fspath(file), cv2.IMREAD_GRAYSCALE)
            if image is None:
                _checks.fail(fn, f"{file}: not an image OpenCV can read")
            out = detect(image, target)
            if out[0].shape[0] >= min_corners:
                found.append((ns, out))
            if bar is not None:
                bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    if verbose:
        print(f"{fn}: {len(frames)} frames, {len(found)} with {min_corners} corners or more "
              f"({sum(d[0].shape[0] for _, d in found)} corners), "
              f"{len(frames) - len(found)} skipped", file=sys.stderr, flush=True)
    return found

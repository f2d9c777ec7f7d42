"""torch_dq.calibration: corner files, Kalibr targets and corner detection.

References: the real EuRoC corner files and frames of ``tests/data/calibration`` (numpy
parses of the CSVs; the published cam0/cam1 radtan intrinsics with OpenCV's
``undistortPoints`` and ``findHomography``), and synthetic targets drawn here with OpenCV
(``aruco.generateImageMarker`` per tag in Kalibr's layout) and warped by a known homography.
"""

import pathlib
import sys

import numpy as np
import pytest
import torch

from torch_dq import calibration
from torch_dq.calibration import CornersFileError, Target

DATA = pathlib.Path(__file__).resolve().parent / "data" / "calibration"
CSV0 = DATA / "euroc_cam_april_cam0_corners.csv"
CSV1 = DATA / "euroc_cam_april_cam1_corners.csv"
FRAME = "1403709395937837056"
# EuRoC's published intrinsics (sensor.yaml, Kalibr): fu, fv, cu, cv and radtan k1 k2 p1 p2.
EUROC = {
    "cam0": ((458.654, 457.296, 367.215, 248.375),
             (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)),
    "cam1": ((457.587, 456.134, 379.999, 255.238),
             (-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05)),
}


def _numpy_parse(path):
    """An independent parse: numpy's loadtxt, nanoseconds kept as Python ints."""
    v = np.loadtxt(path, delimiter=",", comments="#", dtype=np.float64)
    ns = [int(line.split(",", 1)[0]) for line in path.read_text().splitlines()
          if line and not line.startswith("#")]
    return ns, v


# ----------------------------------------------------------------------------- read_corners

@pytest.mark.parametrize("path, rows", [(CSV0, 3728), (CSV1, 4064)])
def test_read_corners_real_files(path, rows):
    times, points, pixels, extra = calibration.read_corners(path, extra=True)
    ns, ref = _numpy_parse(path)
    assert times.shape == (rows,) and points.shape == (rows, 3) and pixels.shape == (rows, 2)
    assert times.dtype == points.dtype == pixels.dtype == torch.float64
    np.testing.assert_array_equal(pixels.numpy(), ref[:, 3:5])
    np.testing.assert_array_equal(points.numpy(), ref[:, 5:8])
    # Correctly rounded seconds of the exact integer nanoseconds (Fraction-free: Python's
    # int true division is correctly rounded; float(ns) * 1e-9 is not).
    assert times.tolist() == [n / 10**9 for n in ns]
    assert len(set(ns)) == 30
    steps = np.diff(np.unique(times.numpy()))
    assert np.all(np.abs(steps - 0.05) < 1e-6)  # 20 Hz
    assert extra["tag_id"].dtype == torch.int64 and extra["corner_idx"].dtype == torch.int64
    np.testing.assert_array_equal(extra["tag_id"].numpy(), ref[:, 1])
    assert set(extra["corner_idx"].tolist()) == {0, 1, 2, 3}
    assert set(extra) == {"tag_id", "corner_idx"}


@pytest.mark.parametrize("path", [CSV0, CSV1])
def test_aprilgrid_matches_the_euroc_corner_files(path):
    _, points, _, extra = calibration.read_corners(path, extra=True)
    grid = calibration.aprilgrid(6, 6, 0.088, 0.3)
    index = extra["tag_id"] * 4 + extra["corner_idx"]
    torch.testing.assert_close(grid[index], points, rtol=0, atol=1e-12)


def test_read_corners_header_variants(tmp_path):
    """'t,u,v,X,Y,Z' without '#', whitespace-separated, columns in another order."""
    p = tmp_path / "plain.txt"
    p.write_text("X Y Z t u v tag\n\n0.1 0.2 0 12.5 100.25 50.5 3\n"
                 "# a comment line\n0.3 0.4 0 12.55 101.0 51.0 4\n")
    times, points, pixels, extra = calibration.read_corners(p, extra=True)
    assert times.tolist() == [12.5, 12.55]
    assert points.tolist() == [[0.1, 0.2, 0.0], [0.3, 0.4, 0.0]]
    assert pixels.tolist() == [[100.25, 50.5], [101.0, 51.0]]
    assert extra["tag"].tolist() == [3, 4]
    q = tmp_path / "ns.csv"
    q.write_text("# written by a detector\n#t_ns, u_px, v_px, X_m, Y_m, Z_m, score\n"
                 "1403709385487836928, 1.5, 2.5, 0.0, 0.0, 0.0, 0.75\n")
    times, _, pixels, extra = calibration.read_corners(q, extra=True)
    assert times.tolist() == [1403709385487836928 / 10**9] and pixels.tolist() == [[1.5, 2.5]]
    assert extra["score"].dtype == torch.float64 and extra["score"].tolist() == [0.75]
    assert len(calibration.read_corners(q)) == 3


def _corrupt(tmp_path, line, text):
    lines = CSV0.read_text().splitlines()
    lines[line - 1] = text
    p = tmp_path / "bad.csv"
    p.write_text("\n".join(lines) + "\n")
    return p


@pytest.mark.parametrize("text, match", [
    ("1403709385487836928,6,0,274.6642,abc,0.0,0.1144,0.0",
     r"line 100: v_px: 'abc' is not a number"),
    ("1403709385487836928,6,0,274.6642,57.4390,0.0,0.1144", r"line 100: expected 8 columns"),
    ("1403709385487836928.5,6,0,274.6,57.4,0.0,0.1144,0.0", r"line 100: t_ns: .* not an integer"),
    ("1403709385487836928,6,0,274.6642,nan,0.0,0.1144,0.0", r"line 100: non-finite value"),
    ("1403709385487836928,6,0,1_0,57.4390,0.0,0.1144,0.0", r"line 100: .* not a row of numbers"),
])
def test_read_corners_names_file_and_line(tmp_path, text, match):
    p = _corrupt(tmp_path, 100, text)
    with pytest.raises(CornersFileError, match=match) as info:
        calibration.read_corners(p)
    assert str(p) in str(info.value) and info.value.line == 100
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("content, match", [
    ("", "no header"),
    ("1,2,3,4,5,6\n", "no header"),
    ("# t_ns,u_px,v_px,X_m,Y_m,Z_m\n", "no data"),
    ("# t_ns,u_px,v_px,X_m,Y_m\n1,2,3,4,5\n", r"line 1: .*none of the target point columns"),
    ("# t,t_ns,u,v,X,Y,Z\n1,2,3,4,5,6,7\n", r"line 1: .*both of the time columns"),
    ("# t,u,v,X,Y,Z,u\n1,2,3,4,5,6,7\n", "column 'u' appears twice"),
    (b"\xff\xfe# t\n", "not a UTF-8 text file"),
])
def test_read_corners_bad_files(tmp_path, content, match):
    p = tmp_path / "c.csv"
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content)
    with pytest.raises(CornersFileError, match=match):
        calibration.read_corners(p)


@pytest.mark.parametrize("t, unit", [
    ((1403709385487836928, 1403709385537837056), "nanoseconds"),
    ((0, 50_000_000), "nanoseconds"),
    ((1403709385487, 1403709385537), "milliseconds"),
    ((0, 50, 100), "milliseconds"),
])
def test_read_corners_warns_on_a_t_column_in_another_unit(tmp_path, t, unit):
    p = tmp_path / "c.csv"
    p.write_text("t,u,v,X,Y,Z\n" + "".join(f"{x},1,2,0,0,0\n" for x in t))
    with pytest.warns(UserWarning, match=unit):
        calibration.read_corners(p)


def test_read_corners_seconds_do_not_warn(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("t,u,v,X,Y,Z\n" + "".join(f"{1403709385.0 + 0.05 * k},1,2,0,0,0\n"
                                           for k in range(5)))
    assert calibration.read_corners(p)[0].shape == (5,)  # warnings are errors here


def test_read_corners_bad_arguments():
    with pytest.raises(TypeError, match="read_corners: expected a path"):
        calibration.read_corners(3)
    with pytest.raises(TypeError, match="read_corners: expected extra to be a bool"):
        calibration.read_corners(CSV0, extra="yes")


# ----------------------------------------------------------------------------- targets

def test_aprilgrid_layout():
    g = calibration.aprilgrid(2, 3, 0.1, 0.5).numpy()
    assert g.shape == (24, 3) and g.dtype == np.float64 and np.all(g[:, 2] == 0)
    # tag 4: row 1, column 1, pitch 0.15; corners counter-clockwise from the lower-left
    np.testing.assert_allclose(g[16:20, :2], [[0.15, 0.15], [0.25, 0.15], [0.25, 0.25],
                                              [0.15, 0.25]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(g[2 * 4 + 1, :2], [0.4, 0.0], rtol=0, atol=1e-15)


def test_checkerboard_order_is_kalibrs():
    g = calibration.checkerboard(3, 4, 0.05, 0.04).numpy()
    r, c = np.divmod(np.arange(12), 4)
    np.testing.assert_allclose(g, np.stack((0.05 * r, 0.04 * c, 0 * r), -1), rtol=0,
                               atol=1e-15)


@pytest.mark.parametrize("call, error, match", [
    (lambda: calibration.aprilgrid(0, 6, 0.088, 0.3), ValueError, "rows must be an int >= 1"),
    (lambda: calibration.aprilgrid(6, 6.0, 0.088, 0.3), ValueError, "cols must be an int"),
    (lambda: calibration.aprilgrid(6, 6, -1.0, 0.3), ValueError, "tag_size must be"),
    (lambda: calibration.aprilgrid(6, 6, 0.088, float("nan")), ValueError, "tag_spacing"),
    (lambda: calibration.checkerboard(2, 6, 0.1, 0.1), ValueError, "rows must be an int >= 3"),
    (lambda: calibration.checkerboard(4, 6, 0.1, 0.0), ValueError, "col_spacing must be"),
    (lambda: Target("circlegrid", 4, 4, 0.1, 0.1), ValueError, "kind must be one of"),
    (lambda: Target.aprilgrid(True, 4, 0.1, 0.1), ValueError, "rows must be an int"),
])
def test_target_bad_arguments(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_target_points_and_counts():
    t = Target.aprilgrid(4, 5, 0.088, 0.3)
    assert (t.tags, t.corners_per_tag) == (20, 4)
    torch.testing.assert_close(t.points, calibration.aprilgrid(4, 5, 0.088, 0.3))
    c = Target.checkerboard(5, 6, 0.03, 0.02)
    assert (c.tags, c.corners_per_tag, c.points.shape) == (1, 30, (30, 3))
    with pytest.raises(AttributeError):
        t.rows = 3  # frozen


@pytest.mark.parametrize("text, expected", [
    ("target_type: 'aprilgrid' #gridtype\ntagCols: 6\ntagRows: 5\ntagSize: 0.088\n"
     "tagSpacing: 0.3\n", Target("aprilgrid", 5, 6, 0.088, 0.3)),
    ("target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\n"
     "colSpacingMeters: 0.05\n", Target("checkerboard", 7, 6, 0.06, 0.05)),
])
def test_read_target(tmp_path, text, expected):
    pytest.importorskip("yaml")
    p = tmp_path / "target.yaml"
    p.write_text(text)
    assert calibration.read_target(p) == expected


@pytest.mark.parametrize("text, match", [
    ("target_type: 'circlegrid'\ntargetCols: 6\n", "target_type must be 'aprilgrid' or"),
    ("tagCols: 6\n", "target_type must be"),
    ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n",
     "missing tagSpacing"),
    ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: -0.088\ntagSpacing: 0.3\n",
     "tagSize must be a finite real number > 0"),
    ("target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7.5\nrowSpacingMeters: 0.06\n"
     "colSpacingMeters: 0.05\n", "targetRows must be an int"),
    ("- a\n- b\n", "expected a yaml mapping"),
    ("target_type: [\n", "not a valid yaml file"),
])
def test_read_target_bad_files(tmp_path, text, match):
    pytest.importorskip("yaml")
    p = tmp_path / "t.yaml"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as info:
        calibration.read_target(p)
    assert str(p) in str(info.value)


def test_optional_dependencies_are_named(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "yaml", None)
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(ImportError, match=r"read_target: .*pip install torch_dq\[calib\]"):
        calibration.read_target(tmp_path / "t.yaml")
    with pytest.raises(ImportError, match=r"detect: .*pip install torch_dq\[calib\]"):
        calibration.detect(np.zeros((32, 32), np.uint8), Target.aprilgrid(2, 2, 0.1, 0.3))


# ----------------------------------------------------------------------------- rendering

PX = 10  # canvas pixels per tag cell: a tag is 10 cells (6 data, 2-bit border each side)


def _canvas_aprilgrid(cv2, rows, cols, margin=40):
    """Kalibr's AprilGrid (tag 0.088 m, spacing 0.3) drawn at 100 px per tag, and the
    map S from target metres to canvas pixels (pixel centres at integers)."""
    tag, gap = 10 * PX, 3 * PX  # 0.088 m and 0.0264 m
    pitch = tag + gap
    ppm = tag / 0.088
    w, h = 2 * margin + cols * pitch + gap, 2 * margin + rows * pitch + gap
    canvas = np.full((h, w), 255, np.uint8)
    x0, ytop = margin + gap, margin  # canvas column of X = 0; row of Y = rows * pitch
    S = np.array([[ppm, 0, x0 - 0.5], [0, -ppm, ytop - 0.5 + rows * pitch], [0, 0, 1]])
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    for i in range(cols + 1):  # the black squares between the tags' corners
        for j in range(rows + 1):
            top = ytop + (rows - j) * pitch
            canvas[top:top + gap, x0 + i * pitch - gap:x0 + i * pitch] = 0
    for tag_id in range(rows * cols):
        r, c = divmod(tag_id, cols)
        marker = cv2.aruco.generateImageMarker(dictionary, tag_id, tag, borderBits=2)
        top = ytop + (rows - 1 - r) * pitch + gap
        left = x0 + c * pitch
        canvas[top:top + tag, left:left + tag] = np.rot90(marker, 2)  # Kalibr's print
    return canvas, S


def _canvas_checkerboard(rows, cols, square=40, margin=40):
    """Kalibr's checkerboard of rows x cols inner corners (X along the row index r, as
    Kalibr's points), black where (a + b) is even for the square a, b (its corner 0's inner
    square is black), and the map S from target metres (0.03 m squares) to the canvas."""
    nx, ny = rows + 1, cols + 1  # squares along X (rows) and Y (cols)
    canvas = np.full((2 * margin + ny * square, 2 * margin + nx * square), 255, np.uint8)
    for a in range(nx):
        for b in range(ny):
            if (a + b) % 2 == 0:
                top = margin + (ny - 1 - b) * square
                canvas[top:top + square, margin + a * square:margin + (a + 1) * square] = 0
    ppm = square / 0.03
    S = np.array([[ppm, 0, margin + square - 0.5], [0, -ppm, margin + (ny - 1) * square - 0.5],
                  [0, 0, 1]])
    return canvas, S


def _view(cv2, canvas, S, quad, size=(640, 480), noise=0.0, seed=0):
    """Warp the canvas so that its corners land on ``quad``; return the image and the
    target-to-image homography."""
    h, w = canvas.shape
    src = np.float32([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    H = cv2.getPerspectiveTransform(src, np.float32(quad)).astype(np.float64)
    scale = np.ptp(np.asarray(quad, np.float64)[:, 0]) / w  # image pixels per canvas pixel
    sigma = max(0.5, 0.5 / scale)  # anti-aliasing before the warp shrinks the canvas
    smooth = cv2.GaussianBlur(canvas.astype(np.float32), (0, 0), sigma)
    image = cv2.warpPerspective(smooth, H, size, flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    image = image + np.random.default_rng(seed).normal(0, noise, image.shape)
    return np.clip(np.round(image), 0, 255).astype(np.uint8), H @ S


def _project(G, points):
    p = np.c_[points[:, :2], np.ones(len(points))] @ G.T
    return p[:, :2] / p[:, 2:]


QUADS = {
    "oblique": [[60, 40], [600, 70], [570, 450], [90, 420]],
    "half_turn": [[580, 440], [70, 450], [60, 30], [600, 50]],  # the target upside down
}


@pytest.mark.parametrize("view", QUADS)
def test_detect_rendered_aprilgrid_is_subpixel(view):
    cv2 = pytest.importorskip("cv2")
    target = Target.aprilgrid(4, 5, 0.088, 0.3)  # rows != cols: no transposition hides
    canvas, S = _canvas_aprilgrid(cv2, 4, 5)
    image, G = _view(cv2, canvas, S, QUADS[view], noise=1.0)
    tags, corners, pixels, points = calibration.detect(torch.from_numpy(image), target)
    assert tags.unique().tolist() == list(range(20)) and pixels.shape == (80, 2)
    assert tags.dtype == corners.dtype == torch.int64 and pixels.dtype == torch.float64
    torch.testing.assert_close(points, target.points[tags * 4 + corners], rtol=0, atol=0)
    err = np.linalg.norm(pixels.numpy() - _project(G, points.numpy()), axis=1)
    # measured: median 0.015 (oblique) and 0.04 px (half turn), max 0.07 px
    assert np.median(err) < 0.06 and err.max() < 0.15, (np.median(err), err.max())


@pytest.mark.parametrize("view", QUADS)
def test_detect_rendered_checkerboard_in_kalibrs_order(view):
    cv2 = pytest.importorskip("cv2")
    target = Target.checkerboard(5, 6, 0.03, 0.03)  # rows + cols odd: the colours tell
    canvas, S = _canvas_checkerboard(5, 6)
    image, G = _view(cv2, canvas, S, QUADS[view], noise=1.0)
    tags, corners, pixels, points = calibration.detect(image, target)
    assert corners.tolist() == list(range(30)) and tags.tolist() == [0] * 30
    err = np.linalg.norm(pixels.numpy() - _project(G, points.numpy()), axis=1)
    # measured: median 0.024 px, max 0.07 px
    assert np.median(err) < 0.06 and err.max() < 0.15, (np.median(err), err.max())


def test_detect_symmetric_checkerboard_keeps_handedness():
    """A square board with rows + cols even: the colours rule out the quarter turns (OpenCV
    returns one here), the order is one of the two half-turn-related ones, never mirrored."""
    cv2 = pytest.importorskip("cv2")
    target = Target.checkerboard(5, 5, 0.03, 0.03)
    canvas, S = _canvas_checkerboard(5, 5)
    for quad in QUADS.values():
        image, G = _view(cv2, canvas, S, quad)
        _, corners, pixels, points = calibration.detect(image, target)
        assert corners.tolist() == list(range(25))
        truth = _project(G, points.numpy())
        err = [np.median(np.linalg.norm(pixels.numpy()[::s] - truth, axis=1)) for s in (1, -1)]
        assert min(err) < 0.06, err


def test_detect_nothing_to_see():
    pytest.importorskip("cv2")
    for target in (Target.aprilgrid(6, 6, 0.088, 0.3), Target.checkerboard(5, 6, 0.03, 0.03)):
        out = calibration.detect(np.full((120, 160), 200, np.uint8), target)
        assert [tuple(o.shape) for o in out] == [(0,), (0,), (0, 2), (0, 3)]


def test_detect_rejects_tags_outside_the_grid():
    """A 4 x 5 grid seen as a 2 x 5 target: tags 10..19 are not on it."""
    cv2 = pytest.importorskip("cv2")
    canvas, S = _canvas_aprilgrid(cv2, 4, 5)
    image, _ = _view(cv2, canvas, S, QUADS["oblique"])
    tags = calibration.detect(image, Target.aprilgrid(2, 5, 0.088, 0.3))[0]
    assert tags.numel() and tags.max() < 10


@pytest.mark.parametrize("image, error, match", [
    (np.zeros((40, 40), np.float32), TypeError, "expected a uint8 grey image"),
    (np.zeros((40, 40, 3), np.uint8), ValueError, "colour image"),
    ([[0] * 40] * 40, TypeError, "expected a numpy array or a tensor"),
])
def test_detect_bad_arguments(image, error, match):
    with pytest.raises(error, match=f"calibration.detect: .*{match}"):
        calibration.detect(image, Target.aprilgrid(6, 6, 0.088, 0.3))
    with pytest.raises(TypeError, match=r"expected a calibration\.Target"):
        calibration.detect(np.zeros((40, 40), np.uint8), "april_6x6.yaml")


# ----------------------------------------------------------------------------- real frames

@pytest.mark.parametrize("cam", ["cam0", "cam1"])
def test_detect_real_euroc_frames(cam):
    """Every tag of the clear view; the corners fit one homography-plus-radtan camera with
    EuRoC's published intrinsics (0.14 px RMS measured; 1.4 px without undistortion)."""
    cv2 = pytest.importorskip("cv2")
    image = cv2.imread(str(DATA / f"{cam}_{FRAME}.png"), cv2.IMREAD_GRAYSCALE)
    tags, _, pixels, points = calibration.detect(image, Target.aprilgrid(6, 6, 0.088, 0.3))
    assert tags.unique().tolist() == list(range(36)) and pixels.shape == (144, 2)
    (f, c), dist = ((EUROC[cam][0][:2], EUROC[cam][0][2:])), np.array(EUROC[cam][1])
    K = np.array([[f[0], 0, c[0]], [0, f[1], c[1]], [0, 0, 1]])
    und = cv2.undistortPoints(pixels.numpy().reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
    H, _ = cv2.findHomography(points.numpy()[:, :2], und, 0)
    rms = np.sqrt(np.mean(np.sum((_project(H, points.numpy()) - und) ** 2, axis=1)))
    assert rms < 0.3, rms


# ----------------------------------------------------------------------------- folders

def test_detect_folder(tmp_path, capsys):
    cv2 = pytest.importorskip("cv2")
    target = Target.aprilgrid(4, 5, 0.088, 0.3)
    canvas, S = _canvas_aprilgrid(cv2, 4, 5)
    folder = tmp_path / "cam0" / "data"
    folder.mkdir(parents=True)
    stamps = [1403709385537837056, 1403709385487836928, 1403709385587836928]
    truth = {}
    for k, ns in enumerate(stamps):
        quad = np.array(QUADS["oblique"]) + np.array([5 * k, -3 * k])
        image, truth[ns] = _view(cv2, canvas, S, quad, seed=k)
        cv2.imwrite(str(folder / f"{ns}.png"), image)
    cv2.imwrite(str(folder / "1403709385637837056.png"), np.full((480, 640), 90, np.uint8))
    (folder / "notes.txt").write_text("not an image")
    csv = tmp_path / "corners.csv"
    times, points, pixels, tags, corners = calibration.detect_folder(
        tmp_path / "cam0", target, csv=csv, verbose=True)
    assert "4 frames, 3 with 16 corners or more" in capsys.readouterr().err
    assert times.shape == (240,) and points.shape == (240, 3) and pixels.shape == (240, 2)
    ordered = sorted(stamps)
    assert times.unique().tolist() == [n / 10**9 for n in ordered]
    assert torch.all(times[1:] >= times[:-1])
    for ns in ordered:
        at = times == ns / 10**9
        err = np.linalg.norm(pixels[at].numpy() - _project(truth[ns], points[at].numpy()),
                             axis=1)
        assert np.median(err) < 0.1
    back = calibration.read_corners(csv, extra=True)
    for a, b in zip(back[:3], (times, points, pixels), strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert back[3]["tag_id"].tolist() == tags.tolist()
    assert back[3]["corner_idx"].tolist() == corners.tolist()


def test_detect_folder_errors_and_empty(tmp_path):
    cv2 = pytest.importorskip("cv2")
    target = Target.aprilgrid(6, 6, 0.088, 0.3)
    with pytest.raises(ValueError, match="is not a folder"):
        calibration.detect_folder(tmp_path / "missing", target)
    with pytest.raises(ValueError, match="no images"):
        calibration.detect_folder(tmp_path, target)
    cv2.imwrite(str(tmp_path / "frame_1.png"), np.zeros((40, 40), np.uint8))
    with pytest.raises(ValueError, match=r"integer nanoseconds.*'frame_1\.png'"):
        calibration.detect_folder(tmp_path, target)
    (tmp_path / "frame_1.png").rename(tmp_path / "100.png")
    with pytest.raises(ValueError, match="min_corners must be an int >= 1"):
        calibration.detect_folder(tmp_path, target, min_corners=0)
    with pytest.raises(ValueError, match="would be overwritten"):
        calibration.detect_folder(tmp_path, target, csv=tmp_path / "100.png")
    with pytest.warns(UserWarning, match="no frame of 1 has 16 corners"):
        out = calibration.detect_folder(tmp_path, target)
    assert [tuple(o.shape) for o in out] == [(0,), (0, 3), (0, 2), (0,), (0,)]

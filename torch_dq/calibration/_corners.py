r"""Corner files: what a target detector saw, one row per corner.

A corners file is a CSV (commas; whitespace when the header has no comma) whose first line
names the columns (it may start with ``#``; blank lines and later ``#`` lines are skipped):

=================  =============================================================
column             meaning
=================  =============================================================
``t_ns`` or ``t``  the frame's time: integer nanoseconds, or seconds
``u_px, v_px``     the corner's pixel (or ``u, v``): column and row, pixels
``X_m, Y_m, Z_m``  the target point (or ``X, Y, Z``), metres, in the target frame
others             kept apart (``tag_id``, ``corner_idx``: see ``extra=True``)
=================  =============================================================

:func:`torch_dq.calibration.detect_folder` writes this format (``t_ns, tag_id,
corner_idx, u_px, v_px, X_m, Y_m, Z_m``), as do the EuRoC corner files in the tests.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import torch

from .. import _checks
from ..io import TrajectoryFileError

__all__ = ["CornersFileError", "read_corners"]

_TIME = (("t_ns", "ns"), ("t", "s"))
_PIXEL = (("u_px", "v_px"), ("u", "v"))
_POINT = (("X_m", "Y_m", "Z_m"), ("X", "Y", "Z"))
WRITTEN = ("t_ns", "tag_id", "corner_idx", "u_px", "v_px", "X_m", "Y_m", "Z_m")


class CornersFileError(TrajectoryFileError):
    """A malformed corners file: the message reads ``"<file>, line <n>: <what is wrong>"``.

    A ``ValueError`` (through :class:`torch_dq.io.TrajectoryFileError`, whose ``path`` and
    ``line`` attributes it has).
    """


def _lines(path) -> tuple[list[str], str | None, int, list[int], list[str]]:
    """(column names, separator, header line, data line numbers, data texts) of a file."""
    header: str | None = None
    at, numbers_, texts = 0, list[int](), list[str]()
    try:
        with open(path, encoding="utf-8-sig") as f:
            for n, line in enumerate(f, 1):
                text = line.strip()
                if not text:
                    continue
                if text.startswith("#"):
                    if not texts:  # the last comment before the data names the columns
                        header, at = text[1:], n
                    continue
                if header is None and not texts and text[:1].isalpha():
                    header, at = text, n
                    continue
                numbers_.append(n)
                texts.append(text)
    except UnicodeDecodeError as exc:
        raise CornersFileError(path, None, f"not a UTF-8 text file ({exc.reason} at byte "
                                           f"{exc.start})") from None
    if header is None:
        raise CornersFileError(path, None, "no header line naming the columns (e.g. "
                                           f"'# {','.join(WRITTEN)}')")
    sep = "," if "," in header else None
    names = [s.strip() for s in header.split(sep)]
    if not texts:
        raise CornersFileError(path, None, "no data (the file holds only a header)")
    return names, sep, at, numbers_, texts


def _columns(path, names: list[str], at: int) -> tuple[int, str, list[int], list[int]]:
    """Indices of the time (and its unit), the pixel and the point columns."""
    def find(options, what):
        found = [opt for opt in options if all(c in names for c in opt)]
        if len(found) != 1:
            alternatives = " or ".join(", ".join(o) for o in options)
            why = "both of" if found else "none of"
            raise CornersFileError(path, at, f"the header names {why} the {what} columns "
                                             f"({alternatives}); got {', '.join(names)}")
        return [names.index(c) for c in found[0]], found[0]
    doubled = sorted({c for c in names if names.count(c) > 1})
    if doubled:
        raise CornersFileError(path, at, f"column {doubled[0]!r} appears twice in the header")
    time, name = find([(c,) for c, _ in _TIME], "time")
    unit = dict(_TIME)[name[0]]
    return time[0], unit, find(_PIXEL, "pixel")[0], find(_POINT, "target point")[0]


def _cells(path, names: list[str], sep: str | None, lines: list[int],
           texts: list[str]) -> np.ndarray:
    """The fields as a (N, C) string array; a line with the wrong count is an error."""
    rows = [t.split(sep) for t in texts]
    width = len(names)
    for n, row, text in zip(lines, rows, texts, strict=True):
        if len(row) != width:
            raise CornersFileError(path, n, f"expected {width} columns ({', '.join(names)}), "
                                            f"got {len(row)}")
        if "_" in text:  # numpy reads "1_0" as 10
            raise CornersFileError(path, n, f"{text!r} is not a row of numbers")
    return np.char.strip(np.array(rows, dtype=str))


def _repeated(path, cells: np.ndarray, lines: list[int]) -> None:
    """A :class:`CornersFileError` on the first row that repeats an earlier one cell for
    cell: the same corner twice (a file written twice) would weigh double in every fit."""
    seen: dict[str, int] = {}
    for k, key in enumerate(map("\x1f".join, cells.tolist())):
        j = seen.setdefault(key, k)
        if j != k:
            raise CornersFileError(path, lines[k], f"the same row as line {lines[j]} (a "
                                                   f"corner listed twice would count twice)")


def _seen_twice(path, names: list[str], cells: np.ndarray, ti: int, lines: list[int]) -> None:
    """A :class:`CornersFileError` on the first row whose time, ``tag_id`` and
    ``corner_idx`` repeat an earlier row's with other values (one corner detected twice in
    one frame, at two pixels: which is it?). Without those columns nothing is checked (the
    corners of adjacent tags coincide on an AprilGrid of spacing 0)."""
    if "tag_id" not in names or "corner_idx" not in names:
        return
    cols = [ti, names.index("tag_id"), names.index("corner_idx")]
    seen: dict[str, int] = {}
    for k, key in enumerate(map("\x1f".join, cells[:, cols].tolist())):
        j = seen.setdefault(key, k)
        if j != k:
            raise CornersFileError(path, lines[k], f"tag_id {cells[k, cols[1]]} corner_idx "
                                                   f"{cells[k, cols[2]]} again in the frame "
                                                   f"{cells[k, ti]} (first on line "
                                                   f"{lines[j]}): one corner detected twice")


def _numbers(path, cells: np.ndarray, lines: list[int], names: list[str],
             dtype: type) -> np.ndarray:
    """Convert string columns, naming the first bad cell (line and column)."""
    try:
        values: np.ndarray = cells.astype(dtype)
    except (ValueError, OverflowError):
        for n, row in zip(lines, cells, strict=True):
            for name, text in zip(names, row, strict=True):
                try:
                    np.array([text]).astype(dtype)
                except (ValueError, OverflowError):
                    what = "an integer" if dtype is np.int64 else "a number"
                    raise CornersFileError(path, n, f"{name}: {str(text)!r} is not {what}"
                                           ) from None
        raise
    if dtype is np.float64:
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if bad.size:
            raise CornersFileError(path, lines[bad[0]], f"non-finite value in "
                                                        f"{', '.join(cells[bad[0]])}")
    return values


def _seconds(ns: np.ndarray) -> np.ndarray:
    """Integer nanoseconds to float64 seconds, correctly rounded (Python's int division)."""
    unique, inverse = np.unique(ns, return_inverse=True)
    return np.array([n / 1_000_000_000 for n in unique.tolist()], np.float64)[inverse]


def _unit_hint(t: np.ndarray) -> str | None:
    """The unit a ``t`` column (seconds) more likely holds, or None when seconds fit."""
    big = float(np.abs(t).max())
    steps = np.diff(np.unique(t))
    step = float(np.median(steps)) if steps.size else 0.0
    if big >= 1e17 or step >= 1e6:
        return "nanoseconds"
    if big >= 1e14 or step >= 1e4:
        return "microseconds"
    if big >= 1e11 or (step >= 10 and bool(np.all(t == np.round(t)))):
        return "milliseconds"
    return None


def read_corners(path: str | os.PathLike[str], *, extra: bool = False) -> tuple:
    r"""Read a corners file: the target points a camera saw and where.

    Args:
        path: the CSV file (see the module's table for its columns).
        extra: also return the other columns (``tag_id``, ``corner_idx``, ...).

    Returns:
        ``(times, points, pixels)``: float64 CPU tensors ``(N,)`` (seconds: ``t_ns``
        converted exactly as integers, then correctly rounded; ``t`` as written),
        ``(N, 3)`` and ``(N, 2)``, one row per line of the file, in its order. With
        ``extra=True`` a fourth element, a dict from each other column's name to an
        ``(N,)`` tensor: int64 when every value is an integer, else float64.

    Raises:
        CornersFileError: (a ``ValueError``) naming the file and the line: no header, a
            header without the time, pixel or point columns (or with both variants of
            one), a row with the wrong number of columns, a value that is not a finite
            number, a ``t_ns`` that is not an integer, a row repeating an earlier one, a
            ``tag_id`` and ``corner_idx`` twice in one frame, an empty file.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: a ``t`` column (seconds) whose values look like nanoseconds,
            microseconds or milliseconds (UNIX times of that size, or frames 10 s or more
            apart on integer times); name the column ``t_ns`` for nanoseconds.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "corners.csv")
        >>> with open(path, "w") as f:
        ...     _ = f.write("# t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m\n"
        ...                 "1403709385487836928,6,0,274.6642,57.4390,0.0,0.1144,0.0\n"
        ...                 "1403709385487836928,6,1,235.9239,51.5984,0.088,0.1144,0.0\n")
        >>> times, points, pixels, ids = read_corners(path, extra=True)
        >>> times.dtype, points.shape, pixels.shape, ids["tag_id"].tolist()
        (torch.float64, torch.Size([2, 3]), torch.Size([2, 2]), [6, 6])
    """
    fn = "calibration.read_corners"
    if not isinstance(path, (str, os.PathLike)):
        _checks.fail(fn, f"expected a path (str or os.PathLike) for path, got "
                         f"{type(path).__name__}", TypeError)
    _checks.flag(fn, "extra", extra)
    names, sep, at, lines, texts = _lines(path)
    ti, unit, pix, pts = _columns(path, names, at)
    cells = _cells(path, names, sep, lines, texts)
    _repeated(path, cells, lines)
    sub = lambda idx: [names[i] for i in idx]  # noqa: E731
    values = _numbers(path, cells[:, pix + pts], lines, sub(pix + pts), np.float64)
    if unit == "ns":
        times = _seconds(_numbers(path, cells[:, [ti]], lines, [names[ti]], np.int64)[:, 0])
    else:
        times = _numbers(path, cells[:, [ti]], lines, [names[ti]], np.float64)[:, 0]
        hint = _unit_hint(times)
        if hint is not None:
            warnings.warn(f"{fn}: {os.fspath(path)}: the column 't' (seconds) looks like "
                          f"{hint}; convert it to seconds (or name integer nanoseconds "
                          f"'t_ns')", UserWarning, stacklevel=2)
    _seen_twice(path, names, cells, ti, lines)
    as_tensor = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
    out = (as_tensor(times), as_tensor(values[:, 2:]), as_tensor(values[:, :2]))
    if not extra:
        return out
    others = [i for i in range(len(names)) if i not in (ti, *pix, *pts)]
    return (*out, {names[i]: as_tensor(_extra(path, cells[:, i], lines, names[i]))
                   for i in others})


def _extra(path, column: np.ndarray, lines: list[int], name: str) -> np.ndarray:
    """An extra column: int64 when every value is an integer, else float64."""
    try:
        return column.astype(np.int64)
    except (ValueError, OverflowError):
        return _numbers(path, column[:, None], lines, [name], np.float64)[:, 0]


def write_corners(path, ns: np.ndarray, tag_ids: np.ndarray, corner_ids: np.ndarray,
                  pixels: np.ndarray, points: np.ndarray) -> None:
    """Write a corners file in :func:`read_corners`' format (columns ``WRITTEN``; every
    float64 written in its shortest exact form, so it reads back bit for bit)."""
    with open(path, "w", encoding="utf-8") as f:
        f.write("# " + ",".join(WRITTEN) + "\n")
        for row in zip(ns.tolist(), tag_ids.tolist(), corner_ids.tolist(), pixels.tolist(),
                       points.tolist(), strict=True):
            n, tag, corner, (u, v), (x, y, z) = row
            f.write(f"{n},{tag},{corner},{u!r},{v!r},{x!r},{y!r},{z!r}\n")

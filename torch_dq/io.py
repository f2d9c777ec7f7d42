r"""Read and write trajectory files (TUM, KITTI, EuRoC ground truth, a resampled CSV) and IMU files.

A trajectory file holds timestamped rigid poses (body to world). Three common formats:

============  ==================================================================  ============
``format``    one pose per line                                                   times
============  ==================================================================  ============
``"tum"``     ``t x y z qx qy qz qw`` (whitespace or commas; ``#`` comments),     seconds
              the TUM RGB-D benchmark's ``groundtruth.txt``
``"kitti"``   ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``: the 3x4 matrix    a separate
              ``[R | t]`` row by row (KITTI odometry ``poses/NN.txt``)            file (s)
``"euroc"``   ``#timestamp [ns], p_RS_R_x [m], p_RS_R_y, p_RS_R_z, q_RS_w,        nanoseconds
              q_RS_x, q_RS_y, q_RS_z`` and optionally velocity and biases
              (``state_groundtruth_estimate0/data.csv``; columns after the 8th
              are ignored)
============  ==================================================================  ============

:func:`read_trajectory` returns a :class:`Trajectory`: ``float64`` times in seconds as
written (absolute UNIX seconds stay absolute: ``float64`` keeps them to ~0.2 µs), rotations
as unit quaternions ``(w, x, y, z)`` and translations, on the CPU; ``trajectory.poses()``
gives the unit dual quaternions. Malformed files raise :class:`TrajectoryFileError` (a
``ValueError``) naming the file and the line: wrong column count, a value that is not a
finite number, timestamps that are not strictly increasing, a quaternion whose norm is not 1
within ``atol`` (a KITTI rotation matrix that is not orthonormal), an empty file.
:func:`write_trajectory` writes the three formats back, exactly (every float64 time and value
reads back bit for bit); :func:`write_csv` writes a resampled trajectory with its velocities
and accelerations (what ``python -m torch_dq fit`` writes). :func:`read_imu` reads gyroscope
and accelerometer samples (EuRoC ``imu0/data.csv`` or plain ``t gx gy gz ax ay az``).

Numbers are read strictly as files write them: ASCII decimals (``1_0``, which Python's
``float`` takes for 10, is an error); a UTF-8 byte-order mark is skipped.

Example:
    >>> import torch, tempfile, os
    >>> from torch_dq import io
    >>> path = os.path.join(tempfile.mkdtemp(), "traj.txt")
    >>> with open(path, "w") as f:
    ...     _ = f.write("# timestamp tx ty tz qx qy qz qw\n"
    ...                 "1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n"
    ...                 "1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980\n")
    >>> traj = io.read_trajectory(path)
    >>> len(traj), traj.times.dtype, traj.poses().shape
    (2, torch.float64, torch.Size([2, 8]))
    >>> round(float(traj.times[1] - traj.times[0]), 4)
    0.0099
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from decimal import Decimal
from fractions import Fraction

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor

from . import _checks, dualquat, quat

__all__ = [
    "CSV_COLUMNS",
    "FORMATS",
    "Trajectory",
    "TrajectoryFileError",
    "read_imu",
    "read_trajectory",
    "write_csv",
    "write_trajectory",
]

#: The file formats :func:`read_trajectory` and :func:`write_trajectory` know.
FORMATS = ("tum", "kitti", "euroc")

#: Columns of :func:`write_csv`, in order (SI units; world frame).
CSV_COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
               "ax", "ay", "az", "alpha_x", "alpha_y", "alpha_z")

_TUM_COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
_KITTI_COLUMNS = ("r11", "r12", "r13", "tx", "r21", "r22", "r23", "ty", "r31", "r32", "r33",
                  "tz")
_EUROC_COLUMNS = ("#timestamp [ns]", "p_RS_R_x [m]", "p_RS_R_y [m]", "p_RS_R_z [m]",
                  "q_RS_w []", "q_RS_x []", "q_RS_y []", "q_RS_z []")


class TrajectoryFileError(ValueError):
    """A malformed trajectory file (or times file).

    The message reads ``"<file>, line <n>: <what is wrong>"`` (without the line for
    problems of the whole file, e.g. an empty one).

    Attributes:
        path: the file, as given.
        line: the 1-based line number, or ``None``.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, message: str):
        self.path = os.fspath(path)
        self.line = line
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True, eq=False)
class Trajectory:
    r"""Timestamped rigid poses (body to world): ``x -> R(rotations[i]) x + translations[i]``.

    Attributes:
        times: ``(N,)`` float64 strictly increasing times in seconds (as in the file:
            UNIX seconds stay absolute).
        rotations: ``(N, 4)`` float64 unit quaternions ``(w, x, y, z)`` (sign as in the
            file).
        translations: ``(N, 3)`` float64 positions of the body origin in the world frame
            (the file's unit: metres for TUM, KITTI and EuRoC).
    """

    times: Tensor
    rotations: Tensor
    translations: Tensor

    def __len__(self) -> int:
        return self.times.shape[0]

    def poses(self) -> Tensor:
        """The poses as ``(N, 8)`` unit dual quaternions (:func:`torch_dq.dualquat.from_rt`)."""
        return dualquat.from_rt(self.rotations, self.translations)

    def select(self, index: slice | Tensor) -> Trajectory:
        """The sub-trajectory at ``index`` (a slice, an index tensor or a bool mask).

        Example:
            >>> t = torch.arange(6.0, dtype=torch.float64)
            >>> traj = Trajectory(t, quat.identity((6,), torch.float64), torch.zeros(6, 3,
            ...                   dtype=torch.float64))
            >>> traj.select(slice(None, None, 2)).times
            tensor([0., 2., 4.], dtype=torch.float64)
        """
        return Trajectory(self.times[index], self.rotations[index], self.translations[index])


# ----------------------------------------------------------------------------- parsing

def _read_lines(path) -> tuple[list[int], list[str], list[str]]:
    """Data lines of a text file: (line numbers, texts, the comment lines before the data).

    ``#`` starts a comment (to the end of the line); blank lines are skipped.
    """
    numbers_, texts, header = [], [], []
    try:
        with open(path, encoding="utf-8-sig") as f:  # a BOM is skipped
            for n, line in enumerate(f, 1):
                text, hash_, comment = line.partition("#")
                text = text.strip()
                if text:
                    numbers_.append(n)
                    texts.append(text)
                elif hash_ and not texts:
                    header.append(comment.strip())
    except UnicodeDecodeError as exc:
        raise TrajectoryFileError(path, None, f"not a UTF-8 text file ({exc.reason} at byte "
                                              f"{exc.start})") from None
    if not texts:
        raise TrajectoryFileError(path, None, "no data (the file is empty or holds only "
                                              "comments)")
    return numbers_, texts, header


def _split(texts: list[str], commas: bool) -> list[list[str]]:
    """Fields of each line: at commas when ``commas``, else at whitespace or commas."""
    if commas:
        return [[s.strip() for s in text.split(",")] for text in texts]
    return [text.replace(",", " ").split() for text in texts]


#: A decimal number as files write it (ASCII digits, no ``_`` separators, which Python's
#: ``float`` would accept: ``float("1_0") == 10.0``); nan and inf are numbers here, rejected
#: later as non-finite.
_NUMBER = re.compile(r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)",
                     re.ASCII | re.IGNORECASE)


def _floats(path, lines: list[int], rows: list[list[str]], names: Sequence[str]) -> np.ndarray:
    """Parse rows of numeric fields into a float64 array, naming the first bad line."""
    width = len(names)
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != width:
            raise TrajectoryFileError(path, n, f"expected {width} columns "
                                               f"({' '.join(names)}), got {len(fields)}")
        for name, text in zip(names, fields, strict=True):
            if not _NUMBER.fullmatch(text):
                raise TrajectoryFileError(path, n, f"{name}: {text!r} is not a number")
    values = np.array(rows, dtype=np.float64)
    _first_bad(path, lines, ~np.isfinite(values).all(axis=1),
               lambda i: f"non-finite value in {' '.join(rows[i])!r}")
    return values


def _first_bad(path, lines: list[int], bad: np.ndarray | np.bool_, message) -> None:
    """Raise for the first True of ``bad`` (per row), saying how many rows are bad."""
    where = np.flatnonzero(bad)
    if where.size:
        i = int(where[0])
        more = f" ({where.size} lines in all)" if where.size > 1 else ""
        raise TrajectoryFileError(path, lines[i], message(i) + more)


def _check_times(path, lines: list[int], t: np.ndarray, duplicates: str,
                 unit: str = "s", hint: str = "") -> np.ndarray:
    """Check that times increase strictly; with duplicates="first" drop repeated ones.

    ``hint`` is appended to the message on a repeated time (e.g. that the times were
    rounded to float32 before they got here).

    Returns:
        The indices of the rows kept.
    """
    step = np.diff(t)
    show = lambda i: str(t[i]) if unit == "ns" else repr(float(t[i]))  # noqa: E731
    _first_bad(path, lines[1:], step < 0,
               lambda i: f"timestamp {show(i + 1)} {unit} is before the previous one "
                         f"({show(i)} {unit}, line {lines[i]}): the rows must be sorted by "
                         f"time")
    if duplicates == "first":
        return np.flatnonzero(np.concatenate(([True], step > 0)))
    _first_bad(path, lines[1:], step == 0,
               lambda i: f"duplicate timestamp {show(i + 1)} {unit} (also on line "
                         f"{lines[i]}){hint}; pass duplicates='first' (fit: --duplicates "
                         f"first) to keep the first pose of each time")
    return np.arange(t.shape[0])


def _unit_quaternions(path, lines: list[int], q: np.ndarray, atol: float) -> np.ndarray:
    """Check ``| |q| - 1 | <= atol`` per row and return the normalized quaternions."""
    norm = np.linalg.norm(q, axis=1)
    _first_bad(path, lines, ~(np.abs(norm - 1.0) <= atol),
               lambda i: f"quaternion norm {norm[i]:.6g} is not 1 (tolerance atol={atol:g})")
    return q / norm[:, None]


def _read_tum(path, lines, texts, atol: float, duplicates: str):
    v = _floats(path, lines, _split(texts, commas=False), _TUM_COLUMNS)
    keep = _check_times(path, lines, v[:, 0], duplicates)
    q = _unit_quaternions(path, lines, v[:, [7, 4, 5, 6]], atol)
    return v[keep, 0], q[keep], v[keep, 1:4]


_INTEGER = re.compile(r"-?\d+", re.ASCII)
_DECIMAL = re.compile(r"-?\d+(?:\.\d*)?", re.ASCII)


def _nanoseconds(path, lines: list[int], texts: list[str], fractions: bool) -> list[Decimal]:
    """EuRoC timestamps: integer nanoseconds, exactly (fractions of a nanosecond too, as
    :func:`write_trajectory` writes times finer than 1 ns, when the header says ``[ns]``)."""
    pattern = _DECIMAL if fractions else _INTEGER
    for n, text in zip(lines, texts, strict=True):
        if not pattern.fullmatch(text):
            hint = ("; a TUM file with commas? pass format='tum' (fit: --format tum)"
                    if "." in text else "")
            raise TrajectoryFileError(path, n, f"timestamp {text!r} is not an integer number "
                                               f"of nanoseconds{hint}")
    return [Decimal(text) for text in texts]


def _read_euroc(path, lines, texts, header, atol: float, duplicates: str):
    rows = _split(texts, commas=True)
    if rows[0][0][:1].isalpha():  # a header row written without the leading "#"
        header, lines, texts, rows = [texts[0]], lines[1:], texts[1:], rows[1:]
        if not rows:
            raise TrajectoryFileError(path, None, "no data (the file holds only a header)")
    # The column count: the header's when it names 8 or more, else the first row's (>= 8).
    names = [s.strip() for s in header[-1].split(",")] if header else []
    if len(names) >= 8:
        names[0] = "#" + names[0]
    else:
        names = list(_EUROC_COLUMNS) + [f"column {k + 1}" for k in range(8, len(rows[0]))]
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != len(names):
            raise TrajectoryFileError(path, n, f"expected {len(names)} comma-separated columns "
                                               f"({', '.join(names[:8])}"
                                               f"{', ...' * (len(names) > 8)}), got "
                                               f"{len(fields)}")
    stated = bool(header) and "[ns]" in header[-1]  # the file's own header says nanoseconds
    ns = _nanoseconds(path, lines, [f[0] for f in rows], fractions=stated)
    v = _floats(path, lines, [f[1:8] for f in rows], names[1:8])
    keep = _check_times(path, lines, np.array(ns, dtype=object), duplicates, unit="ns")
    # Fraction -> float is correctly rounded: the float64 nearest to ns * 1e-9.
    t = np.array([float(Fraction(ns[i]) / 10**9) for i in keep], dtype=np.float64)
    q = _unit_quaternions(path, lines, v[:, 3:7], atol)
    return t, q[keep], v[keep, 0:3]


def _narrow_hint(times) -> str:
    """What to say when the times of an array repeat: a float32 array rounds UNIX seconds."""
    dtype = getattr(times, "dtype", None)
    if dtype is None or dtype in (torch.float64, np.float64):
        return ""
    try:
        eps = torch.finfo(dtype).eps if isinstance(dtype, torch.dtype) else np.finfo(dtype).eps
    except (TypeError, ValueError):  # an integer array: no rounding to explain
        return ""
    ulp = float(np.abs(np.asarray(times, dtype=np.float64)).max(initial=0.0)) * float(eps)
    return (f" (the times came as {str(dtype).replace('torch.', '')}, which rounds them to "
            f"steps of {ulp:.3g} s: pass them as float64)")


def _kitti_times(fn: str, path, times, n_poses: int) -> tuple[np.ndarray, object, list[int],
                                                                str]:
    """KITTI times from a file or an array: (times, where they came from, their lines, the
    hint for repeated times)."""
    if times is None:
        _checks.fail(fn, f"KITTI poses ({os.fspath(path)}) carry no times: pass times= (the "
                         f"sequence's times.txt, one time in seconds per line, or a (N,) "
                         f"array; fit: --times FILE)")
    if isinstance(times, (str, os.PathLike)):
        lines, texts, _ = _read_lines(times)
        t = _floats(times, lines, _split(texts, commas=False), ("time",))[:, 0]
        if t.shape[0] != n_poses:
            raise TrajectoryFileError(times, None, f"holds {t.shape[0]} times but the poses "
                                                   f"file {os.fspath(path)} has {n_poses}")
        return t, times, lines, ""
    try:
        t = np.asarray(times.detach().cpu() if isinstance(times, Tensor) else times,
                       dtype=np.float64)
    except (TypeError, ValueError):
        _checks.fail(fn, f"times must be a path or a (N,) array of seconds, got "
                         f"{type(times).__name__}", TypeError)
    if t.shape != (n_poses,):
        _checks.fail(fn, f"times must have shape ({n_poses},) (one per pose), got "
                         f"{_checks.shape_str(t.shape)}")
    if not np.isfinite(t).all():
        _checks.fail(fn, "times must be finite")
    hint = _narrow_hint(times.detach().cpu() if isinstance(times, Tensor) else times)
    return t, "times", list(range(1, n_poses + 1)), hint


def _read_kitti(fn: str, path, lines, texts, times, atol: float, duplicates: str):
    v = _floats(path, lines, _split(texts, commas=False), _KITTI_COLUMNS)
    t, t_path, t_lines, hint = _kitti_times(fn, path, times, v.shape[0])
    keep = _check_times(t_path, t_lines, t, duplicates, hint=hint)
    R = v.reshape(-1, 3, 4)[:, :, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    _first_bad(path, lines, ~(err <= atol),
               lambda i: f"rotation is not orthonormal: max |R^T R - I| = {err[i]:.3g} "
                         f"(tolerance atol={atol:g})")
    _first_bad(path, lines, np.linalg.det(R) < 0,
               lambda i: "rotation matrix has determinant -1 (a reflection)")
    q = quat.normalize(quat.from_matrix(torch.from_numpy(np.ascontiguousarray(R)))).numpy()
    return t[keep], q[keep], v[keep][:, [3, 7, 11]]


def _detect(path, lines: list[int], texts: list[str], header: list[str]) -> str:
    """Guess the format from the header comment and the first data line.

    A header naming TUM's columns (``timestamp tx ty tz qx qy qz qw``, spaces or commas)
    means TUM. Commas (in the first row or a ``timestamp,...`` header) mean EuRoC, unless
    the row has TUM's 8 fields with a time in decimal seconds and no ``[ns]`` header.
    """
    names = header[-1].lower().replace(",", " ").split() if header else []
    if tuple(names[:8]) == _TUM_COLUMNS:
        return "tum"
    if "," in texts[0] or any(h.lower().startswith("timestamp") and "," in h for h in header):
        first = [f.strip() for f in texts[0].split(",")]
        seconds = len(first) == 8 and not _INTEGER.fullmatch(first[0]) \
            and _NUMBER.fullmatch(first[0]) is not None
        return "tum" if seconds and "[ns]" not in names else "euroc"
    width = len(texts[0].split())
    if width in (8, 12):
        return "tum" if width == 8 else "kitti"
    raise TrajectoryFileError(path, lines[0], f"cannot tell the format: {width} "
                                              f"whitespace-separated columns, where TUM has 8 "
                                              f"and KITTI 12 (EuRoC is comma-separated); pass "
                                              f"format= (fit: --format)")


def read_trajectory(path: str | os.PathLike[str], format: str = "auto",
                    times: str | os.PathLike[str] | Tensor | npt.ArrayLike | None = None, *,
                    atol: float = 1e-3, duplicates: str = "error") -> Trajectory:
    r"""Read timestamped poses from a TUM, KITTI or EuRoC file.

    Args:
        path: the file (``str`` or ``os.PathLike``).
        format: ``"tum"``, ``"kitti"``, ``"euroc"`` or ``"auto"`` (default): a header naming
            TUM's columns (``# timestamp tx ty tz qx qy qz qw``, with spaces or commas) means
            TUM; comma-separated rows or a ``#timestamp,...`` header mean EuRoC, except 8
            fields with a decimal time and no ``[ns]`` header (TUM with commas); else 8
            whitespace-separated columns mean TUM and 12 KITTI.
        times: KITTI only (required there): the times file (one time in seconds per line,
            like KITTI's ``times.txt``) or a ``(N,)`` array of seconds, one per pose (keep
            absolute times float64: a float32 array rounds UNIX seconds to 128 s steps, and
            the error on the repeated times says so).
        atol: tolerance on unit norms: ``| |q| - 1 |`` for TUM and EuRoC quaternions, the
            largest entry of ``|R^T R - I|`` for KITTI matrices. The default 1e-3 accepts
            the 4-decimal rounding of TUM files (~1e-4); rotations are normalized after the
            check.
        duplicates: ``"error"`` (default): a repeated timestamp is an error;
            ``"first"``: keep the first pose of each repeated timestamp (real files have
            them, e.g. TUM freiburg2_desk at line 10863).

    Returns:
        :class:`Trajectory` of float64 CPU tensors: ``times (N,)`` in seconds (EuRoC's
        nanoseconds converted with correct rounding), ``rotations (N, 4)`` unit ``(w, x, y,
        z)``, ``translations (N, 3)``.

    Raises:
        TrajectoryFileError: (a ``ValueError``) malformed file, naming the file and the
            line: wrong column count, a value that is not a finite number (EuRoC: a
            timestamp that is not an integer), unsorted or (with ``duplicates="error"``)
            repeated timestamps, a non-unit quaternion (the message gives its norm), a
            non-orthonormal or reflecting KITTI rotation, a times file of another length,
            an empty file.
        ValueError: bad ``format``/``atol``/``duplicates``, KITTI without ``times``, or
            ``times`` given for another format.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: times that look like nanoseconds, microseconds or milliseconds (poses
            hours apart, or nearly still in seconds while plausible in the finer unit; TUM
            and KITTI). Quaternion columns in another order cannot be told from the poses
            alone (a permutation of the components keeps the angle between any two
            rotations); ``python -m torch_dq fit --imu`` tells them by the gyroscope.

    Example:
        >>> traj = read_trajectory("tests/data/tum_fr1_xyz_sub.txt")  # doctest: +SKIP
        >>> spline = nn.BSpline.from_poses(traj.rotations, traj.translations,
        ...                                traj.times, n_ctrl=60)  # doctest: +SKIP
    """
    fn = "io.read_trajectory"
    if not isinstance(path, (str, os.PathLike)):
        _checks.fail(fn, f"expected a path (str or os.PathLike) for path, got "
                         f"{type(path).__name__}", TypeError)
    if format not in (*FORMATS, "auto"):
        _checks.fail(fn, f"format must be one of 'auto', 'tum', 'kitti', 'euroc', got "
                         f"{format!r}")
    if isinstance(atol, bool) or not isinstance(atol, (int, float)) or not atol > 0 \
            or math.isinf(atol):
        _checks.fail(fn, f"atol must be a finite number > 0, got {atol!r}")
    if duplicates not in ("error", "first"):
        _checks.fail(fn, f"duplicates must be 'error' or 'first', got {duplicates!r}")
    lines, texts, header = _read_lines(path)
    if format == "auto":
        format = _detect(path, lines, texts, header)
    if times is not None and format != "kitti":
        _checks.fail(fn, f"times= applies to KITTI files only ({format.upper()} files hold "
                         f"their own times)")
    if format == "tum":
        t, q, p = _read_tum(path, lines, texts, atol, duplicates)
    elif format == "euroc":
        t, q, p = _read_euroc(path, lines, texts, header, atol, duplicates)
    else:
        t, q, p = _read_kitti(fn, path, lines, texts, times, atol, duplicates)
    if format != "euroc":  # EuRoC states nanoseconds
        _warn_time_unit(fn, path, t, q, p)
    as_tensor = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))  # noqa: E731
    return Trajectory(as_tensor(t), as_tensor(q), as_tensor(p))


# ----------------------------------------------------------------------------- units

#: Motion no recording reaches (m/s, rad/s): times read in the wrong unit reach it or
#: stay below ``_STILL`` where another unit gives plausible motion.
_FASTEST = 50.0
_STILL = 0.02
_TIME_UNITS = (("nanoseconds", 1e-9), ("microseconds", 1e-6), ("milliseconds", 1e-3))


def _time_unit_guess(t: np.ndarray, q: np.ndarray, p: np.ndarray) -> str | None:
    """The message of a likely time unit other than seconds, or None.

    Seconds are implausible where poses lie hours apart (a median step above 1e4) or where,
    at least 2 apart, the motion is almost still (below ``_STILL`` m/s and rad/s) while read
    in a finer unit it is plausible; the unit named is the first of nanoseconds,
    microseconds, milliseconds whose median step lies in [0.2 ms, 5 s] with motion below
    ``_FASTEST``."""
    if len(t) < 3:
        return None
    step = float(np.median(np.diff(t)))
    dots = np.clip(np.abs(np.sum(q[1:] * q[:-1], axis=1)), 0.0, 1.0)
    dt = np.maximum(np.diff(t), 1e-300)
    speed = float(np.median(np.linalg.norm(np.diff(p, axis=0), axis=1) / dt))
    turn = float(np.median(2.0 * np.arccos(dots) / dt))
    if not (step > 1e4 or (step >= 2.0 and speed < _STILL and turn < _STILL)):
        return None
    for name, scale in _TIME_UNITS:
        if 2e-4 <= step * scale <= 5.0 and max(speed, turn) / scale < _FASTEST and (
                step > 1e4 or max(speed, turn) / scale >= _STILL):
            return (f"the timestamps look like {name}, not seconds: read as seconds, poses "
                    f"lie {step:.3g} s apart (median) and move at {speed:.3g} m/s, "
                    f"{turn:.3g} rad/s; as {name}, every {step * scale:.3g} s at "
                    f"{speed / scale:.3g} m/s, {turn / scale:.3g} rad/s: divide the times by "
                    f"{1 / scale:.0e}")
    return None


def _warn_time_unit(fn: str, path, t: np.ndarray, q: np.ndarray, p: np.ndarray) -> None:
    """Warn when the times look like another unit than seconds (:func:`_time_unit_guess`)."""
    guess = _time_unit_guess(t, q, p)
    if guess:
        warnings.warn(f"{fn}: {os.fspath(path)}: {guess}", UserWarning, stacklevel=3)


def _warn_imu_time_unit(fn: str, path, t: np.ndarray) -> None:
    """Warn when IMU times read as seconds are 0.5 s or more apart (median; IMUs sample at
    20 Hz to a few kHz) and another unit gives such a rate (relative nanoseconds, shorter
    than the 16 digits that ``time_unit="auto"`` takes for nanoseconds, or milliseconds)."""
    step = float(np.median(np.diff(t))) if len(t) > 2 else 0.0
    if step < 0.5:
        return
    for name, scale in _TIME_UNITS:
        if 2e-4 <= step * scale <= 0.05:
            warnings.warn(f"{fn}: {os.fspath(path)}: the times look like {name}, not "
                          f"seconds: read as seconds the samples lie {step:.3g} s apart "
                          f"(median), {1 / (step * scale):.4g} Hz as {name}; pass "
                          f"time_unit='ns' for nanoseconds or divide the times by "
                          f"{1 / scale:.0e}", UserWarning, stacklevel=3)
            return


# ----------------------------------------------------------------------------- IMU

_IMU_COLUMNS = ("t", "gx", "gy", "gz", "ax", "ay", "az")
_EUROC_IMU_COLUMNS = ("#timestamp [ns]", "w_RS_S_x [rad s^-1]", "w_RS_S_y [rad s^-1]",
                      "w_RS_S_z [rad s^-1]", "a_RS_S_x [m s^-2]", "a_RS_S_y [m s^-2]",
                      "a_RS_S_z [m s^-2]")


def _imu_unit(header: list[str], first: str, time_unit: str) -> str:
    """``"ns"`` or ``"s"``: as given, else from a ``[ns]`` header or a 16+ digit integer."""
    if time_unit != "auto":
        return time_unit
    if header and "[ns]" in header[-1]:
        return "ns"
    return "ns" if _INTEGER.fullmatch(first) and len(first.lstrip("-")) >= 16 else "s"


def read_imu(path: str | os.PathLike[str], *, time_unit: str = "auto",
             duplicates: str = "error") -> tuple[Tensor, Tensor, Tensor]:
    r"""Read IMU samples: EuRoC ``imu0/data.csv`` or plain ``t gx gy gz ax ay az`` files.

    ============  ====================================================================
    EuRoC         ``#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y,w_RS_S_z,a_RS_S_x
                  [m s^-2],a_RS_S_y,a_RS_S_z``: integer nanoseconds, comma-separated
    plain         ``t gx gy gz ax ay az``: seconds, whitespace or commas, ``#`` comments
    ============  ====================================================================

    The gyroscope reads angular velocity (rad/s) and the accelerometer specific force
    (m/s²), both in the IMU's axes, as :class:`torch_dq.fitting.Gyro` and
    :class:`torch_dq.fitting.Accel` take them.

    Args:
        path: the file (``str`` or ``os.PathLike``).
        time_unit: ``"s"``, ``"ns"`` or ``"auto"`` (default): nanoseconds when the header
            says ``[ns]`` (EuRoC) or the first time is an integer of 16 digits or more
            (UNIX nanoseconds), else seconds.
        duplicates: ``"error"`` (default) or ``"first"`` (keep the first sample of a
            repeated time).

    Returns:
        ``(times, gyro, accel)``: float64 CPU tensors ``(N,)`` (seconds; nanoseconds
        converted with correct rounding), ``(N, 3)`` and ``(N, 3)``.

    Raises:
        TrajectoryFileError: (a ``ValueError``) naming the file and the line: not 7
            columns, a value that is not a finite number, unsorted or repeated times, an
            empty file.
        ValueError: bad ``time_unit`` or ``duplicates``.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: times read as seconds (``time_unit="auto"``) whose median step is
            0.5 s or more while nanoseconds, microseconds or milliseconds give an IMU's rate
            (20 Hz to 5 kHz).

    Example:
        >>> times, gyro, accel = read_imu("mav0/imu0/data.csv")  # doctest: +SKIP
        >>> gyro.shape, times.dtype  # doctest: +SKIP
        (torch.Size([36820, 3]), torch.float64)
    """
    fn = "io.read_imu"
    if not isinstance(path, (str, os.PathLike)):
        _checks.fail(fn, f"expected a path (str or os.PathLike) for path, got "
                         f"{type(path).__name__}", TypeError)
    if time_unit not in ("auto", "s", "ns"):
        _checks.fail(fn, f"time_unit must be 'auto', 's' or 'ns', got {time_unit!r}")
    if duplicates not in ("error", "first"):
        _checks.fail(fn, f"duplicates must be 'error' or 'first', got {duplicates!r}")
    lines, texts, header = _read_lines(path)
    if texts[0][:1].isalpha():  # a header row written without the leading "#"
        header, lines, texts = [texts[0]], lines[1:], texts[1:]
        if not texts:
            raise TrajectoryFileError(path, None, "no data (the file holds only a header)")
    rows = _split(texts, commas=False)
    unit = _imu_unit(header, rows[0][0], time_unit)
    names = _EUROC_IMU_COLUMNS if unit == "ns" else _IMU_COLUMNS
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != 7:
            raise TrajectoryFileError(path, n, f"expected 7 columns ({', '.join(names)}), got "
                                               f"{len(fields)}")
    v = _floats(path, lines, [f[1:] for f in rows], names[1:])
    if unit == "ns":
        stated = bool(header) and "[ns]" in header[-1]
        ns = _nanoseconds(path, lines, [f[0] for f in rows], fractions=stated)
        keep = _check_times(path, lines, np.array(ns, dtype=object), duplicates, unit="ns")
        t = np.array([float(Fraction(ns[i]) / 10**9) for i in keep], dtype=np.float64)
    else:
        t = _floats(path, lines, [f[:1] for f in rows], names[:1])[:, 0]
        keep = _check_times(path, lines, t, duplicates)
        t = t[keep]
        if time_unit == "auto":
            _warn_imu_time_unit(fn, path, t)
    as_tensor = lambda a: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))  # noqa: E731
    return as_tensor(t), as_tensor(v[keep, :3]), as_tensor(v[keep, 3:])


# ----------------------------------------------------------------------------- writing

def _numpy(fn: str, name: str, x, last: int | None) -> np.ndarray:
    _checks.tensor(fn, name, x, last)
    return x.detach().to("cpu", torch.float64).numpy()


def _trajectory_arrays(fn: str, trajectory) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(trajectory, Trajectory):
        _checks.fail(fn, f"expected a Trajectory for trajectory, got "
                         f"{type(trajectory).__name__}", TypeError)
    t = _numpy(fn, "trajectory.times", trajectory.times, None)
    q = _numpy(fn, "trajectory.rotations", trajectory.rotations, 4)
    p = _numpy(fn, "trajectory.translations", trajectory.translations, 3)
    if t.ndim != 1 or q.shape != (t.shape[0], 4) or p.shape != (t.shape[0], 3):
        _checks.fail(fn, f"expected times (N,), rotations (N, 4) and translations (N, 3), "
                         f"got {_checks.shape_str(t.shape)}, {_checks.shape_str(q.shape)} "
                         f"and {_checks.shape_str(p.shape)}")
    return t, q, p


def write_trajectory(path: str | os.PathLike[str], trajectory: Trajectory, format: str = "tum",
                     times_path: str | os.PathLike[str] | None = None) -> None:
    r"""Write a trajectory as a TUM, KITTI or EuRoC file (read back by :func:`read_trajectory`).

    Every number is written as the shortest decimal that reads back as the same float64
    (Python's ``repr``), times included, whatever their scale (UNIX seconds or
    ``linspace(0, 1, 7)``): reading the file back returns the same values bit for bit.
    EuRoC times are integer nanoseconds where those read back exactly (always at UNIX
    scale), else decimal nanoseconds (``166666666.66666666``), which :func:`read_trajectory`
    reads under the ``#timestamp [ns]`` header this function writes.

    Args:
        path: the file to (over)write.
        trajectory: a :class:`Trajectory`.
        format: ``"tum"`` (default; ``t x y z qx qy qz qw``), ``"kitti"`` (3x4 matrix rows;
            the times go to ``times_path``) or ``"euroc"`` (the 8 pose columns, integer
            nanoseconds).
        times_path: KITTI only (required there): the times file to write.

    Example:
        >>> write_trajectory("/tmp/traj.txt", traj)  # doctest: +SKIP
    """
    fn = "io.write_trajectory"
    if format not in FORMATS:
        _checks.fail(fn, f"format must be one of 'tum', 'kitti', 'euroc', got {format!r}")
    if (format == "kitti") != (times_path is not None):
        _checks.fail(fn, "times_path is required for format='kitti' and only there")
    t, q, p = _trajectory_arrays(fn, trajectory)
    if format == "tum":
        _write_rows(path, np.column_stack((t, p, q[:, 1:], q[:, :1])),
                    "# " + " ".join(_TUM_COLUMNS))
    elif format == "kitti":
        R = quat.to_matrix(torch.from_numpy(q)).numpy()
        _write_rows(path, np.concatenate((R, p[:, :, None]), axis=2).reshape(-1, 12))
        assert times_path is not None  # required for kitti, checked above
        _write_rows(times_path, t[:, None])
    else:
        with open(path, "w", encoding="utf-8") as f:
            f.write(",".join(_EUROC_COLUMNS) + "\n")
            for ti, pi, qi in zip(t, p, q, strict=True):
                f.write(",".join([_ns_text(float(ti))] + [repr(float(v)) for v in (*pi, *qi)])
                        + "\n")


def _write_rows(path, values: np.ndarray, header: str | None = None) -> None:
    """Rows of numbers, each the shortest text that reads back as the same float64."""
    with open(path, "w", encoding="utf-8") as f:
        if header is not None:
            f.write(header + "\n")
        f.writelines(" ".join(map(repr, row)) + "\n" for row in values.tolist())


def _ns_text(t: float) -> str:
    """``t`` seconds as nanoseconds that read back as ``t``: the nearest integer where that
    suffices (always at UNIX scale, where float64 steps are ~240 ns), else the shortest
    decimal fraction of a nanosecond."""
    exact = Fraction(t) * 10**9
    ns = round(exact)
    if float(Fraction(ns, 10**9)) == t:
        return str(ns)
    for digits in range(1, 40):
        scaled = abs(round(exact * 10**digits))
        text = f"{'-' * (exact < 0)}{scaled // 10**digits}.{scaled % 10**digits:0{digits}d}"
        if float(Fraction(text) / 10**9) == t:
            return text
    raise AssertionError(f"no decimal text for {t!r}")  # pragma: no cover (17 digits do)


def _extra_columns(fn: str, extra, n: int, taken: Sequence[str]
                   ) -> tuple[list[str], list[np.ndarray], list[str], list[str]]:
    """Names, ``(N, 1)`` float64 values, formats and unit notes of ``extra_columns``."""
    if not hasattr(extra, "items"):
        _checks.fail(fn, f"extra_columns must be a mapping name -> (values, note), got "
                         f"{type(extra).__name__}", TypeError)
    names, values, fmts, notes = [], [], [], []
    for name, item in extra.items():
        if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name) \
                or name in taken or name in names:
            _checks.fail(fn, f"extra_columns: a column name must be a new identifier (not one "
                             f"of {', '.join(taken)}), got {name!r}")
        if not isinstance(item, tuple) or len(item) != 2 or not isinstance(item[1], str):
            _checks.fail(fn, f"extra_columns[{name!r}] must be a pair (values, note: str), "
                             f"got {item!r}", TypeError)
        x, note = item
        if not isinstance(x, (Tensor, np.ndarray)):
            _checks.fail(fn, f"extra_columns[{name!r}] values must be a tensor or a numpy "
                             f"array, got {type(x).__name__}", TypeError)
        a = x.detach().cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
        if a.dtype.kind not in "biuf":
            _checks.fail(fn, f"extra_columns[{name!r}] values must be bool, integer or "
                             f"floating, got dtype {a.dtype}", TypeError)
        if a.shape != (n,):
            _checks.fail(fn, f"expected ({n},) values for extra_columns[{name!r}], got "
                             f"{_checks.shape_str(a.shape)}")
        names.append(name)
        values.append(a.astype(np.float64)[:, None])
        fmts.append("%.15g" if a.dtype.kind == "f" else "%d")
        notes.append(note)
    return names, values, fmts, notes


def write_csv(path: str | os.PathLike[str], trajectory: Trajectory, kinematics: object = None,
              comments: Sequence[str] = (), *, extra_columns=None,
              comments_first: bool = False) -> None:
    r"""Write a (resampled) trajectory with its velocities and accelerations as CSV.

    The columns are :data:`CSV_COLUMNS`: ``t, x, y, z, qw, qx, qy, qz, vx, vy, vz, wx, wy,
    wz, ax, ay, az, alpha_x, alpha_y, alpha_z`` (SI units: s, m, unit quaternion, m/s,
    rad/s, m/s², rad/s²; all vectors in the world frame: ``v = dp/dt``, ``w`` with
    ``dR/dt = [w]x R``, ``a = d²p/dt²``, ``alpha = dw/dt``), then the ``extra_columns``.
    The ``#`` comment block holds the units line (each extra column's note appended to it)
    and then ``comments``. By default the file opens with the header row, then the comment
    block, then one row per time: readable with ``numpy.genfromtxt(path, delimiter=",",
    names=True)``, ``numpy.loadtxt(path, delimiter=",", skiprows=1)`` or
    ``pandas.read_csv(path, comment="#")``. With ``comments_first=True`` the comment block
    comes first, opened by a line that counts the comment lines ``c`` and says how to read
    the file (``pandas.read_csv(path, comment='#')`` or ``numpy.genfromtxt(path,
    delimiter=',', names=True, skip_header=c)``), then the header row and the rows.

    Times are written with 9 decimals (nanoseconds, UNIX seconds included), other floats
    with 15 significant digits, bool and integer extra columns as integers.

    Args:
        path: the file to (over)write.
        trajectory: a :class:`Trajectory` (times in seconds, positions in metres).
        kinematics: world-frame kinematics at ``trajectory.times``: anything with
            ``(N, 3)`` attributes ``linear_velocity``, ``angular_velocity``,
            ``linear_acceleration``, ``angular_acceleration`` (e.g. what
            :func:`torch_dq.curves.kinematics` returns); ``None`` writes the pose columns
            only.
        comments: extra lines for the comment block (e.g. the source file).
        extra_columns: a mapping ``name -> (values, note)`` of columns written after the
            others, in its order: ``values`` an ``(N,)`` tensor or numpy array (bool,
            integer or floating), ``note`` the column's meaning and unit, appended to the
            units line as ``"; " + note``. Names are identifiers not in
            :data:`CSV_COLUMNS`.
        comments_first: put the comment block (and the line counting it) before the header
            row.

    Raises:
        ValueError: shapes that do not match ``N`` times, kinematics without accelerations,
            a bad or repeated extra column name.
        TypeError: a ``trajectory`` that is not a :class:`Trajectory`, non-floating tensors,
            extra columns that are not ``(values, note)`` pairs of numbers.

    Example:
        >>> k = spline.kinematics(traj.times)  # doctest: +SKIP
        >>> write_csv("resampled.csv", traj, k)  # doctest: +SKIP
        >>> write_csv("resampled.csv", traj, k, ["source: run 3"],  # doctest: +SKIP
        ...           extra_columns={"valid": (mask, "valid 1 where measured, else 0")},
        ...           comments_first=True)
    """
    fn = "io.write_csv"
    t, q, p = _trajectory_arrays(fn, trajectory)
    _checks.flag(fn, "comments_first", comments_first)
    if isinstance(comments, str) or not all(isinstance(c, str) for c in comments):
        _checks.fail(fn, "comments must be a sequence of str (one per line)", TypeError)
    columns = [t[:, None], p, q]
    names = list(CSV_COLUMNS[:8])
    if kinematics is not None:
        for attr in ("linear_velocity", "angular_velocity", "linear_acceleration",
                     "angular_acceleration"):
            value = getattr(kinematics, attr, None)
            if value is None:
                _checks.fail(fn, f"kinematics has no {attr} (pass curves.kinematics(..., "
                                 f"ddx) with accelerations)")
            a = _numpy(fn, f"kinematics.{attr}", value, 3)
            if a.shape != (t.shape[0], 3):
                _checks.fail(fn, f"expected ({t.shape[0]}, 3) for kinematics.{attr}, got "
                                 f"{_checks.shape_str(a.shape)}")
            columns.append(a)
        names = list(CSV_COLUMNS)
    units = ("units (SI, world frame): t [s]; x, y, z [m]; qw, qx, qy, qz unit quaternion "
             "(body to world)")
    if kinematics is not None:
        units += ("; vx, vy, vz [m/s]; wx, wy, wz angular velocity [rad/s]; ax, ay, az "
                  "[m/s^2]; alpha_x, alpha_y, alpha_z angular acceleration [rad/s^2]")
    fmt = ["%.9f"] + ["%.15g"] * (len(names) - 1)
    if extra_columns is not None:
        more, values, fmts, notes = _extra_columns(fn, extra_columns, t.shape[0], CSV_COLUMNS)
        names, columns, fmt = names + more, columns + values, fmt + fmts
        units = "; ".join([units, *notes])
    lines = ["# " + units] + ["# " + c for c in comments]
    if comments_first:
        count = len(lines) + 1
        lines.insert(0, f"# {count} comment lines, then the header row: read with "
                        f"pandas.read_csv(path, comment='#') or numpy.genfromtxt(path, "
                        f"delimiter=',', names=True, skip_header={count})")
        header = "\n".join(lines + [",".join(names)])
    else:
        header = "\n".join([",".join(names)] + lines)
    np.savetxt(path, np.concatenate(columns, axis=1), delimiter=",", header=header,
               comments="", fmt=fmt)

r"""Trajectory files: TUM, KITTI and EuRoC poses read into a :class:`Trajectory` (private;
the public names are :mod:`torch_dq.io`'s).

Each format's rows are parsed by :mod:`._text`; the poses are made here, once for every
format: quaternion columns in the file's order to unit ``(w, x, y, z)`` quaternions
(:func:`_unit_quaternions`; TUM's ``qx qy qz qw`` through
:func:`torch_dq.quat.from_xyzw`), KITTI's ``[R | t]`` rows to quaternions
(:func:`_matrix_rotations`).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import torch
from torch import Tensor

from .. import _checks, dualquat, quat
from ._text import (
    INTEGER,
    NUMBER,
    TrajectoryFileError,
    as_tensor,
    check_times,
    first_bad,
    floats,
    header_row,
    nanoseconds,
    read_lines,
    seconds_from_ns,
    split,
)
from ._units import warn_ns_unit, warn_time_unit

__all__ = ["EUROC_COLUMNS", "FORMATS", "TUM_COLUMNS", "Trajectory", "narrow_hint",
           "read_trajectory"]

#: The file formats :func:`torch_dq.io.read_trajectory` and
#: :func:`torch_dq.io.write_trajectory` know.
FORMATS = ("tum", "kitti", "euroc")

TUM_COLUMNS = ("timestamp", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
_KITTI_COLUMNS = ("r11", "r12", "r13", "tx", "r21", "r22", "r23", "ty", "r31", "r32", "r33",
                  "tz")
EUROC_COLUMNS = ("#timestamp [ns]", "p_RS_R_x [m]", "p_RS_R_y [m]", "p_RS_R_z [m]",
                 "q_RS_w []", "q_RS_x []", "q_RS_y []", "q_RS_z []")


@dataclass(frozen=True, eq=False, repr=False)
class Trajectory:
    r"""Timestamped rigid poses (body to world): ``x -> R(rotations[i]) x + translations[i]``.

    Attributes:
        times: ``(N,)`` float64 strictly increasing times in seconds (as in the file:
            UNIX seconds stay absolute).
        rotations: ``(N, 4)`` float64 unit quaternions ``(w, x, y, z)`` (sign as in the
            file).
        translations: ``(N, 3)`` float64 positions of the body origin in the world frame
            (the file's unit: metres for TUM, KITTI and EuRoC).

    The three are stored attributes; the poses as ``(N, 8)`` unit dual quaternions are
    computed from them by the method :meth:`poses` (``traj.poses()``, with parentheses);
    ``traj.select(index)`` gives a sub-trajectory and ``len(traj)`` its ``N``.
    """

    times: Tensor
    rotations: Tensor
    translations: Tensor

    def __post_init__(self) -> None:
        """Check the fields' types and shapes (their values, as finiteness, order and unit
        norm, are :func:`write_trajectory`'s and the readers' to check)."""
        fn = "io.Trajectory"
        t = _checks.tensor(fn, "times", self.times)
        q = _checks.tensor(fn, "rotations", self.rotations)
        p = _checks.tensor(fn, "translations", self.translations)
        if t.dim() != 1 or q.shape != (t.numel(), 4) or p.shape != (t.numel(), 3):
            _checks.fail(fn, f"expected times (N,), rotations (N, 4) (w, x, y, z) and "
                             f"translations (N, 3), got {_checks.shape_str(t.shape)}, "
                             f"{_checks.shape_str(q.shape)} and {_checks.shape_str(p.shape)}")

    def __repr__(self) -> str:
        n = len(self)
        span = (f", times {float(self.times[0])!r} to {float(self.times[-1])!r}" if n else "")
        return f"Trajectory({n} poses{span}, dtype={self.times.dtype})"

    def __len__(self) -> int:
        return self.times.shape[0]

    def poses(self) -> Tensor:
        """The poses as ``(N, 8)`` unit dual quaternions (:func:`torch_dq.dualquat.from_rt`)."""
        return dualquat.from_rt(self.rotations, self.translations)

    def select(self, index: slice | Tensor) -> Trajectory:
        """The sub-trajectory at ``index`` (a slice, an index tensor or a bool mask).

        Example:
            >>> import torch
            >>> from torch_dq import quat
            >>> t = torch.arange(6.0, dtype=torch.float64)
            >>> traj = Trajectory(t, quat.identity((6,), torch.float64), torch.zeros(6, 3,
            ...                   dtype=torch.float64))
            >>> traj.select(slice(None, None, 2)).times
            tensor([0., 2., 4.], dtype=torch.float64)
        """
        return Trajectory(self.times[index], self.rotations[index], self.translations[index])


def _unit_quaternions(path, lines: list[int], q: np.ndarray, atol: float) -> np.ndarray:
    """Check ``| |q| - 1 | <= atol`` per row and return the normalized quaternions."""
    norm = np.linalg.norm(q, axis=1)
    first_bad(path, lines, ~(np.abs(norm - 1.0) <= atol),
              lambda i: f"quaternion norm {norm[i]:.6g} is not 1 (tolerance atol={atol:g})")
    return q / norm[:, None]


def _matrix_rotations(path, lines: list[int], R: np.ndarray, atol: float) -> np.ndarray:
    """Unit quaternions ``(N, 4)`` of rotation matrices ``(N, 3, 3)``, checked orthonormal
    (``max |R^T R - I| <= atol``) and proper (determinant +1) per row."""
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    first_bad(path, lines, ~(err <= atol),
              lambda i: f"rotation is not orthonormal: max |R^T R - I| = {err[i]:.3g} "
                        f"(tolerance atol={atol:g})")
    first_bad(path, lines, np.linalg.det(R) < 0,
              lambda i: "rotation matrix has determinant -1 (a reflection)")
    return quat.normalize(quat.from_matrix(torch.from_numpy(np.ascontiguousarray(R)))).numpy()


def _quaternion_columns(header: list[str]) -> list[int]:
    """The columns of ``qx, qy, qz, qw`` in a TUM row: ``4, 5, 6, 7``, unless the header's
    last line names 8 columns whose last four are the quaternion's in another order (``qw qx
    qy qz``, ``q_w ...`` or ``w x y z``; spaces or commas), which is then followed."""
    names = header[-1].lower().replace(",", " ").split() if header else []
    tail = [n.removeprefix("q").strip("_") for n in names[4:]] if len(names) == 8 else []
    if sorted(tail) != ["w", "x", "y", "z"]:
        return [4, 5, 6, 7]
    return [4 + tail.index(c) for c in "xyzw"]


def _read_tum(path, lines, texts, header, atol: float, duplicates: str):
    v = floats(path, lines, split(texts, commas=False), TUM_COLUMNS)
    keep = check_times(path, lines, v[:, 0], duplicates)
    xyzw = v[:, _quaternion_columns(header)]
    q = _unit_quaternions(path, lines, quat.from_xyzw(torch.from_numpy(xyzw)).numpy(), atol)
    return v[keep, 0], q[keep], v[keep, 1:4]


def _read_euroc(path, lines, texts, header, atol: float, duplicates: str):
    lines, texts, header = header_row(path, lines, texts, header)
    rows = split(texts, commas=True)
    # The column count: the header's when it names 8 or more, else the first row's (>= 8).
    names = [s.strip() for s in header[-1].split(",")] if header else []
    if len(names) >= 8:
        names[0] = "#" + names[0]
    else:
        names = list(EUROC_COLUMNS) + [f"column {k + 1}" for k in range(8, len(rows[0]))]
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != len(names):
            raise TrajectoryFileError(path, n, f"expected {len(names)} comma-separated columns "
                                               f"({', '.join(names[:8])}"
                                               f"{', ...' * (len(names) > 8)}), got "
                                               f"{len(fields)}")
    stated = bool(header) and "[ns]" in header[-1]  # the file's own header says nanoseconds
    ns = nanoseconds(path, lines, [f[0] for f in rows], fractions=stated)
    v = floats(path, lines, [f[1:8] for f in rows], names[1:8])
    keep = check_times(path, lines, np.array(ns, dtype=object), duplicates, unit="ns")
    q = _unit_quaternions(path, lines, v[:, 3:7], atol)
    return seconds_from_ns(ns, keep), q[keep], v[keep, 0:3]


def narrow_hint(times) -> str:
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
        lines, texts, _ = read_lines(times)
        t = floats(times, lines, split(texts, commas=False), ("time",))[:, 0]
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
    hint = narrow_hint(times.detach().cpu() if isinstance(times, Tensor) else times)
    return t, "times", list(range(1, n_poses + 1)), hint


def _read_kitti(fn: str, path, lines, texts, times, atol: float, duplicates: str):
    v = floats(path, lines, split(texts, commas=False), _KITTI_COLUMNS)
    t, t_path, t_lines, hint = _kitti_times(fn, path, times, v.shape[0])
    keep = check_times(t_path, t_lines, t, duplicates, hint=hint)
    q = _matrix_rotations(path, lines, v.reshape(-1, 3, 4)[:, :, :3], atol)
    return t[keep], q[keep], v[keep][:, [3, 7, 11]]


_CORNER_NAMES = {"tag_id", "corner_idx", "u_px", "v_px"}


def _not_poses(path, names: list[str], text: str) -> None:
    """A header naming the columns of a corners file (``tag_id``, ``u_px``, ...) or of
    EuRoC's IMU file (``w_RS_S_x [rad s^-1]``, ...) is an error naming the right reader:
    read as poses, such rows raised errors that pointed elsewhere (repeated timestamps, a
    quaternion's norm)."""
    if _CORNER_NAMES & set(names):
        raise TrajectoryFileError(path, None, "holds target corners (its header: "
                                              f"{text!r}), not poses: read it with "
                                              "torch_dq.calibration.read_corners (python -m "
                                              "torch_dq calibrate --corners)")
    if any(n.startswith(("w_rs_s", "a_rs_s")) for n in names):
        raise TrajectoryFileError(path, None, "holds IMU readings (its header: "
                                              f"{text!r}), not poses: read it with "
                                              "torch_dq.io.read_imu (python -m torch_dq fit "
                                              "POSES_FILE --imu IMU_FILE)")


def _detect(path, lines: list[int], texts: list[str], header: list[str]) -> str:
    """Guess the format from the header comment and the first data line.

    A header naming TUM's columns (``timestamp tx ty tz qx qy qz qw``, spaces or commas)
    means TUM; one naming a corners file's or EuRoC's IMU columns is an error
    (``_not_poses``). Commas (in the first row or a ``timestamp,...`` header) mean EuRoC,
    unless the row has TUM's 8 fields with a time in decimal seconds and no ``[ns]`` header.
    """
    names = header[-1].lower().replace(",", " ").split() if header else []
    if tuple(names[:8]) == TUM_COLUMNS:
        return "tum"
    _not_poses(path, names, header[-1] if header else "")
    if "," in texts[0] or any(h.lower().startswith("timestamp") and "," in h for h in header):
        first = [f.strip() for f in texts[0].split(",")]
        seconds = len(first) == 8 and not INTEGER.fullmatch(first[0]) \
            and NUMBER.fullmatch(first[0]) is not None
        return "tum" if seconds and "[ns]" not in names else "euroc"
    width = len(texts[0].split())
    if width in (8, 12):
        return "tum" if width == 8 else "kitti"
    imu = (" (7 columns are an IMU file's, t gx gy gz ax ay az: read it with "
           "torch_dq.io.read_imu; fit: POSES_FILE --imu IMU_FILE)") * (width == 7)
    raise TrajectoryFileError(path, lines[0], f"cannot tell the format: {width} "
                                              f"whitespace-separated columns, where TUM has 8 "
                                              f"and KITTI 12 (EuRoC is comma-separated); pass "
                                              f"format= (fit: --format){imu}")


def read_trajectory(path: str | os.PathLike[str], format: str = "auto",
                    times: str | os.PathLike[str] | Tensor | npt.ArrayLike | None = None, *,
                    atol: float = 1e-3, duplicates: str = "error",
                    times_path: str | os.PathLike[str] | None = None) -> Trajectory:
    r"""Read timestamped poses from a TUM, KITTI or EuRoC file.

    Args:
        path: the file (``str`` or ``os.PathLike``).
        format: ``"tum"``, ``"kitti"``, ``"euroc"`` or ``"auto"`` (default): a header naming
            TUM's columns (``# timestamp tx ty tz qx qy qz qw``, with spaces or commas) means
            TUM; comma-separated rows or a ``#timestamp,...`` header mean EuRoC, except 8
            fields with a decimal time and no ``[ns]`` header (TUM with commas); else 8
            whitespace-separated columns mean TUM and 12 KITTI. The header may also be a
            first row without ``#``. A TUM header that names the quaternion columns in
            another order (``# timestamp tx ty tz qw qx qy qz``; ``q_w`` or ``w`` alike) is
            followed.
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
        times_path: the same as ``times`` (a times file), by :func:`write_trajectory`'s
            name for it; give one of the two.

    Returns:
        :class:`Trajectory` of float64 CPU tensors: ``times (N,)`` in seconds (EuRoC's
        nanoseconds converted with correct rounding), ``rotations (N, 4)`` unit ``(w, x, y,
        z)``, ``translations (N, 3)``; ``.poses()`` gives them as ``(N, 8)`` unit dual
        quaternions. TUM and KITTI times are kept as written, in the file's unit, also where
        they look like nanoseconds, microseconds or milliseconds (a warning names the
        division; ``python -m torch_dq fit`` converts such times to seconds itself, with a
        note: the same file gives the API the file's numbers and the command seconds).

    Raises:
        TrajectoryFileError: (a ``ValueError``) malformed file, naming the file and the
            line: wrong column count, a value that is not a finite number (EuRoC: a
            timestamp that is not an integer), unsorted or (with ``duplicates="error"``)
            repeated timestamps, a non-unit quaternion (the message gives its norm), a
            non-orthonormal or reflecting KITTI rotation, a times file of another length,
            an empty file.
        ValueError: bad ``format``/``atol``/``duplicates``, KITTI without ``times``,
            ``times`` given for another format, or both ``times`` and ``times_path``.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: times that look like nanoseconds, microseconds or milliseconds (poses
            hours apart, or nearly still in seconds while plausible in the finer unit; TUM
            and KITTI): they are kept as read, and the warning names the division to do
            (the ``fit`` command does it). Quaternion columns in another order than the
            header names (or than TUM's, without a header) cannot be told from the poses
            alone (a permutation of the components keeps the angle between any two
            rotations);
            ``python -m torch_dq fit --imu`` tells them by the gyroscope.

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
    if times_path is not None:
        if times is not None:
            _checks.fail(fn, "times and times_path name the same argument (the KITTI times "
                             "file): give one")
        times = times_path
    lines, texts, header = header_row(path, *read_lines(path))
    if format == "auto":
        format = _detect(path, lines, texts, header)
    if times is not None and format != "kitti":
        _checks.fail(fn, f"times= applies to KITTI files only ({format.upper()} files hold "
                         f"their own times)")
    if format == "tum":
        t, q, p = _read_tum(path, lines, texts, header, atol, duplicates)
    elif format == "euroc":
        t, q, p = _read_euroc(path, lines, texts, header, atol, duplicates)
    else:
        t, q, p = _read_kitti(fn, path, lines, texts, times, atol, duplicates)
    if format != "euroc":  # EuRoC states nanoseconds
        warn_time_unit(fn, path, t, q, p)
    else:
        warn_ns_unit(fn, path, t, longest=5.0, fix="write the times as integer nanoseconds, "
                                                    "as EuRoC's header says")
    return Trajectory(as_tensor(t), as_tensor(q), as_tensor(p))


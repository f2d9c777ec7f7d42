r"""Writing trajectories: TUM, KITTI and EuRoC files read back bit for bit, and the resampled
CSV with velocities and accelerations (private; the public names are
:mod:`torch_dq.io`'s)."""

from __future__ import annotations

import io
import os
import re
from collections.abc import Sequence
from fractions import Fraction

import numpy as np
import torch
from torch import Tensor

from .. import _checks, quat
from ._trajectory import EUROC_COLUMNS, FORMATS, TUM_COLUMNS, Trajectory, narrow_hint

__all__ = ["CSV_COLUMNS", "write_csv", "write_trajectory"]

#: Columns of :func:`torch_dq.io.write_csv`, in order (SI units; world frame).
CSV_COLUMNS = ("t", "x", "y", "z", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz",
               "ax", "ay", "az", "alpha_x", "alpha_y", "alpha_z")


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
    bad = ~np.isfinite(t)
    if bad.any():
        _checks.fail(fn, f"trajectory.times[{int(np.flatnonzero(bad)[0])}] is "
                         f"{float(t[bad][0])}: "
                         f"times must be finite")
    steps = np.flatnonzero(~(np.diff(t) > 0))
    if steps.size:
        i = int(steps[0])
        _checks.fail(fn, f"trajectory.times must increase strictly: times[{i + 1}] = "
                         f"{float(t[i + 1])!r} follows times[{i}] = {float(t[i])!r} "
                         f"({steps.size} of the {t.size - 1} steps do not increase)"
                         f"{narrow_hint(trajectory.times.detach().cpu())}")
    return t, q, p


def _check_poses(fn: str, q: np.ndarray, p: np.ndarray) -> None:
    """Finite translations and unit quaternions (``| |q| - 1 | <= 1e-3``, what
    :func:`~torch_dq.io.read_trajectory` accepts by default), else a ``ValueError``."""
    norm = np.linalg.norm(q, axis=1)
    rows = np.flatnonzero(~(np.isfinite(p).all(axis=1) & (np.abs(norm - 1.0) <= 1e-3)))
    if rows.size:
        i = int(rows[0])
        _checks.fail(fn, f"pose {i} (of {rows.size} bad) has translation {p[i].tolist()} and "
                         f"a quaternion of norm {norm[i]:.6g}: translations must be finite "
                         f"and rotations unit quaternions (within 1e-3)")


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
        times_path: KITTI only (required there): the times file to write (another file
            than ``path``).

    Raises:
        ValueError: what :func:`read_trajectory` would reject: times that are not finite or
            not strictly increasing (float32 UNIX seconds, rounded to 128 s steps, say so),
            non-finite translations, rotations whose norm is not 1 within 1e-3; a bad
            ``format``, ``times_path`` missing for KITTI, given for another format or equal
            to ``path``. Nothing is written then.
        TypeError: ``trajectory`` is not a :class:`Trajectory`.

    Example:
        >>> write_trajectory("/tmp/traj.txt", traj)  # doctest: +SKIP
    """
    fn = "io.write_trajectory"
    if format not in FORMATS:
        _checks.fail(fn, f"format must be one of 'tum', 'kitti', 'euroc', got {format!r}")
    if (format == "kitti") != (times_path is not None):
        _checks.fail(fn, "times_path is required for format='kitti' and only there")
    t, q, p = _trajectory_arrays(fn, trajectory)
    _check_poses(fn, q, p)
    if times_path is not None and os.path.abspath(times_path) == os.path.abspath(path):
        _checks.fail(fn, f"times_path and path are the same file ({os.fspath(path)}): the "
                         f"times would overwrite the poses")
    if format == "tum":
        _write_rows(path, np.column_stack((t, p, quat.to_xyzw(torch.from_numpy(q)).numpy())),
                    "# " + " ".join(TUM_COLUMNS))
    elif format == "kitti":
        R = quat.to_matrix(torch.from_numpy(q)).numpy()
        _write_rows(path, np.concatenate((R, p[:, :, None]), axis=2).reshape(-1, 12))
        assert times_path is not None  # required for kitti, checked above
        _write_rows(times_path, t[:, None])
    else:
        with open(path, "w", encoding="utf-8") as f:
            f.write(",".join(EUROC_COLUMNS) + "\n")
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

    The columns are :data:`~torch_dq.io.CSV_COLUMNS`: ``t, x, y, z, qw, qx, qy, qz, vx, vy,
    vz, wx, wy, wz, ax, ay, az, alpha_x, alpha_y, alpha_z`` (SI units: s, m, unit quaternion, m/s,
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

    Times are written as the shortest decimal that reads back as the same float64 (Python's
    ``repr``, as :func:`write_trajectory`): a time read from a file as ``1305031098.6659``
    is written ``1305031098.6659``, so a join on the time column with the input works where
    the times agree. Other floats with 15 significant digits, bool and integer extra columns
    as integers.

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
            :data:`~torch_dq.io.CSV_COLUMNS`.
        comments_first: put the comment block (and the line counting it) before the header
            row.

    Raises:
        ValueError: shapes that do not match ``N`` times, times that are not finite or not
            strictly increasing, kinematics without accelerations, a bad or repeated extra
            column name.
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
    fmt = ["%.15g"] * (len(names) - 1)
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
        header = "\n".join([*lines, ",".join(names)])
    else:
        header = "\n".join([",".join(names), *lines])
    _write_table(path, header, t, np.concatenate(columns[1:], axis=1), fmt)


_ROWS_PER_CHUNK = 10_000


def _write_table(path, header: str, t: np.ndarray, values: np.ndarray, fmt: list[str]) -> None:
    """``header``, then one row per time: the time's shortest round-trip decimal
    (``repr``), then ``values`` formatted by ``fmt`` (``numpy.savetxt``), comma-separated."""
    with open(path, "w", encoding="utf-8") as f:
        f.write(header + "\n")
        for start in range(0, t.shape[0], _ROWS_PER_CHUNK):
            chunk = slice(start, start + _ROWS_PER_CHUNK)
            rows = io.StringIO()
            np.savetxt(rows, values[chunk], delimiter=",", fmt=fmt)
            f.writelines(f"{ti!r},{row}\n" for ti, row in
                         zip(t[chunk].tolist(), rows.getvalue().splitlines(), strict=True))

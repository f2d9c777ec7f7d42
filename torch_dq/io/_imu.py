r"""IMU files: gyroscope and accelerometer samples (private; :func:`torch_dq.io.read_imu`)."""

from __future__ import annotations

import os
import re

import numpy as np
from torch import Tensor

from .. import _checks
from ._text import (
    INTEGER,
    TrajectoryFileError,
    as_tensor,
    check_times,
    floats,
    header_row,
    nanoseconds,
    read_lines,
    seconds_from_ns,
    split,
)
from ._units import warn_imu_time_unit, warn_imu_units, warn_ns_unit

__all__ = ["read_imu"]

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
    return "ns" if INTEGER.fullmatch(first) and len(first.lstrip("-")) >= 16 else "s"


# units a header may state that read_imu does not return: degrees (per second), g
_FOREIGN_UNITS = ((re.compile(r"\[\s*deg|\bdeg\s*/\s*s\b|\bdps\b", re.IGNORECASE),
                   "the gyroscope in degrees per second", "rad/s: multiply those columns "
                   "by pi / 180"),
                  (re.compile(r"\[\s*g\s*\]"), "the accelerometer in g",
                   "m/s^2: multiply those columns by 9.80665"))


def _check_header_units(path, header: list[str]) -> None:
    """A :class:`TrajectoryFileError` where the header states a unit other than rad/s or
    m/s^2 (``w_x [deg s^-1]``, ``gx [deg/s]``, ``ax [g]``): read as they are, the readings
    would be 57 (or 9.8) times off."""
    for pattern, what, fix in _FOREIGN_UNITS:
        if header and pattern.search(header[-1]):
            raise TrajectoryFileError(path, None, f"the header gives {what} "
                                                  f"({header[-1].strip()!r}); read_imu "
                                                  f"returns {fix}")


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
            empty file; naming the file: a header that states the gyroscope in degrees
            (``[deg s^-1]``, ``deg/s``) or the accelerometer in ``[g]``.
        ValueError: bad ``time_unit`` or ``duplicates``.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: times read as seconds (``time_unit="auto"``) whose median step is
            0.5 s or more while nanoseconds, microseconds or milliseconds give an IMU's rate
            (20 Hz to 5 kHz); times read as nanoseconds less than 10 us apart while
            seconds (or ms, us) give such a rate (decimal seconds under a ``[ns]``
            header); accelerometer readings in g (their mean about 1 long, not gravity's
            9.81 m/s²) or in milli-g (about 1000 long); gyroscope readings averaging
            gravity's magnitude while the accelerometer's are small (the two sets of
            columns swapped); gyroscope readings 57 times what the accelerometer's
            turning says (deg/s, not rad/s).

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
    lines, texts, header = header_row(path, *read_lines(path))
    _check_header_units(path, header)
    rows = split(texts, commas=False)
    unit = _imu_unit(header, rows[0][0], time_unit)
    names = _EUROC_IMU_COLUMNS if unit == "ns" else _IMU_COLUMNS
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != 7:
            raise TrajectoryFileError(path, n, f"expected 7 columns ({', '.join(names)}), got "
                                               f"{len(fields)}")
    v = floats(path, lines, [f[1:] for f in rows], names[1:])
    if unit == "ns":
        stated = bool(header) and "[ns]" in header[-1]
        ns = nanoseconds(path, lines, [f[0] for f in rows], fractions=stated)
        keep = check_times(path, lines, np.array(ns, dtype=object), duplicates, unit="ns")
        t = seconds_from_ns(ns, keep)
        warn_ns_unit(fn, path, t)
    else:
        t = floats(path, lines, [f[:1] for f in rows], names[:1])[:, 0]
        keep = check_times(path, lines, t, duplicates)
        t = t[keep]
        if time_unit == "auto":
            warn_imu_time_unit(fn, path, t)
    warn_imu_units(fn, path, t, v[keep, :3], v[keep, 3:])
    return as_tensor(t), as_tensor(v[keep, :3]), as_tensor(v[keep, 3:])


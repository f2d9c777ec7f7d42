r"""The ``fit`` command's input (private): the trajectory file read
(:func:`torch_dq.io.read_trajectory`) with its times in seconds, converted from the finer
unit they are in where the reader finds them implausible as seconds."""

from __future__ import annotations

import time
import warnings

import numpy as np

from .. import _checks, io
from .._report import say_warnings
from ..io import _units
from ._errors import OptionError

__all__ = ["in_seconds", "read_seconds"]


def read_seconds(path: str, format: str, times, duplicates: str
                 ) -> tuple[io.Trajectory, list[str], float, str | None]:
    """The file's poses (at least 2) in seconds (:func:`in_seconds`), the warnings on units
    the data contradict (printed once), the seconds it took and the unit converted from
    (``None``: seconds as read)."""
    begin = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        traj = io.read_trajectory(path, format=format, times=times, duplicates=duplicates)
    traj, unit, guess = in_seconds(traj)
    if unit:  # the reader's warning is answered by the conversion, which is printed
        caught = [w for w in caught if guess not in str(w.message)]
    read_warnings = say_warnings("torch-dq fit", caught)
    read_s = time.perf_counter() - begin
    if len(traj) < 2:
        raise OptionError(f"fit: {path} holds {len(traj)} pose; a fit needs at least 2")
    return traj, read_warnings, read_s, unit


def in_seconds(traj: io.Trajectory) -> tuple[io.Trajectory, str | None, str]:
    """The poses with their times in seconds, the unit they were converted from and the
    reader's guess (:func:`torch_dq.io.read_trajectory`'s warning that the times look like
    nanoseconds, microseconds or milliseconds: integer UNIX nanoseconds in a TUM file).

    The times are divided by the first finer unit in which the reader finds them plausible
    seconds: every output (``trajectory.csv``'s times, velocities and accelerations, the
    knot spacing, ``--rate``) is then in seconds, as the command states. Times it finds
    implausible in every unit are kept, with the reader's warning."""
    t = traj.times.numpy()
    q, p = traj.rotations.numpy(), traj.translations.numpy()
    guess = _units._time_unit_guess(t, q, p)
    if guess is None:
        return traj, None, ""
    step = float(np.median(np.diff(t)))
    for name, scale in _checks.TIME_UNITS:
        if 2e-4 <= step * scale <= 5.0 and _units._time_unit_guess(t * scale, q, p) is None:
            seconds = io.Trajectory(traj.times * scale, traj.rotations, traj.translations)
            return seconds, name, guess
    return traj, None, guess

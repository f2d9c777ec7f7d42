r"""Times written in another unit than seconds: the readers' warnings (private).

A trajectory's times are implausible as seconds where poses lie hours apart or barely move
while a finer unit (nanoseconds, microseconds, milliseconds) gives plausible motion
(:func:`warn_time_unit`); an IMU's where its samples lie 0.5 s or more apart while a finer
unit gives an IMU's rate (:func:`warn_imu_time_unit`). An accelerometer's readings average
to gravity's 9.81 m/s² (the specific force of a body that ends near where it started): a
mean near 1 says g, a gyroscope whose mean is gravity's says the columns are swapped
(:func:`warn_imu_units`).
"""

from __future__ import annotations

import os
import warnings

import numpy as np

__all__ = ["warn_imu_time_unit", "warn_imu_units", "warn_time_unit"]

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


def warn_time_unit(fn: str, path, t: np.ndarray, q: np.ndarray, p: np.ndarray) -> None:
    """Warn when the times look like another unit than seconds (:func:`_time_unit_guess`)."""
    guess = _time_unit_guess(t, q, p)
    if guess:
        warnings.warn(f"{fn}: {os.fspath(path)}: {guess}", UserWarning, stacklevel=3)


def warn_imu_time_unit(fn: str, path, t: np.ndarray) -> None:
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



def warn_imu_units(fn: str, path, gyro: np.ndarray, accel: np.ndarray) -> None:
    """Warn when the mean accelerometer reading is about 1 long (and its median magnitude
    too: g, not m/s²), or when the gyroscope's is about gravity's (7 to 14) while the
    accelerometer's readings are small (median magnitude below 5: the columns swapped)."""
    if len(accel) < 3:
        return
    mean_a, mean_g = (float(np.linalg.norm(x.mean(axis=0))) for x in (accel, gyro))
    size_a = float(np.median(np.linalg.norm(accel, axis=1)))
    if 7.0 <= mean_g <= 14.0 and size_a < 5.0:
        what = (f"the gyroscope and accelerometer columns look swapped: the gyroscope "
                f"readings average {mean_g:.3g} long, as gravity's 9.81 m/s^2 does, the "
                f"accelerometer's are {size_a:.3g} (median); the columns are t gx gy gz ax "
                f"ay az")
    elif 0.7 <= mean_a <= 1.4 and 0.7 <= size_a <= 1.4:
        what = (f"the accelerometer readings look like g (standard gravity), not m/s^2: "
                f"they average {mean_a:.3g} long where gravity reads 9.81 m/s^2; multiply "
                f"them by 9.80665")
    else:
        return
    warnings.warn(f"{fn}: {os.fspath(path)}: {what}", UserWarning, stacklevel=3)

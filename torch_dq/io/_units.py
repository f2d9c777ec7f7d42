r"""Times written in another unit than seconds: the readers' warnings (private).

A trajectory's times are implausible as seconds where poses lie hours apart or barely move
while a finer unit (nanoseconds, microseconds, milliseconds) gives plausible motion
(:func:`warn_time_unit`); an IMU's where its samples lie 0.5 s or more apart while a finer
unit gives an IMU's rate (:func:`warn_imu_time_unit`). An accelerometer's readings average
to gravity's 9.81 m/s² (the specific force of a body that ends near where it started): a
mean near 1 says g, a gyroscope whose mean is gravity's says the columns are swapped, and
an accelerometer turning 57 times slower than the gyroscope says deg/s
(:func:`warn_imu_units`).
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from .. import _checks

__all__ = ["gyro_scale", "warn_imu_time_unit", "warn_imu_units", "warn_ns_unit",
           "warn_time_unit"]

#: Motion no recording reaches (m/s, rad/s): times read in the wrong unit reach it or
#: stay below ``_STILL`` where another unit gives plausible motion.
_FASTEST = 50.0
_STILL = 0.02


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
    for name, scale in _checks.TIME_UNITS:
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
    for name, scale in _checks.TIME_UNITS:
        if 2e-4 <= step * scale <= 0.05:  # time_unit='ns' for nanoseconds only (not ms)
            fix = "pass time_unit='ns' or " if name == "nanoseconds" else ""
            warnings.warn(f"{fn}: {os.fspath(path)}: the times look like {name}, not "
                          f"seconds: read as seconds the samples lie {step:.3g} s apart "
                          f"(median), {1 / (step * scale):.4g} Hz as {name}; {fix}divide "
                          f"the times by {1 / scale:.0e}", UserWarning, stacklevel=3)
            return



def warn_ns_unit(fn: str, path, t: np.ndarray, longest: float = 0.05,
                 fix: str = "pass time_unit='s' for seconds or write integer nanoseconds"
                 ) -> None:
    """Warn when times read as nanoseconds (a ``[ns]`` header, or ``time_unit="ns"``) lie
    less than 10 us apart (median; beyond any sensor's rate) while seconds, milliseconds or
    microseconds put them 0.2 ms to ``longest`` s apart (an IMU: 0.05 s; poses: 5 s):
    decimal seconds under EuRoC's header; ``fix`` says what to do."""
    step = float(np.median(np.diff(t))) if len(t) > 2 else 1.0
    if step >= 1e-5:
        return
    for name, scale in (("seconds", 1e9), ("milliseconds", 1e6), ("microseconds", 1e3)):
        if 2e-4 <= step * scale <= longest:
            warnings.warn(f"{fn}: {os.fspath(path)}: the times look like {name}, not "
                          f"nanoseconds: read as nanoseconds the samples lie {step:.3g} s "
                          f"apart (median), {1 / (step * scale):.4g} Hz as {name}; {fix}",
                          UserWarning, stacklevel=3)
            return


def gyro_scale(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> tuple[float, float]:
    r"""The factor ``s`` by which the gyroscope's readings explain the turning of the
    accelerometer's, and the correlation of that fit (0 where they do not turn).

    A specific force ``f`` fixed in the world (gravity, mostly) turns in the IMU's axes as
    :math:`\dot f = -\omega \times f`; central differences of ``f`` over about 0.05 s against
    :math:`\omega \times f \, \Delta t` by least squares give ``s`` (1 for rad/s, 1/57.3 for
    deg/s: the readings' scale is ``1 / s`` times rad/s); the body's own accelerations and
    the noise enter as uncorrelated residuals, lowering the correlation, not biasing ``s``."""
    if len(t) < 20:
        return 1.0, 0.0
    k = max(1, round(0.025 / max(float(np.median(np.diff(t))), 1e-12)))
    df = accel[2 * k:] - accel[:-2 * k]
    c = np.cross(gyro[k:-k], accel[k:-k]) * (t[2 * k:] - t[:-2 * k])[:, None]
    dot, cc, ff = -float((df * c).sum()), float((c * c).sum()), float((df * df).sum())
    if not (cc > 0.0 and ff > 0.0):
        return 1.0, 0.0
    return dot / cc, dot / np.sqrt(cc * ff)


def _imu_units_guess(t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> str | None:
    """The message of a likely unit error of :func:`warn_imu_units`, or None."""
    mean_a, mean_g = (float(np.linalg.norm(x.mean(axis=0))) for x in (accel, gyro))
    size_a = float(np.median(np.linalg.norm(accel, axis=1)))
    if 7.0 <= mean_g <= 14.0 and size_a < 5.0:
        return (f"the gyroscope and accelerometer columns look swapped: the gyroscope "
                f"readings average {mean_g:.3g} long, as gravity's 9.81 m/s^2 does, the "
                f"accelerometer's are {size_a:.3g} (median); the columns are t gx gy gz ax "
                f"ay az")
    if 0.7 <= mean_a <= 1.4 and 0.7 <= size_a <= 1.4:
        return (f"the accelerometer readings look like g (standard gravity), not m/s^2: "
                f"they average {mean_a:.3g} long where gravity reads 9.81 m/s^2; multiply "
                f"them by 9.80665")
    if 700.0 <= mean_a <= 1400.0 and 700.0 <= size_a <= 1400.0:
        return (f"the accelerometer readings look like milli-g, not m/s^2: they average "
                f"{mean_a:.4g} long where gravity reads 9.81 m/s^2; multiply them by "
                f"0.00980665")
    scale, corr = gyro_scale(t, gyro, accel)
    if corr >= 0.2 and 1.0 / 100.0 <= scale <= 1.0 / 30.0:
        return (f"the gyroscope readings look like deg/s, not rad/s: the accelerometer's "
                f"readings turn {1.0 / scale:.3g} times slower than the gyroscope says (180/pi"
                f" = 57.3; fit correlation {corr:.2f}); convert them with torch.deg2rad")
    return None


def warn_imu_units(fn: str, path, t: np.ndarray, gyro: np.ndarray, accel: np.ndarray) -> None:
    """Warn when the mean accelerometer reading is about 1 long (and its median magnitude
    too: g, not m/s²) or about 1000 (milli-g), when the gyroscope's is about gravity's (7
    to 14) while the accelerometer's readings are small (median magnitude below 5: the
    columns swapped), or when the accelerometer's readings turn about 57 times slower than
    the gyroscope's say (:func:`gyro_scale`, with a correlation of 0.2 at least: deg/s, not
    rad/s)."""
    if len(accel) < 3:
        return
    what = _imu_units_guess(t, gyro, accel)
    if what:
        warnings.warn(f"{fn}: {os.fspath(path)}: {what}", UserWarning, stacklevel=3)

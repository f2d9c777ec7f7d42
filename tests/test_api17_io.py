"""``io.read_imu`` on a plain ``t gx gy gz ax ay az`` file whose times are milliseconds
(session 17): the warning said "pass time_unit='ns' for nanoseconds or divide the times by
1e+03", and ``time_unit='ns'`` read the file as nanoseconds, 1e6 times too fast. The fix
named is now the unit's: dividing for milliseconds (and microseconds), ``time_unit='ns'``
only for nanoseconds, which then reads seconds (numpy's ``t / 1e9`` the reference)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from torch_dq import io

STEP = 0.005  # 200 Hz


def _write(tmp_path, scale: float):
    t = np.arange(400) * STEP
    rows = np.column_stack([t * scale, 0.1 * np.sin(t), np.full((400, 2), 0.2),
                            np.zeros((400, 2)), np.full(400, 9.81)])
    path = tmp_path / "imu.txt"
    np.savetxt(path, rows, fmt=["%.0f" if scale >= 1e9 else "%.6f"] + ["%.6f"] * 6)
    return path, t


def test_milliseconds_are_not_sent_to_time_unit_ns(tmp_path):
    path, t = _write(tmp_path, 1e3)
    with pytest.warns(UserWarning, match=r"look like milliseconds.*divide the times by "
                                         r"1e\+03") as rec:
        times, _, _ = io.read_imu(path)
    assert all("time_unit='ns'" not in str(w.message) for w in rec)
    np.testing.assert_allclose(times.numpy() / 1e3, t, atol=1e-9)


def test_relative_nanoseconds_name_time_unit_ns(tmp_path):
    path, t = _write(tmp_path, 1e9)
    with pytest.warns(UserWarning, match=r"look like nanoseconds.*pass time_unit='ns' or "
                                         r"divide the times by 1e\+09"):
        io.read_imu(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        times, _, _ = io.read_imu(path, time_unit="ns")
    np.testing.assert_allclose(times.numpy(), t, atol=1e-12)

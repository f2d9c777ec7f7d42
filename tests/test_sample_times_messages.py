"""Errors on bad sample times name the first offending sample and its values (a 20,957-line
TUM file with one repeated timestamp said only "times must be strictly increasing")."""

import numpy as np
import pytest
import torch

from torch_dq import dualquat as dq
from torch_dq import nn

F64 = torch.float64


def _poses(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return dq.to_rt(dq.exp(0.1 * torch.randn(n, 6, generator=g, dtype=F64)))


@pytest.mark.parametrize("where", [1, 7, 18])
def test_repeated_time_named(where):
    t = np.arange(20, dtype=np.float64) * 0.01 + 1.3e9
    t[where + 1] = t[where]  # a repeated stamp, as in TUM freiburg2_desk's line 10863
    q, p = _poses(20)
    i = int(np.flatnonzero(np.diff(t) <= 0)[0])
    with pytest.raises(ValueError, match=rf"times\[{i + 1}\] = {float(t[i + 1])!r} is not after "
                                         rf"times\[{i}\] = {float(t[i])!r} \(sort the samples"):
        nn.BSpline.from_poses(q, p, torch.from_numpy(t), n_ctrl=6)


def test_unsorted_and_nonfinite_named():
    t = np.arange(12, dtype=np.float64)
    t[[4, 5]] = t[[5, 4]]
    q, p = _poses(12)
    with pytest.raises(ValueError, match=r"times\[5\] = 4.0 is not after times\[4\] = 5.0"):
        nn.BSpline.from_poses(q, p, torch.from_numpy(t), n_ctrl=6)
    t = np.arange(12, dtype=np.float64)
    t[9] = np.inf
    with pytest.raises(ValueError, match=r"times must be finite: times\[9\] = inf"):
        nn.BSpline.from_poses(q, p, torch.from_numpy(t), n_ctrl=6)


def test_batched_rows_named():
    t = torch.arange(12, dtype=F64).expand(3, 12).clone()
    t[2, 6] = t[2, 5]
    q, p = _poses(12)
    with pytest.raises(ValueError, match=r"in each row, not so in row 2\b"):
        nn.BSpline.from_poses(q.expand(3, 12, 4), p.expand(3, 12, 3), t, n_ctrl=6)


def test_float32_absolute_times_hint():
    t = torch.arange(10, dtype=torch.float32) * 0.01 + 1.3e9  # float32 steps of 128 s there
    q, p = _poses(10)
    with pytest.raises(ValueError, match=r"torch.float32 rounds these times to steps of 128"):
        nn.BSpline.from_poses(q.float(), p.float(), t, n_ctrl=6)


@pytest.mark.parametrize("batched", [False, True])
def test_nonfinite_pose_named(batched):
    t = torch.arange(12, dtype=F64)
    q, p = _poses(12)
    p = p.clone()
    p[7, 1] = float("nan")
    if batched:  # trajectory 1 holds the NaN
        q, p = q.expand(2, 12, 4), torch.stack((torch.zeros_like(p), p))
    where = r"1, 7" if batched else r"7"
    with pytest.raises(ValueError, match=rf"poses must be finite, with non-zero rotations "
                                         rf"\(not poses\[{where}\]\)"):
        nn.BSpline.from_poses(q, p, t, n_ctrl=5)


def test_too_few_poses_advice():
    """Fewer samples than a degree-3 curve needs: the advice is to add samples or lower the
    degree, not finer knots (which need more samples too)."""
    t = torch.arange(2, dtype=F64)
    q, p = _poses(2)
    with pytest.raises(ValueError, match=r"needs at least 4 samples: add samples or lower the "
                                         r"degree$"):
        nn.BSpline.from_poses(q, p, t, n_ctrl=4)
    assert nn.BSpline.from_poses(q, p, t, n_ctrl=2, degree=1).n_ctrl == 2  # the advice works


@pytest.mark.parametrize("unit, scale", [("nanoseconds", 1e9), ("microseconds", 1e6),
                                         ("milliseconds", 1e3)])
def test_unix_times_in_a_finer_unit_warn(unit, scale):
    """UNIX times in ns / us / ms fit a curve in that unit (the caller's), whose rates would
    be per nanosecond: a warning names the unit and the factor to seconds."""
    t = (1.6e9 + 0.05 * np.arange(12)) * scale
    q, p = _poses(12)
    with pytest.warns(UserWarning, match=rf"look like UNIX {unit} .*pass seconds \(times \* "
                                         rf"{1 / scale:g}\)"):
        nn.BSpline.from_poses(q, p, torch.from_numpy(t), n_ctrl=5)


@pytest.mark.parametrize("t0", [0.0, 1.6e9])
def test_seconds_do_not_warn(t0):
    import warnings
    q, p = _poses(12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        nn.BSpline.from_poses(q, p, torch.from_numpy(t0 + 0.05 * np.arange(12)), n_ctrl=5)
        nn.BSpline.from_poses(q, p, torch.from_numpy(50.0 * np.arange(12)), n_ctrl=5)  # ms

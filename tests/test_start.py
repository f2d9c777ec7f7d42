"""The least-squares start (torch_dq._start) on fast rotations (issue 22): 0.2 broke above
~1 rad of rotation per knot span without a word. The reference is pytransform3d's
exponential of a constant twist, which the start must reproduce exactly."""

import math
import re

import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch

import torch_dq.dualquat as dq
from torch_dq.nn import BSpline

F64 = torch.float64


def spin(rate, duration=6.0, count=241):
    """Poses of a constant screw motion turning at ``rate`` rad/s, as 4x4 matrices."""
    axis = np.array([0.3, 0.0, 0.95]) / math.hypot(0.3, 0.95)
    xi = np.concatenate((rate * axis, [1.0, 0.5, 0.0]))
    times = torch.linspace(0.0, duration, count, dtype=F64)
    T = np.stack([pt.transform_from_exponential_coordinates(s * xi) for s in times.tolist()])
    return times, torch.from_numpy(T)


def max_errors(spline, times, T):
    with torch.no_grad():
        got = dq.to_matrix(spline(times)).numpy()
    ref = T.numpy()
    return (np.abs(got[..., :3, 3] - ref[..., :3, 3]).max(),
            np.abs(got[..., :3, :3] - ref[..., :3, :3]).max())


@pytest.mark.parametrize("form", ["de_boor", "cumulative"])
def test_start_is_exact_up_to_two_radians_per_knot_span(form):
    """1.75 rad per knot span: 0.2's start was 0.025 m and 9.4 deg off; now the windows
    shrink where the motion is fast and the start is exact again."""
    times, T = spin(7.0)
    spline = BSpline.from_matrices(T, times, n_ctrl=round(6.0 / 0.25) + 3, form=form)
    trans, rot = max_errors(spline, times, T)
    assert trans < 1e-9 and rot < 1e-9


def test_start_warns_beyond_with_a_spacing_that_works():
    """2.5 rad per span: a UserWarning with the rate found and a knot spacing that, used
    literally, gives an exact start."""
    times, T = spin(10.0)
    with pytest.warns(UserWarning, match=r"^nn\.BSpline\.from_matrices: the poses turn at up "
                                         r"to 10 rad per unit of time \(rad/s for "
                                         r"times in seconds\), 2\.5 rad per knot span of "
                                         r"0\.25.*use knots at most [0-9.]+ apart") as record:
        BSpline.from_matrices(T, times, n_ctrl=round(6.0 / 0.25) + 3)
    h = float(re.search(r"at most ([0-9.]+) apart", str(record[0].message)).group(1))
    spline = BSpline.from_matrices(T, times, n_ctrl=math.ceil(6.0 / h) + 3)
    trans, rot = max_errors(spline, times, T)
    assert trans < 1e-9 and rot < 1e-9


def test_sample_times_per_trajectory():
    """check_sample_times: (N,) only by default (the estimation terms' times); with
    batched=True rows of their own, each finite and strictly increasing, the message naming
    the first bad row."""
    from torch_dq._start import check_sample_times

    rows = torch.stack((torch.linspace(0, 1, 5, dtype=F64), 1.7e9 + torch.arange(5, dtype=F64)))
    assert check_sample_times("f", rows, 5, batched=True) is rows
    with pytest.raises(ValueError, match=r"^f: expected a 1-D \(N,\) tensor for times"):
        check_sample_times("f", rows, 5)
    bad = rows.clone()
    bad[1, 3] = bad[1, 2]
    with pytest.raises(ValueError, match=r"^f: times must be strictly increasing in each row, "
                                         r"not so in row 1 \(sort the samples, and drop or "
                                         r"merge repeated times\)$"):
        check_sample_times("f", bad, batched=True)
    bad = rows[None].repeat(2, 1, 1)
    bad[1, 0, 4] = math.inf
    with pytest.raises(ValueError, match=r"times must be finite in each row, not so in row "
                                         r"\(1, 0\)"):
        check_sample_times("f", bad, batched=True)
    with pytest.raises(ValueError, match=r"expected shape \(\.\.\., 4\) for the N = 4 poses"):
        check_sample_times("f", rows, 4, batched=True)
    with pytest.raises(ValueError, match=r"float32 rounds these times to steps of 128"):
        check_sample_times("f", rows.float(), batched=True)

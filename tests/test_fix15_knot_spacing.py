"""A ``knot_spacing`` far finer than the poses (a unit mistake: nanosecond times with a
spacing in seconds) is a ``ValueError`` naming ``knot_spacing``, the control points it needs,
the times' unit and the spacing that works, raised before anything of that size is
allocated (it asked for 960 GB), by every constructor that takes ``knot_spacing``
(user15 finding 2)."""

import re
import time
import warnings

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.nn import BSpline

F64 = torch.float64


def _poses(n):
    s = torch.linspace(0.0, 1.0, n, dtype=F64)
    return dq.exp(s[:, None] * torch.tensor([0.0, 0.0, 1.0, 1.0, 0.0, 0.0], dtype=F64))


def test_nanosecond_times_with_a_spacing_in_seconds():
    t = 1.7e18 + torch.arange(61, dtype=F64) * 5e7  # 3 s at 20 Hz, in ns
    x = _poses(61)
    q, p = dq.to_rt(x)
    T = dq.to_matrix(x)
    builds = (lambda **kw: BSpline.from_poses(q, p, t, **kw),
              lambda **kw: BSpline.from_dualquats(x, t, **kw),
              lambda **kw: BSpline.from_matrices(T, t, **kw))
    for build in builds:
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the "UNIX nanoseconds" warning
            with pytest.raises(ValueError, match=r"knot_spacing=0\.1 .*needs 30000000003 control "
                                                 r"points for N = 61 poses .*UNIX nanoseconds.*"
                                                 r"times \* 1e-09"):
                build(knot_spacing=0.1, degree=3)
        assert time.perf_counter() - start < 2.0
    # followed: the times in seconds, the same spacing
    spline = BSpline.from_poses(q, p, t * 1e-9, knot_spacing=0.1)
    assert spline.n_ctrl == 30 + 3  # 3 s / 0.1 s spans, clamped cubic


def test_the_spacing_advised_works_literally():
    t = torch.linspace(0.0, 1.0, 11, dtype=F64)  # seconds, 0.1 s apart
    x = _poses(11)
    with pytest.raises(ValueError, match=r"knot_spacing=1e-05 is more than") as err:
        BSpline.from_dualquats(x, t, knot_spacing=1e-5, margin=0.5)
    msg = str(err.value)
    assert "nanoseconds" not in msg and "needs 200003 control points" in msg, msg
    advised = float(re.search(r"pass knot_spacing=([0-9.e+-]+) or more", msg).group(1))
    assert advised == pytest.approx(1e-4)
    spline = BSpline.from_dualquats(x, t, knot_spacing=advised)
    assert spline.n_ctrl == 10000 + 3
    err = dq.to_rt(dq.mul(dq.inv(spline(t).detach()), x))[1].norm(dim=-1).max()
    assert float(err) < 1e-6

"""A new user's few-pose fits (user12): ``BSpline.from_poses`` with the default ``n_ctrl=None``
on too few poses names itself and what to pass, and the values it suggests work."""

import re

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import nn, quat


def _poses(n):
    t = torch.arange(n, dtype=torch.float64) * 0.5
    q = quat.from_axis_angle(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), 0.3 * t)
    p = torch.stack((t, 0.2 * t, 0 * t), -1)
    return q, p, t


@pytest.mark.parametrize("n", [2, 3, 5, 9])
def test_too_few_poses_for_the_default_name_from_poses_and_a_working_fix(n):
    q, p, t = _poses(n)
    with pytest.raises(ValueError, match=r"nn\.BSpline\.from_poses: n_ctrl=None .* at least "
                                         r"10 .* got N = " + str(n)) as info:
        nn.BSpline.from_poses(q, p, t)
    hint = re.search(r"e\.g\. (.*)$", str(info.value)).group(1)
    kwargs = {k: int(v) for k, v in re.findall(r"(\w+)=(\d+)", hint)}
    spline = nn.BSpline.from_poses(q, p, t, **kwargs)
    with torch.no_grad():
        qf, pf = dq.to_rt(spline(t))
    # n_ctrl = N control points nearly interpolate N poses (the start is a linearised fit)
    np.testing.assert_allclose(pf.numpy(), p.numpy(), atol=1e-3)
    np.testing.assert_allclose(np.abs((qf * q).sum(-1).numpy()), 1.0, atol=1e-6)

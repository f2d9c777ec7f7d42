"""``from_poses(knot_spacing=h, margin=m)`` puts the knots on multiples of ``h`` when the
domain is a whole number of them: the domain's length was read through a float32 tensor
(``torch.as_tensor`` of a Python float), 3.2 s became 3.2000000477 s and 0.1 s knots 33
spans of 0.09697 s."""

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import nn


@pytest.mark.parametrize("t0", [0.0, 1305031098.6659])
@pytest.mark.parametrize("degree", [3, 4])
def test_knots_on_the_spacing(t0, degree):
    s = torch.linspace(0.0, 3.0, 91, dtype=torch.float64)
    x = dq.exp(torch.stack((0 * s, 0 * s, 0.1 * s, s, 0 * s, 0 * s), -1))
    spline = nn.BSpline.from_dualquats(x, t0 + s, degree=degree, margin=0.1, knot_spacing=0.1)
    inner = spline.knots[degree:-degree].numpy() - t0
    ref = np.arange(-0.1, 3.1 + 1e-9, 0.1)  # 32 spans of 0.1 s
    assert spline.control_points.shape[0] == 32 + degree
    np.testing.assert_allclose(inner, ref, atol=1e-6)

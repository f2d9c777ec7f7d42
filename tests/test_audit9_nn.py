"""Audit of torch_dq.nn's layers (API.md, "torch_dq.nn"): every method names itself in its
errors; batch shapes of the control points and the times that do not broadcast raised from
``curves.bspline`` / ``curves.bezier``, which the caller never called."""

import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.nn import Bezier, BSpline

F64 = torch.float64


def _ctrl(batch, n):
    gen = torch.Generator().manual_seed(9)
    return dq.exp(0.5 * torch.randn(*batch, n, 6, generator=gen, dtype=F64))


@pytest.mark.parametrize("cls, n", [(BSpline, 6), (Bezier, 4)])
@pytest.mark.parametrize("method", ["forward", "derivatives"])
def test_unbroadcastable_times_name_the_layer_method(cls, n, method):
    layer = cls(_ctrl((3,), n))
    call = layer if method == "forward" else layer.derivatives
    name = cls.__name__
    with pytest.raises(ValueError, match=rf"^nn\.{name}\.{method}: batch shapes do not "
                                         r"broadcast: ctrl \(3,\), t \(2,\)$"):
        call(torch.rand(2, 4, dtype=F64))


@pytest.mark.parametrize("t_batch, out", [((), (3, 4, 8)), ((3,), (3, 4, 8)),
                                          ((1,), (3, 4, 8)), ((2, 3), (2, 3, 4, 8)),
                                          ((2, 1), (2, 3, 4, 8))])
def test_broadcastable_times_still_evaluate(t_batch, out):
    layer = BSpline(_ctrl((3,), 6))
    t = torch.rand(*t_batch, 4, dtype=F64)
    assert layer(t).shape == out
    assert layer.kinematics(t).angular_acceleration.shape == (*out[:-1], 3)

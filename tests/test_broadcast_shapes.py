"""torch_dq._checks.broadcast_shapes: plain-Python broadcasting (no sympy import on the first
call, as ``torch.broadcast_shapes`` has), equal to torch's on every case, errors included."""

import pytest
import torch

from torch_dq._checks import broadcast_shapes

CASES = [(), ((),), ((2, 1), (3,)), ((5,), ()), ((1,), (5,)), ((2, 5), (5,), (1, 1)),
         ((3, 1, 5), (1, 4, 1), (4, 5)), ((0,), (1,)), ((1, 0), (3, 1)), (4, (1,)),
         (torch.Size([2, 1, 3]), (7, 1)), ((1, 1, 1), ())]
BAD = [((2,), (3,)), ((2, 3), (3, 2)), ((0,), (2,)), ((4, 1), (1, 3), (2, 3))]


@pytest.mark.parametrize("shapes", CASES)
def test_equals_torch(shapes):
    got = broadcast_shapes(*shapes)
    assert isinstance(got, torch.Size)
    assert got == torch.broadcast_shapes(*shapes)


@pytest.mark.parametrize("shapes", BAD)
def test_raises_as_torch(shapes):
    with pytest.raises(RuntimeError):
        torch.broadcast_shapes(*shapes)
    with pytest.raises(RuntimeError, match="cannot be broadcast"):
        broadcast_shapes(*shapes)

"""Audit of torch_dq.dual against mpmath (API.md, "torch_dq.dual"): f(a + eps b) = f(a) + eps b
f'(a) with the derivative taken by mpmath at 40 digits, near the ends of acos's domain where
the derivative's 1 - a^2 cancels."""

import mpmath
import pytest
import torch

from torch_dq import dual
from torch_dq.dual import Dual

F64 = torch.float64


@pytest.mark.parametrize("a", [0.999999, 1.0 - 1e-10, -(1.0 - 1e-12), 0.5])
def test_acos_dual_part_near_one_matches_mpmath(a):
    # 1 - a * a lost eps / (1 - |a|) relatively: 2.5e-11 at a = 1 - 1e-10 before the fix.
    with mpmath.workdps(40):
        ref = float(-0.75 / mpmath.sqrt(1 - mpmath.mpf(a) ** 2))
        ref_real = float(mpmath.acos(mpmath.mpf(a)))
    out = dual.acos(Dual(torch.tensor(a, dtype=F64), torch.tensor(0.75, dtype=F64)))
    assert abs(out.dual.item() / ref - 1.0) <= 4e-16
    assert abs(out.real.item() / ref_real - 1.0) <= 4e-16

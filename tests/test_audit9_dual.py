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


@pytest.mark.parametrize("a", [1e-200, -3e-170, 1e200, 2.0 ** 600])
def test_inv_at_extreme_scales_matches_mpmath(a):
    # b / a^2 with a^2 formed first overflowed to inf (a = 1e-200: -inf instead of -1e200)
    # or underflowed to 0 (a = 1e200: 0 instead of -1e-200).
    b = 0.5 * a
    with mpmath.workdps(50):  # 1 / (a + eps b) = 1 / a - eps b / a^2, exact arithmetic
        ref_real, ref_dual = float(1 / mpmath.mpf(a)), float(-mpmath.mpf(b) / mpmath.mpf(a) ** 2)
    out = dual.inv(Dual(torch.tensor(a, dtype=F64), torch.tensor(b, dtype=F64)))
    assert abs(out.real.item() / ref_real - 1.0) <= 4e-16
    assert abs(out.dual.item() / ref_dual - 1.0) <= 4e-16


@pytest.mark.parametrize("scale", [1e-200, 1e200, 1e-170, 2.0 ** 600])
def test_atan2_at_extreme_scales_matches_mpmath(scale):
    # (x y_d - y x_d) / (x^2 + y^2): the squares overflowed (NaN = inf / inf) or underflowed
    # (0 / 0) for representable points; the reference evaluates the formula in mpmath.
    yr, yd, xr, xd = 0.75 * scale, 0.25 * scale, -1.5 * scale, 1.0 * scale
    with mpmath.workdps(50):
        y, x = mpmath.mpf(yr), mpmath.mpf(xr)
        ref_real = float(mpmath.atan2(y, x))
        ref_dual = float((x * yd - y * xd) / (x * x + y * y))  # d/ds atan2(y + s yd, x + s xd)
    out = dual.atan2(Dual(torch.tensor(yr, dtype=F64), torch.tensor(yd, dtype=F64)),
                     Dual(torch.tensor(xr, dtype=F64), torch.tensor(xd, dtype=F64)))
    assert abs(out.real.item() - ref_real) <= 4e-16 * abs(ref_real)
    assert abs(out.dual.item() - ref_dual) <= 4e-16 * abs(ref_dual)

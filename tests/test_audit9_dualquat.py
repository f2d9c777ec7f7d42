"""Audit of torch_dq.dualquat's algebra at extreme scales (API.md: inv and norm take dual
quaternions of any norm): references are pytransform3d's conjugate of the unit dual quaternion
(the inverse of ``c x`` is ``conj(x) / c``) and mpmath's 50-digit norm, never the library."""

import mpmath
import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch
from torch.autograd import gradcheck, gradgradcheck

import torch_dq.dualquat as dq

F64 = torch.float64
# Powers of two: c x is exact, and the references 1 / c exact. Squares of the real part
# overflow (2**600 in float64, 2**70 in float32) or underflow (2**-600, 2**-70) to 0.
SCALES = {F64: (2.0 ** 600, 2.0 ** -600), torch.float32: (2.0 ** 70, 2.0 ** -70)}
CASES = [(dtype, c) for dtype, cs in SCALES.items() for c in cs]


def _unit(dtype):
    m = pt.transform_from_exponential_coordinates(np.array([0.3, -0.2, 0.5, 1.0, 2.0, -3.0]))
    return torch.tensor(pt.dual_quaternion_from_transform(m), dtype=dtype)


@pytest.mark.parametrize(("dtype", "c"), CASES)
def test_inv_of_scaled_dual_quaternion_matches_scaled_conjugate(dtype, c):
    # Before the fix |r|^2 over/underflowed: NaN (huge) or inf (tiny) in every component.
    x = _unit(dtype)
    ref = torch.tensor(pt.dq_q_conj(x.double().numpy()), dtype=F64) / c
    got = dq.inv(x * c)
    tol = 1e-15 if dtype == F64 else 1e-6
    assert torch.isfinite(got).all()
    assert ((got.double() - ref).abs() / c ** -1).max().item() <= tol


@pytest.mark.parametrize(("dtype", "c"), CASES)
def test_norm_of_scaled_dual_quaternion_matches_mpmath(dtype, c):
    x = (_unit(dtype) * torch.tensor([1.0, 1.0, 1.0, 1.0, 1.5, -0.5, 2.0, 1.0],
                                     dtype=dtype)) * c
    with mpmath.workdps(50):
        v = [mpmath.mpf(float(e)) for e in x.double()]
        real = mpmath.sqrt(sum(e * e for e in v[:4]))
        dual = sum(a * b for a, b in zip(v[:4], v[4:], strict=True)) / real
        ref_real, ref_dual = float(real), float(dual)
    got = dq.norm(x)
    tol = 1e-15 if dtype == F64 else 1e-6
    assert abs(got.real.item() / ref_real - 1.0) <= tol
    assert abs(got.dual.item() - ref_dual) <= tol * abs(ref_real)


def test_norm_and_inv_stay_twice_differentiable():
    x = (_unit(F64) * 1.3).requires_grad_(True)
    assert gradcheck(lambda y: torch.stack([dq.norm(y).real, dq.norm(y).dual]), (x,))
    assert gradgradcheck(lambda y: torch.stack([dq.norm(y).real, dq.norm(y).dual]), (x,))
    assert gradcheck(dq.inv, (x,)) and gradgradcheck(dq.inv, (x,))

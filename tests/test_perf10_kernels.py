"""The estimator's kernels after their restructuring for speed (session 10): the cumulative
form's closed-form vector-Jacobian products in parts of samples (``_cumulative_lie.vjp``,
``VJP_CHUNK``), with 3 and 6 cotangent rows, against reverse mode through the public
``derivatives``; the inertial residuals' closed-form rows (``fitting._imu_jacobians``)
against autograd through the module docstring's quaternion formulas, written with the
public ``quat`` functions.
"""

from __future__ import annotations

import pytest
import torch
from test_span_jacobians import _closed_form, _curve, _reference

import torch_dq.dualquat as dq
from torch_dq import _cumulative_lie, quat
from torch_dq.fitting._imu_jacobians import accel_rows, gyro_rows
from torch_dq.fitting._local import SpanEvaluator

F64 = torch.float64


@pytest.mark.parametrize("k", [3, 6])
@pytest.mark.parametrize("chunk", [2, 4, 1 << 12])
def test_vjp_in_parts_equals_reverse_mode(k, chunk, monkeypatch):
    """Parts of 2 and 4 samples (the last one shorter) and one part give reverse mode's
    rows, with 3 cotangent rows and 6 (two terms' rows in one call), on identical
    neighbours and a half turn."""
    monkeypatch.setattr(_cumulative_lie, "VJP_CHUNK", chunk)
    curve = _curve("cumulative", True, ())
    t = torch.tensor([0.05, 0.5, 0.77, 1.0, 1.31, 1.6, 1.9], dtype=F64)
    first = SpanEvaluator(curve).first(t)
    Jd = torch.randn(t.numel(), k, 3, 8, generator=torch.Generator().manual_seed(k),
                     dtype=F64)
    Jc, _ = _closed_form(curve, [t], [first], 2, [Jd])
    ref, _ = _reference(curve, t, first, 2)  # (N, 24, w, 6)
    want = torch.einsum("nkc,ncwj->nkwj", Jd.flatten(-2), ref)
    torch.testing.assert_close(Jc, want, atol=1e-10 * float(want.abs().max()), rtol=0)


def _motion(n: int, dtype: torch.dtype):
    """Unit dual quaternions ``x`` and arbitrary derivatives ``dx, ddx`` ``(n, 8)``, a
    gravity ``(1, 3)``."""
    g = torch.Generator().manual_seed(5)
    x = dq.exp(torch.randn(n, 6, generator=g, dtype=F64))
    dx, ddx = (torch.randn(n, 8, generator=g, dtype=F64) for _ in range(2))
    grav = torch.tensor([[0.1, -0.2, -9.8]], dtype=F64)
    return [v.to(dtype) for v in (x, dx, ddx, grav)]


def _rows(f, inputs: list[torch.Tensor]) -> list[torch.Tensor]:
    """Per-sample rows ``(n, 3, 8)`` of ``f``'s 3 outputs with respect to each input."""
    inputs = [v.detach().requires_grad_() for v in inputs]
    out = f(*inputs)
    grads = [torch.autograd.grad(out[:, j].sum(), inputs, retain_graph=True)
             for j in range(3)]
    return [torch.stack([g[i] for g in grads], 1) for i in range(len(inputs))]


def _vec(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return quat.mul(a, quat.conj(b))[..., 1:]


@pytest.mark.parametrize("dtype", [F64, torch.float32])
def test_imu_rows_equal_autograd_through_the_quaternion_formulas(dtype):
    """``accel_rows``: the specific force :math:`\\mathrm{vec}(r^* U r)`, :math:`U = (0,
    2\\,\\mathrm{vec}(\\ddot d r^* + 2 \\dot d \\dot r^* + d \\ddot r^*) - g)`; ``gyro_rows``:
    :math:`2\\,\\mathrm{vec}(r^* \\dot r)`; and the gravity rows, all by autograd."""
    x, dx, ddx, grav = _motion(9, dtype)

    def force(x, dx, ddx, grav):
        r, d, rd, dd, rdd, ddd = (v[..., s] for v in (x, dx, ddx) for s in
                                  (slice(0, 4), slice(4, 8)))
        u = 2.0 * (_vec(ddd, r) + 2.0 * _vec(dd, rd) + _vec(d, rdd)) - grav
        U = torch.cat((torch.zeros_like(u[..., :1]), u), -1)
        return quat.mul(quat.conj(r), quat.mul(U, r))[..., 1:]

    def rate(x, dx):
        return 2.0 * quat.mul(quat.conj(x[..., :4]), dx[..., :4])[..., 1:]

    tol = dict(atol=1e-13 if dtype == F64 else 1e-5, rtol=0)
    rows, toward_g = accel_rows(x, dx, ddx, grav)
    want = _rows(force, [x, dx, ddx, grav.expand(9, 3)])
    assert rows.shape == (9, 3, 3, 8) and toward_g.shape == (9, 3, 3)
    for i in range(3):
        torch.testing.assert_close(rows[:, :, i], want[i], **tol)
    torch.testing.assert_close(toward_g, want[3], **tol)
    rows = gyro_rows(x, dx)
    want = _rows(rate, [x, dx])
    assert rows.shape == (9, 3, 2, 8)
    for i in range(2):
        torch.testing.assert_close(rows[:, :, i], want[i], **tol)

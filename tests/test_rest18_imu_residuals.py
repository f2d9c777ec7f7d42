"""rest18: the inertial residuals by the compiled loop (``_imu_jacobians.imu_residuals``,
``csrc/imu_rows.c``) against the formulas written here (body rate ``2 vec(r^* dr)``, specific
force ``vec(r^* U r)``) and against the terms' PyTorch path: batches, strided derivatives,
bias and gravity broadcast, the Gyro / Accel terms' whitened residuals."""

import pytest
import torch
from test_asm17_imu_rows import _conj, _qmul  # the products written once, there

import torch_dq.dualquat as dq
from torch_dq._kernels import native
from torch_dq.fitting import Accel, Gyro
from torch_dq.fitting._imu_jacobians import imu_residuals

F64 = torch.float64
pytestmark = pytest.mark.skipif(native.library() is None,
                                reason="the compiled kernels are not built (or TORCH_DQ_NATIVE=0)")


def _inputs(lead, seed):
    """Unit poses and derivatives ``(*lead, 8)`` (strided views of one array)."""
    g = torch.Generator().manual_seed(seed)
    x = dq.exp(torch.randn(*lead, 6, dtype=F64, generator=g))
    both = torch.randn(*lead, 2, 8, dtype=F64, generator=g)
    return x, both[..., 0, :], both[..., 1, :], g


@pytest.mark.parametrize("lead", [(7,), (2, 5)])
def test_compiled_residuals_are_the_formulas(lead):
    x, dx, ddx, g = _inputs(lead, len(lead))
    bias = torch.randn(*lead[:-1], 1, 3, dtype=F64, generator=g)
    y = torch.randn(*lead, 3, dtype=F64, generator=g)
    grav = torch.tensor([0.1, -0.2, -9.81], dtype=F64)
    r, d, rd, dd, rdd, ddd = x[..., :4], x[..., 4:], dx[..., :4], dx[..., 4:], ddx[..., :4], \
        ddx[..., 4:]
    gyro = 2.0 * _qmul(_conj(r), rd)[..., 1:] + bias - y
    S = _qmul(ddd, _conj(r)) + 2.0 * _qmul(dd, _conj(rd)) + _qmul(d, _conj(rdd))
    U = torch.cat((torch.zeros_like(S[..., :1]), 2.0 * S[..., 1:] - grav), -1)
    accel = _qmul(_qmul(_conj(r), U), r)[..., 1:] + bias - y
    torch.testing.assert_close(imu_residuals(x, dx, None, None, bias, y), gyro, rtol=0,
                               atol=1e-12)
    torch.testing.assert_close(imu_residuals(x, dx, ddx, grav, bias, y), accel, rtol=0,
                               atol=1e-12)


def test_terms_residuals_equal_the_torch_path(monkeypatch):
    N = 9
    x, dx, ddx, g = _inputs((2, N), 7)
    t = torch.linspace(0.0, 1.0, N, dtype=F64)
    mask = torch.ones(2, N, dtype=torch.bool)
    mask[0, 3] = False
    sig = torch.tensor([0.1, 0.2, 0.4], dtype=F64)
    y = torch.randn(2, N, 3, dtype=F64, generator=g)
    gyro = Gyro(t, y, sigma=sig, bias=True, mask=mask)
    accel = Accel(t, y, sigma=sig, bias=True, mask=mask,
                  gravity=torch.tensor([0.0, 0.0, -9.81], dtype=F64))
    p = {"bias": torch.randn(2, 1, 3, dtype=F64, generator=g),
         "gravity": torch.tensor([[0.0, 0.3, -9.81]], dtype=F64)}
    got = [gyro.residuals([(x, dx)], p), accel.residuals([(x, dx, ddx)], p)]
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    ref = [gyro.residuals([(x, dx)], p), accel.residuals([(x, dx, ddx)], p)]
    for a, b in zip(got, ref, strict=True):
        assert a.shape == b.shape == (2, N, 3)
        torch.testing.assert_close(a, b, rtol=0, atol=1e-11 * float(b.abs().max()))
    assert not got[0][0, 3].any()  # masked
    with torch.enable_grad():  # autograd: the PyTorch path (a graph to differentiate)
        xg = x.clone().requires_grad_()
        assert gyro.residuals([(xg, dx)], p).requires_grad

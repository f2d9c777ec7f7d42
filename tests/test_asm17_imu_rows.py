"""The compiled inertial rows (``csrc/imu_rows.c`` behind ``_imu_jacobians.gyro_rows`` and
``accel_rows``) against the Jacobians (``torch.func.jacrev``) of the residual formulas
written here with their own quaternion product, and against the PyTorch path: batches,
strided derivatives (views of a stacked array, as the linearisation passes them), gravity
shared or per sample, the component-major layout, no samples."""

import pytest
import torch

from torch_dq._kernels import native
from torch_dq.fitting._imu_jacobians import accel_rows, gyro_rows

F64 = torch.float64
pytestmark = pytest.mark.skipif(native.library() is None,
                                reason="the compiled kernels are not built (or TORCH_DQ_NATIVE=0)")


def _qmul(a, b):
    a0, av, b0, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return torch.cat((a0 * b0 - (av * bv).sum(-1, keepdim=True),
                      a0 * bv + b0 * av + torch.linalg.cross(av, bv)), -1)


def _conj(a):
    return torch.cat((a[..., :1], -a[..., 1:]), -1)


def _gyro(x, dx):
    """Body rate ``2 vec(r^* dr)``."""
    return 2.0 * _qmul(_conj(x[:4]), dx[:4])[1:]


def _accel(x, dx, ddx, g):
    """Specific force ``vec(r^* U r)``, ``U = (0, 2 vec(ddd r^* + 2 dd dr^* + d ddr^*) - g)``."""
    r, d, rd, dd, rdd, ddd = x[:4], x[4:], dx[:4], dx[4:], ddx[:4], ddx[4:]
    S = _qmul(ddd, _conj(r)) + 2.0 * _qmul(dd, _conj(rd)) + _qmul(d, _conj(rdd))
    U = torch.cat((torch.zeros(1, dtype=F64), 2.0 * S[1:] - g))
    return _qmul(_qmul(_conj(r), U), r)[1:]


def _inputs(lead, per_sample_gravity):
    """Derivatives ``(*lead, 8)`` as strided views of one ``(*lead, 3, 8)`` array."""
    g = torch.Generator().manual_seed(len(lead) + 3 * per_sample_gravity)
    x, dx, ddx = torch.randn(*lead, 3, 8, dtype=F64, generator=g).unbind(-2)
    grav = torch.randn(*((*lead, 3) if per_sample_gravity else (3,)), dtype=F64, generator=g)
    return x, dx, ddx, grav


@pytest.mark.parametrize("lead", [(7,), (2, 5), (1,)])
@pytest.mark.parametrize("per_sample_gravity", [False, True])
def test_compiled_rows_are_the_formulas_jacobians(lead, per_sample_gravity):
    x, dx, ddx, grav = _inputs(lead, per_sample_gravity)
    assert x.stride(-2) == 24  # strided: the kernel reads them as they lie
    rows, toward = accel_rows(x, dx, ddx, grav)
    flat = [t.reshape(-1, 8) for t in (x, dx, ddx)]
    G = grav.expand(*lead, 3).reshape(-1, 3)
    jac = torch.func.vmap(torch.func.jacrev(_accel, argnums=(0, 1, 2, 3)))(*flat, G)
    ref = torch.stack(jac[:3], -2).reshape(*lead, 3, 3, 8)
    torch.testing.assert_close(rows, ref, rtol=0, atol=1e-12 * float(ref.abs().max()))
    torch.testing.assert_close(toward, jac[3].reshape(*lead, 3, 3), rtol=0, atol=1e-14)
    gyro = gyro_rows(x, dx)
    jg = torch.func.vmap(torch.func.jacrev(_gyro, argnums=(0, 1)))(*flat[:2])
    torch.testing.assert_close(gyro, torch.stack(jg, -2).reshape(*lead, 3, 2, 8), rtol=0,
                               atol=1e-14)
    # component-major, as the span products read them (the samples' stride 1)
    assert rows.shape == (*lead, 3, 3, 8) and gyro.shape == (*lead, 3, 2, 8)
    assert lead[-1] == 1 or rows.stride(len(lead) - 1) == gyro.stride(len(lead) - 1) == 1


@pytest.mark.parametrize("lead", [(9,), (2, 4)])
def test_compiled_rows_equal_the_torch_path(monkeypatch, lead):
    x, dx, ddx, grav = _inputs(lead, True)
    got = (*accel_rows(x, dx, ddx, grav), gyro_rows(x, dx))
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    ref = (*accel_rows(x, dx, ddx, grav), gyro_rows(x, dx))
    for a, b in zip(got, ref, strict=True):
        assert a.shape == b.shape
        assert float((a - b).abs().max()) <= 1e-12 * float(b.abs().max())


def test_rows_of_no_samples_and_of_float32():
    x = torch.zeros(0, 8, dtype=F64)
    rows, toward = accel_rows(x, x, x, torch.zeros(3, dtype=F64))
    assert rows.shape == (0, 3, 3, 8) and toward.shape == (0, 3, 3)
    assert gyro_rows(x, x).shape == (0, 3, 2, 8)
    x, dx, ddx, grav = _inputs((6,), False)  # float32: the PyTorch path, the same rows
    ref, single = accel_rows(x, dx, ddx, grav)[0], accel_rows(
        *(t.float() for t in (x, dx, ddx, grav)))[0]
    assert single.dtype == torch.float32
    torch.testing.assert_close(single.double(), ref, rtol=1e-5, atol=1e-5 * float(ref.abs().max()))

"""rest18: the inertial rows whitened as they are written (``gyro_rows`` / ``accel_rows``
``scale=``, ``csrc/imu_rows.c`` and the PyTorch path) against the formulas' Jacobians
(``torch.func.jacrev`` of the residuals written here) times the scales, row by row; a
scale shared by a batch; masked samples' rows zero; the Gyro / Accel terms' rows with a
wider batch of masks (whitened after) against the same reference."""

import pytest
import torch
from test_asm17_imu_rows import _accel, _gyro  # the residuals written once, there

from torch_dq._kernels import native
from torch_dq.fitting._imu_jacobians import accel_rows, gyro_rows

F64 = torch.float64


def _reference(x, dx, ddx, grav, lead):
    flat = [t.reshape(-1, 8) for t in (x, dx, ddx)]
    G = grav.expand(*lead, 3).reshape(-1, 3)
    ja = torch.func.vmap(torch.func.jacrev(_accel, argnums=(0, 1, 2)))(*flat, G)
    jg = torch.func.vmap(torch.func.jacrev(_gyro, argnums=(0, 1)))(*flat[:2])
    return (torch.stack(jg, -2).reshape(*lead, 3, 2, 8),
            torch.stack(ja, -2).reshape(*lead, 3, 3, 8))


@pytest.mark.parametrize("native_on", ["1", "0"])
@pytest.mark.parametrize(("lead", "scale_lead"), [((7,), (7,)), ((2, 5), (2, 5)),
                                                  ((2, 5), (5,))])
def test_scaled_rows_are_the_jacobians_times_the_scales(monkeypatch, native_on, lead,
                                                        scale_lead):
    if native_on == "1" and native.library() is None:
        pytest.skip("the compiled kernels are not built")
    monkeypatch.setenv("TORCH_DQ_NATIVE", native_on)
    g = torch.Generator().manual_seed(len(lead) + len(scale_lead))
    x, dx, ddx = torch.randn(*lead, 3, 8, dtype=F64, generator=g).unbind(-2)  # strided
    grav = torch.randn(3, dtype=F64, generator=g)
    scale = torch.rand(*scale_lead, 3, dtype=F64, generator=g) + 0.5
    scale[..., 1, :] = 0.0  # a masked sample
    ref_g, ref_a = _reference(x, dx, ddx, grav, lead)
    got_g = gyro_rows(x, dx, scale)
    got_a = accel_rows(x, dx, ddx, grav, scale)[0]
    s = scale[..., None, None]
    tol = 1e-12 * float(ref_a.abs().max())
    torch.testing.assert_close(got_g, (ref_g * s).expand(*lead, 3, 2, 8), rtol=0, atol=1e-13)
    torch.testing.assert_close(got_a, (ref_a * s).expand(*lead, 3, 3, 8), rtol=0, atol=tol)
    assert not got_a[..., 1, :, :, :].any() and not got_g[..., 1, :, :, :].any()


@pytest.mark.parametrize("native_on", ["1", "0"])
def test_terms_rows_with_a_wider_batch_of_masks(monkeypatch, native_on):
    """Masks ``(2, N)`` over unbatched derivatives: the rows whitened after, per element."""
    from torch_dq.fitting import Accel, Gyro
    monkeypatch.setenv("TORCH_DQ_NATIVE", native_on)
    N = 6
    g = torch.Generator().manual_seed(5)
    t = torch.linspace(0.0, 1.0, N, dtype=F64)
    x, dx, ddx = torch.randn(N, 3, 8, dtype=F64, generator=g).unbind(-2)
    mask = torch.ones(2, N, dtype=torch.bool)
    mask[1, 2] = False
    sig = torch.tensor([0.1, 0.2, 0.4], dtype=F64)
    ref_g, ref_a = _reference(x, dx, ddx, torch.tensor([0.0, 0.0, -9.81], dtype=F64), (N,))
    w = mask[..., None].to(F64) / sig  # (2, N, 3)
    gyro = Gyro(t, torch.zeros(2, N, 3, dtype=F64), sigma=sig, bias=True, mask=mask)
    accel = Accel(t, torch.zeros(2, N, 3, dtype=F64), sigma=sig, bias=True, mask=mask,
                  gravity=torch.tensor([0.0, 0.0, -9.81], dtype=F64))
    p = {"bias": torch.zeros(2, 1, 3, dtype=F64),
         "gravity": torch.tensor([[0.0, 0.0, -9.81]], dtype=F64)}
    r = torch.zeros(2, N, 3, dtype=F64)
    rows_g = gyro.residual_jacobians([(x, dx)], p, ["bias"], r)[1][0]
    rows_a = accel.residual_jacobians([(x, dx, ddx)], p, ["bias"], r)[1][0]
    torch.testing.assert_close(rows_g, ref_g * w[..., None, None], rtol=0, atol=1e-12)
    torch.testing.assert_close(rows_a, ref_a * w[..., None, None], rtol=0,
                               atol=1e-12 * float(ref_a.abs().max()))


@pytest.mark.parametrize("native_on", ["1", "0"])
@pytest.mark.parametrize("lead", [(7,), (2, 5)])
def test_rows_written_into_a_groups_stacked_rows(monkeypatch, native_on, lead):
    """``out=``: views of one ``(6, 3, 8, *lead)`` buffer (gyro rows 0-2, orders 0-1; accel
    rows 3-5, orders 0-2), as the linearisation stacks a group's rows: the rows land there
    (returned as views of it), the rest of the buffer is left as it was."""
    if native_on == "1" and native.library() is None:
        pytest.skip("the compiled kernels are not built")
    monkeypatch.setenv("TORCH_DQ_NATIVE", native_on)
    g = torch.Generator().manual_seed(11)
    x, dx, ddx = torch.randn(*lead, 3, 8, dtype=F64, generator=g).unbind(-2)
    grav = torch.randn(3, dtype=F64, generator=g)
    scale = torch.rand(*lead, 3, dtype=F64, generator=g) + 0.5
    buf = torch.full((6, 3, 8, *lead), float("nan"), dtype=F64)
    stacked = buf.movedim((0, 1, 2), (-3, -2, -1))  # (*lead, 6, 3, 8)
    got_g = gyro_rows(x, dx, scale, out=stacked[..., :3, :, :])
    got_a = accel_rows(x, dx, ddx, grav, scale, out=stacked[..., 3:, :, :])[0]
    assert got_g.data_ptr() == buf.data_ptr() and got_a.data_ptr() == buf[3].data_ptr()
    ref_g, ref_a = _reference(x, dx, ddx, grav, lead)
    s = scale[..., None, None]
    torch.testing.assert_close(stacked[..., :3, :2, :], ref_g * s, rtol=0, atol=1e-13)
    torch.testing.assert_close(stacked[..., 3:, :, :], ref_a * s, rtol=0,
                               atol=1e-12 * float(ref_a.abs().max()))
    assert torch.isnan(buf[:3, 2]).all()  # the gyro's absent order: not written
    # an out of another layout is not written: the rows come in an array of their own
    other = torch.zeros(*lead, 3, 2, 8, dtype=F64)
    rows = gyro_rows(x, dx, scale, out=other)
    assert not other.any() and rows.data_ptr() != other.data_ptr()
    torch.testing.assert_close(rows, ref_g * s, rtol=0, atol=1e-13)

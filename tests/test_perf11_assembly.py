"""Session 11's assembly changes: the windows' normal matrices against numpy sums, a term's
nuisance columns with and without per-window selection, the residuals a trial's cost kept
(not evaluated again by the IMU terms' closed forms) and the Jacobian rows' component-major
layout (the span's vector-Jacobian products read them without a transpose)."""

import numpy as np
import pytest
import torch
from test_shared_spans import FIELDS, _job

from torch_dq.fitting import Accel, Gyro, _linearize
from torch_dq.fitting._imu_jacobians import accel_rows, gyro_rows
from torch_dq.fitting._linearize import Memo, _stacked, _window_normal

F64 = torch.float64


@pytest.mark.parametrize("shuffle", [False, True])
def test_window_normal_sums_each_windows_outer_products(shuffle):
    """Per window key, the sum of ``Y_i^T Y_i`` over its samples (numpy loop), with uneven
    counts (pages with padding), unsorted keys and a window used once."""
    rng = np.random.default_rng(0)
    keys = np.sort(np.concatenate([np.full(c, k) for k, c in
                                   zip([0, 3, 4, 9, 12], [7, 1, 12, 5, 9], strict=True)]))
    if shuffle:
        keys = rng.permutation(keys)
    Y = rng.standard_normal((keys.size, 3, 5))
    win, block = _window_normal(torch.from_numpy(keys), torch.from_numpy(Y))
    ref = {k: sum(Y[i].T @ Y[i] for i in np.flatnonzero(keys == k)) for k in np.unique(keys)}
    assert win.tolist() == sorted(ref)
    for k, b in zip(win.tolist(), block.numpy(), strict=True):
        np.testing.assert_allclose(b, ref[k], rtol=1e-13, atol=1e-13)


def test_window_normal_of_no_samples():
    win, block = _window_normal(torch.zeros(0, dtype=torch.int64), torch.zeros(0, 2, 4))
    assert win.numel() == 0 and block.shape == (0, 4, 4)


def test_stacked_rows_pad_and_are_component_major():
    """A group's rows stacked: each term's orders in place, the orders it does not read zero,
    the memory component-major (rows, orders, components, samples)."""
    g = torch.randn(5, 3, 2, 8, dtype=F64)
    a = torch.randn(5, 2, 3, 8, dtype=F64)
    out = _stacked([g, a], 3)
    assert out.shape == (5, 5, 3, 8)
    assert torch.equal(out[:, :3, :2], g) and torch.equal(out[:, 3:], a)
    assert not out[:, :3, 2].any()
    assert out.stride(0) == 1 and out.permute(1, 2, 3, 0).is_contiguous()


def test_imu_rows_are_component_major():
    """``gyro_rows`` and ``accel_rows`` return component-major views (sample stride 1)."""
    x, dx, ddx = (torch.randn(7, 8, dtype=F64) for _ in range(3))
    assert gyro_rows(x, dx).stride(0) == 1
    rows, _ = accel_rows(x, dx, ddx, torch.tensor([0.0, 0.0, -9.81], dtype=F64))
    assert rows.stride(0) == 1 and rows.shape == (7, 3, 3, 8)


def test_the_system_takes_the_trial_costs_residuals(monkeypatch):
    """Built from a memo, the system's IMU rows use the residuals the cost kept (the IMU
    terms' residual code runs for the cost alone) and equal a fresh system's to the bit."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    fresh = problem.system(ctrl, values, w)
    memo = Memo()
    problem.data_cost(ctrl, values, memo)
    assert sorted(memo.residuals) == sorted(memo.entries)
    calls = {"n": 0}
    for cls in (Gyro, Accel):
        inner = cls._residual

        def counted(self, *a, _inner=inner):
            calls["n"] += 1
            return _inner(self, *a)
        monkeypatch.setattr(cls, "_residual", counted)
    kept = problem.system(ctrl, values, w, memo)
    assert calls["n"] == 0 and not memo.entries and not memo.residuals
    for field in FIELDS:
        assert torch.equal(getattr(kept, field), getattr(fresh, field))
    for a, b in zip(kept.residuals, fresh.residuals, strict=True):
        assert torch.equal(a, b)


def test_memo_over_budget_keeps_nothing(monkeypatch):
    """A memo without room keeps neither derivatives nor residuals; the system is then
    evaluated afresh, the same."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    monkeypatch.setattr(_linearize, "MEMO_BYTES", 0)
    memo = Memo()
    problem.data_cost(ctrl, values, memo)
    assert not memo.entries and not memo.residuals
    a, b = problem.system(ctrl, values, w, memo), problem.system(ctrl, values, w)
    for field in FIELDS:
        assert torch.equal(getattr(a, field), getattr(b, field))


def test_rows_place_the_nuisance_columns_with_and_without_selection():
    """The whitened rows ``[J_c | J_n | r]`` times the square-rooted weights: all the term's
    columns in order (no selection), and per-window selected columns (reversed, the last
    one padding), against numpy."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    lin = problem.linearization
    r, _, Jc, Jn = lin._chained(1, problem.terms[1], ctrl, values, w)
    S, k = r.shape
    wt = torch.rand(S, dtype=F64, generator=torch.Generator().manual_seed(1))
    sw = wt.sqrt().numpy()[:, None, None]
    J = np.concatenate([x.numpy() for x in Jn.values()], -1)  # (S, k, 3)
    jc = Jc.reshape(S, k, 6 * w).numpy()
    plain = lin._rows(slice(0, S), r, wt, Jc, Jn, w, None)[0].numpy()
    ref = np.concatenate([jc, J, r.numpy()[..., None]], -1) * sw
    np.testing.assert_array_equal(plain, ref)
    local = torch.tensor([2, 1, 0]).expand(1, S, 3)
    valid = torch.tensor([True, True, False]).expand(1, S, 3)
    picked = lin._rows(slice(0, S), r, wt, Jc, Jn, w, (local, valid))[0].numpy()
    sel = J[..., [2, 1, 0]] * np.array([1.0, 1.0, 0.0])
    ref = np.concatenate([jc, sel, r.numpy()[..., None]], -1) * sw
    np.testing.assert_array_equal(picked, ref)

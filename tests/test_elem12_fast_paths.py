"""Fast paths of the elementary ops (elem12) against independent references.

- ``canonical`` skips its search for the first non-zero component where no ``w`` is zero;
  ``quat.log`` / ``to_rotvec`` skip the negative-real-axis branch where no row is on it:
  scipy's canonical rotation vectors and numpy's logarithm, on batches that take either
  path (a zero ``w``, ``-0.0``, the smallest subnormal ``w``, a row on the axis added).
- ``_numerics.even`` evaluates its series on the few elements below the switch alone (no
  reverse mode, from ``_FEW_MIN`` elements): scipy's ``from_rotvec`` and numpy's ``cos`` /
  ``sinc`` on both sides of the switch, the size and count boundaries of that path,
  non-finite rows, and forward-mode tangents against finite differences of scipy.
- ``lift`` / ``lower``: float16 and bfloat16 are still computed in float32 and cast back.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.autograd.forward_ad as fwad
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import _numerics, quat

F64 = torch.float64


def _unit(n, seed):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=F64)
    return q / q.norm(dim=-1, keepdim=True)


def _scipy_rotvec(q):
    """scipy's rotation vectors of ``(w, x, y, z)`` rows (canonical: angle in [0, pi])."""
    return Rotation.from_quat(q.numpy()[:, [1, 2, 3, 0]]).as_rotvec()


def _numpy_log(q):
    a = q.numpy()
    s = np.hypot(np.hypot(a[:, 1], a[:, 2]), a[:, 3])  # no square underflows
    n = np.hypot(a[:, 0], s)
    theta = np.arctan2(s, a[:, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        vec = a[:, 1:] * np.where(s > 0, theta / np.where(s > 0, s, 1.0), 0.0)[:, None]
    return np.concatenate((np.log(n)[:, None], vec), -1)


EDGE_W = {"zero": 0.0, "negative zero": -0.0, "subnormal": 5e-324, "-subnormal": -5e-324}


@pytest.mark.parametrize("edge", list(EDGE_W))
def test_to_rotvec_canonical_paths_match_scipy(edge):
    """A batch whose w are all non-zero (no search) and the same batch with one row whose
    w is zero, -0.0 or subnormal (the search, or not): scipy's canonical vectors."""
    q = _unit(500, 0)
    q[::7] *= -1.0  # w < 0: flipped
    fast = quat.to_rotvec(q)
    np.testing.assert_allclose(fast.numpy(), _scipy_rotvec(q), rtol=0, atol=1e-14)
    row = torch.tensor([[EDGE_W[edge], 0.0, -0.6, 0.8]], dtype=F64)
    both = quat.to_rotvec(torch.cat((q, row)))
    np.testing.assert_allclose(both.numpy(), np.concatenate((_scipy_rotvec(q), _scipy_rotvec(
        row))), rtol=0, atol=1e-14)
    # 180 degrees about (0, -0.6, 0.8): scipy's sign makes the first non-zero (y) positive
    # for w = 0 and -0.0; a subnormal w keeps its own sign.
    expect = {"zero": 1, "negative zero": 1, "subnormal": -1, "-subnormal": 1}[edge]
    assert np.sign(both[-1, 1].item()) == expect
    assert torch.equal(both[:-1], fast)


def test_to_rotvec_gradient_matches_finite_differences_on_both_paths():
    q = _unit(40, 1)
    q[::3] *= -1.0
    for batch in (q, torch.cat((q, torch.tensor([[0.0, 0.0, 1.0, 0.0]], dtype=F64)))):
        x = batch.clone().requires_grad_(True)
        w = torch.linspace(-1, 1, 3 * x.shape[0], dtype=F64).reshape(-1, 3)
        (g,) = torch.autograd.grad((quat.to_rotvec(x) * w).sum(), x)
        h = 1e-6
        for k in range(4):
            e = torch.zeros(4, dtype=F64)
            e[k] = h
            fd = (_scipy_rotvec(q + e) - _scipy_rotvec(q - e)) / (2 * h)
            np.testing.assert_allclose(g[: q.shape[0], k].numpy(), (fd * w[: q.shape[0]].numpy()
                                                                    ).sum(-1), atol=1e-7)


def test_log_negative_real_axis_branch_only_where_a_row_is_on_it():
    q = _unit(300, 2) * 3.0
    ref = _numpy_log(q)
    np.testing.assert_allclose(quat.log(q).numpy(), ref, rtol=0, atol=1e-14)
    axis = torch.tensor([[-2.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [-1.0, 1e-170, 0.0, 0.0]],
                        dtype=F64)
    out = quat.log(torch.cat((q, axis)))
    np.testing.assert_allclose(out[:300].numpy(), ref, rtol=0, atol=1e-14)
    # log(-2) = (log 2, pi, 0, 0) (direction x by convention); log 0 = (-inf, 0, 0, 0); a
    # vector part whose square underflows lies on the axis too: (0, pi, 0, 0) (hypot).
    np.testing.assert_allclose(out[300].numpy(), [math.log(2.0), math.pi, 0.0, 0.0], atol=1e-15)
    assert out[301, 0].item() == -math.inf and torch.equal(out[301, 1:], torch.zeros(3, dtype=F64))
    np.testing.assert_allclose(out[302].numpy(), _numpy_log(axis[2:]).ravel(), atol=1e-15)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_rows_stay_nan_in_their_own_row(bad):
    q = _unit(64, 3)
    q[5, 2] = bad
    for fn, ref in ((quat.to_rotvec, _scipy_rotvec), (quat.log, _numpy_log)):
        out = fn(q)
        assert torch.isnan(out[5, -3:]).all()  # log's real part: log|q| (inf for an inf q)
        keep = torch.arange(64) != 5
        np.testing.assert_allclose(out[keep].numpy(), ref(q[keep]), rtol=0, atol=1e-14)


def _switch(name, dtype=F64):
    return _numerics.threshold("even_series", dtype, _numerics._EVEN[name][0][-1])


def _rotvecs(n, seed, few_small):
    """``n`` rotation vectors with angles in (1, 3) rad and ``few_small`` of them with the
    half-angle's square just below, at and just above cos's and sinc's switches."""
    g = torch.Generator().manual_seed(seed)
    axis = torch.randn(n, 3, generator=g, dtype=F64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = 1.0 + 2.0 * torch.rand(n, generator=g, dtype=F64)
    edges = [s * f for s in (_switch("cos"), _switch("sinc"))
             for f in (1 - 1e-12, 1.0, 1 + 1e-12, 0.5, 1e-3, 0.0)]
    half = torch.tensor(edges, dtype=F64).sqrt()
    k = min(few_small, n)
    angle[:k] = (2.0 * half).repeat(k // len(edges) + 1)[:k]
    return axis * angle[:, None]


def _scipy_quat(rv):
    a = Rotation.from_rotvec(rv.numpy()).as_quat(canonical=False)
    return a[:, [3, 0, 1, 2]]


@pytest.mark.parametrize("n, few", [(_numerics._FEW_MIN - 1, 50), (_numerics._FEW_MIN, 50),
                                    (40000, 40000 // 4 - 1), (40000, 40000 // 4), (40000, 0)])
def test_from_rotvec_series_on_few_elements_matches_scipy(n, few):
    """Below and at the size from which the series runs on the few small elements, and a
    count of small elements just below and at a quarter: scipy, and the bits of the same
    rows through reverse mode (every element through both branches, selected)."""
    rv = _rotvecs(n, 4, few)
    with torch.no_grad():
        out = quat.from_rotvec(rv)
    np.testing.assert_allclose(out.numpy(), _scipy_quat(rv), rtol=0, atol=4e-16)
    x = rv.clone().requires_grad_(True)
    assert torch.equal(quat.from_rotvec(x).detach(), out)


def test_even_series_on_few_elements_matches_numpy_at_the_switch():
    x2 = _rotvecs(30000, 5, 60).pow(2).sum(-1) / 4.0
    assert 0 < int((x2 < _switch("cos")).sum()) < x2.numel() // 4
    th = np.sqrt(x2.numpy())
    np.testing.assert_allclose(_numerics.even("cos", x2).numpy(), np.cos(th), rtol=0,
                               atol=4e-16)
    np.testing.assert_allclose(_numerics.even("sinc", x2).numpy(), np.sinc(th / np.pi), rtol=0,
                               atol=4e-16)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_from_rotvec_non_finite_row_in_a_large_batch(bad):
    rv = _rotvecs(20000, 6, 40)
    rv[7, 1] = bad
    with torch.no_grad():
        out = quat.from_rotvec(rv)
    assert torch.isnan(out[7]).all()
    keep = torch.arange(20000) != 7
    np.testing.assert_allclose(out[keep].numpy(), _scipy_quat(rv[keep]), rtol=0, atol=4e-16)


def test_forward_mode_tangents_on_the_few_elements_path():
    """Forward mode (no reverse graph: the series on the few elements) against central
    finite differences of scipy."""
    rv = _rotvecs(20000, 7, 40)
    tangent = torch.randn(rv.shape, generator=torch.Generator().manual_seed(8), dtype=F64)
    with fwad.dual_level():
        t = fwad.unpack_dual(quat.from_rotvec(fwad.make_dual(rv, tangent))).tangent
    h = 1e-6
    fd = (_scipy_quat(rv + h * tangent) - _scipy_quat(rv - h * tangent)) / (2 * h)
    np.testing.assert_allclose(t.numpy(), fd, rtol=0, atol=1e-8)


def test_dualquat_exp_log_large_batches_match_numpy():
    """dualquat.exp (four even functions) and log on 20000 twists, most far from the
    identity and a few near it: the rotation against scipy, the translation against the
    closed form of SE(3)'s V(omega) in numpy."""
    omega = _rotvecs(20000, 9, 40)
    v = torch.randn(20000, 3, generator=torch.Generator().manual_seed(10), dtype=F64)
    with torch.no_grad():
        x = dq.exp(torch.cat((omega, v), -1))
        back = dq.log(x)
    q, t = dq.to_rt(x)
    np.testing.assert_allclose(q.numpy(), _scipy_quat(omega), rtol=0, atol=4e-16)
    o, vv = omega.numpy(), v.numpy()
    th = np.linalg.norm(o, axis=-1, keepdims=True)
    small = th < 1e-3
    ths = np.where(small, 1.0, th)
    c1 = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(ths)) / ths**2)
    c2 = np.where(small, 1 / 6 - th**2 / 120, (ths - np.sin(ths)) / ths**3)
    wxv = np.cross(o, vv)
    np.testing.assert_allclose(t.numpy(), vv + c1 * wxv + c2 * np.cross(o, wxv), rtol=0,
                               atol=1e-13)
    # every angle below pi: the log gives the twist back
    np.testing.assert_allclose(back.numpy(), np.concatenate((o, vv), -1), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16, torch.float32])
def test_low_precision_still_computed_in_float32_and_cast_back(dtype):
    q = _unit(50, 11)
    x = q.to(dtype)
    ref = Rotation.from_quat(x.double().numpy()[:, [1, 2, 3, 0]])
    tol = {torch.float16: 2e-3, torch.bfloat16: 1.6e-2, torch.float32: 1e-6}[dtype]
    for out, expect in ((quat.to_matrix(x), ref.as_matrix()), (quat.to_rotvec(x), ref.as_rotvec()),
                        (quat.normalize(x), x.double().numpy() / np.linalg.norm(
                            x.double().numpy(), axis=-1, keepdims=True))):
        assert out.dtype == dtype
        np.testing.assert_allclose(out.double().numpy(), expect, rtol=0, atol=tol)

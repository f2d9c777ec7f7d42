"""The fast forms of the elementary ops (perf8): vector-form Hamilton product, canonical sign
by one argmax, ``quat.to_matrix`` from one outer product, ``quat.normalize``'s single mask,
``from_rotvec`` / ``to_rotvec`` without the unused real part. References: scipy,
pytransform3d and numpy formulas written here; both sides of every branch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq._core import canonical, qmul

SHAPES = [(), (1,), (5,), (2, 5), (3, 1, 5)]


def _np_hamilton(a, b):
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack((aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw), -1)


@pytest.mark.parametrize("shape", SHAPES)
def test_mul_matches_the_component_formula(shape):
    g = torch.Generator().manual_seed(0)
    a = torch.randn(*shape, 4, generator=g, dtype=torch.float64)
    b = torch.randn(*shape[-1:], 4, generator=g, dtype=torch.float64)  # broadcast
    ref = _np_hamilton(a.numpy(), np.broadcast_to(b.numpy(), a.shape))
    np.testing.assert_allclose(quat.mul(a, b).numpy(), ref, rtol=0, atol=1e-15)


def test_mul_float32_error_and_ij_k():
    g = torch.Generator().manual_seed(1)
    a, b = torch.randn(1000, 4, generator=g), torch.randn(1000, 4, generator=g)
    ref = _np_hamilton(a.double().numpy(), b.double().numpy())
    err = np.abs(quat.mul(a, b).double().numpy() - ref).max()
    assert err < 2e-6  # measured ~6e-7 (components up to ~10)
    i, j = torch.tensor([0.0, 1, 0, 0]), torch.tensor([0.0, 0, 1, 0])
    assert torch.equal(qmul(i, j), torch.tensor([0.0, 0, 0, 1]))


def test_mul_non_finite_stays_in_its_row():
    a = torch.tensor([[float("inf"), 0, 0, 0], [1.0, 0, 0, 0]])
    out = quat.mul(a, torch.tensor([1.0, 2, 3, 4]))
    assert not torch.isfinite(out[0]).all() and torch.equal(out[1], torch.tensor([1.0, 2, 3, 4]))


@pytest.mark.parametrize("point", ["generic", "zero", "identity"])
def test_mul_gradgradcheck(point):
    g = torch.Generator().manual_seed(2)
    a = torch.randn(3, 4, generator=g, dtype=torch.float64)
    b = torch.randn(3, 4, generator=g, dtype=torch.float64)
    if point == "zero":
        a = torch.zeros_like(a)
    elif point == "identity":
        a = quat.identity((3,), dtype=torch.float64)
    a.requires_grad_(), b.requires_grad_()
    assert torch.autograd.gradcheck(quat.mul, (a, b))
    assert torch.autograd.gradgradcheck(quat.mul, (a, b))


def test_dq_mul_matches_pytransform3d():
    ptr = pytest.importorskip("pytransform3d.trajectories")
    g = torch.Generator().manual_seed(3)
    x = dq.from_rt(quat.normalize(torch.randn(50, 4, generator=g, dtype=torch.float64)),
                   torch.randn(50, 3, generator=g, dtype=torch.float64))
    y = dq.from_rt(quat.normalize(torch.randn(50, 4, generator=g, dtype=torch.float64)),
                   torch.zeros(50, 3, dtype=torch.float64))  # zero translations
    ref = ptr.batch_concatenate_dual_quaternions(x.numpy(), y.numpy())
    np.testing.assert_allclose(dq.mul(x, y).numpy(), ref, rtol=0, atol=1e-14)


def _np_canonical(q):
    out = q.copy()
    for row in out.reshape(-1, 4):
        for c in row:
            if np.isnan(c) or c > 0:
                break
            if c < 0:
                row *= -1
                break
    return out


def test_canonical_every_branch():
    nan, z = float("nan"), -0.0
    q = torch.tensor([
        [1.0, -2, 3, 4], [-1.0, 2, 3, 4],      # decided by w
        [0.0, -1, 2, 3], [z, 1, -2, 3],         # by x (w = +-0)
        [0.0, 0, -1, 2], [0.0, z, 1, -2],       # by y
        [0.0, 0, 0, -1], [z, z, z, 1],          # by z
        [0.0, 0, 0, 0], [z, z, z, z],           # all zero: unchanged
        [nan, -1, 0, 0], [0.0, nan, -1, 0],     # a NaN stops the search: no flip
    ], dtype=torch.float64)
    got = canonical(q)
    ref = _np_canonical(q.numpy())
    np.testing.assert_array_equal(got.numpy(), ref)
    assert torch.equal(torch.signbit(got[~got.isnan()]),
                       torch.signbit(torch.from_numpy(ref)[~got.isnan()]))


def test_to_rotvec_at_half_turns_matches_scipy():
    q = torch.tensor([[0.0, -1, 0, 0], [0.0, 0, -1, 0], [0.0, 0, 0, -1], [0.0, 0, -0.6, 0.8],
                      [-0.0, -0.6, 0.8, 0], [1e-9, -1, 0, 0], [-1e-9, 1, 0, 0]],
                     dtype=torch.float64)
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy()).as_rotvec()
    np.testing.assert_allclose(quat.to_rotvec(q).numpy(), ref, rtol=0, atol=1e-12)


@pytest.mark.parametrize("scale", [1.0, 1e-30, 1e30, 3.7])
def test_to_matrix_matches_scipy(scale):
    g = torch.Generator().manual_seed(4)
    q = torch.randn(200, 4, generator=g, dtype=torch.float64)
    q[:4] = torch.tensor([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1], [1, 1e-9, 0, 0]])
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy()).as_matrix()
    np.testing.assert_allclose(quat.to_matrix(q * scale).numpy(), ref, rtol=0, atol=1e-15)
    f32 = (quat.to_matrix((q * scale).float()).double().numpy() - ref)
    if scale in (1.0, 3.7) or np.isfinite(f32).all():
        assert np.abs(f32).max() < 1e-6  # measured ~4e-7


def test_to_matrix_bad_rows_and_shapes():
    q = torch.tensor([[0.0, 0, 0, 0], [float("inf"), 0, 0, 0], [float("nan"), 0, 0, 0],
                      [0.0, 0, 0, 2]])
    R = quat.to_matrix(q)
    assert R[:3].isnan().all()
    assert torch.equal(R[3], torch.diag(torch.tensor([-1.0, -1, 1])))
    for shape in SHAPES:
        assert quat.to_matrix(torch.randn(*shape, 4)).shape == (*shape, 3, 3)
    assert quat.to_matrix(torch.randn(4, dtype=torch.float16)).dtype == torch.float16


@pytest.mark.parametrize("point", ["generic", "identity", "half_turn"])
def test_to_matrix_gradgradcheck(point):
    q = {"generic": torch.tensor([0.3, -0.5, 0.7, 0.2]), "identity": torch.tensor([1.0, 0, 0, 0]),
         "half_turn": torch.tensor([0.0, 0, 0.6, 0.8])}[point].double().requires_grad_()
    assert torch.autograd.gradcheck(quat.to_matrix, (q,))
    assert torch.autograd.gradgradcheck(quat.to_matrix, (q,))


def test_normalize_rows_and_check():
    q = torch.tensor([[0.0, 0, 0, 0], [float("inf"), 1, 0, 0], [3.0, 0, 4, 0],
                      [1e-30, 0, 1e-30, 0]])
    out = quat.normalize(q)
    assert out[:2].isnan().all()
    np.testing.assert_allclose(out[2:].numpy(), [[0.6, 0, 0.8, 0], [2 ** -0.5, 0, 2 ** -0.5, 0]],
                               rtol=1e-6)
    for bad in (q[:1], q[1:2]):
        with pytest.raises(ValueError, match=r"quat\.normalize"):
            quat.normalize(bad, check=True)
    assert torch.equal(quat.normalize(q[2:], check=True), out[2:])
    g = torch.Generator().manual_seed(5)
    r = torch.randn(100, 4, generator=g, dtype=torch.float64)
    ref = r.numpy() / np.linalg.norm(r.numpy(), axis=-1, keepdims=True)
    np.testing.assert_allclose(quat.normalize(r).numpy(), ref, rtol=0, atol=1e-16)


def test_from_rotvec_matches_scipy_and_is_smooth_at_zero():
    g = torch.Generator().manual_seed(6)
    rv = torch.randn(100, 3, generator=g, dtype=torch.float64)
    rv[0], rv[1], rv[2] = 0.0, 1e-9, torch.tensor([np.pi, 0, 0])
    ref = Rotation.from_rotvec(rv.numpy()).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(quat.from_rotvec(rv).numpy(), ref, rtol=0, atol=1e-15)
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    H = torch.autograd.functional.hessian(lambda v: quat.from_rotvec(v)[0], z)
    np.testing.assert_allclose(H.numpy(), -np.eye(3) / 4, atol=1e-15)
    assert torch.autograd.gradgradcheck(quat.from_rotvec, (z,))


def test_to_rotvec_matches_scipy_and_gradgradcheck():
    g = torch.Generator().manual_seed(7)
    q = torch.randn(100, 4, generator=g, dtype=torch.float64)
    q[0] = torch.tensor([1.0, 1e-9, 0, 0])
    ref = Rotation.from_quat(q[:, [1, 2, 3, 0]].numpy()).as_rotvec()
    np.testing.assert_allclose(quat.to_rotvec(q).numpy(), ref, rtol=0, atol=1e-14)
    for p in (torch.tensor([1.0, 0, 0, 0]), torch.tensor([0.4, -0.1, 0.2, 0.3])):
        p = p.double().requires_grad_()
        assert torch.autograd.gradgradcheck(quat.to_rotvec, (p,))


@pytest.mark.parametrize("n", [1, 7, 65537])  # 65537: more than one chunk (the Function)
@pytest.mark.parametrize("grad", [False, True])
def test_slerp_small_batch_path_matches_scipy_and_the_function(n, grad):
    g = torch.Generator().manual_seed(8)
    q0 = quat.normalize(torch.randn(n, 4, generator=g, dtype=torch.float64))
    q1 = quat.normalize(torch.randn(n, 4, generator=g, dtype=torch.float64))
    t = torch.rand(n, generator=g, dtype=torch.float64)
    q1[0] = -q0[0]  # opposite: the shortest path is constant
    out = quat.slerp(*(x.clone().requires_grad_(grad) for x in (q0, q1, t)))
    with torch.enable_grad():
        ref_fn = quat.slerp(q0.clone().requires_grad_(), q1, t)  # always the Function
    assert torch.equal(out.detach(), ref_fn.detach())
    k = min(n, 500)
    r0 = Rotation.from_quat(q0[:k, [1, 2, 3, 0]].numpy())
    r1 = Rotation.from_quat(q1[:k, [1, 2, 3, 0]].numpy())
    ref = (r0 * Rotation.from_rotvec(t[:k, None].numpy() * (r0.inv() * r1).as_rotvec())).as_quat()
    got = out.detach()[:k].numpy()
    got = got * np.sign((got * ref[:, [3, 0, 1, 2]]).sum(-1, keepdims=True))
    np.testing.assert_allclose(got, ref[:, [3, 0, 1, 2]], rtol=0, atol=1e-13)

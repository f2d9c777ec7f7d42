"""torch_dq.dualquat: algebra, conversions and actions (angle, sclerp, dlb: test_interp.py).

pytransform3d stores dual quaternions in our layout ``(rw, rx, ry, rz, dw, dx, dy, dz)``,
so its functions are direct references. Every comparison runs in float64 over random poses
and the adversarial set of ``strategies.adversarial_dqs`` (identity, pure translations, half
turns about axes and diagonals, rotations of 1e-9 and 1e-6 and half turns missed by them,
combined with translations up to 2e3) and states its maximum error. Errors of quantities
that carry a translation are divided by ``max(1, |t|)`` per pose ("relative to the
translation scale"); dual quaternions are compared up to sign where both signs are the same
transform.
"""

import math

import numpy as np
import pytest
import pytransform3d.trajectories as ptr
import pytransform3d.transformations as pt
import torch
from hypothesis import given
from hypothesis import strategies as st
from strategies import adversarial_dqs, dual_quats, gradcheck_at, grads, quats, unit_dq, unit_quat

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.dual import Dual

F64 = torch.float64
# float32 against float64 on the same (rounded) unit-scale inputs, see test_float32_accuracy.
F32_TOL = 3e-6


# ----------------------------------------------------------------------------- helpers

def scale(x):
    """``max(1, |t|)`` per pose, ``(N,)``."""
    return dq.to_rt(x)[1].norm(dim=-1).clamp_min(1.0)


def rel_err(a, b, s):
    """Max over rows of ``max|a - b| / s`` (rows = first dim)."""
    diff = (a - b).abs().reshape(a.shape[0], -1).max(-1).values
    return (diff / s).max().item()


def align(x, ref):
    """``x`` with each row's sign flipped to agree with ``ref`` (same transform)."""
    return torch.where((x * ref).sum(-1, keepdim=True) < 0, -x, x)


def rows(f, *arrays):
    """Apply a single-pose pytransform3d function row by row; stack as a float64 tensor."""
    out = [f(*(a.numpy() for a in args)) for args in zip(*arrays, strict=True)]
    return torch.from_numpy(np.stack(out))


def pt_matrix(x):
    return rows(pt.transform_from_dual_quaternion, x)


@pytest.fixture
def poses(gen):
    """300 random poses (translations of scale 1 and 100) and the adversarial set, (N, 8)."""
    return torch.cat((unit_dq((150,), gen), unit_dq((150,), gen, scale=100.0), adversarial_dqs()))


def twists(gen):
    """Random twists and the singular ones: zero, pure translations (omega = 0), half turns,
    angles pi - 1e-9, pi - 1e-6 and 1e-9 with translations up to 1e3. ``(N, 6)``."""
    axis = torch.tensor([[1.0, 0, 0], [0, 0, 1], [1, 1, 1], [-1, 2, 3]], dtype=F64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    v = torch.tensor([[0.0, 0, 0], [1, -2, 0.5], [1e3, 0, -2e3]], dtype=F64)
    angles = torch.tensor([0.0, 1e-9, 1.0, math.pi - 1e-6, math.pi - 1e-9, math.pi], dtype=F64)
    omega = (axis[:, None] * angles[:, None]).reshape(-1, 3)
    special = torch.cat((omega[:, None].expand(-1, 3, 3), v[None].expand(omega.shape[0], -1, 3)),
                        dim=-1).reshape(-1, 6)
    rv = torch.randn(200, 3, generator=gen, dtype=F64)
    rv = rv / rv.norm(dim=-1, keepdim=True) * torch.rand(200, 1, generator=gen, dtype=F64) * 3.1
    rand = torch.cat((rv, torch.randn(200, 3, generator=gen, dtype=F64) * 5), dim=-1)
    return torch.cat((special, rand))


# ----------------------------------------------------------------- agreement with pytransform3d

def test_to_matrix_matches_pytransform3d(poses):
    T, s = dq.to_matrix(poses), scale(poses)
    assert rel_err(T, pt_matrix(poses), s) < 2e-15  # measured 6.8e-16
    assert rel_err(T, torch.from_numpy(ptr.transforms_from_dual_quaternions(poses.numpy())),
                   s) < 2e-15
    assert torch.equal(T[:, 3], poses.new_tensor([0.0, 0, 0, 1]).expand(len(poses), 4))
    assert torch.equal(dq.to_matrix(-poses), T)  # x and -x: the same matrix, bitwise


def test_from_matrix_matches_pytransform3d(poses):
    T, s = dq.to_matrix(poses), scale(poses)
    x = dq.from_matrix(T)
    assert (x[:, 0] >= 0).all()
    assert rel_err(align(x, poses), poses, s) < 1e-15  # round trip, measured 2.2e-16
    ref = rows(pt.dual_quaternion_from_transform, T)
    assert rel_err(align(x, ref), ref, s) < 1e-15  # measured 3.3e-16
    ref = torch.from_numpy(ptr.dual_quaternions_from_transforms(T.numpy()))
    assert rel_err(align(x, ref), ref, s) < 2e-15  # measured 3.3e-16
    # the bottom row is not read
    T2 = T.clone()
    T2[:, 3] = 7.0
    assert torch.equal(dq.from_matrix(T2), x)


def test_mul_matches_pytransform3d_and_matrix_product(poses, gen):
    a, b = poses, poses[torch.randperm(len(poses), generator=gen)]
    s = scale(a) + scale(b)
    ab = dq.mul(a, b)
    assert rel_err(ab, rows(pt.concatenate_dual_quaternions, a, b), s) < 1e-15  # 2.0e-16
    ref = torch.from_numpy(ptr.batch_concatenate_dual_quaternions(a.numpy(), b.numpy()))
    assert rel_err(ab, ref, s) < 1e-15
    assert rel_err(dq.to_matrix(ab), pt_matrix(a) @ pt_matrix(b), s) < 2e-15  # 9.6e-16


def test_apply_matches_matrix_and_pytransform3d(poses, gen):
    p = torch.randn(len(poses), 3, generator=gen, dtype=F64) * 3
    T, s = pt_matrix(poses), scale(poses)
    out = dq.apply(poses, p)
    assert rel_err(out, (T[:, :3, :3] @ p[..., None])[..., 0] + T[:, :3, 3], s) < 1e-14  # 3.6e-15
    assert rel_err(out, rows(pt.dq_prod_vector, poses, p), s) < 1e-14  # measured 3.6e-15


def test_apply_line_matches_two_transformed_points(poses, gen):
    n = len(poses)
    direction = torch.randn(n, 3, generator=gen, dtype=F64)
    direction = direction / direction.norm(dim=-1, keepdim=True)
    p = torch.randn(n, 3, generator=gen, dtype=F64) * 2
    moment = torch.linalg.cross(p, direction, dim=-1)
    l2, m2 = dq.apply_line(poses, direction, moment)
    T, s = pt_matrix(poses), scale(poses)
    p0 = (T[:, :3, :3] @ p[..., None])[..., 0] + T[:, :3, 3]
    p1 = (T[:, :3, :3] @ (p + direction)[..., None])[..., 0] + T[:, :3, 3]
    # p1 - p0 cancels the translation: its error scales with |t|
    assert rel_err(l2, p1 - p0, s) < 3e-15  # measured 1.3e-15
    assert (l2 - (T[:, :3, :3] @ direction[..., None])[..., 0]).abs().max() < 3e-15  # 8.9e-16
    assert rel_err(m2, torch.linalg.cross(p0, l2, dim=-1), s) < 2e-14  # measured 2.5e-15
    # any point of the moved line has the moved moment
    p2 = (T[:, :3, :3] @ (p - 3 * direction)[..., None])[..., 0] + T[:, :3, 3]
    assert rel_err(m2, torch.linalg.cross(p2, l2, dim=-1), s) < 5e-14


def test_to_screw_matches_pytransform3d(poses):
    """pytransform3d returns (point q, axis, pitch h, theta): our moment is q x axis and our
    d is h theta; a pure translation is h = inf and theta = |t| there, theta 0, d |t| here."""
    axis, moment, theta, d = dq.to_screw(poses)
    s = scale(poses)
    n_pure = 0
    for i, x in enumerate(poses):
        q, s_axis, h, th = pt.screw_parameters_from_dual_quaternion(x.numpy())
        if np.isinf(h):
            n_pure += 1
            ref = (s_axis, np.zeros(3), 0.0, th)
        else:
            ref = (s_axis, np.cross(q, s_axis), th, h * th)
        ref = [torch.as_tensor(r, dtype=F64) for r in ref]
        assert (axis[i] - ref[0]).abs().max() < 1e-15, i  # measured 2.2e-16
        # the moment is ill-conditioned, |t| / theta: relative error to max(1, |m|)
        assert ((moment[i] - ref[1]).abs().max() / ref[1].norm().clamp_min(1)) < 1e-14, i  # 9e-16
        assert abs(theta[i] - ref[2]) < 2e-15, i  # measured 8.9e-16
        assert abs(d[i] - ref[3]) / s[i] < 5e-15, i  # measured 6.6e-16
    assert n_pure == 8  # rotations 1 and -1 with each adversarial translation (incl. zero)
    assert ((theta >= 0) & (theta <= math.pi)).all()


def test_to_screw_pure_translation_convention():
    t = torch.tensor([[0.0, 3.0, 4.0], [0.0, 0.0, 0.0], [1e-300, 0.0, 0.0]], dtype=F64)
    x = dq.from_rt(quat.identity((3,), dtype=F64), t)
    axis, moment, theta, d = dq.to_screw(x)
    assert torch.equal(axis[0], t.new_tensor([0.0, 0.6, 0.8]))
    assert torch.equal(axis[1:], t.new_tensor([[1.0, 0, 0], [1.0, 0, 0]]))  # no direction
    assert torch.equal(moment, torch.zeros(3, 3, dtype=F64))
    assert torch.equal(theta, torch.zeros(3, dtype=F64))
    assert torch.equal(d[:2], t.new_tensor([5.0, 0.0]))
    # and from_screw inverts it
    assert (dq.from_screw(axis, moment, theta, d) - x).abs().max() < 1e-16


def test_from_screw_matches_pytransform3d(gen):
    n = 100
    point = torch.randn(n, 3, generator=gen, dtype=F64) * 3
    axis = torch.randn(n, 3, generator=gen, dtype=F64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    theta = (torch.rand(n, generator=gen, dtype=F64) * 2 - 1) * 7
    theta[:4] = torch.tensor([0.0, math.pi, 1e-9, -math.pi])
    pitch = torch.randn(n, generator=gen, dtype=F64)
    x = dq.from_screw(axis, torch.linalg.cross(point, axis, dim=-1), theta, pitch * theta)
    ref = torch.from_numpy(np.stack([
        pt.dual_quaternion_from_screw_parameters(q.numpy(), a.numpy(), h.item(), th.item())
        for q, a, h, th in zip(point, axis, pitch, theta, strict=True)]))
    # signs agree (theta as given); dual parts up to ~20: measured 1.8e-15
    assert (x - ref).abs().max() < 5e-15
    # pure translation: pytransform3d's h = inf with theta = d
    d = torch.randn(n, generator=gen, dtype=F64) * 10
    x = dq.from_screw(axis, torch.zeros_like(axis), 0.0, d)
    ref = torch.from_numpy(np.stack([
        pt.dual_quaternion_from_screw_parameters(np.zeros(3), a.numpy(), np.inf, dd.item())
        for a, dd in zip(axis, d, strict=True)]))
    assert (x - ref).abs().max() < 1e-15 * d.abs().max()
    assert (dq.to_rt(x)[1] - d[:, None] * axis).abs().max() < 1e-14
    # batch version of pytransform3d
    _, a, _, _ = ptr.screw_parameters_from_dual_quaternions(x.numpy())
    assert (torch.from_numpy(a) - axis * torch.sign(d)[:, None]).abs().max() < 1e-15


def test_log_matches_pytransform3d(poses, gen):
    xi = dq.log(poses)
    T, s = pt_matrix(poses), scale(poses)
    ref = rows(lambda m: pt.exponential_coordinates_from_transform(m, check=False), T)
    theta = xi[:, :3].norm(dim=-1)
    assert (theta <= math.pi + 1e-15).all()
    # the rotation part is the rotation vector (checked against scipy in test_quat.py)
    assert torch.equal(xi[:, :3], quat.to_rotvec(poses[:, :4]))
    # pytransform3d takes the axis from R - R^T, which loses digits as sin(theta) -> 0: within
    # 1e-6 of pi (its own threshold) it switches to sqrt((R + I) / 2) with errors up to 1.2e-10
    # relative (3.4e-14 outside). Our log is checked there by pytransform3d's exp below.
    near_pi = (ref[:, :3].norm(dim=-1) - math.pi).abs() < 1e-5
    assert rel_err(xi[~near_pi], ref[~near_pi], s[~near_pi]) < 1e-13  # measured 3.4e-14
    assert (theta[near_pi] - ref[near_pi, :3].norm(dim=-1)).abs().max() < 1e-14  # 8.9e-16
    # pytransform3d's exp of our log is the input matrix, at every pose
    back = rows(pt.transform_from_exponential_coordinates, xi)
    assert rel_err(back, T, s) < 2e-15  # measured 7.7e-16


def test_exp_matches_pytransform3d(gen):
    xi = twists(gen)
    x = dq.exp(xi)
    s = scale(x)
    ref = rows(pt.transform_from_exponential_coordinates, xi)
    assert rel_err(dq.to_matrix(x), ref, s) < 2e-15  # measured 6.1e-16
    # pytransform3d's batch version treats theta < ~1e-8 as omega = 0 (off by |v| theta / 2)
    # and loses digits to cancellation for small theta (1e-14 at theta = 5e-3): compare away
    # from tiny angles, with that tolerance
    big = xi[:, :3].norm(dim=-1) > 1e-6
    ref_b = torch.from_numpy(ptr.transforms_from_exponential_coordinates(xi[big].numpy()))
    assert rel_err(dq.to_matrix(x[big]), ref_b, s[big]) < 2e-14  # measured 5.9e-15
    # zero twist: identity, bitwise; pure translation (omega = 0): translation v, bitwise
    z = torch.zeros(6, dtype=F64)
    assert torch.equal(dq.exp(z), dq.identity(dtype=F64))
    v = torch.tensor([0.0, 0, 0, 1.0, -2.0, 3e3], dtype=F64)
    assert torch.equal(dq.to_rt(dq.exp(v))[1], v[3:])
    assert torch.equal(dq.log(dq.exp(v)), v)


def test_exp_matches_high_precision(gen):
    """Against mpmath's 4x4 matrix exponential (30 digits) of the se(3) element: the special
    twists (zero, omega = 0, 1e-9, pi - 1e-6, pi - 1e-9, pi; |v| up to 2.2e3) and 28 random."""
    mpmath = pytest.importorskip("mpmath")
    xi = twists(gen)[:100]
    T = dq.to_matrix(dq.exp(xi))
    with mpmath.workdps(30):
        ref = []
        for w in xi.tolist():
            M = mpmath.matrix([[0, -w[2], w[1], w[3]], [w[2], 0, -w[0], w[4]],
                               [-w[1], w[0], 0, w[5]], [0, 0, 0, 0]])
            E = mpmath.expm(M)
            ref.append([[float(E[i, j]) for j in range(4)] for i in range(4)])
    assert rel_err(T, torch.tensor(ref, dtype=F64), scale(dq.exp(xi))) < 1e-15  # 4.1e-16


def test_log_at_half_turns(gen):
    """At exactly 180 degrees both signs of omega are logs; ours is canonical and the same
    for x and -x (scipy's rotvec sign)."""
    q = torch.tensor([[0.0, 1, 0, 0], [0, -1, 0, 0], [0, 0, 0.6, -0.8], [0, 0, -0.6, 0.8]],
                     dtype=F64)
    t = torch.randn(4, 3, generator=gen, dtype=F64) * 10
    x = dq.from_rt(q, t)
    xi = dq.log(x)
    assert torch.equal(xi, dq.log(-x))
    assert torch.equal(xi[:, :3], quat.to_rotvec(q))
    assert rel_err(align(dq.exp(xi), x), x, scale(x)) < 1e-15
    assert (xi[:, :3].norm(dim=-1) - math.pi).abs().max() < 1e-15


def test_pose7_matches_pytransform3d_pq(poses):
    """pypose/ROS layout (t, qx, qy, qz, qw); pytransform3d's pq is (t, qw, qx, qy, qz)."""
    p7 = dq.to_pose7(poses)
    pq = torch.from_numpy(ptr.pqs_from_dual_quaternions(poses.numpy()))
    s = scale(poses)
    assert rel_err(p7[:, :3], pq[:, :3], s) < 1e-15  # measured 2.0e-16
    assert torch.equal(p7[:, [6, 3, 4, 5]], pq[:, 3:])
    assert torch.equal(p7[:, 3:], quat.to_xyzw(poses[:, :4]))
    x = dq.from_pose7(p7)
    assert rel_err(x, poses, s) < 1e-15  # round trip, measured 2.1e-16
    ref = torch.from_numpy(ptr.dual_quaternions_from_pqs(pq.numpy()))
    assert rel_err(dq.from_pose7(pq[:, [0, 1, 2, 4, 5, 6, 3]]), ref, s) < 1e-15
    assert rel_err(x, rows(pt.dual_quaternion_from_pq, pq), s) < 1e-15


def test_conjugates_match_formulas_and_pytransform3d(poses, gen):
    x = poses
    sign = {
        dq.conj: [1, -1, -1, -1, 1, -1, -1, -1],
        dq.conj_dual: [1, 1, 1, 1, -1, -1, -1, -1],
        dq.conj_full: [1, -1, -1, -1, -1, 1, 1, 1],
    }
    for f, sg in sign.items():
        assert torch.equal(f(x), x * x.new_tensor(sg))
        assert torch.equal(f(f(x)), x)
    s = scale(x)
    # pytransform3d renormalises by |r| first: equal to rounding relative to |t|
    assert rel_err(dq.conj(x), rows(pt.dq_q_conj, x), s) < 1e-15  # measured 1.7e-16
    assert rel_err(dq.conj_full(x), rows(pt.dq_conj, x), s) < 1e-15
    # conj and conj_full reverse products, conj_dual keeps their order
    y = x[torch.randperm(len(x), generator=gen)]
    s2 = s + scale(y)
    assert rel_err(dq.conj(dq.mul(x, y)), dq.mul(dq.conj(y), dq.conj(x)), s2) < 1e-15
    assert rel_err(dq.conj_full(dq.mul(x, y)), dq.mul(dq.conj_full(y), dq.conj_full(x)), s2) < 1e-15
    assert rel_err(dq.conj_dual(dq.mul(x, y)), dq.mul(dq.conj_dual(x), dq.conj_dual(y)), s2) < 1e-15
    # a point (1, 0, 0, 0, 0, p) maps to x p conj_full(x), as in the paper and pytransform3d
    p = torch.randn(len(x), 3, generator=gen, dtype=F64)
    pdq = torch.cat((dq.identity((len(x),), dtype=F64)[:, :5], p), dim=-1)
    moved = dq.mul(dq.mul(x, pdq), dq.conj_full(x))
    assert rel_err(moved[:, 5:], dq.apply(x, p), s) < 1e-14


# ------------------------------------------------------------- unit norm, normalize, inverse

def _perturb(x, gen):
    """Scaled by a factor in [0.1, 3.1] plus noise of 1e-2 in every component."""
    k = torch.rand(len(x), 1, generator=gen, dtype=F64) * 3 + 0.1
    return x * k + torch.randn(x.shape, generator=gen, dtype=F64) * 1e-2


def test_normalize(poses, gen):
    y = _perturb(poses, gen)
    n = dq.normalize(y)
    s = scale(poses)
    r, d = n[:, :4], n[:, 4:]
    assert ((r * r).sum(-1) - 1).abs().max() < 1e-15  # measured 4.4e-16
    assert ((r * d).sum(-1).abs() / s).max() < 1e-15  # measured 7.1e-17
    assert dq.is_unit(n, atol=1e-12).all()
    # the translation 2 vec(d r*) / |r|^2 is kept
    ry, dy = y[:, :4], y[:, 4:]
    t = 2 * quat.mul(dy, quat.conj(ry))[:, 1:] / (ry * ry).sum(-1, keepdim=True)
    assert rel_err(dq.to_rt(n)[1], t, t.norm(dim=-1).clamp_min(1)) < 1e-15  # measured 4.3e-16
    # idempotent, invariant to positive scaling, identity on unit input
    assert rel_err(dq.normalize(n), n, s) < 1e-15
    for k in (7.3, 1e-3, 1e3):
        assert rel_err(dq.normalize(k * y), n, s) < 1e-15
    assert rel_err(dq.normalize(poses), poses, s) < 1e-15
    # check=True accepts valid input and rejects a zero real part
    assert torch.equal(dq.normalize(y, check=True), n)
    bad = y.clone()
    bad[3, :4] = 0
    with pytest.raises(ValueError, match=r"dualquat\.normalize.*x.*zero or non-finite"):
        dq.normalize(bad, check=True)
    out = dq.normalize(bad)
    assert torch.isnan(out[3]).all() and torch.equal(out[:3], n[:3])


@pytest.mark.parametrize("k", [1e-30, 1e-25, 1e20, 1e30], ids=lambda k: f"{k:g}")
def test_normalize_over_scales(k, gen):
    """float32 dual quaternions scaled by 1e-30 .. 1e30 normalise like the unscaled ones
    (0.1: the square of the real part under/overflowed and gave NaN)."""
    x = unit_dq((16,), gen, dtype=torch.float32)
    torch.testing.assert_close(dq.normalize(x * k), dq.normalize(x), rtol=0, atol=1e-6)


def test_vmap_over_normalize_check_names_the_way_out(gen):
    x = unit_dq((3,), gen)
    with pytest.raises(RuntimeError, match=r"dualquat\.normalize: check=True .*check=False"):
        torch.func.vmap(lambda y: dq.normalize(y, check=True))(x)


def test_is_unit(poses, gen):
    assert dq.is_unit(poses).all()
    # atol is absolute and r . d scales with |t|: the float32 default 1e-5 holds up to |t| ~ 1e2
    assert dq.is_unit(poses[scale(poses) < 100].float()).all()
    y = poses.clone()
    y[0, 0] += 1e-6  # |r| off by 1e-6
    y[1, 4:] += 1e-3 * y[1, :4]  # dual part not orthogonal
    y[2, 5] = math.nan
    y[3, 6] = math.inf
    y[4] *= -1  # still unit
    ok = dq.is_unit(y)
    assert ok.dtype == torch.bool and ok.shape == (len(y),)
    assert ok.tolist()[:5] == [False, False, False, False, True] and ok[5:].all()
    assert dq.is_unit(y, atol=1e-2)[:2].all()  # within a loose tolerance
    assert not dq.is_unit(torch.zeros(8, dtype=F64))
    assert dq.is_unit(torch.full((2, 3, 8), math.nan)).shape == (2, 3)


def test_inv(poses, gen):
    s = scale(poses)
    ident = dq.identity((1,), dtype=F64)
    assert rel_err(dq.mul(poses, dq.inv(poses)), ident, s) < 1e-15  # measured 2.0e-16
    assert rel_err(dq.mul(dq.inv(poses), poses), ident, s) < 1e-15
    assert rel_err(dq.inv(poses), dq.conj(poses), s) < 1e-15  # equals conj for unit input
    y = _perturb(poses, gen)  # any dual quaternion with a non-zero real part
    assert rel_err(dq.mul(y, dq.inv(y)), ident, s) < 1e-14
    assert rel_err(dq.inv(dq.inv(y)), y, s) < 1e-14
    T = pt_matrix(poses)
    assert rel_err(dq.to_matrix(dq.inv(poses)), torch.linalg.inv(T), s) < 1e-14


def test_norm_and_dot_return_dual(poses, gen):
    s = scale(poses)
    n = dq.norm(poses)
    assert isinstance(n, Dual) and n.shape == (len(poses),)
    assert (n.real - 1).abs().max() < 1e-15
    assert (n.dual.abs() / s).max() < 1e-15
    y = _perturb(poses, gen)
    ny = dq.norm(y)
    r, d = y[:, :4], y[:, 4:]
    assert (ny.real - r.norm(dim=-1)).abs().max() < 1e-15
    assert ((ny.dual - (r * d).sum(-1) / r.norm(dim=-1)).abs() / s).max() < 1e-14
    # |x|^2 = x . x, and the norm of a normalized element is 1 + eps 0
    sq = dq.dot(y, y)
    assert (sq.real - ny.real**2).abs().max() < 1e-14
    assert ((sq.dual - 2 * ny.real * ny.dual).abs() / s).max() < 1e-13
    nn = dq.norm(dq.normalize(y))
    assert (nn.real - 1).abs().max() < 1e-15 and (nn.dual.abs() / s).max() < 1e-15
    # eq. 1: a . b = r_a . r_b + eps (r_a . d_b + r_b . d_a) = scalar part of (a b* + b a*) / 2
    a, b = poses, poses[torch.randperm(len(poses), generator=gen)]
    dt = dq.dot(a, b)
    assert torch.equal(dt.real, (a[:, :4] * b[:, :4]).sum(-1))
    assert torch.equal(dt.dual, (a[:, :4] * b[:, 4:] + b[:, :4] * a[:, 4:]).sum(-1))
    sym = 0.5 * (dq.mul(a, dq.conj(b)) + dq.mul(b, dq.conj(a)))
    assert (sym[:, 0] - dt.real).abs().max() < 1e-15
    assert ((sym[:, 4] - dt.dual).abs() / (scale(a) + scale(b))).max() < 1e-15
    assert (sym[:, [1, 2, 3, 5, 6, 7]].abs().max(-1).values / (scale(a) + scale(b))).max() < 1e-15


def test_identity():
    x = dq.identity()
    assert torch.equal(x, torch.tensor([1.0, 0, 0, 0, 0, 0, 0, 0]))
    x = dq.identity((2, 3), dtype=F64)
    assert x.shape == (2, 3, 8) and x.dtype == F64
    assert torch.equal(dq.identity(4), dq.identity((4,)))
    y = unit_dq((2, 3), torch.Generator().manual_seed(0))
    assert torch.equal(dq.mul(x, y), y) and torch.equal(dq.mul(y, x), y)


def test_non_finite_stays_in_its_element(gen):
    """NaN or inf in one component of one pose: that pose's outputs are not all finite, and
    the other poses are untouched."""
    x0 = unit_dq((3,), gen)
    x0[2] = dq.from_rt(quat.identity((), dtype=F64), torch.tensor([1.0, 2, 3], dtype=F64))
    p = torch.randn(3, 3, generator=gen, dtype=F64)
    fns = {
        "mul": lambda x: dq.mul(x, x0.flip(0)), "inv": dq.inv, "normalize": dq.normalize,
        "to_rt": dq.to_rt, "to_matrix": lambda x: dq.to_matrix(x)[..., :3, :],
        "to_pose7": dq.to_pose7, "to_screw": dq.to_screw, "log": dq.log,
        "apply": lambda x: dq.apply(x, p), "apply_line": lambda x: dq.apply_line(x, p, p),
        "norm": lambda x: tuple(dq.norm(x)), "dot": lambda x: tuple(dq.dot(x, x0)),
    }
    for bad in (math.nan, math.inf):
        for i in (0, 2):  # a rotated pose, a pure translation
            for k in range(8):
                x = x0.clone()
                x[i, k] = bad
                for name, f in fns.items():
                    ref = f(x0)
                    out = f(x)
                    ref, out = (ref, out) if isinstance(out, tuple) else ((ref,), (out,))
                    others = [j for j in range(3) if j != i]
                    for o, r in zip(out, ref, strict=True):
                        assert torch.equal(o[others], r[others]), (name, bad, i, k)
                    assert not all(torch.isfinite(o[i]).all() for o in out), (name, bad, i, k)
    # exp: a bad twist component
    xi = dq.log(x0)
    for k in range(6):
        xb = xi.clone()
        xb[1, k] = math.nan
        out = dq.exp(xb)
        assert not torch.isfinite(out[1]).all()
        assert torch.equal(out[[0, 2]], dq.exp(xi)[[0, 2]])


def test_to_screw_nan_translation_gives_nan_axis():
    """Regression: a rotation-free pose with a NaN translation used to return the fallback
    axis (1, 0, 0) as if the translation were zero."""
    x = torch.tensor([1.0, 0, 0, 0, 0, math.nan, 0, 0], dtype=F64)
    axis, _, _, d = dq.to_screw(x)
    assert torch.isnan(axis).all() and torch.isnan(d)


def test_to_screw_half_turn_is_sign_invariant(gen):
    """Regression: at r_w = 0 exactly, x and -x used to give opposite axes (and moments, d)."""
    q = torch.tensor([[0.0, 1, 0, 0], [0, -0.6, 0, 0.8], [0, 0, 0, -1]], dtype=F64)
    x = dq.from_rt(q, torch.randn(3, 3, generator=gen, dtype=F64))
    for u, v in zip(dq.to_screw(x), dq.to_screw(-x), strict=True):
        assert torch.equal(u, v)
    # scipy's canonical sign: the first non-zero of x, y, z positive
    assert torch.equal(dq.to_screw(x)[0], q[:, 1:] * q.new_tensor([[1.0], [-1.0], [-1.0]]))


def test_from_screw_broadcasts_scalar_angle_and_distance(gen):
    """Regression: Python-float (or 0-d) theta and d with batched axes used to fail in cat."""
    axis, moment, _, _ = dq.to_screw(unit_dq((2, 3), gen))
    out = dq.from_screw(axis, moment, 0.5, torch.tensor(2.0, dtype=F64))
    full = torch.full((2, 3), 0.5, dtype=F64)
    assert torch.equal(out, dq.from_screw(axis, moment, full, 4 * full))


# ----------------------------------------------------------------------------- properties

@given(a=dual_quats(), b=dual_quats(), c=dual_quats())
def test_group_axioms(a, b, c):
    # translations up to ~170: absolute tolerances scaled by it
    s = float(scale(torch.stack((a, b, c))).sum())
    lhs, rhs = dq.mul(dq.mul(a, b), c), dq.mul(a, dq.mul(b, c))
    assert (lhs - rhs).abs().max() < 2e-15 * s
    ident = dq.identity(dtype=F64)
    assert torch.equal(dq.mul(a, ident), a) and torch.equal(dq.mul(ident, a), a)
    assert (dq.mul(a, dq.inv(a)) - ident).abs().max() < 1e-15 * s
    assert (dq.mul(dq.inv(a), a) - ident).abs().max() < 1e-15 * s
    # matrices compose the same way
    assert (dq.to_matrix(dq.mul(a, b)) - dq.to_matrix(a) @ dq.to_matrix(b)).abs().max() < 2e-15 * s


@given(x=dual_quats(), flip=st.booleans())
def test_round_trips(x, flip):
    x = -x if flip else x
    s = float(scale(x[None]))
    q, t = dq.to_rt(x)
    assert torch.equal(dq.from_rt(q, t).sub(x).abs().max() < 1e-15 * s, torch.tensor(True))
    assert (align(dq.from_matrix(dq.to_matrix(x)), x) - x).abs().max() < 1e-15 * s
    assert (align(dq.from_screw(*dq.to_screw(x)), x) - x).abs().max() < 2e-15 * s
    assert (align(dq.exp(dq.log(x)), x) - x).abs().max() < 2e-15 * s
    assert (dq.from_pose7(dq.to_pose7(x)) - x).abs().max() < 1e-15 * s


@given(q=quats(), t=st.lists(st.floats(-100, 100), min_size=3, max_size=3),
       p=st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_sign_invariance(q, t, p):
    """x and -x are the same transform: to_matrix, apply and log agree bitwise."""
    x = dq.from_rt(q, torch.tensor(t, dtype=F64))
    pts = torch.tensor(p, dtype=F64)
    assert torch.equal(dq.to_matrix(x), dq.to_matrix(-x))
    assert torch.equal(dq.apply(x, pts), dq.apply(-x, pts))
    assert torch.equal(dq.log(x), dq.log(-x))
    a, m, th, d = dq.to_screw(x)
    for u, v in zip((a, m, th, d), dq.to_screw(-x), strict=True):
        assert torch.equal(u, v)


@given(xi=st.lists(st.floats(-3, 3), min_size=6, max_size=6),
       k=st.sampled_from([1.0, 1e-9, 1e-4, 0.0]))
def test_log_inverts_exp_on_the_principal_ball(xi, k):
    xi = torch.tensor(xi, dtype=F64)
    xi[:3] = xi[:3] * k if k else xi[:3]
    theta = xi[:3].norm()
    if theta >= math.pi - 1e-6:  # outside the principal branch (or within 1e-6 of it)
        xi[:3] = xi[:3] / theta * 3.0
    assert (dq.log(dq.exp(xi)) - xi).abs().max() < 5e-14  # |v| <= 5: 1e-14 relative


# ----------------------------------------------------------------------------- batch shapes

def test_batch_shapes(batch_shape, gen):
    a = unit_dq(batch_shape, gen)
    b = unit_dq((*batch_shape[:-1], 1) if batch_shape else (), gen)
    p = torch.randn((*batch_shape, 3), generator=gen, dtype=F64)
    fa, fb, fp = (y.expand(*batch_shape, y.shape[-1]).reshape(-1, y.shape[-1])
                  for y in (a, b, p))
    T = dq.to_matrix(a)
    cases = [
        (dq.mul(a, b), dq.mul(fa, fb)),
        (dq.apply(a, p), dq.apply(fa, fp)),
        (dq.from_matrix(T), dq.from_matrix(T.reshape(-1, 4, 4))),
        (dq.log(a), dq.log(fa)),
        (dq.exp(dq.log(a)), dq.exp(dq.log(fa))),
        (dq.apply_line(a, p, p)[1], dq.apply_line(fa, fp, fp)[1]),
        (dq.normalize(a), dq.normalize(fa)),
        (dq.to_pose7(a), dq.to_pose7(fa)),
    ]
    for out, ref in cases:
        assert out.shape == (*batch_shape, ref.shape[-1])
        assert (out.reshape(ref.shape) - ref).abs().max() < 1e-15
    assert T.shape == (*batch_shape, 4, 4)
    assert dq.is_unit(a).shape == batch_shape
    assert dq.norm(a).shape == batch_shape and dq.dot(a, b).shape == batch_shape
    axis, moment, theta, d = dq.to_screw(a)
    assert axis.shape == moment.shape == (*batch_shape, 3)
    assert theta.shape == d.shape == batch_shape
    assert dq.from_screw(axis, moment, theta, d).shape == (*batch_shape, 8)
    assert dq.from_screw(axis, moment, 0.5, 1.0).shape == (*batch_shape, 8)
    assert dq.identity(batch_shape).shape == (*batch_shape, 8)


def test_broadcasting(gen):
    a, b = unit_dq((4, 1), gen), unit_dq((3,), gen)
    p = torch.randn(3, 3, generator=gen, dtype=F64)
    out = dq.mul(a, b)
    assert out.shape == (4, 3, 8)
    assert torch.equal(out[2, 1], dq.mul(a[2, 0], b[1]))
    assert dq.apply(a, p).shape == (4, 3, 3)
    assert torch.equal(dq.apply(a, p)[3, 2], dq.apply(a[3, 0], p[2]))
    assert dq.dot(a, b).shape == (4, 3)
    l2, m2 = dq.apply_line(a, p, p[:1])
    assert l2.shape == m2.shape == (4, 3, 3)
    q, t = dq.to_rt(a)
    assert dq.from_rt(q, t[None]).shape == (1, 4, 1, 8)
    assert dq.from_screw(p, p, torch.zeros(4, 1, dtype=F64), 1.0).shape == (4, 3, 8)


# ----------------------------------------------------------------------------- autograd

def test_gradcheck(gen):
    a, b = unit_dq((3,), gen), unit_dq((3,), gen)
    q, t = dq.to_rt(a)
    p = torch.randn(3, 3, generator=gen, dtype=F64)
    axis, moment, theta, d = dq.to_screw(a)
    # off the manifold: mul, inv and normalize are smooth for any non-zero real part
    y = _perturb(a, gen)
    gradcheck_at(dq.mul, y, b)
    gradcheck_at(dq.inv, y)
    gradcheck_at(dq.normalize, y)
    gradcheck_at(dq.from_rt, q, t)
    gradcheck_at(dq.to_rt, y)
    gradcheck_at(dq.to_matrix, y)
    gradcheck_at(dq.from_matrix, dq.to_matrix(a))
    gradcheck_at(dq.from_screw, axis, moment, theta, d)
    gradcheck_at(dq.to_screw, a)
    gradcheck_at(dq.exp, dq.log(a))
    gradcheck_at(dq.log, a)
    gradcheck_at(dq.apply, a, p)
    gradcheck_at(dq.apply_line, a, p, torch.randn(3, 3, generator=gen, dtype=F64))
    gradcheck_at(lambda x, z: tuple(dq.dot(x, z)), y, b)
    gradcheck_at(lambda x: tuple(dq.norm(x)), y)
    gradcheck_at(dq.to_pose7, a)
    gradcheck_at(dq.from_pose7, dq.to_pose7(a))


def test_gradcheck_at_smooth_singular_points():
    """exp and log are smooth at the zero twist and at pure translations."""
    xi = torch.tensor([[0.0, 0, 0, 0, 0, 0], [0, 0, 0, 1, -2, 3]], dtype=F64)
    gradcheck_at(dq.exp, xi)
    gradcheck_at(dq.log, dq.exp(xi))
    gradcheck_at(dq.exp, xi + torch.tensor([1e-9, 0, 0, 0, 0, 0], dtype=F64))


@pytest.mark.parametrize("point", ["zero", "translation", "half_turn", "near_half_turn"])
def test_finite_gradients_at_singular_points(point):
    xi = {
        "zero": [0.0, 0, 0, 0, 0, 0],
        "translation": [0.0, 0, 0, 1, 2, 3],
        "half_turn": [0.0, math.pi, 0, 1, 2, 3],
        "near_half_turn": [0.0, 0, math.pi - 1e-9, 1, 2, 3],
    }[point]
    xi = torch.tensor(xi, dtype=F64)
    x = dq.exp(xi)
    for f, arg in ((dq.exp, xi), (dq.log, x), (dq.to_screw, x), (dq.to_matrix, x),
                   (dq.from_matrix, dq.to_matrix(x))):
        (g,) = grads(f, arg)
        assert torch.isfinite(g).all(), (f.__name__, point)


def test_to_screw_gradients_generic_and_pure_translation(gen):
    a = unit_dq((4,), gen)
    pure = dq.from_rt(quat.identity((2,), dtype=F64), torch.tensor([[1.0, 2, 3], [0, 0, 0]],
                                                                    dtype=F64))
    for x in (a, pure):
        (g,) = grads(dq.to_screw, x)
        assert torch.isfinite(g).all()


# ----------------------------------------------------------------------------- dtypes

def test_float32_accuracy(gen):
    """Max error of float32 against float64 on the same float32-rounded inputs, unit-scale
    translations (5000 poses): 2.8e-7 (mul) to 1.5e-6 (log, apply); all below 3e-6."""
    x = unit_dq((5000,), gen).float().double()
    y = x.flip(0)
    p = torch.randn(5000, 3, generator=gen, dtype=F64).float().double()
    T = dq.to_matrix(x)
    cases = {
        "mul": (dq.mul, (x, y)),
        "apply": (dq.apply, (x, p)),
        "to_matrix": (dq.to_matrix, (x,)),
        "from_matrix": (lambda m: dq.from_matrix(m)[:, :4].abs(), (T,)),
        "exp": (dq.exp, (dq.log(x).float().double(),)),
        "log": (dq.log, (x,)),
        "normalize": (dq.normalize, (1.1 * x,)),
        "inv": (dq.inv, (x,)),
        "to_screw": (lambda z: dq.to_screw(z)[2], (x,)),
    }
    for name, (f, args) in cases.items():
        ref = f(*args)
        out = f(*(v.float() for v in args))
        assert out.dtype == torch.float32
        err = (out.double() - ref).abs().max().item()
        assert err < F32_TOL, (name, err)


def test_dtype_device_follow_inputs(dtype, device, gen):
    x = unit_dq((5,), gen).to(dtype=dtype, device=device)
    p = torch.randn(5, 3, generator=gen, dtype=F64).to(dtype=dtype, device=device)
    outs = [dq.mul(x, x), dq.inv(x), dq.normalize(x), dq.to_matrix(x), dq.from_matrix(
        dq.to_matrix(x)), dq.exp(dq.log(x)), dq.apply(x, p), *dq.to_screw(x), *dq.to_rt(x),
        dq.to_pose7(x), dq.conj_full(x), dq.norm(x).dual, dq.identity(dtype=dtype, device=device)]
    for o in outs:
        assert o.dtype == dtype and o.device.type == device.type


def test_inputs_not_modified(gen):
    x = unit_dq((4,), gen)
    keep = x.clone()
    p = torch.randn(4, 3, generator=gen, dtype=F64)
    for f in (dq.inv, dq.normalize, dq.to_matrix, dq.to_screw, dq.log, dq.conj, dq.conj_dual,
              dq.conj_full, dq.to_pose7, lambda z: dq.apply(z, p), lambda z: dq.mul(z, z)):
        f(x)
        assert torch.equal(x, keep)


# ----------------------------------------------------------------------------- bad arguments

Z8, Z4, Z3 = torch.zeros(8), torch.zeros(4), torch.zeros(3)
I64 = torch.int64


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: dq.mul(torch.zeros(7), Z8), ValueError,
         r"dualquat\.mul: expected a \(\.\.\., 8\) tensor for a, got shape \(7,\)"),
        (lambda: dq.mul(Z8, torch.zeros(2, 4)), ValueError, r"dualquat\.mul.* for b.*\(2, 4\)"),
        (lambda: dq.mul(torch.zeros(2, 8), torch.zeros(3, 8)), ValueError,
         r"dualquat\.mul: batch shapes do not broadcast: a \(2,\), b \(3,\)"),
        (lambda: dq.mul(Z8, Z8.double()), TypeError, r"dualquat\.mul: b has dtype torch\.float64"),
        (lambda: dq.mul(Z8.to(I64), Z8), TypeError, r"dualquat\.mul.*floating.* a"),
        (lambda: dq.mul([0.0] * 8, Z8), TypeError, r"dualquat\.mul.*torch\.Tensor for a.*list"),
        (lambda: dq.conj(Z4), ValueError, r"dualquat\.conj: .*for x"),
        (lambda: dq.conj_dual(Z8.to(I64)), TypeError, r"dualquat\.conj_dual.*x"),
        (lambda: dq.conj_full(torch.zeros(8, 1)), ValueError, r"dualquat\.conj_full.*x.*\(8, 1\)"),
        (lambda: dq.inv(torch.zeros(2, 9)), ValueError, r"dualquat\.inv.*x.*\(2, 9\)"),
        (lambda: dq.norm(Z3), ValueError, r"dualquat\.norm.*x"),
        (lambda: dq.dot(Z8, torch.zeros(3, 7)), ValueError, r"dualquat\.dot.*b"),
        (lambda: dq.dot(torch.zeros(4, 8), torch.zeros(2, 8)), ValueError, r"dot.*a \(4,\), b"),
        (lambda: dq.normalize(Z4), ValueError, r"dualquat\.normalize.*x"),
        (lambda: dq.is_unit(Z8.to(torch.bool)), TypeError, r"dualquat\.is_unit.*x"),
        (lambda: dq.from_rt(Z3, Z3), ValueError, r"dualquat\.from_rt.*for q, got shape \(3,\)"),
        (lambda: dq.from_rt(Z4, Z4), ValueError, r"dualquat\.from_rt.*\(\.\.\., 3\).*for t"),
        (lambda: dq.from_rt(Z4, Z3.double()), TypeError, r"from_rt: t has dtype"),
        (lambda: dq.from_rt(torch.zeros(2, 4), torch.zeros(5, 3)), ValueError,
         r"from_rt: batch shapes do not broadcast: q \(2,\), t \(5,\)"),
        (lambda: dq.to_rt(Z4), ValueError, r"dualquat\.to_rt.*x"),
        (lambda: dq.from_matrix(torch.zeros(3, 3)), ValueError,
         r"dualquat\.from_matrix: expected a \(\.\.\., 4, 4\) tensor for T, got shape \(3, 3\)"),
        (lambda: dq.from_matrix(torch.zeros(4, 3)), ValueError, r"from_matrix.*T.*\(4, 3\)"),
        (lambda: dq.from_matrix(torch.zeros(16)), ValueError, r"from_matrix.*T.*\(16,\)"),
        (lambda: dq.from_matrix(torch.eye(4, dtype=I64)), TypeError, r"from_matrix.*T"),
        (lambda: dq.to_matrix(torch.eye(4)), ValueError, r"dualquat\.to_matrix.*x.*\(4, 4\)"),
        (lambda: dq.from_pose7(Z8), ValueError, r"dualquat\.from_pose7.*\(\.\.\., 7\).*p"),
        (lambda: dq.to_pose7(torch.zeros(7)), ValueError, r"dualquat\.to_pose7.*x"),
        (lambda: dq.from_screw(Z4, Z3, 0.0, 0.0), ValueError, r"from_screw.*axis"),
        (lambda: dq.from_screw(Z3, Z4, 0.0, 0.0), ValueError, r"from_screw.*moment"),
        (lambda: dq.from_screw(Z3, Z3.double(), 0.0, 0.0), TypeError, r"from_screw: moment"),
        (lambda: dq.from_screw(Z3, Z3, torch.zeros((), dtype=I64), 0.0), TypeError,
         r"from_screw.*theta"),
        (lambda: dq.from_screw(Z3, Z3, 0.0, torch.zeros((), dtype=F64)), TypeError,
         r"from_screw: d has dtype"),
        (lambda: dq.from_screw(torch.zeros(2, 3), Z3, torch.zeros(5), 0.0), ValueError,
         r"from_screw: batch shapes do not broadcast: axis \(2,\), moment \(\), theta \(5,\)"),
        (lambda: dq.from_screw(Z3, Z3, 0.0, "1"), TypeError, r"from_screw.*d.*str"),
        (lambda: dq.to_screw(Z4), ValueError, r"dualquat\.to_screw.*x"),
        (lambda: dq.exp(Z8), ValueError,
         r"dualquat\.exp: expected a \(\.\.\., 6\) tensor for xi, got shape \(8,\)"),
        (lambda: dq.exp(torch.zeros(6, dtype=I64)), TypeError, r"dualquat\.exp.*xi"),
        (lambda: dq.log(torch.zeros(6)), ValueError, r"dualquat\.log.*x.*\(6,\)"),
        (lambda: dq.apply(Z8, Z4), ValueError, r"dualquat\.apply.*points.*\(4,\)"),
        (lambda: dq.apply(Z3, Z3), ValueError, r"dualquat\.apply.*for x"),
        (lambda: dq.apply(Z8, Z3.double()), TypeError, r"apply: points has dtype"),
        (lambda: dq.apply(torch.zeros(2, 8), torch.zeros(3, 3)), ValueError,
         r"apply: batch shapes do not broadcast: x \(2,\), points \(3,\)"),
        (lambda: dq.apply(Z8, torch.zeros(3, dtype=I64)), TypeError, r"apply.*points"),
        (lambda: dq.apply_line(Z8, Z4, Z3), ValueError, r"apply_line.*direction"),
        (lambda: dq.apply_line(Z8, Z3, torch.zeros(2, 2)), ValueError, r"apply_line.*moment"),
        (lambda: dq.apply_line(Z8, Z3, Z3.double()), TypeError, r"apply_line: moment has dtype"),
        (lambda: dq.apply_line(Z8, torch.zeros(2, 3), torch.zeros(4, 3)), ValueError,
         r"apply_line: batch shapes.*direction \(2,\), moment \(4,\)"),
        (lambda: dq.identity(dtype=I64), TypeError, r"dualquat\.identity.*floating dtype"),
        (lambda: dq.identity((2, -1)), ValueError, r"dualquat\.identity.*shape.*\(2, -1\)"),
        (lambda: dq.normalize(torch.zeros(8), check=True), ValueError,
         r"dualquat\.normalize.*x contains zero"),
        (lambda: dq.normalize(torch.ones(8), check="yes"), TypeError,
         r"dualquat\.normalize: expected check to be a bool"),
    ],
)
def test_bad_arguments(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


def test_unit_quat_strategy_sanity(gen):
    """The samplers used above really produce unit dual quaternions."""
    assert dq.is_unit(adversarial_dqs()).all()
    assert dq.is_unit(unit_dq((10,), gen, scale=100.0)).all()
    assert (unit_quat((5,), gen).norm(dim=-1) - 1).abs().max() < 1e-15

"""Tests for torch_dq.quat: agreement with scipy, round trips, properties, autograd, errors.

scipy stores quaternions as (x, y, z, w); torch_dq as (w, x, y, z). Every comparison with
scipy runs in float64 and states its maximum error; quaternions are compared up to sign
where both signs are the same rotation.
"""

import math
import warnings

import numpy as np
import pytest
import torch
from conftest import TOL
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp
from strategies import adversarial_quats, gradcheck_at, grads, quats, rotvec, unit_quat

from torch_dq import quat

F64 = torch.float64
SEQS = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b != c]
ALL_SEQS = SEQS + [s.upper() for s in SEQS]
# float32 accuracy against float64 on unit-scale quantities (stated in the report).
F32_TOL = 2e-6


# ----------------------------------------------------------------------------- helpers

def to_scipy(q):
    return Rotation.from_quat(q.reshape(-1, 4)[:, [1, 2, 3, 0]].numpy())


def from_scipy(x):
    return torch.from_numpy(np.asarray(x))[..., [3, 0, 1, 2]]


def qdist(a, b):
    """Largest distance between quaternions up to sign."""
    return torch.minimum((a - b).norm(dim=-1), (a + b).norm(dim=-1)).max().item()


def maxabs(a, b):
    return (a - b).abs().max().item()


def scipy_euler(q, seq):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # scipy's gimbal-lock warning
        return torch.from_numpy(to_scipy(q).as_euler(seq))


@pytest.fixture
def rots(gen):
    """Random and adversarial float64 unit quaternions, (N, 4)."""
    return torch.cat((unit_quat((64,), gen), adversarial_quats()))


def near_lock_euler(seq, gen):
    """Euler angles whose second angle is at, or 1e-9, 1e-7, 1e-5 from, a gimbal lock."""
    locks = (0.0, math.pi) if seq[0].lower() == seq[2].lower() else (-math.pi / 2, math.pi / 2)
    lo, hi = (locks[0], locks[1])
    mids = [m + o for m in locks for o in (0.0, 1e-9, -1e-9, 1e-7, -1e-7, 1e-5, -1e-5)]
    mids = torch.tensor([m for m in mids if lo <= m <= hi], dtype=F64)
    e = (torch.rand(mids.numel(), 3, generator=gen, dtype=F64) * 2 - 1) * math.pi
    e[:, 1] = mids
    return e


# ------------------------------------------------------------------ agreement with scipy

def test_to_matrix_matches_scipy(rots):
    err = maxabs(quat.to_matrix(rots), torch.from_numpy(to_scipy(rots).as_matrix()))
    assert err < 2e-15, err


def test_from_matrix_matches_scipy(rots):
    r = to_scipy(rots)
    out = quat.from_matrix(torch.from_numpy(r.as_matrix()))
    err = qdist(out, from_scipy(r.as_quat(canonical=True)))
    assert err < 1e-15, err
    assert (out[:, 0] >= 0).all()  # scipy's canonical sign


def test_from_matrix_exact_half_turns_are_canonical():
    mats = torch.diag_embed(torch.tensor([[1.0, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=F64))
    expected = torch.tensor([[0.0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=F64)
    assert torch.equal(quat.from_matrix(mats), expected)
    # 180 degrees about -x: scipy's tie break makes the first non-zero of x, y, z positive.
    r = Rotation.from_rotvec([-math.pi, 0, 0]).as_matrix()
    out = quat.from_matrix(torch.from_numpy(r))
    assert maxabs(out, from_scipy(Rotation.from_matrix(r).as_quat(canonical=True))) < 1e-15


def test_rotvec_matches_scipy(rots, gen):
    r = to_scipy(rots)
    err = maxabs(quat.to_rotvec(rots), torch.from_numpy(r.as_rotvec()))
    assert err < 2e-15, err
    rv = torch.cat((rotvec((64,), gen, max_angle=3 * math.pi), quat.to_rotvec(rots)))
    err = qdist(quat.from_rotvec(rv), from_scipy(Rotation.from_rotvec(rv.numpy()).as_quat()))
    assert err < 1e-15, err


def test_axis_angle_matches_scipy(rots, gen):
    axis, angle = quat.to_axis_angle(rots)
    rv = torch.from_numpy(to_scipy(rots).as_rotvec())
    assert maxabs(axis * angle[:, None], rv) < 2e-15
    assert maxabs(angle, rv.norm(dim=-1)) < 2e-15
    assert ((angle >= 0) & (angle <= math.pi)).all()
    assert maxabs(axis.norm(dim=-1), torch.ones_like(angle)) < 1e-15
    # unnormalised axes, angles beyond [0, pi] and negative
    ax = torch.randn(64, 3, generator=gen, dtype=F64) * 3
    an = (torch.rand(64, generator=gen, dtype=F64) * 2 - 1) * 3 * math.pi
    ref = Rotation.from_rotvec((ax / ax.norm(dim=-1, keepdim=True) * an[:, None]).numpy())
    err = qdist(quat.from_axis_angle(ax, an), from_scipy(ref.as_quat()))
    assert err < 1e-15, err


def test_exp_log_match_scipy_on_unit_quaternions(rots, gen):
    canonical = torch.where(rots[:, :1] < 0, -rots, rots)
    lg = quat.log(canonical)
    assert lg[:, 0].abs().max() < 1e-15
    err = maxabs(2 * lg[:, 1:], torch.from_numpy(to_scipy(rots).as_rotvec()))
    assert err < 2e-15, err
    rv = rotvec((64,), gen, max_angle=4 * math.pi)
    pure = torch.cat((torch.zeros(64, 1, dtype=F64), rv / 2), dim=-1)
    err = qdist(quat.exp(pure), from_scipy(Rotation.from_rotvec(rv.numpy()).as_quat()))
    assert err < 1e-15, err


@pytest.mark.parametrize("seq", ALL_SEQS)
def test_euler_matches_scipy(seq, rots, gen):
    # Random and adversarial rotations: angles compared directly.
    err = maxabs(quat.to_euler(rots, seq), scipy_euler(rots, seq))
    assert err < 1e-14, err
    e = (torch.rand(32, 3, generator=gen, dtype=F64) * 2 - 1) * 2 * math.pi
    err = qdist(quat.from_euler(e, seq), from_scipy(Rotation.from_euler(seq, e.numpy()).as_quat()))
    assert err < 1e-15, err


@pytest.mark.parametrize("seq", ALL_SEQS)
def test_euler_near_gimbal_lock_matches_scipy(seq, gen):
    e = near_lock_euler(seq, gen)
    q = quat.from_euler(e, seq)
    ours, ref = quat.to_euler(q, seq), scipy_euler(q, seq)
    # The second angle is well conditioned: direct.
    assert maxabs(ours[:, 1], ref[:, 1]) < 1e-15
    # First and third angles are not unique at the lock: compare the rotations they give.
    err = qdist(quat.from_euler(ours, seq), quat.from_euler(ref, seq))
    assert err < 1e-15, err
    # Within scipy's 1e-7 lock threshold the third angle is 0 and the rotation is off by
    # at most the threshold, as in scipy; outside it the rotation is reproduced.
    lock_dist = (ours[:, 1:2] - torch.tensor([[0.0, math.pi, -math.pi / 2, math.pi / 2]],
                                             dtype=F64)).abs().min(-1).values
    back = quat.from_euler(ours, seq)
    assert (ours[lock_dist < 0.9e-7, 2] == 0).all()
    assert qdist(back[lock_dist > 1.1e-7], q[lock_dist > 1.1e-7]) < 1e-14
    assert qdist(back, q) < 1e-7
    # Canonical ranges.
    half = math.pi / 2 if seq[0].lower() != seq[2].lower() else None
    lo, hi = (-half, half) if half else (0.0, math.pi)
    assert ((ours[:, 1] >= lo) & (ours[:, 1] <= hi)).all()
    assert (ours[:, ::2].abs() <= math.pi).all()


def test_slerp_matches_scipy(gen):
    q0, q1 = unit_quat((16,), gen), unit_quat((16,), gen)
    q1[:4] = q0[:4] * torch.tensor([[1.0], [-1.0], [1.0], [-1.0]], dtype=F64)  # equal / opposite
    ts = torch.linspace(0, 1, 7, dtype=F64)
    ours = quat.slerp(q0, q1, ts[:, None])
    err = 0.0
    for n in range(16):
        ref = Slerp([0.0, 1.0], to_scipy(torch.stack((q0[n], q1[n]))))(ts.numpy())
        err = max(err, qdist(ours[:, n], from_scipy(ref.as_quat())))
    assert err < 1e-15, err


# ---------------------------------------------------------------------------- round trips

def test_round_trips(dtype, gen):
    tol = 4 * TOL[dtype]
    q = unit_quat((128,), gen, dtype=dtype)
    assert qdist(quat.from_matrix(quat.to_matrix(q)), q) < tol
    assert qdist(quat.from_rotvec(quat.to_rotvec(q)), q) < tol
    assert qdist(quat.from_axis_angle(*quat.to_axis_angle(q)), q) < tol
    assert maxabs(quat.exp(quat.log(q)), q) < tol
    rv = rotvec((128,), gen, max_angle=math.pi * 0.999, dtype=dtype)
    assert maxabs(quat.to_rotvec(quat.from_rotvec(rv)), rv) < tol * 4
    # exp / log on general quaternions (any norm, w < 0 included), |v| < pi for log(exp)
    p = torch.randn(128, 4, generator=gen, dtype=F64).to(dtype)
    assert maxabs(quat.exp(quat.log(p)), p) < tol * 4
    p = torch.cat((p[:, :1], rv / 2), dim=-1)
    assert maxabs(quat.log(quat.exp(p)), p) < tol * 4


@pytest.mark.parametrize("seq", ALL_SEQS)
def test_euler_round_trip(seq, dtype, gen):
    q = unit_quat((64,), gen, dtype=dtype)
    e = quat.to_euler(q, seq)
    assert qdist(quat.from_euler(e, seq), q) < 4 * TOL[dtype]
    if dtype == F64:  # near gimbal lock float32 angles are ill conditioned, float64 direct
        assert maxabs(quat.to_euler(quat.from_euler(e, seq), seq), e) < 1e-12


@given(q=quats(), seq=st.sampled_from(ALL_SEQS))
def test_round_trips_hypothesis(q, seq):
    assert qdist(quat.from_matrix(quat.to_matrix(q)), q) < 1e-15
    assert qdist(quat.from_rotvec(quat.to_rotvec(q)), q) < 1e-15
    assert qdist(quat.from_euler(quat.to_euler(q, seq), seq), q) < 1e-7  # gimbal-lock bound


def test_round_trips_adversarial(rots):
    assert qdist(quat.from_matrix(quat.to_matrix(rots)), rots) < 1e-15
    assert qdist(quat.from_rotvec(quat.to_rotvec(rots)), rots) < 1e-15
    assert qdist(quat.from_axis_angle(*quat.to_axis_angle(rots)), rots) < 1e-15
    assert maxabs(quat.exp(quat.log(rots)), rots) < 1e-15


# ----------------------------------------------------------------------------- properties

def test_matrix_properties(dtype, gen):
    tol = 4 * TOL[dtype]
    a, b = unit_quat((32,), gen, dtype=dtype), unit_quat((32,), gen, dtype=dtype)
    v = torch.randn(32, 3, generator=gen, dtype=F64).to(dtype)
    assert torch.equal(quat.to_matrix(a), quat.to_matrix(-a))
    assert maxabs(quat.to_matrix(quat.mul(a, b)), quat.to_matrix(a) @ quat.to_matrix(b)) < tol
    assert maxabs(quat.to_matrix(a) @ v[..., None], quat.rotate(a, v)[..., None]) < tol * 4
    # non-unit q: the rotation matrix of q / |q|
    assert maxabs(quat.to_matrix(1.7 * a), quat.to_matrix(a)) < tol


def test_slerp_endpoints_and_constant_speed(dtype, gen):
    tol = 4 * TOL[dtype]
    q0, q1 = unit_quat((32,), gen, dtype=dtype), unit_quat((32,), gen, dtype=dtype)
    q1s = torch.where(quat.dot(q0, q1)[:, None] < 0, -q1, q1)
    assert torch.equal(quat.slerp(q0, q1, 0.0), q0)
    assert maxabs(quat.slerp(q0, q1, 1.0), q1s) < tol
    assert maxabs(quat.slerp(q0, q1, 1.0, shortest=False), q1) < tol
    ts = torch.linspace(0, 1, 9, dtype=dtype)[:, None]
    path = quat.slerp(q0, q1, ts)
    step = 2 * torch.atan2((path[1:] - path[:-1]).norm(dim=-1), (path[1:] + path[:-1]).norm(dim=-1))
    total = 2 * torch.atan2((q1s - q0).norm(dim=-1), (q1s + q0).norm(dim=-1))
    assert maxabs(step, (total / 8).expand_as(step)) < tol * 4
    assert maxabs(path.norm(dim=-1), torch.ones_like(path[..., 0])) < tol


@pytest.mark.parametrize("shortest", [True, False])
def test_slerp_extrapolation_equals_power(shortest, gen):
    q0, q1 = unit_quat((32,), gen), unit_quat((32,), gen)
    # near-antipodal pairs (shortest=False turns by up to 360 degrees)
    q1[:4] = quat.mul(q0[:4], quat.from_rotvec(torch.tensor([[2 * math.pi - 1e-3, 0, 0]] * 4,
                                                            dtype=F64)))
    target = q1 if not shortest else torch.where(quat.dot(q0, q1)[:, None] < 0, -q1, q1)
    rel = quat.mul(quat.conj(q0), target)
    err = 0.0
    for t in (-0.5, 0.3, 1.5):
        power = quat.mul(q0, quat.exp(t * quat.log(rel)))
        err = max(err, maxabs(quat.slerp(q0, q1, t, shortest=shortest), power))
    assert err < 1e-12, err


def relative_rotations(gen, angles, n=8):
    """``(q0, q1)`` with ``q1 = +-q0 rot(angle)`` about random axes, for each angle (float64)."""
    q0 = unit_quat((len(angles), n), gen)
    axis = torch.randn(len(angles), n, 3, generator=gen, dtype=F64)
    half = torch.tensor(angles, dtype=F64)[:, None, None] / 2
    rel = torch.cat((torch.cos(half).expand(-1, n, 1),
                     torch.sin(half) * axis / axis.norm(dim=-1, keepdim=True)), -1)
    sign = torch.where(torch.arange(n) % 2 == 0, 1.0, -1.0).to(F64)[None, :, None]
    return q0.reshape(-1, 4), (sign * quat.mul(q0, rel)).reshape(-1, 4)


ANGLES = (0.0, 1e-9, 1e-6, 1e-3, 0.3, 0.6, 1.0, 2.0, 3.0, math.pi - 1e-6)


@pytest.mark.parametrize("dtype", [F64, torch.float32])
def test_slerp_at_degenerate_angles_against_scipy_power(dtype, gen):
    """``q0 (q0^-1 q1)^t`` by scipy rotation vectors (shortest path: angle in [0, pi]), at
    relative rotations from 0 to nearly 180 degrees, ``q1`` of either sign, per-pair and
    common ``t``, extrapolation included."""
    q0, q1 = relative_rotations(gen, ANGLES)
    r0, r1 = to_scipy(q0), to_scipy(q1)
    rv = (r0.inv() * r1).as_rotvec()
    tol = 1e-15 if dtype == F64 else 2e-6
    for t in (-0.5, 0.0, 0.3, 1.0, 1.5):
        ref = from_scipy((r0 * Rotation.from_rotvec(t * rv)).as_quat())
        common = quat.slerp(q0.to(dtype), q1.to(dtype), t).double()
        per_pair = quat.slerp(q0.to(dtype), q1.to(dtype), torch.full((len(q0),), t, dtype=dtype))
        assert qdist(common, ref) < tol * max(1.0, abs(t))
        assert torch.equal(per_pair.double(), common)
    # shortest path: the result is on q1's side (sign-aligned), and exact at t = 0
    assert torch.equal(quat.slerp(q0, q1, 0.0), q0)
    q1s = torch.where(quat.dot(q0, q1)[:, None] < 0, -q1, q1)
    assert maxabs(quat.slerp(q0, q1, 1.0), q1s) < 4e-16


@pytest.mark.parametrize("angle", [0.0, 1e-7, 1e-3])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_slerp_second_derivatives_at_and_near_equal_and_opposite(gen, angle, sign):
    """gradcheck and gradgradcheck (finite differences of the first and of the analytic
    second derivatives) where ``q1`` is ``q0`` (``sign = 1``) or ``-q0`` (``sign = -1``) up
    to a rotation by ``angle``, with ``t`` inside and outside [0, 1]."""
    q0, q1 = relative_rotations(gen, (angle,), n=2)
    q1 = sign * q1 * torch.tensor([[1.0], [-1.0]], dtype=F64)  # undo the alternating sign
    t = torch.tensor([0.3, 1.4], dtype=F64)
    args = [x.clone().requires_grad_() for x in (q0, q1, t)]
    assert torch.autograd.gradcheck(quat.slerp, args, eps=1e-6, atol=1e-7)
    assert torch.autograd.gradgradcheck(quat.slerp, args, eps=1e-6, atol=1e-6)
    one_t = [x.clone().requires_grad_() for x in (q0, q1, torch.tensor(0.6, dtype=F64))]
    assert torch.autograd.gradgradcheck(quat.slerp, one_t, eps=1e-6, atol=1e-6)


def test_slerp_antipodal_without_shortest_is_documented_circle(gen):
    q0 = unit_quat((5,), gen)
    q1 = unit_quat((5,), gen)
    q1[2] = -q0[2]
    t = torch.tensor([0.25, 0.5, 0.25, 0.75, 1.0], dtype=F64)
    out = quat.slerp(q0, q1, t, shortest=False)
    assert torch.isfinite(out).all()
    circle = torch.tensor([math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0], dtype=F64)
    assert maxabs(out[2], quat.mul(q0[2], circle)) < 1e-15
    others = [0, 1, 3, 4]
    assert maxabs(out[others], quat.slerp(q0[others], q1[others], t[others], shortest=False)) == 0
    # Nearly antipodal: still unit, on a great circle through q0, endpoints kept.
    near = -q0 + 1e-13 * torch.randn(5, 4, generator=gen, dtype=F64)
    near = near / near.norm(dim=-1, keepdim=True)
    ts = torch.linspace(0, 1, 5, dtype=F64)[:, None]
    path = quat.slerp(q0, near, ts, shortest=False)
    assert maxabs(path.norm(dim=-1), torch.ones(5, 5, dtype=F64)) < 1e-15
    assert torch.equal(path[0], q0) and maxabs(path[-1], near) < 1e-15


def test_log_of_negative_real_axis():
    out = quat.log(torch.tensor([[-2.0, 0, 0, 0], [0, 0, 0, 0]], dtype=F64))
    assert maxabs(out[0], torch.tensor([math.log(2), math.pi, 0, 0], dtype=F64)) < 1e-15
    assert out[1, 0] == -math.inf and torch.equal(out[1, 1:], torch.zeros(3, dtype=F64))


def test_zero_axis_and_identity_conventions():
    q = quat.from_axis_angle(torch.zeros(2, 3, dtype=F64), torch.tensor([0.0, 1.0], dtype=F64))
    assert torch.equal(q, quat.identity((2,), dtype=F64))
    axis, angle = quat.to_axis_angle(quat.identity((), dtype=F64))
    assert torch.equal(axis, torch.tensor([1.0, 0, 0], dtype=F64)) and angle == 0


def test_float32_accuracy(gen):
    q = torch.cat((unit_quat((256,), gen), adversarial_quats()))
    q1 = unit_quat((q.shape[0],), gen)
    rv, e = quat.to_rotvec(q), quat.to_euler(q, "xyz")
    cases = {
        "to_matrix": (quat.to_matrix, (q,)),
        "from_matrix": (quat.from_matrix, (quat.to_matrix(q),)),
        "to_rotvec": (quat.to_rotvec, (q,)),
        "from_rotvec": (quat.from_rotvec, (rv,)),
        "log": (quat.log, (q,)),
        "exp": (quat.exp, (quat.log(q),)),
        "from_euler": (lambda a: quat.from_euler(a, "xyz"), (e,)),
        "slerp": (lambda a, b: quat.slerp(a, b, 0.3), (q, q1)),
    }
    errs = {}
    for name, (f, args) in cases.items():
        ref = f(*args)
        out = f(*(a.float() for a in args)).double()
        errs[name] = qdist(out, ref) if ref.shape[-1] == 4 else maxabs(out, ref)
    assert max(errs.values()) < F32_TOL, errs
    # to_euler angles are ill conditioned near gimbal lock: compare through the rotation.
    e32 = quat.to_euler(q.float(), "xyz").double()
    assert qdist(quat.from_euler(e32, "xyz"), q) < F32_TOL


@pytest.mark.parametrize("dtype16", [torch.float16, torch.bfloat16])
def test_half_precision_computes_in_float32(dtype16, gen):
    q = unit_quat((8,), gen)
    out = quat.from_matrix(quat.to_matrix(q).to(dtype16))
    assert out.dtype == dtype16
    assert qdist(out.double(), q) < 2e-2
    assert quat.slerp(q.to(dtype16), q.to(dtype16), 0.5).dtype == dtype16
    assert quat.to_axis_angle(q.to(dtype16))[1].dtype == dtype16


def test_dtype_device_follow_inputs(dtype, device, gen):
    q = unit_quat((4,), gen, dtype=dtype).to(device)
    outs = [quat.slerp(q, q, 0.5), quat.exp(q), quat.log(q), quat.to_matrix(q),
            quat.from_matrix(quat.to_matrix(q)), quat.to_rotvec(q), quat.to_euler(q, "zyz"),
            *quat.to_axis_angle(q), quat.from_euler(q[:, 1:], "XYZ"),
            quat.from_axis_angle(q[:, 1:], 1.0), quat.from_rotvec(q[:, 1:])]
    assert all(o.dtype == dtype and o.device == q.device for o in outs)


def test_inputs_not_modified(gen):
    q, q1 = unit_quat((6,), gen), unit_quat((6,), gen)
    copies = (q.clone(), q1.clone())
    quat.slerp(q, q1, 0.4, shortest=True)
    quat.from_matrix(quat.to_matrix(q))
    quat.to_euler(q, "XYX")
    quat.to_rotvec(q)
    quat.to_axis_angle(q)
    assert torch.equal(q, copies[0]) and torch.equal(q1, copies[1])


def test_non_finite_stays_in_its_element(gen):
    q = unit_quat((4,), gen)
    bad = q.clone()
    bad[1, 2] = math.nan
    calls = [lambda x: quat.slerp(x, q, 0.5), lambda x: quat.from_matrix(quat.to_matrix(x)),
             quat.log, quat.to_rotvec, lambda x: quat.to_euler(x, "zxz"),
             lambda x: quat.to_axis_angle(x)[0]]
    for f in calls:
        out, ref = f(bad), f(q)
        assert torch.isnan(out[1]).any()
        assert torch.equal(out[[0, 2, 3]], ref[[0, 2, 3]])


def test_vmap_has_no_data_dependent_branches(gen):
    q0, q1 = unit_quat((5,), gen), unit_quat((5,), gen)
    vm = torch.func.vmap
    assert torch.equal(vm(lambda a, b: quat.slerp(a, b, 0.3))(q0, q1), quat.slerp(q0, q1, 0.3))
    m = quat.to_matrix(q0)
    assert torch.equal(vm(quat.from_matrix)(m), quat.from_matrix(m))
    assert torch.equal(vm(lambda a: quat.to_euler(a, "YXY"))(q0), quat.to_euler(q0, "YXY"))
    assert torch.equal(vm(quat.log)(q0), quat.log(q0))


def test_vmap_over_normalize_check_names_the_way_out(gen):
    """0.1 raised torch's raw data-dependent control-flow error under vmap."""
    q = unit_quat((3,), gen)
    with pytest.raises(RuntimeError, match=r"quat\.normalize: check=True .*check=False"):
        torch.func.vmap(lambda x: quat.normalize(x, check=True))(q)
    torch.testing.assert_close(torch.func.vmap(quat.normalize)(2 * q), q)


SCALES = [10.0 ** k for k in range(-30, 31, 5)]


@pytest.mark.parametrize("scale", SCALES, ids=lambda s: f"{s:g}")
def test_any_norm_functions_over_scales(scale, dtype, gen):
    """Functions documented for any non-zero norm agree with scipy on q / |q| for |q| from
    1e-30 to 1e30 (0.1: to_axis_angle of 1e-25 q gave the identity, to_matrix and normalize
    of 1e-25 q and to_rotvec of 1e20 q gave NaN in float32: squares under/overflowed)."""
    q = torch.cat((unit_quat((32,), gen), adversarial_quats()))
    q = q[q[:, 0] > 1e-3]  # away from 180 degrees, where the canonical sign is rounding
    r = to_scipy(q)
    x = (q * scale).to(dtype)
    tol = 1e-12 if dtype == F64 else F32_TOL
    assert maxabs(quat.to_matrix(x).double(), torch.from_numpy(r.as_matrix())) < tol
    assert maxabs(quat.normalize(x).double(), q) < tol
    assert maxabs(quat.to_rotvec(x).double(), torch.from_numpy(r.as_rotvec())) < 4 * tol
    axis, angle = quat.to_axis_angle(x)
    assert maxabs(angle.double(), torch.from_numpy(r.magnitude())) < 4 * tol
    moved = angle.double() > 1e-4
    assert maxabs((axis.double() * angle.double()[:, None])[moved],
                  torch.from_numpy(r.as_rotvec())[moved]) < 4 * tol
    euler = quat.to_euler(x, "ZYX").double()
    assert qdist(quat.from_euler(euler, "ZYX"), q) < 4 * tol
    # Algebra on any norm: |q|, q^-1 and log|q| follow the scale.
    assert maxabs(quat.norm(x).double() / scale, torch.ones(len(q), dtype=F64)) < tol
    assert maxabs(quat.inv(x).double() * scale, q * q.new_tensor([1, -1, -1, -1])) < tol
    log = quat.log(x).double()
    assert maxabs(log[:, 0], torch.full((len(q),), math.log(scale), dtype=F64)) < 70 * tol
    assert maxabs(2 * log[:, 1:], torch.from_numpy(r.as_rotvec())) < 4 * tol


# ---------------------------------------------------------------------------- batch shapes

def test_batch_shapes(batch_shape, gen):
    a = unit_quat(batch_shape, gen)
    b = unit_quat((*batch_shape[:-1], 1) if batch_shape else (), gen)
    v = torch.randn((*batch_shape, 3), generator=gen, dtype=F64)
    t = torch.rand(batch_shape, generator=gen, dtype=F64)
    flat = [x.reshape(-1, x.shape[-1]) for x in (a, b.expand_as(a), v)]
    cases = [
        (quat.mul(a, b), quat.mul(flat[0], flat[1])),
        (quat.rotate(a, v), quat.rotate(flat[0], flat[2])),
        (quat.slerp(a, b, t), quat.slerp(flat[0], flat[1], t.reshape(-1))),
        (quat.from_matrix(quat.to_matrix(a)), quat.from_matrix(quat.to_matrix(flat[0]))),
        (quat.to_euler(a, "xyz"), quat.to_euler(flat[0], "xyz")),
        (quat.from_axis_angle(v, t), quat.from_axis_angle(flat[2], t.reshape(-1))),
    ]
    for out, ref in cases:
        assert out.shape == (*batch_shape, ref.shape[-1])
        assert maxabs(out.reshape(ref.shape), ref) < 1e-15
    assert quat.to_matrix(a).shape == (*batch_shape, 3, 3)
    assert quat.to_axis_angle(a)[1].shape == batch_shape


def test_slerp_broadcasts_t_against_batch(gen):
    q0, q1 = unit_quat((3,), gen), unit_quat((3,), gen)
    t = torch.linspace(0, 1, 5, dtype=F64)[:, None]
    assert quat.slerp(q0, q1, t).shape == (5, 3, 4)
    assert quat.slerp(q0[None], q1, t).shape == (5, 3, 4)
    assert quat.from_axis_angle(q0[:, 1:], t).shape == (5, 3, 4)


# --------------------------------------------------------------------------------- autograd

def _random_points(gen):
    q0, q1 = unit_quat((4,), gen), unit_quat((4,), gen)
    return q0, q1, quat.to_matrix(q0), quat.to_rotvec(q0)


def test_gradcheck_random_points(gen):
    q0, q1, m, rv = _random_points(gen)
    v = torch.randn(4, 3, generator=gen, dtype=F64)
    t = torch.tensor([-0.5, 0.2, 0.7, 1.5], dtype=F64)
    gradcheck_at(lambda a, b, s: quat.slerp(a, b, s), q0, q1, t)
    gradcheck_at(lambda a, b, s: quat.slerp(a, b, s, shortest=False), q0, q1, t)
    gradcheck_at(quat.exp, torch.randn(4, 4, generator=gen, dtype=F64))
    gradcheck_at(quat.log, torch.randn(4, 4, generator=gen, dtype=F64))
    gradcheck_at(quat.from_matrix, m)
    gradcheck_at(quat.to_matrix, q0)
    gradcheck_at(quat.from_rotvec, rv)
    gradcheck_at(quat.to_rotvec, q0)
    gradcheck_at(quat.from_axis_angle, v, t)
    gradcheck_at(lambda q: quat.to_axis_angle(q), q0)
    for seq in ("xyz", "ZXZ"):
        gradcheck_at(lambda e, s=seq: quat.from_euler(e, s), v)
        gradcheck_at(lambda q, s=seq: quat.to_euler(q, s), q0)
    for f in (quat.mul, quat.dot):
        gradcheck_at(f, q0, q1)
    for f in (quat.conj, quat.inv, quat.norm, quat.normalize):
        gradcheck_at(f, q0)
    gradcheck_at(quat.rotate, q0, v)


def test_gradcheck_at_smooth_singular_points():
    """Removable singularities: the functions are smooth there, so gradcheck must pass."""
    ident = quat.identity((2,), dtype=F64)
    gradcheck_at(quat.from_rotvec, torch.zeros(2, 3, dtype=F64))
    gradcheck_at(quat.exp, torch.zeros(2, 4, dtype=F64))
    gradcheck_at(quat.log, ident)
    gradcheck_at(quat.to_rotvec, ident)
    gradcheck_at(quat.from_matrix, torch.eye(3, dtype=F64).expand(2, 3, 3))
    for t in (0.0, 0.5, 1.0):
        gradcheck_at(lambda a, b, s=t: quat.slerp(a, b, s), ident, ident)


@pytest.mark.parametrize("point", ["identity", "half_turn"])
def test_finite_gradients_at_singular_points(point):
    ident = quat.identity((), dtype=F64)
    q = ident if point == "identity" else torch.tensor([0.0, 0, 1, 0], dtype=F64)
    rv = quat.to_rotvec(q)
    cases = [(quat.from_matrix, quat.to_matrix(q)), (quat.to_rotvec, q),
             (quat.from_rotvec, rv), (quat.log, q), (quat.exp, quat.log(q)),
             (quat.to_axis_angle, q), (lambda x: quat.to_euler(x, "zyz"), q),
             (lambda x: quat.to_euler(x, "xyz"), quat.from_euler(
                 torch.tensor([0.3, math.pi / 2, 0.0], dtype=F64), "xyz"))]
    for f, x in cases:
        (g,) = grads(f, x)
        assert torch.isfinite(g).all(), f
    for t in (0.0, 0.5, 1.0):
        for shortest in (True, False):
            ga, gb = grads(lambda a, b, s=t, sh=shortest: quat.slerp(a, b, s, sh), q, q)
            assert torch.isfinite(ga).all() and torch.isfinite(gb).all()
        ga, gb = grads(lambda a, b, s=t: quat.slerp(a, b, s, shortest=False), q, -q)
        assert torch.isfinite(ga).all() and torch.isfinite(gb).all()
    gs = grads(quat.from_axis_angle, torch.zeros(3, dtype=F64), torch.tensor(1.0, dtype=F64))
    assert all(torch.isfinite(g).all() for g in gs)


# --------------------------------------------------------------------------- bad arguments

@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: quat.slerp(torch.zeros(3), torch.zeros(4), 0.5), ValueError,
         r"quat\.slerp: expected a \(\.\.\., 4\) tensor for q0, got shape \(3,\)"),
        (lambda: quat.slerp(torch.zeros(4), torch.zeros(2, 5), 0.5), ValueError, "q1"),
        (lambda: quat.slerp(torch.zeros(2, 4), torch.zeros(3, 4), 0.5), ValueError, "q0.*q1"),
        (lambda: quat.slerp(torch.zeros(2, 4), torch.zeros(2, 4), torch.zeros(3)),
         ValueError, r"t \(3,\)"),
        (lambda: quat.slerp(torch.zeros(4), torch.zeros(4), torch.zeros((), dtype=F64)),
         TypeError, "t"),
        (lambda: quat.slerp(torch.zeros(4, dtype=torch.int64), torch.zeros(4), 0.5),
         TypeError, "q0"),
        (lambda: quat.exp(torch.zeros(3)), ValueError, r"quat\.exp.*q.*\(3,\)"),
        (lambda: quat.log(torch.zeros(4, dtype=torch.int32)), TypeError, r"quat\.log.*q"),
        (lambda: quat.from_matrix(torch.zeros(4, 4)), ValueError,
         r"quat\.from_matrix: expected a \(\.\.\., 3, 3\) tensor for R, got shape \(4, 4\)"),
        (lambda: quat.from_matrix(torch.zeros(3)), ValueError, "R"),
        (lambda: quat.from_matrix(torch.eye(3, dtype=torch.int64)), TypeError, "R"),
        (lambda: quat.to_matrix(torch.zeros(3, 3)), ValueError, r"quat\.to_matrix.*q"),
        (lambda: quat.from_axis_angle(torch.zeros(4), 1.0), ValueError, "axis"),
        (lambda: quat.from_axis_angle(torch.zeros(2, 3), torch.zeros(3)), ValueError, "angle"),
        (lambda: quat.from_axis_angle(torch.zeros(3), torch.zeros((), dtype=torch.int64)),
         TypeError, "angle"),
        (lambda: quat.to_axis_angle(torch.zeros(3)), ValueError, "q"),
        (lambda: quat.from_rotvec(torch.zeros(4)), ValueError, r"from_rotvec.*rotvec"),
        (lambda: quat.from_rotvec(torch.zeros(3, dtype=torch.int64)), TypeError, "rotvec"),
        (lambda: quat.to_rotvec(torch.zeros(3)), ValueError, r"to_rotvec.*q"),
        (lambda: quat.from_euler(torch.zeros(4), "xyz"), ValueError, "angles"),
        (lambda: quat.from_euler(torch.zeros(3, dtype=torch.int64), "xyz"), TypeError, "angles"),
        (lambda: quat.from_euler(torch.zeros(3), "xyw"), ValueError, r"from_euler.*seq.*'xyw'"),
        (lambda: quat.from_euler(torch.zeros(3), "xxy"), ValueError, "seq.*consecutive"),
        (lambda: quat.from_euler(torch.zeros(3), "xy"), ValueError, "seq"),
        (lambda: quat.from_euler(torch.zeros(3), "xYz"), ValueError, "seq mixes"),
        (lambda: quat.to_euler(torch.zeros(4), "ZYz"), ValueError, r"to_euler: seq mixes"),
        (lambda: quat.to_euler(torch.zeros(4), "abc"), ValueError, "seq"),
        (lambda: quat.to_euler(torch.zeros(4), 123), TypeError, "seq.*str"),
        (lambda: quat.to_euler(torch.zeros(5), "xyz"), ValueError, r"for q, got shape \(5,\)"),
        (lambda: quat.slerp(torch.zeros(4), torch.zeros(4), 0.5, shortest="no"), TypeError,
         r"quat\.slerp: expected shortest to be a bool"),
        (lambda: quat.slerp(torch.zeros(4), torch.zeros(4), 0.5, shortest=1), TypeError,
         "shortest"),
        (lambda: quat.normalize(torch.ones(4), check="no"), TypeError,
         r"quat\.normalize: expected check to be a bool"),
    ],
)
def test_bad_arguments(call, exc, match):
    with pytest.raises(exc, match=match):
        call()


# ------------------------------------------------------------------ scalar-last conversion

def test_xyzw_matches_scipy_and_round_trips(rots, batch_shape, gen):
    # scipy renormalises in from_quat: equal to rounding (max error 2.2e-16)
    xyzw = torch.from_numpy(to_scipy(rots).as_quat(canonical=False))
    assert maxabs(quat.from_xyzw(xyzw), rots) < 1e-15
    mat = torch.from_numpy(Rotation.from_quat(quat.to_xyzw(rots).numpy()).as_matrix())
    assert maxabs(mat, quat.to_matrix(rots)) < 1e-15
    assert torch.equal(quat.to_xyzw(rots), rots[:, [1, 2, 3, 0]])
    q = unit_quat(batch_shape, gen)
    assert quat.to_xyzw(q).shape == q.shape
    assert torch.equal(quat.from_xyzw(quat.to_xyzw(q)), q)
    assert torch.equal(quat.to_xyzw(q)[..., 3], q[..., 0])
    x = torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=torch.float32)
    assert torch.equal(quat.from_xyzw(x), torch.tensor([4.0, 1.0, 2.0, 3.0]))


def test_xyzw_gradients_are_permutations():
    q = torch.randn(3, 4, dtype=F64, requires_grad=True)
    w = torch.randn(3, 4, dtype=F64)
    (quat.from_xyzw(q) * w).sum().backward()
    assert torch.equal(q.grad, quat.to_xyzw(w))


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda: quat.from_xyzw(torch.zeros(3)), ValueError,
         r"quat\.from_xyzw: expected a \(\.\.\., 4\) tensor for q, got shape \(3,\)"),
        (lambda: quat.to_xyzw(torch.zeros(2, 5)), ValueError, r"quat\.to_xyzw.*q.*\(2, 5\)"),
        (lambda: quat.from_xyzw(torch.zeros(4, dtype=torch.int64)), TypeError, r"from_xyzw.*q"),
        (lambda: quat.to_xyzw([0.0, 0.0, 0.0, 1.0]), TypeError, r"to_xyzw.*q.*list"),
    ],
)
def test_xyzw_bad_arguments(call, exc, match):
    with pytest.raises(exc, match=match):
        call()

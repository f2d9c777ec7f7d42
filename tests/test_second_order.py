"""Second derivatives at and near the degenerate points (docs/api_contract.md, "Second order").

Gauss-Newton, Laplace approximations and Newton steps in an ``x exp(xi)`` chart evaluate
Hessians exactly at the degenerate points (zero rotation, equal poses, zero error). For each
case of the table below the library's Hessian, computed four ways (``torch.func.hessian``,
``jacfwd(jacrev)``, double backward with ``torch.autograd.grad``, and nested forward mode
``jvp`` of ``jvp`` along a direction), is compared with central finite differences of an
independent reference: the mathematical definition written here in mpmath at 50 digits
(the SE(3) exponential is mpmath's matrix ``expm``, the logarithm the Mercator series of the
matrix logarithm, itself checked against mpmath's ``logm``), evaluated with steps of 1e-18 so
that the differences are exact to ~1e-14.

Points: the degenerate point itself and points 1e-9 and 1e-3 away from it. Functions that
are a cone at the degenerate point (an angle, a distance: no second derivative there) are
checked only near it. Inputs on a manifold (unit quaternions and dual quaternions) are
parametrised by a chart written here in plain torch (and the same in mpmath), so that the
Hessians are intrinsic and do not depend on how a function extends off the manifold.

0.1 failed every "at" row: its ``safe_norm`` / ``where`` guards gave zero second
derivatives at the degenerate points (e.g. the Hessian of ``w`` of ``from_rotvec`` at 0 was
0, not ``-I/4``, and the rotation block of ``pose_loss`` at zero error was 0, not ``2 I``).
"""

import functools
import math

import mpmath as mp
import pytest
import torch
from references import hamilton
from registry import DIFFERENTIABLE, FAMILIES, flat, sample_args

import torch_dq.dualquat as dq
from torch_dq import losses, quat

F64 = torch.float64
DPS = 50  # mpmath's digits for the references (H_STEP^2 = 1e-36 needs them)
H_STEP = mp.mpf("1e-18")


@pytest.fixture(autouse=True)
def _mp_precision():
    """mpmath's precision for this module's tests only (another module's setting, left
    global, made the second differences lose 6 digits)."""
    with mp.workdps(DPS):
        yield


# ----------------------------------------------------------------------------- test-local algebra


def t_chart(xi):
    """A smooth chart of unit quaternions at the identity: (1, xi / 2) / |(1, xi / 2)|.

    Its rotation angle is 2 atan(|xi| / 2) = |xi| + O(|xi|^3)."""
    c = torch.cat((torch.ones_like(xi[..., :1]), xi / 2), -1)
    return c / torch.sqrt((c * c).sum(-1, keepdim=True))


def t_dq(q, t):
    return torch.cat((q, 0.5 * hamilton(torch.cat((torch.zeros_like(t[..., :1]), t), -1), q)), -1)


def m_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw]


def m_norm(v):
    return mp.sqrt(sum(c * c for c in v))


def m_chart(xi):
    c = [mp.mpf(1)] + [x / 2 for x in xi]
    n = m_norm(c)
    return [x / n for x in c]


def m_dq(q, t):
    return q + [c / 2 for c in m_mul([mp.mpf(0), *list(t)], q)]


def m_log_vec(q):
    """Vector part of the quaternion logarithm: atan2(|v|, w) v / |v| (limit v / w at 0)."""
    s = m_norm(q[1:])
    scale = mp.atan2(s, q[0]) / s if s != 0 else 1 / q[0]
    return [scale * c for c in q[1:]]


def m_quat_of_matrix(R):
    """Quaternion (w > 0) of a rotation matrix near the identity."""
    w = mp.sqrt(1 + R[0, 0] + R[1, 1] + R[2, 2]) / 2
    return [w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
            (R[1, 0] - R[0, 1]) / (4 * w)]


def m_angle(qa, qb):
    """Rotation angle between two unit quaternions: 2 acos |qa . qb|."""
    d = abs(sum(x * y for x, y in zip(qa, qb, strict=True))) / (m_norm(qa) * m_norm(qb))
    return 2 * mp.acos(min(d, mp.mpf(1)))


# ----------------------------------------------------------------------------- references

def ref_from_rotvec(x):
    th = m_norm(x)
    if th == 0:
        return [mp.mpf(1), 0, 0, 0]
    return [mp.cos(th / 2)] + [mp.sin(th / 2) / th * c for c in x]


def ref_exp(x):
    e, n = mp.exp(x[0]), m_norm(x[1:])
    if n == 0:
        return [e, 0, 0, 0]
    return [e * mp.cos(n)] + [e * mp.sin(n) / n * c for c in x[1:]]


def ref_log(x):
    return [mp.log(m_norm(x)), *m_log_vec(x)]


def ref_to_rotvec(x):
    q = x if x[0] >= 0 else [-c for c in x]
    return [2 * c for c in m_log_vec(q)]


def ref_to_axis_angle(x):
    q = x if x[0] >= 0 else [-c for c in x]
    s = m_norm(q[1:])
    return [c / s for c in q[1:]] + [2 * mp.atan2(s, q[0])]


def m_logm_near_identity(M):
    r"""Principal matrix logarithm by the Mercator series
    :math:`\log(I + X) = \sum_{k \ge 1} (-1)^{k+1} X^k / k`, summed until a power of ``X``
    is below the working precision.

    For the homogeneous SE(3) matrices here ``X = M - I`` has eigenvalues
    :math:`e^{\pm i \theta} - 1` and 0 with :math:`\theta \le 10^{-3}`, so the terms shrink
    by ~1e-3 each (17 terms at 50 digits). About 7 times faster than ``mp.logm`` (an inverse
    scaling and squaring with many LU solves), which made the ``dualquat.log`` rows the slowest
    tests of the suite; ``test_logm_series_matches_mpmath_logm`` checks the two agree."""
    X = M - mp.eye(M.rows)
    power, total, k = X, X, 1
    while mp.mnorm(power, 1) > mp.eps * k:
        k += 1
        power = power * X
        total = total + power * (mp.mpf((-1) ** (k + 1)) / k)
    return total


def _se3_matrix(xi):
    wx, wy, wz, vx, vy, vz = xi
    return mp.matrix([[0, -wz, wy, vx], [wz, 0, -wx, vy], [-wy, wx, 0, vz], [0, 0, 0, 0]])


def ref_dq_exp(x):
    T = mp.expm(_se3_matrix(x))
    q = m_quat_of_matrix(T)
    return m_dq(q, [T[0, 3], T[1, 3], T[2, 3]])


T0 = (0.4, -1.1, 0.7)


def lib_dq_log_chart(x):
    return dq.log(t_dq(t_chart(x[:3]), torch.tensor(T0, dtype=F64) + x[3:]))


def _m_pose_matrix(x):
    """The homogeneous matrix of the pose (chart(x[:3]), T0 + x[3:])."""
    q, t = m_chart(x[:3]), [mp.mpf(c) + d for c, d in zip(T0, x[3:], strict=True)]
    w, a, b, c = q
    return mp.matrix([[1 - 2 * (b * b + c * c), 2 * (a * b - w * c), 2 * (a * c + w * b), t[0]],
                      [2 * (a * b + w * c), 1 - 2 * (a * a + c * c), 2 * (b * c - w * a), t[1]],
                      [2 * (a * c - w * b), 2 * (b * c + w * a), 1 - 2 * (a * a + b * b), t[2]],
                      [0, 0, 0, 1]])


def ref_dq_log_chart(x):
    L = m_logm_near_identity(_m_pose_matrix(x))
    return [L[2, 1], L[0, 2], L[1, 0], L[0, 3], L[1, 3], L[2, 3]]


Q0 = (0.5, -0.5, 0.1, 0.7)


def _q0():
    q = torch.tensor(Q0, dtype=F64)
    return q / q.norm()


def _m_q0():
    """``Q0`` normalised at 50 digits (its float64 rounding is not unit at that precision)."""
    q = [mp.mpf(c) for c in Q0]
    n = m_norm(q)
    return [c / n for c in q]


def lib_slerp_chart(x):
    """slerp(q0 c(d0), q0 c(d1), t) with x = (d0, d1, t)."""
    q0 = _q0()
    return quat.slerp(hamilton(q0, t_chart(x[:3])), hamilton(q0, t_chart(x[3:6])), x[6])


def ref_slerp_chart(x):
    q0 = _m_q0()
    a, b, t = m_mul(q0, m_chart(x[:3])), m_mul(q0, m_chart(x[3:6])), x[6]
    d = sum(u * v for u, v in zip(a, b, strict=True))
    if d < 0:
        b, d = [-c for c in b], -d
    omega = mp.acos(min(d, mp.mpf(1)))
    if omega == 0:
        return a
    s = mp.sin(omega)
    return [mp.sin((1 - t) * omega) / s * u + mp.sin(t * omega) / s * v
            for u, v in zip(a, b, strict=True)]


TA = (0.3, 0.2, -0.5)
WR, WT = 1.3, 0.7


def _pose_pair(x):
    a = t_dq(_q0(), torch.tensor(TA, dtype=F64))
    b = t_dq(hamilton(_q0(), t_chart(x[:3])), torch.tensor(TA, dtype=F64) + x[3:])
    return a, b


def _m_pose_pair(x):
    qa = _m_q0()
    qb = m_mul(qa, m_chart(x[:3]))
    return qa, qb, [mp.mpf(d) for d in x[3:]]


def lib_pose_loss(x):
    return losses.pose_loss(*_pose_pair(x), rot_weight=WR, trans_weight=WT)[None]


def ref_pose_loss(x):
    qa, qb, dt = _m_pose_pair(x)
    return [WR * m_angle(qa, qb) ** 2 + WT * sum(d * d for d in dt)]


def ref_squared_angle(x):
    qa, qb, _ = _m_pose_pair(x)
    return [m_angle(qa, qb) ** 2]


def ref_angle(x):
    qa, qb, _ = _m_pose_pair(x)
    return [m_angle(qa, qb)]


def ref_translation_error(x):
    return [m_norm(_m_pose_pair(x)[2])]


# ----------------------------------------------------------------------------- the table

# name: (library function of a flat float64 vector, reference, degenerate point, direction
# of the "near" points, whether the function is smooth AT the degenerate point)
CASES = {
    "quat.from_rotvec at 0": (quat.from_rotvec, ref_from_rotvec, [0.0] * 3, [0.3, -0.8, 0.5],
                              True),
    "quat.exp at v = 0": (quat.exp, ref_exp, [0.3, 0.0, 0.0, 0.0], [0.0, 0.6, 0.2, -0.7], True),
    "quat.log at the identity": (quat.log, ref_log, [1.2, 0.0, 0.0, 0.0], [0.0, 0.6, 0.2, -0.7],
                                 True),
    "quat.to_rotvec at the identity": (quat.to_rotvec, ref_to_rotvec, [0.9, 0.0, 0.0, 0.0],
                                       [0.1, -0.3, 0.7, 0.6], True),
    "quat.to_axis_angle near the identity": (
        lambda q: torch.cat((quat.to_axis_angle(q)[0], quat.to_axis_angle(q)[1][None])),
        ref_to_axis_angle, [1.0, 0.0, 0.0, 0.0], [0.0, -0.3, 0.7, 0.6], False),
    "dualquat.exp at a zero rotation": (dq.exp, ref_dq_exp, [0.0, 0.0, 0.0, 0.3, -0.2, 0.5],
                                        [0.5, -0.4, 0.7, 0.0, 0.0, 0.0], True),
    "dualquat.exp at a zero twist": (dq.exp, ref_dq_exp, [0.0] * 6,
                                     [0.5, -0.4, 0.7, 0.1, 0.2, 0.3], True),
    "dualquat.log at the identity rotation": (lib_dq_log_chart, ref_dq_log_chart, [0.0] * 6,
                                              [0.5, -0.4, 0.7, 0.0, 0.0, 0.0], True),
    "quat.slerp at q0 == q1": (lib_slerp_chart, ref_slerp_chart, [0.0] * 6 + [0.3],
                               [0.0] * 3 + [0.5, -0.4, 0.7, 0.0], True),
    "quat.slerp at q0 == q1, t = 1.7": (lib_slerp_chart, ref_slerp_chart, [0.0] * 6 + [1.7],
                                        [0.2, 0.1, 0.0, 0.5, -0.4, 0.7, 0.0], True),
    "losses.pose_loss at zero error": (lib_pose_loss, ref_pose_loss, [0.0] * 6,
                                       [0.5, -0.4, 0.7, 0.1, 0.2, 0.3], True),
    "losses.squared_rotation_angle at zero error": (
        lambda x: losses.squared_rotation_angle(*_pose_pair(x))[None], ref_squared_angle,
        [0.0] * 6, [0.5, -0.4, 0.7, 0.1, 0.2, 0.3], True),
    "losses.rotation_angle near zero error": (
        lambda x: losses.rotation_angle(*_pose_pair(x))[None], ref_angle,
        [0.0] * 6, [0.5, -0.4, 0.7, 0.1, 0.2, 0.3], False),
    "losses.translation_error near zero error": (
        lambda x: losses.translation_error(*_pose_pair(x))[None], ref_translation_error,
        [0.0] * 6, [0.1, 0.2, 0.3, 0.5, -0.4, 0.7], False),
}

OFFSETS = (0.0, 1e-9, 1e-3)
POINTS = [(name, off) for name, case in CASES.items() for off in OFFSETS
          if off > 0 or case[4]]


def _point(name, offset):
    _, _, x0, u, _ = CASES[name]
    u = torch.tensor(u, dtype=F64)
    return torch.tensor(x0, dtype=F64) + offset * u / u.norm()


@functools.cache
def reference_hessian(name, offset):
    """Central differences of the mpmath reference: ``(out, n, n)``, at 50 digits."""
    ref = CASES[name][1]
    x = [mp.mpf(float(v)) for v in _point(name, offset)]
    n, h = len(x), H_STEP

    center = ref(x)  # the two mixed evaluations of a diagonal entry (i == j) are at x

    def at(i, si, j, sj):
        if i == j and si != sj:
            return center
        y = list(x)
        y[i] += si * h
        y[j] += sj * h
        return ref(y)

    out = None
    for i in range(n):
        for j in range(i, n):
            pp, pm, mp_, mm = at(i, 1, j, 1), at(i, 1, j, -1), at(i, -1, j, 1), at(i, -1, j, -1)
            col = [float((a - b - c + d) / (4 * h * h)) for a, b, c, d in zip(pp, pm, mp_, mm,
                                                                             strict=True)]
            if out is None:
                out = torch.zeros(len(col), n, n, dtype=F64)
            out[:, i, j] = out[:, j, i] = torch.tensor(col, dtype=F64)
    return out


def double_backward_hessian(f, x):
    x = x.detach().clone().requires_grad_(True)
    y = f(x).reshape(-1)
    out = torch.zeros(y.numel(), x.numel(), x.numel(), dtype=F64)
    for k in range(y.numel()):
        (g,) = torch.autograd.grad(y[k], x, create_graph=True)
        if not g.requires_grad:  # a function linear in x: zero second derivative
            continue
        for i in range(x.numel()):
            (row,) = torch.autograd.grad(g[i], x, retain_graph=True, allow_unused=True)
            if row is not None:
                out[k, i] = row
    return out


def _close(got, want, what, offset):
    # Near a cone (an angle or a distance ~offset), rounding of the float64 inputs alone
    # moves the Hessian (~1 / offset) by eps / offset relative.
    tol = 1e-7 + (10 * torch.finfo(F64).eps / offset if offset > 0 else 0.0)
    scale = want.abs().max().clamp(min=1.0)
    err = ((got - want).abs().max() / scale).item()
    assert err < tol, f"{what}: relative error {err:.2e} (max |H| {scale.item():.2e})"


def _flat(f):
    return lambda x: f(x).reshape(-1)


@pytest.mark.parametrize("name,offset", POINTS, ids=[f"{n} + {o:g}" for n, o in POINTS])
def test_hessians(name, offset):
    f = _flat(CASES[name][0])
    x = _point(name, offset)
    want = reference_hessian(name, offset)
    _close(torch.func.hessian(f)(x), want, "torch.func.hessian", offset)
    _close(torch.func.jacfwd(torch.func.jacrev(f))(x), want, "jacfwd(jacrev)", offset)
    _close(double_backward_hessian(f, x), want, "double backward", offset)
    # Nested forward mode: d^2/ds^2 f(x + s u) = u^T H u.
    gen = torch.Generator().manual_seed(5)
    u = torch.randn(x.shape, generator=gen, dtype=F64)
    second = torch.func.jvp(lambda y: torch.func.jvp(f, (y,), (u,))[1], (x,), (u,))[1]
    _close(second, torch.einsum("kij,i,j->k", want, u, u), "jvp of jvp", offset)


def test_logm_series_matches_mpmath_logm():
    """The series behind ``ref_dq_log_chart`` against mpmath's own ``logm`` at the farthest
    point of its rows (1e-3 from the identity rotation), to 45 of the 50 digits."""
    _, _, x0, u, _ = CASES["dualquat.log at the identity rotation"]
    scale = mp.mpf("1e-3") / m_norm([mp.mpf(c) for c in u])
    R = _m_pose_matrix([mp.mpf(a) + scale * c for a, c in zip(x0, u, strict=True)])
    assert mp.mnorm(m_logm_near_identity(R) - mp.logm(R), 1) < mp.mpf("1e-45")


def test_pose_loss_gauss_newton_block():
    """The issue's statement, in so many words: at zero error the Hessian of pose_loss in the
    chart b = a exp(xi) is 2 diag(rot_weight I, trans_weight I)."""
    H = torch.func.hessian(lambda x: lib_pose_loss(x)[0])(torch.zeros(6, dtype=F64))
    want = torch.diag(torch.tensor([WR] * 3 + [WT] * 3, dtype=F64)) * 2.0
    torch.testing.assert_close(H, want, atol=1e-12, rtol=0)


def test_from_rotvec_and_exp_hessian_of_w():
    """The issue's figures: Hessian of w at 0 is -I/4 for from_rotvec and -I for exp."""
    zero3, zero4 = torch.zeros(3, dtype=F64), torch.zeros(4, dtype=F64)
    h = torch.func.hessian(lambda v: quat.from_rotvec(v)[0])(zero3)
    torch.testing.assert_close(h, -torch.eye(3, dtype=F64) / 4, atol=1e-14, rtol=0)
    h = torch.func.hessian(lambda q: quat.exp(q)[0])(zero4)
    torch.testing.assert_close(h[1:, 1:], -torch.eye(3, dtype=F64), atol=1e-14, rtol=0)


# ----------------------------------------------------------------------------- the series

EVEN_REFS = {
    "cos": mp.cos,
    "sinc": lambda t: mp.sin(t) / t,
    "atanc": lambda t: mp.atan(t) / t,
    "se3_c1": lambda t: (1 - mp.cos(t)) / t**2,
    "se3_c2": lambda t: (t - mp.sin(t)) / t**3,
    "se3_c3": lambda t: (1 - t / 2 * mp.cot(t / 2)) / t**2,
}
# Relative error bounds in units of eps, for the value and the first two derivatives in
# x2 (measured maxima: float64 13, 2.5e3, 1.3e6; float32 3, 24, 1.2e3; the derivatives'
# at se3_c3 just above the switch, where the closed form's derivatives cancel).
EVEN_BOUNDS = (30, 8e3, 4e6)


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
@pytest.mark.parametrize("name", sorted(EVEN_REFS))
def test_even_series_and_derivatives_against_mpmath(name, dtype):
    """_numerics.even: value, d/dx2 and d2/dx2^2 of f(sqrt(x2)) on both sides of the switch
    between the series and the closed form (x2 from 1e-12 to 4), against mpmath."""
    from torch_dq._numerics import even

    x2 = torch.logspace(-12, 0.6, 61, dtype=F64).to(dtype).requires_grad_()
    y = even(name, x2)
    (g,) = torch.autograd.grad(y.sum(), x2, create_graph=True)
    (h,) = torch.autograd.grad(g.sum(), x2)
    ref = EVEN_REFS[name]
    eps = torch.finfo(dtype).eps
    for order, got, bound in zip((0, 1, 2), (y, g, h), EVEN_BOUNDS, strict=True):
        want = torch.tensor([float(mp.diff(lambda u: ref(mp.sqrt(u)), mp.mpf(float(v)), order))
                             for v in x2.detach().double()], dtype=F64)
        # Relative error, floored at 10% of the largest value (cos crosses zero).
        scale = torch.maximum(want.abs(), 0.1 * want.abs().max())
        err = ((got.detach().double() - want).abs() / scale).max().item() / eps
        assert err < bound, (name, order, err)


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
@pytest.mark.parametrize("name", ["sinc", "se3_c1", "se3_c2", "se3_c3"])
def test_even_slope_against_mpmath(name, dtype):
    """_numerics.even_slope (the dual-number evaluation of the closed-form span Jacobians):
    its value is even's to the bit, its slope d/dx2 within twice even's bound of its
    autograd derivative (measured: float64 8.8e3 eps, se3_c3 just above the switch, where
    its closed form cancels), on both sides of the switch (x2 from 1e-12 to 9.8, just under
    pi^2)."""
    from torch_dq._numerics import even, even_slope

    x2 = torch.logspace(-12, math.log10(9.8), 61, dtype=F64).to(dtype)
    value, slope = even_slope(name, x2)
    assert torch.equal(value, even(name, x2))
    ref = EVEN_REFS[name]
    want = torch.tensor([float(mp.diff(lambda u: ref(mp.sqrt(u)), mp.mpf(float(v)), 1))
                         for v in x2.double()], dtype=F64)
    err = ((slope.double() - want).abs() / want.abs()).max().item()
    assert err < 2 * EVEN_BOUNDS[1] * torch.finfo(dtype).eps, err


SECOND_ORDER = [(o, family) for o in DIFFERENTIABLE for family in FAMILIES
                if family not in o.kinks]


@pytest.mark.parametrize("o, family", SECOND_ORDER,
                         ids=[f"{o.id}-{family}" for o, family in SECOND_ORDER])
def test_gradgradcheck_on_the_registry(o, family):
    """Every registry row, at a sample of every degenerate family of the sampler (identity,
    equal poses, opposite signs, pure translations, half turns) and at a random point:
    torch's gradgradcheck (double backward against finite differences of the gradient) in
    ambient coordinates (off the manifold too), which a zero second derivative from a guard
    fails. Skipped families (``Op.kinks``) are where the function has no second derivative.
    ``fast_mode``: the Jacobians are compared along random directions (one vector-Jacobian
    product instead of one per entry), which a wrong or missing entry still fails."""
    gen = torch.Generator().manual_seed(11)
    args = tuple(a.requires_grad_() for a in sample_args(o, (), gen, family))
    assert torch.autograd.gradgradcheck(flat(o), args, fast_mode=True)

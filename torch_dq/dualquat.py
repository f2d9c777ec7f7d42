r"""Dual quaternions on plain ``(..., 8)`` tensors (``import torch_dq.dualquat as dq``).

Layout ``(rw, rx, ry, rz, dw, dx, dy, dz)``: real part then dual part, each a
``(w, x, y, z)`` Hamilton quaternion. The rigid transform :math:`x \mapsto R x + t` is
``real = r`` (the rotation quaternion) and ``dual = 0.5 * (0, t) * r``, the layout of
pytransform3d. A unit dual quaternion and its negative are the same transform.
Products compose like matrices: ``mul(a, b)`` applies ``b`` first.

float16/bfloat16 inputs are computed in float32 and cast back. Inputs are never modified in
place. Non-unit input: the algebra (``mul``, ``conj*``, ``inv``, ``norm``, ``dot``) takes any
dual quaternion; ``normalize`` projects (``check=True`` raises on a zero or non-finite real
part), ``is_unit`` tests; every other function assumes unit input and does not check it
(call ``normalize`` first). Non-finite components give NaN (or inf) in their own batch
element only, never a finite value.
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _dispatch, quat
from ._core import (
    dq_from_rt,
    dq_mul,
    hemisphere,
    join,
    lift,
    lower,
    qconj,
    qmul,
    qrotate,
    split,
    translation,
    twist_translation,
)
from ._dq_conversions import (
    from_matrix,
    from_pose7,
    from_rt,
    from_screw,
    to_matrix,
    to_pose7,
    to_rt,
    to_screw,
)
from ._kernels import dual_angle as _dual_angle_kernel
from ._kernels import sclerp as _sclerp_kernel
from ._kernels.weights import screw_weights
from ._numerics import (
    compute_dtype,
    even,
    nan_unless,
    power_of_two_scale,
    prescale,
    safe_denominator,
    safe_norm,
    threshold,
    unscaled,
)
from .dual import Dual

__all__ = [
    "angle",
    "apply",
    "apply_line",
    "conj",
    "conj_dual",
    "conj_full",
    "dlb",
    "dot",
    "exp",
    "from_matrix",
    "from_pose7",
    "from_rt",
    "from_screw",
    "identity",
    "inv",
    "is_unit",
    "log",
    "mul",
    "norm",
    "normalize",
    "sclerp",
    "to_matrix",
    "to_pose7",
    "to_rt",
    "to_screw",
]

for _f in (from_matrix, from_pose7, from_rt, from_screw, to_matrix, to_pose7, to_rt, to_screw):
    _f.__module__ = __name__  # documented and pickled as torch_dq.dualquat.<name>


# ----------------------------------------------------------------------------- helpers

def _dq(fn: str, name: str, x: Tensor) -> Tensor:
    return _checks.tensor(fn, name, x, 8)


def _normalize(x: Tensor) -> Tensor:
    """Unchecked projection onto unit dual quaternions (see :func:`normalize`)."""
    x = unscaled(x)
    r, d = split(x)
    n = torch.linalg.vector_norm(r, dim=-1, keepdim=True)
    m = prescale(r, n, power=1)
    if m is None:  # every |r| finite and far from under- or overflow
        n = unscaled(n)
    else:
        x = x / m  # exact; no square of r over- or underflows
        r, d = split(x)
        n = torch.linalg.vector_norm(r, dim=-1, keepdim=True)
        n = nan_unless((n > 0) & torch.isfinite(n), n)
    r = r / n
    d = d / n
    return join(r, d - r * (r * d).sum(-1, keepdim=True))


# ----------------------------------------------------------------------------- algebra

def identity(shape: int | Sequence[int] = (), dtype: torch.dtype | None = None,
             device: torch.device | str | None = None) -> Tensor:
    """Identity transforms ``(1, 0, 0, 0, 0, 0, 0, 0)`` of batch shape ``shape``.

    Example:
        >>> identity()
        tensor([1., 0., 0., 0., 0., 0., 0., 0.])
    """
    dims, dtype = _checks.factory_args("dualquat.identity", shape, dtype)
    r = quat.identity(dims, dtype=dtype, device=device)
    return torch.cat((r, torch.zeros_like(r)), dim=-1)


def mul(a: Tensor, b: Tensor) -> Tensor:
    r"""Dual-quaternion product :math:`(r_a + \epsilon d_a)(r_b + \epsilon d_b)`.

    Args:
        a: ``(..., 8)`` dual quaternions (any, not necessarily unit).
        b: ``(..., 8)`` dual quaternions, batch broadcastable with ``a``.

    Returns:
        ``(..., 8)``: for unit inputs, the transform ``b`` followed by ``a``
        (``to_matrix(mul(a, b)) == to_matrix(a) @ to_matrix(b)``).
    """
    _checks.pair("dualquat.mul", a, b, 8)
    return lower(dq_mul(lift(a), lift(b)), a.dtype)


def conj(x: Tensor) -> Tensor:
    r"""Quaternion conjugate of both parts, :math:`r^* + \epsilon d^*` (the inverse of a unit x).

    Args:
        x: ``(..., 8)`` dual quaternions (any norm).
    """
    _dq("dualquat.conj", "x", x)
    return x * x.new_tensor([1.0, -1.0, -1.0, -1.0, 1.0, -1.0, -1.0, -1.0])


def conj_dual(x: Tensor) -> Tensor:
    r"""Dual-number conjugate :math:`r - \epsilon d`.

    Args:
        x: ``(..., 8)`` dual quaternions (any norm).
    """
    _dq("dualquat.conj_dual", "x", x)
    return x * x.new_tensor([1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0])


def conj_full(x: Tensor) -> Tensor:
    r"""Both conjugates, :math:`r^* - \epsilon d^*` (used to act on points as dual quaternions).

    Args:
        x: ``(..., 8)`` dual quaternions (any norm).
    """
    _dq("dualquat.conj_full", "x", x)
    return x * x.new_tensor([1.0, -1.0, -1.0, -1.0, -1.0, 1.0, 1.0, 1.0])


def inv(x: Tensor) -> Tensor:
    r"""Multiplicative inverse :math:`r^{-1} - \epsilon\, r^{-1} d\, r^{-1}`.

    Valid for any dual quaternion with a non-zero real part (zero real part: non-finite
    values in that element, a non-finite real part: NaN); for a unit dual quaternion it
    equals :func:`conj` (non-unit input is inverted exactly, not normalised). The real part
    is scaled by a power of two first (as :func:`torch_dq.quat.inv`), so no square of a huge
    or tiny ``r`` (1e200 in float64, 1e20 in float32) overflows or underflows.

    Args:
        x: ``(..., 8)`` dual quaternions (any norm).
    """
    _dq("dualquat.inv", "x", x)
    dtype = x.dtype
    r, d = split(lift(x))
    m = power_of_two_scale(r)
    p = r / m  # exact
    n2 = (p * p).sum(-1, keepdim=True)
    r_inv = qconj(p) / (nan_unless(torch.isfinite(n2), n2) * m)
    return lower(join(r_inv, -qmul(qmul(r_inv, d), r_inv)), dtype)


def norm(x: Tensor) -> Dual:
    r"""Dual norm :math:`\|x\| = \sqrt{x x^*} = |r| + \epsilon\, (r \cdot d) / |r|`.

    Args:
        x: ``(..., 8)`` dual quaternions (any norm).

    Returns:
        ``Dual`` of batch shape ``(...)``; ``1 + eps 0`` for a unit dual quaternion. ``r`` is
        scaled by a power of two first and the dual part formed as :math:`(r / |r|) \cdot d`,
        so huge or tiny inputs (1e200 in float64, 1e20 in float32) neither overflow nor
        underflow; a zero real part gives a NaN dual part.
    """
    _dq("dualquat.norm", "x", x)
    r, d = split(lift(x))
    m = power_of_two_scale(r)
    n = torch.linalg.vector_norm(r / m, dim=-1, keepdim=True)
    u = r / m / n
    return Dual((m * n)[..., 0].to(x.dtype), (u * d).sum(-1).to(x.dtype))


def dot(a: Tensor, b: Tensor) -> Dual:
    r"""The paper's dual scalar product (eq. 1).

    :math:`a \cdot b = \tfrac12 (a b^* + b a^*) = r_a \cdot r_b
    + \epsilon\, (r_a \cdot d_b + r_b \cdot d_a)`. For unit inputs it is
    :math:`\cos \bar\theta` of their dual angle (eq. 7).

    Args:
        a: ``(..., 8)`` dual quaternions (any norm).
        b: ``(..., 8)`` dual quaternions, batch broadcastable with ``a``.

    Returns:
        ``Dual`` of the broadcast batch shape.
    """
    _checks.pair("dualquat.dot", a, b, 8)
    ra, da = split(lift(a))
    rb, db = split(lift(b))
    return Dual((ra * rb).sum(-1).to(a.dtype), (ra * db + rb * da).sum(-1).to(a.dtype))


def normalize(x: Tensor, check: bool = False) -> Tensor:
    r"""Project onto unit dual quaternions: :math:`x / \|x\|` in dual arithmetic.

    With :math:`n = |r|`: :math:`r' = r / n` and
    :math:`d' = d / n - r' \, (r' \cdot d) / n`, so :math:`|r'| = 1` and
    :math:`r' \cdot d' = 0`. The translation :math:`2\,\mathrm{vec}(d r^*)/|r|^2` is kept
    exactly; only the non-rigid scalar part of :math:`d r^*` is removed. Idempotent.

    Args:
        x: ``(..., 8)`` with non-zero real part.
        check: if True, raise ``ValueError`` when some real part is zero or non-finite
            (synchronises with the device). Otherwise such an element gives NaN in its own
            output only.

    Returns:
        ``(..., 8)`` unit dual quaternions.
    """
    _dq("dualquat.normalize", "x", x)
    check = _checks.flag("dualquat.normalize", "check", check)
    dtype, x = x.dtype, lift(x)
    if check:
        r = x[..., :4]
        ok = torch.isfinite(r).all(-1) & (r != 0).any(-1)
        if not _checks.host_all("dualquat.normalize", "check=True", ok):
            _checks.fail("dualquat.normalize", "x contains zero or non-finite real parts")
    return lower(_normalize(x), dtype)


def is_unit(x: Tensor, atol: float | None = None) -> Tensor:
    r"""Per-element test that ``x`` is a unit dual quaternion, to ``atol``.

    Checks :math:`\big||r| - 1\big| \le atol` and
    :math:`|r \cdot d| \le atol \max(1, |d|)`: the orthogonality defect is measured relative
    to the dual part, whose size is half the translation, so that rounding of a pose far from
    the origin (``|t| = 1e3`` in float32) still counts as unit.

    Args:
        x: ``(..., 8)`` dual quaternions (any values).
        atol: tolerance; default ``1e-10`` for float64, ``1e-5`` for float32 and 10 machine
            epsilons for float16 (``9.8e-3``) and bfloat16 (``7.8e-2``), whose rounding of a
            unit dual quaternion alone leaves defects up to one epsilon.

    Returns:
        ``(...)`` bool tensor; False where ``x`` has a non-finite component. float16/bfloat16
        are tested in float32.
    """
    _dq("dualquat.is_unit", "x", x)
    if atol is not None and (isinstance(atol, bool) or not isinstance(atol, numbers.Real)
                             or not atol >= 0):
        _checks.fail("dualquat.is_unit", f"expected atol to be a number >= 0, got {atol!r}")
    if atol is None:
        atol = threshold("unit_atol", x.dtype)
    x = lift(x)
    r, d = split(x)
    finite = torch.isfinite(x).all(-1)
    scale = torch.linalg.vector_norm(d, dim=-1).clamp(min=1.0)
    unit_real = (torch.linalg.vector_norm(r, dim=-1) - 1.0).abs() <= atol
    return finite & unit_real & ((r * d).sum(-1).abs() <= atol * scale)


# ----------------------------------------------------------------------------- exp / log

def exp(xi: Tensor) -> Tensor:
    r"""Rigid-motion exponential of twists :math:`\xi = (\omega, v)`.

    The matrix exponential of :math:`\begin{pmatrix}[\omega]_\times & v\\0&0\end{pmatrix}`
    (pytransform3d's exponential coordinates; no factor 1/2): rotation by
    :math:`|\omega|` about :math:`\omega`, translation
    :math:`t = v + c_1\,\omega\times v + c_2\,\omega\times(\omega\times v)` with
    :math:`c_1 = (1-\cos\theta)/\theta^2`, :math:`c_2 = (\theta-\sin\theta)/\theta^3`.
    :math:`c_1, c_2` (and the rotation) are evaluated from :math:`\theta^2 = |\omega|^2`
    with series near 0, so a pure translation ``omega = 0`` is exact, and first and second
    derivatives there are exact too.

    Args:
        xi: ``(..., 6)`` twists ``(omega_x, omega_y, omega_z, v_x, v_y, v_z)``.

    Returns:
        ``(..., 8)`` unit dual quaternions.
    """
    _checks.tensor("dualquat.exp", "xi", xi, 6)
    xl = lift(xi)
    omega, v = xl[..., :3], xl[..., 3:]
    theta2 = (omega * omega).sum(-1, keepdim=True)
    wxv = torch.linalg.cross(omega, v, dim=-1)
    t = v + even("se3_c1", theta2) * wxv + even("se3_c2", theta2) * torch.linalg.cross(
        omega, wxv, dim=-1)
    return lower(dq_from_rt(quat.from_rotvec(omega), t), xi.dtype)


def log(x: Tensor) -> Tensor:
    r"""Twist :math:`(\omega, v)` with :math:`\exp(\xi) = x`; inverse of :func:`exp`.

    :math:`\omega` is the rotation vector with angle in ``[0, pi]`` (``x`` and ``-x`` give the
    same twist) and :math:`v = t - \frac12 \omega \times t + c_3\,\omega \times (\omega \times t)`
    with :math:`c_3 = (1 - \frac\theta2 \cot\frac\theta2)/\theta^2`, evaluated from
    :math:`\theta^2` (a series near 0), so the twist is smooth at the identity rotation:
    value, gradient and Hessian exact there.
    At exactly 180 degrees the sign of :math:`\omega` is scipy's canonical one (first non-zero
    of its x, y, z positive, see :func:`torch_dq.quat.to_rotvec`), for ``x`` and ``-x`` alike.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).

    Returns:
        ``(..., 6)`` twists.
    """
    _dq("dualquat.log", "x", x)
    r, d = split(lift(x))
    omega = quat.to_rotvec(r)
    return lower(torch.cat((omega, twist_translation(omega, translation(r, d))), -1), x.dtype)


# ----------------------------------------------------------------------------- actions

def apply(x: Tensor, points: Tensor) -> Tensor:
    r"""Transform points, :math:`p \mapsto R p + t`.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).
        points: ``(..., 3)``, batch broadcastable with ``x``.

    Returns:
        ``(..., 3)`` transformed points.

    Example:
        >>> x = from_rt(torch.tensor([1., 0., 0., 0.]), torch.tensor([1., 2., 3.]))
        >>> apply(x, torch.zeros(3))
        tensor([1., 2., 3.])
    """
    fn = "dualquat.apply"
    _dq(fn, "x", x)
    _checks.tensor(fn, "points", points, 3)
    _checks.same_dtype_device(fn, x=x, points=points)
    _checks.broadcast_batch(fn, x=(x, 1), points=(points, 1))
    r, d = split(lift(x))
    return lower(qrotate(r, lift(points)) + translation(r, d), x.dtype)


def apply_line(x: Tensor, direction: Tensor, moment: Tensor) -> tuple[Tensor, Tensor]:
    r"""Transform Plücker lines :math:`(l, m)`: :math:`l' = R l`, :math:`m' = R m + t \times R l`.

    Equivalent to the dual-vector product :math:`x (l + \epsilon m) x^*` of the paper.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).
        direction: ``(..., 3)`` line directions ``l``.
        moment: ``(..., 3)`` line moments ``m = p x l``.

    Returns:
        ``(direction', moment')``, both ``(..., 3)``.
    """
    fn = "dualquat.apply_line"
    _dq(fn, "x", x)
    _checks.tensor(fn, "direction", direction, 3)
    _checks.tensor(fn, "moment", moment, 3)
    _checks.same_dtype_device(fn, x=x, direction=direction, moment=moment)
    batch = _checks.broadcast_batch(fn, x=(x, 1), direction=(direction, 1), moment=(moment, 1))
    r, d = split(lift(x))
    l2 = qrotate(r, lift(direction)).expand(*batch, 3)
    t = translation(r, d).expand(*batch, 3)
    m2 = qrotate(r, lift(moment)).expand(*batch, 3) + torch.linalg.cross(t, l2, dim=-1)
    return l2.to(x.dtype), m2.to(x.dtype)


# ----------------------------------------------------------------------------- dual angle

def angle(a: Tensor, b: Tensor) -> Dual:
    r"""Dual angle :math:`\bar\theta = \theta + \epsilon\hat\theta` between unit dual quaternions.

    The paper's eqs. 4-7, with no sign flip, so that ``dual.cos(angle(a, b)) == dot(a, b)``
    (eq. 7, :math:`\bar q_0 \cdot \bar q_1 = \cos\bar\theta`):

    - real part (eq. 4): :math:`\theta = \arccos(q_0 \cdot q_1) \in [0, \pi]`, evaluated as
      :math:`2\,\mathrm{atan2}(|q_1 - q_0|, |q_1 + q_0|)`, accurate near 0 and pi. It is half
      the relative rotation angle (or pi minus it when the signs disagree).
    - dual part (eq. 5): :math:`\hat\theta = -(q_0 \cdot \hat q_1 + q_1 \cdot \hat q_0)
      / \sin\theta`, half the translation along the relative screw axis (signed).
    - degenerate branch (eq. 6), taken where :math:`\sin\theta \le \sqrt{\epsilon}` of the
      dtype (equal or opposite rotations to working precision): :math:`|d_1 - d_0|` with
      :math:`d_i` the translation of pose ``i`` along its own screw axis, i.e.
      :math:`|(t_1 - t_0)\cdot u|` for the common rotation axis ``u``, and
      :math:`|t_1 - t_0|` when the rotations are the identity. As written in the paper this
      is a full axial distance, while eq. 5 tends to half the relative screw's translation
      (signed) as :math:`\theta \to 0`: for a motion along the common rotation axis the
      value jumps by a factor 2 at the branch switch (in general the two branches measure
      along different axes: the poses' own, and the relative screw's).

    Derivatives: :math:`\theta` is smooth for :math:`0 < \theta < \pi` and has a kink (a
    cone, like ``|x|``) at 0 and pi, where its gradient is the zero subgradient;
    :math:`\hat\theta` is smooth in each branch. Eager reverse mode runs a fused op with an
    analytic backward (twice differentiable); under ``torch.func`` transforms
    (``hessian``, ``jacfwd``, nested ``jvp``, ``vmap``) and forward-mode AD the plain-op
    formulas of :func:`_eqs4_5` and :func:`_eq6` run instead, so second derivatives are
    right in every mode.

    Args:
        a: ``(..., 8)`` unit dual quaternions (not checked).
        b: ``(..., 8)`` unit dual quaternions, batch broadcastable with ``a``.

    Returns:
        ``Dual`` of the broadcast batch shape. Non-finite components give NaN (or inf) in
        their own batch element.

    Example:
        >>> a = identity()
        >>> b = from_screw(torch.tensor([0., 0., 1.]), torch.zeros(3), 1.0, 2.0)
        >>> angle(a, b)  # half the screw: (theta + eps d) / 2
        Dual(real=tensor(0.5000), dual=tensor(1.))
    """
    fn = "dualquat.angle"
    _checks.pair(fn, a, b, 8)
    dtype = a.dtype
    a, b = torch.broadcast_tensors(lift(a), lift(b))
    if _dispatch.fused_path(a, b):
        theta, theta_hat, degenerate = _dual_angle_kernel.dual_angle(a, b)
    else:
        theta, theta_hat, degenerate = _eqs4_5(a, b)
    theta_hat = torch.where(degenerate, _eq6(a, b), theta_hat)
    return Dual(theta.to(dtype), theta_hat.to(dtype))


def _eqs4_5(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r"""Eqs. 4 and 5 on broadcast ``a, b (..., 8)``, in plain torch ops (smooth to every
    order for :math:`0 < \theta < \pi`): ``(theta, theta_hat, degenerate)``, where
    ``degenerate`` marks :math:`\sin\theta` below the eq. 6 threshold (``theta_hat`` there is
    a placeholder). The fused op ``torch_dq._kernels.dual_angle.dual_angle`` computes the
    same; :func:`angle` documents the conventions."""
    P, Q, R, S = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    # eq. 1: q0 . q1 = c + eps delta, with c = P . R and delta = P . S + R . Q.
    delta = (P * S).sum(-1) + (R * Q).sum(-1)
    # eq. 4: theta = acos(c) in [0, pi], as 2 atan2(|R - P|, |R + P|) (for unit P and R:
    # |R -+ P|^2 = 2 -+ 2c), accurate near 0 and pi; an infinite input gives NaN, not pi / 2.
    u, v = safe_norm(R - P), safe_norm(R + P)
    theta = nan_unless(torch.isfinite(u) & torch.isfinite(v), 2.0 * torch.atan2(u, v))
    sin_theta = 0.5 * u * v  # = sqrt(1 - c^2)
    # eq. 7's dual part, delta = -theta_hat sin(theta), solved where sin(theta) != 0: eq. 5.
    degenerate = sin_theta <= threshold("dual_angle_degenerate", a.dtype)
    theta_hat = -delta / safe_denominator(sin_theta, degenerate)
    return theta, theta_hat, degenerate


def _eq6(a: Tensor, b: Tensor) -> Tensor:
    r"""Eq. 6 on broadcast ``a, b (..., 8)``: :math:`\hat\theta = |d_1 - d_0|`, for equal or
    opposite rotations.

    :math:`d_i = t_i \cdot u_i` is the translation of pose ``i`` along its own screw axis
    (eq. 2; for a screw through ``p``, :math:`t = d u + (I - R) p` and
    :math:`((I - R) p)\cdot u = 0`), with ``u_1`` taken with the sign of ``u_0``
    (``-q`` turns about ``-u``). On equal rotations this is :math:`|(t_1 - t_0)\cdot u|`;
    for the identity rotation (no axis) it is :math:`|t_1 - t_0|`.
    """
    def axis(q: Tensor) -> tuple[Tensor, Tensor]:
        n = safe_norm(q[..., 1:])
        none = n <= threshold("dual_angle_degenerate", q.dtype)
        return q[..., 1:] / safe_denominator(n, none)[..., None], none

    P, Q, R, S = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    t0, t1 = translation(P, Q), translation(R, S)
    (u0, none0), (u1, none1) = axis(P), axis(R)
    sign = hemisphere(R, P)
    d0, d1 = (t0 * u0).sum(-1), sign * (t1 * u1).sum(-1)
    return torch.where(none0 | none1, safe_norm(t1 - t0), (d1 - d0).abs())


def sclerp(a: Tensor, b: Tensor, t: Tensor | float, shortest: bool = True) -> Tensor:
    r"""Screw linear interpolation, the paper's eq. 11: :math:`a\,(a^{-1} b)^t`.

    .. math::
        q(t) = \frac{\sin((1 - t)\bar\theta)}{\sin\bar\theta}\, a
             + \frac{\sin(t\bar\theta)}{\sin\bar\theta}\, b

    with :math:`\bar\theta` the dual angle (:func:`angle`). The dual weights are evaluated
    without forming :math:`\hat\theta = -\delta / \sin\theta` (see :func:`_eq11`),
    so the result is exact to rounding at every degenerate point (equal rotations, pure
    translations, tiny relative rotations with large translations), where it reduces to the
    paper's linear branch :math:`(1 - t) a + t b`. ``t`` may be any real number
    (extrapolation); ``t = 0`` and ``t = 1`` return ``a`` and ``b`` (``b`` sign-aligned).

    With ``shortest=True`` (default) ``b`` is replaced by ``-b`` when the real parts' dot is
    negative (same transform, shorter path). The paper's linear branch is wrong for opposite
    rotations: :math:`(1 - t) q + t (-q)` passes through zero; the sign choice avoids it.
    At a tie (orthogonal real parts, a half-turn relative rotation) both paths are equally
    short and the sign of the zero dot decides, so ``a`` and ``-a`` may take different ones.
    With ``shortest=False`` the path from ``a`` to ``b`` as given is followed; it is
    ill-conditioned when the real parts are nearly opposite, and undefined (no unique
    path) when they are opposite: where :math:`1 + q_0 \cdot q_1 \le 8\epsilon` of the
    inputs' dtype (closer than their rounding can tell from opposite) the result is NaN.

    Derivatives in ``a``, ``b`` and ``t`` are finite at every degenerate point and smooth to
    every order (the weights are analytic in :math:`\cos\theta`). Eager reverse mode runs a
    fused op with an analytic backward (twice differentiable); under ``torch.func``
    transforms (``hessian``, ``jacfwd``, nested ``jvp``, ``vmap``) and forward-mode AD the
    plain-op :func:`_eq11` runs instead, so Hessians and nested forward mode are right too.
    float16/bfloat16 inputs are computed in float32.

    Args:
        a: ``(..., 8)`` unit dual quaternions (not checked; start, ``t = 0``).
        b: ``(..., 8)`` unit dual quaternions (not checked; end, ``t = 1``).
        t: ``(...)`` tensor or Python float; ``a``, ``b`` and ``t`` broadcast together.
        shortest: bool; flip ``b`` to the representative nearest to ``a``.

    Returns:
        ``(..., 8)`` unit dual quaternions of the broadcast batch shape.

    Raises:
        TypeError: ``shortest`` is not a bool, or a tensor argument is not floating point
            or does not share ``a``'s dtype and device.
        ValueError: trailing dimensions other than 8, or batch shapes that do not
            broadcast.

    Example:
        >>> a = identity()
        >>> b = from_rt(torch.tensor([1., 0., 0., 0.]), torch.tensor([2., 0., 0.]))
        >>> sclerp(a, b, 0.5)
        tensor([1.0000, 0.0000, 0.0000, 0.0000, 0.0000, 0.5000, 0.0000, 0.0000])
    """
    fn = "dualquat.sclerp"
    _checks.pair(fn, a, b, 8)
    t = _checks.as_float_tensor(fn, "t", t, a, "a")
    shortest = _checks.flag(fn, "shortest", shortest)
    batch = _checks.broadcast_batch(fn, a=(a, 1), b=(b, 1), t=(t, 0))
    dtype = a.dtype
    a, b, t = (x.to(compute_dtype(dtype)) for x in (a, b, t))
    a, b, t = a.expand(*batch, 8), b.expand(*batch, 8), t.expand(batch)
    if _dispatch.fused_path(a, b, t):
        out = _sclerp_kernel.sclerp(a, b, t, shortest)
    else:
        out = _eq11(a, b, t, shortest)
    if not shortest:  # opposite real parts: no unique path (and acos(-1) has sin ~ 1e-16)
        # the inputs' own rounding (their dtype's eps) bounds how close to -1 the dot can be
        opposite = 1.0 + (a[..., :4] * b[..., :4]).sum(-1) <= threshold("opposite_real_parts",
                                                                         dtype)
        out = nan_unless(~opposite[..., None], out)
    return lower(out, dtype)


def _eq11(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
    r"""Eq. 11 on broadcast ``a, b (..., 8)`` and ``t (...)``, in plain torch ops.

    The reference for the fused ``torch_dq._kernels.sclerp.sclerp`` (same formula on
    component rows) and what :func:`sclerp` runs under ``torch.func`` transforms.

    With :math:`a = P + \epsilon Q`, :math:`b = R + \epsilon S` and the dual scalar product
    :math:`\cos\bar\theta = c + \epsilon\delta` (eqs. 1, 7), each dual weight of eq. 11 is
    :math:`F(s, \bar\theta) = F + \epsilon\hat\theta\,\partial_\theta F = F - \epsilon\delta G`
    (section 2.2's dual function) with :math:`F = \sin(s\theta)/\sin\theta`,
    :math:`G = \partial_\theta F/\sin\theta` and :math:`\hat\theta = -\delta/\sin\theta`
    (eq. 5), so that

    .. math::
        q(t) = F_0 a + F_1 b - \epsilon\,\delta\,(G_0 P + G_1 R),\qquad s_0 = 1 - t,\ s_1 = t.

    ``F`` and ``G`` (``torch_dq._kernels.weights.screw_weights``) are one power series
    in :math:`1 - \cos\theta` near 0 (no 0/0 at equal rotations, where this is the paper's
    linear branch :math:`(1 - t) a + t b`) and closed forms elsewhere: analytic in
    :math:`c`, so every derivative, to any order, is right.
    """
    P, Q, R, S = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    c = (P * R).sum(-1)
    sigma = hemisphere(R, P) if shortest else torch.ones_like(c)
    R, S = sigma[..., None] * R, sigma[..., None] * S  # b's representative nearest to a
    c, delta = sigma * c, (P * S).sum(-1) + (R * Q).sum(-1)  # eq. 1: c + eps delta
    weights = screw_weights(c, t, derivatives=False)
    (F0, F1), (G0, G1) = weights.F[..., None], weights.G[..., None]
    real = F0 * P + F1 * R
    dual = F0 * Q + F1 * S - delta[..., None] * (G0 * P + G1 * R)
    return torch.cat((real, dual), -1)


def dlb(weights: Tensor, xs: Tensor) -> Tensor:
    r"""Dual-quaternion linear blending (Kavan et al.): normalised weighted sum.

    :math:`\mathrm{normalize}(\sum_k w_k \sigma_k x_k)` with
    :math:`\sigma_k = \pm 1` aligning each ``xs[k]`` with ``xs[0]`` (the sign of the real
    parts' dot; 0 counts as +). Fast and smooth but not geodesic: it differs from
    :func:`sclerp` except at the endpoints and for a common screw axis. Weights need not sum
    to one (normalisation removes the scale); a blend whose real part vanishes has no
    direction and gives NaN in that element.

    Args:
        weights: ``(..., K)`` blend weights, ``K >= 1``.
        xs: ``(..., K, 8)`` unit dual quaternions (not checked), batch broadcastable with
            ``weights``.

    Returns:
        ``(..., 8)`` unit dual quaternions.
    """
    fn = "dualquat.dlb"
    _checks.tensor(fn, "xs", xs, 8)
    _checks.tensor(fn, "weights", weights)
    _checks.same_dtype_device(fn, xs=xs, weights=weights)
    if xs.dim() < 2 or weights.dim() < 1 or weights.shape[-1] != xs.shape[-2]:
        _checks.fail(fn, f"expected weights (..., K) and xs (..., K, 8) with the same K, got "
                         f"weights {_checks.shape_str(weights.shape)} and xs "
                         f"{_checks.shape_str(xs.shape)}")
    if xs.shape[-2] == 0:
        _checks.fail(fn, f"expected at least one pose to blend (K >= 1), got xs "
                         f"{_checks.shape_str(xs.shape)}")
    _checks.broadcast_batch(fn, weights=(weights, 1), xs=(xs, 2))
    dtype, xs, weights = xs.dtype, lift(xs), lift(weights)
    sign = hemisphere(xs, xs[..., :1, :])
    return lower(_normalize(((weights * sign)[..., None] * xs).sum(-2)), dtype)

r"""Quaternions on plain ``(..., 4)`` tensors.

Conventions: components ``(w, x, y, z)`` (scalar first), Hamilton product
(``i j = k``), and unit quaternions rotate vectors actively, :math:`v' = q v q^*`.
``q`` and ``-q`` are the same rotation. Batch dimensions come first and broadcast like
torch ops; dtype and device follow the inputs (float16/bfloat16 are computed in float32
and cast back). Inputs are never modified in place and outputs are new tensors.

Non-unit input, per function: ``mul``, ``conj``, ``inv``, ``norm``, ``normalize``, ``dot``,
``exp``, ``log`` are plain quaternion algebra (any norm); ``to_matrix``, ``to_axis_angle``,
``to_rotvec``, ``to_euler`` normalise implicitly (any non-zero ``q``: these and ``norm``,
``normalize``, ``inv``, ``log`` divide by a power of two near ``max |q_i|`` first, exactly,
so no square under- or overflows, e.g. from 1e-30 to 1e30 in float32; ``normalize``,
``to_matrix`` and ``to_rotvec`` only where some row of the batch needs it, the same bits);
``rotate`` and ``slerp`` assume unit input (not checked); ``normalize(q, check=True)``
raises on zero or non-finite rows. Non-finite components give NaN (or inf) in their own
row only, never a finite value (the one IEEE limit kept: ``exp`` of a real part ``-inf`` is
0, as ``torch.exp``).

Second order: removable singularities (``sin|v| / |v|`` in ``exp``, ``atan2(|v|, w) / |v|``
in ``log``, the slerp weights at ``q0 == q1``) are even functions evaluated from the
*squared* norm, so Hessians, double backward and nested forward mode are exact at and near
the identity (a ``where`` guard on ``|v|`` itself would give zero second derivatives).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _dispatch, _numerics
from ._core import canonical, lift, lower, qconj, qmul, qrotate
from ._euler import from_euler, to_euler
from ._kernels import slerp as _slerp_kernel

__all__ = [
    "conj",
    "dot",
    "exp",
    "from_axis_angle",
    "from_euler",
    "from_matrix",
    "from_rotvec",
    "from_xyzw",
    "identity",
    "inv",
    "log",
    "mul",
    "norm",
    "normalize",
    "rotate",
    "slerp",
    "to_axis_angle",
    "to_euler",
    "to_matrix",
    "to_rotvec",
    "to_xyzw",
]

for _f in (from_euler, to_euler):
    _f.__module__ = __name__  # documented and pickled as torch_dq.quat.<name>


def _exp(q: Tensor) -> Tensor:
    r"""Unchecked :math:`e^w (\cos|v|, \operatorname{sinc}|v| \, v)`.

    ``cos`` and ``sinc`` are evaluated from :math:`|v|^2` (:func:`_numerics.even`), so the
    result is smooth to every order at :math:`v = 0` (a Hessian there is exact)."""
    return torch.exp(q[..., :1]) * _exp_pure(q[..., 1:])


def _exp_pure(v: Tensor) -> Tensor:
    r""":math:`e^{(0, v)} = (\cos|v|, \operatorname{sinc}|v| \, v)` of ``v (..., 3)``
    (:func:`_exp` without the factor :math:`e^0 = 1`, which changes no bit)."""
    v2 = (v * v).sum(-1, keepdim=True)
    return torch.cat((_numerics.even("cos", v2), _numerics.even("sinc", v2) * v), dim=-1)


def _log(q: Tensor, real: bool = True) -> Tensor:
    r"""Unchecked :math:`(\log|q|, \theta v / |v|)` with :math:`\theta = atan2(|v|, w)`
    (only the vector part, ``(..., 3)``, if not ``real``).

    ``q`` is first divided by a power of two near its largest component (exact), so no
    square over- or underflows (for the vector part alone only the rows that need it, as
    ``_numerics.prescale`` finds them: the same bits). For :math:`|v| \le w` the scale
    :math:`\theta / |v| = \operatorname{atanc}(|v|^2 / w^2) / w` is a smooth function of
    :math:`|v|^2` (every derivative exact at the identity); elsewhere
    :math:`\operatorname{atan2}(|v|, w) / |v|` with :math:`|v| \ge |w|` or :math:`w < 0`.
    """
    if real:
        m: Tensor | None = _numerics.power_of_two_scale(q)
    else:  # only where some row needs it (the scale itself is not read)
        q = _numerics.unscaled(q)
        m = _numerics.prescale(q, torch.linalg.vector_norm(q, dim=-1, keepdim=True), power=1)
    p = q if m is None else q / m
    # Scalars per row keep a trailing dim of 1: a 0-dim float32 tensor times a Python float
    # gets a float64 tangent under forward mode (pytorch#90065), which broke torch.func.jvp
    # and hessian of an unbatched float32 ``dualquat.log``.
    w, v = p[..., :1], p[..., 1:]
    v2, w2 = (v * v).sum(-1, keepdim=True), w * w
    inner = (w > 0) & (v2 <= w2)  # theta <= pi / 4
    w_in = torch.where(inner, w, 1.0)
    # 1 elsewhere: atanc's closed form there (its series only on the few rows near 0)
    z2 = torch.where(inner, v2, 1.0) / (w_in * w_in)
    flat = v2 == 0
    s = torch.sqrt(torch.where(inner | flat, 1.0, v2))
    scale = torch.where(inner, _numerics.even("atanc", z2) / w_in, torch.atan2(s, w) / s)
    vec = v * scale
    # On the negative real axis (v = 0, w < 0) the direction of v is undefined: use x.
    # (q = 0 gives theta = atan2(0, 0) = 0.) Eager on the CPU only where some row is there.
    axis_line = flat & (w <= 0)
    if _numerics.may_hold(axis_line):
        # Safe-where: atan2(0, w) is only read on that line; elsewhere w = -1 keeps its
        # derivatives finite (at w = 0 they are 0 / 0 and would poison the double backward).
        theta = torch.atan2(torch.zeros_like(w), torch.where(axis_line, w, -1.0))
        vec = torch.where(axis_line, theta * p.new_tensor([1.0, 0.0, 0.0]), vec)
    if m is None:  # every row finite
        return vec
    n2 = v2 + w2
    # A non-finite q has no direction: NaN, not the finite limit theta -> 0 or pi.
    vec = _numerics.nan_unless(torch.isfinite(n2), vec)
    if not real:
        return vec
    return torch.cat((0.5 * torch.log(n2) + torch.log(m[..., :1]), vec), dim=-1)


def identity(shape: int | Sequence[int] = (), dtype: torch.dtype | None = None,
             device: torch.device | str | None = None) -> Tensor:
    """Identity quaternions ``(1, 0, 0, 0)`` of batch shape ``shape``.

    Args:
        shape: batch shape (int or tuple of ints).
        dtype: floating dtype (default: torch's default dtype).
        device: device (default: torch's default device).

    Returns:
        ``(*shape, 4)`` tensor.

    Example:
        >>> identity((2,))
        tensor([[1., 0., 0., 0.],
                [1., 0., 0., 0.]])
    """
    shape, dtype = _checks.factory_args("quat.identity", shape, dtype)
    q = torch.zeros((*shape, 4), dtype=dtype, device=device)
    q[..., 0] = 1.0
    return q


def mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a b``.

    Args:
        a: ``(..., 4)`` quaternions (any norm).
        b: ``(..., 4)`` quaternions, batch broadcastable with ``a``.

    Returns:
        ``(..., 4)``: the rotation ``b`` followed by ``a`` when both are unit.

    Example:
        >>> mul(torch.tensor([0., 1., 0., 0.]), torch.tensor([0., 0., 1., 0.]))  # i j = k
        tensor([0., 0., 0., 1.])
    """
    _checks.pair("quat.mul", a, b, 4)
    return lower(qmul(lift(a), lift(b)), a.dtype)


def conj(q: Tensor) -> Tensor:
    """Conjugate ``(w, -x, -y, -z)``; the inverse rotation for a unit ``q``.

    Args:
        q: ``(..., 4)`` quaternions (any norm).
    """
    _checks.tensor("quat.conj", "q", q, 4)
    return qconj(q)


def norm(q: Tensor) -> Tensor:
    """Euclidean norm ``|q|``.

    Args:
        q: ``(..., 4)`` quaternions (any norm).

    Returns:
        ``(...)`` tensor.
    """
    _checks.tensor("quat.norm", "q", q, 4)
    ql = lift(q)
    m = _numerics.power_of_two_scale(ql)
    return lower(m[..., 0] * torch.linalg.vector_norm(ql / m, dim=-1), q.dtype)


def inv(q: Tensor) -> Tensor:
    """Inverse ``q* / |q|^2``.

    Args:
        q: ``(..., 4)`` non-zero quaternions (any norm); a zero quaternion gives non-finite
            values, a non-finite one NaN (in its own row only).
    """
    _checks.tensor("quat.inv", "q", q, 4)
    ql = lift(q)
    m = _numerics.power_of_two_scale(ql)
    p = ql / m
    n2 = (p * p).sum(-1, keepdim=True)
    return lower(qconj(p) / (_numerics.nan_unless(torch.isfinite(n2), n2) * m), q.dtype)


def normalize(q: Tensor, check: bool = False) -> Tensor:
    """Project onto unit quaternions, ``q / |q|``.

    Args:
        q: ``(..., 4)`` quaternions (any norm).
        check: if True, raise ``ValueError`` when some ``q`` is zero or non-finite (this
            synchronises with the device). Otherwise a zero or non-finite quaternion, which
            has no direction, gives NaN in its own output row only. Idempotent.

    Returns:
        ``(..., 4)`` unit quaternions.
    """
    _checks.tensor("quat.normalize", "q", q, 4)
    check = _checks.flag("quat.normalize", "check", check)
    dtype, q = q.dtype, _numerics.unscaled(lift(q))
    n = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    m = _numerics.prescale(q, n, power=1)
    if m is None:  # every norm finite and far from under- or overflow
        return lower(q / _numerics.unscaled(n), dtype)
    q = q / m  # exact; no square over- or underflows
    n = torch.linalg.vector_norm(q, dim=-1, keepdim=True)
    finite = torch.isfinite(n)
    if check and not _checks.host_all("quat.normalize", "check=True", finite & (n > 0)):
        _checks.fail("quat.normalize", "q contains zero or non-finite quaternions")
    # n = 0 (q = 0) gives 0 / 0 = NaN in every component by itself.
    return lower(q / _numerics.nan_unless(finite, n), dtype)


def dot(a: Tensor, b: Tensor) -> Tensor:
    """Euclidean scalar product of quaternions, ``cos`` of the half-angle between unit ones.

    Args:
        a: ``(..., 4)`` quaternions (any norm).
        b: ``(..., 4)``, broadcastable with ``a``.

    Returns:
        ``(...)`` tensor.
    """
    _checks.pair("quat.dot", a, b, 4)
    return lower((lift(a) * lift(b)).sum(-1), a.dtype)


def rotate(q: Tensor, v: Tensor) -> Tensor:
    r"""Rotate vectors actively, :math:`v' = q v q^*`.

    Args:
        q: ``(..., 4)`` unit quaternions (not checked; for a non-unit ``q`` the result is
            ``v + |q|^2 (R - I) v``, not a rotation: normalise first).
        v: ``(..., 3)`` vectors, batch broadcastable with ``q``.

    Returns:
        ``(..., 3)`` rotated vectors.

    Example:
        >>> q = from_axis_angle(torch.tensor([0., 0., 1.]), torch.tensor(torch.pi / 2))
        >>> rotate(q, torch.tensor([1., 0., 0.])).round(decimals=6)
        tensor([0., 1., 0.])
    """
    _checks.tensor("quat.rotate", "q", q, 4)
    _checks.tensor("quat.rotate", "v", v, 3)
    _checks.same_dtype_device("quat.rotate", q=q, v=v)
    _checks.broadcast_batch("quat.rotate", q=(q, 1), v=(v, 1))
    return lower(qrotate(lift(q), lift(v)), q.dtype)


def slerp(q0: Tensor, q1: Tensor, t: Tensor | float, shortest: bool = True) -> Tensor:
    r"""Spherical linear interpolation :math:`q_0 (q_0^{-1} q_1)^t`.

    Travels the great circle from ``q0`` (``t = 0``) to ``q1`` (``t = 1``) at constant
    angular speed; any real ``t`` is allowed (``t < 0`` or ``t > 1`` extrapolates).

    Args:
        q0: ``(..., 4)`` unit quaternions (not checked).
        q1: ``(..., 4)`` unit quaternions (not checked), batch broadcastable with ``q0``.
        t: Python float or tensor whose shape broadcasts against the batch shape (it is
            not an extra trailing axis: use ``t[:, None]`` with ``q0[None]`` for a sweep).
        shortest: if True, use ``-q1`` when ``dot(q0, q1) < 0`` so that the path is the
            shorter rotation (at most 180 degrees). If False, interpolate the given
            quaternions (the path turns by up to 360 degrees).

    Returns:
        ``(..., 4)`` quaternions, batch shape broadcast of ``q0``, ``q1`` and ``t``.

    Singular points: at ``q0 == q1`` (and with ``shortest=True`` at ``q0 == -q1``) the value
    and its derivatives of every order are exact (the weights are analytic functions of the
    cosine, or of the squared angle, evaluated by power series there). With
    ``shortest=False`` and ``q1`` close to ``-q0`` the great circle is ill-conditioned (the
    path is still a unit great circle through ``q0``, but its direction has error about
    ``eps / (pi - angle)``). For ``q1 == -q0`` (within ``eps``) every great circle is a
    geodesic and the one through ``q0 (0, 1, 0, 0)`` is returned,
    ``cos(pi t) q0 + sin(pi t) q0 (0, 1, 0, 0)``, consistent with ``log(-1) = (0, pi, 0, 0)``.

    With ``shortest=True`` the result is ``F0 q0 + F1 q1'`` (``q1'`` the sign of ``q1``
    nearest ``q0``) with the weights ``F = sin(s omega) / sin(omega)`` evaluated from the
    cosine ``|q0 . q1|`` (a power series near 1, as the real part of
    :func:`torch_dq.dualquat.sclerp`); eager reverse mode runs it as a fused op with an
    analytic, twice differentiable backward, and under ``torch.func`` transforms and
    forward-mode AD the same formula in plain ops (the same values to the bit).

    Example:
        >>> q = from_axis_angle(torch.tensor([0., 0., 1.]), torch.pi / 2)
        >>> to_axis_angle(slerp(identity(), q, 0.5))[1]
        tensor(0.7854)
    """
    fn = "quat.slerp"
    _checks.pair(fn, q0, q1, 4, ("q0", "q1"))
    t = _checks.as_float_tensor(fn, "t", t, q0, "q0")
    batch = _checks.broadcast_batch(fn, q0=(q0, 1), q1=(q1, 1), t=(t, 0))
    shortest = _checks.flag(fn, "shortest", shortest)
    dtype = q0.dtype
    q0, q1, t = lift(q0).expand(*batch, 4), lift(q1).expand(*batch, 4), lift(t)
    if not shortest:
        out = _great_circle(q0, q1, t[..., None])
    elif _dispatch.fused_path(q0, q1, t):
        out = _slerp_kernel.slerp(q0, q1, t)
    else:
        out = _slerp_kernel.plain(q0, q1, t.expand(batch))
    return lower(out, dtype)


def _great_circle(q0: Tensor, q1: Tensor, t: Tensor) -> Tensor:
    r"""Slerp of ``q0, q1 (..., 4)`` as given (no sign choice) at ``t (..., 1)``.

    The result is :math:`\cos(t\omega) q_0 + \sin(t\omega) r / |r|`, with :math:`\omega`
    the angle between ``q0`` and ``q1`` in :math:`R^4` and ``r`` the part of ``q1``
    orthogonal to ``q0`` (:math:`|r| = \sin\omega`), which stays a unit great circle
    through ``q0`` however close ``q1`` is to ``-q0``. (The shortest path,
    :func:`torch_dq._kernels.slerp.plain`, has :math:`\omega \le \pi / 2` and needs none of
    this.)
    """
    d = (q0 * q1).sum(-1, keepdim=True)
    # Projecting twice keeps r orthogonal to q0 to rounding even when q1 is nearly -q0.
    r = q1 - d * q0
    r = r - (r * q0).sum(-1, keepdim=True) * q0
    dm, dp = q1 - q0, q1 + q0
    near = d >= 0  # omega <= pi / 2
    # Near: z2 = |q1 - q0|^2 / |q1 + q0|^2 = tan^2(omega / 2) <= 1, so
    # omega^2 = 4 z2 atanc(z2)^2, and cos(t omega), sin(t omega) / sin(omega) are even
    # functions of omega evaluated from omega^2: smooth to every order at q0 == q1.
    dp2 = torch.where(near, (dp * dp).sum(-1, keepdim=True), 1.0)
    z2 = torch.where(near, (dm * dm).sum(-1, keepdim=True) / dp2, 0.0)
    omega2 = 4.0 * z2 * _numerics.even("atanc", z2) ** 2
    tw2 = t * t * omega2
    cos_near = _numerics.even("cos", tw2)
    scale_near = t * _numerics.even("sinc", tw2) / _numerics.even("sinc", omega2)
    # Far (omega > pi / 2): sin(t omega) / |r|, where sin of the rounded omega would lose the
    # relative accuracy |r| keeps; for q1 == -q0 (within eps) r is replaced by q0 (0, 1, 0, 0).
    omega = 2.0 * torch.atan2(_numerics.safe_norm(dm), _numerics.safe_norm(dp))[..., None]
    r_norm = _numerics.safe_norm(r)[..., None]
    antipodal = ~near & (r_norm <= _numerics.threshold("antipodal", r.dtype))
    r = torch.where(antipodal, qmul(q0, q0.new_tensor([0.0, 1.0, 0.0, 0.0])), r)
    scale_far = torch.sin(t * omega) / _numerics.safe_denominator(r_norm, near | antipodal)
    return (torch.where(near, cos_near, torch.cos(t * omega)) * q0
            + torch.where(near, scale_near, scale_far) * r)


def exp(q: Tensor) -> Tensor:
    r"""Quaternion exponential :math:`e^{w + v} = e^w (\cos|v|, \frac{v}{|v|} \sin|v|)`.

    Args:
        q: ``(..., 4)`` quaternions (any norm). For a pure quaternion ``(0, v)`` the result
            is the unit quaternion of the rotation by ``2 |v|`` about ``v``.

    Returns:
        ``(..., 4)`` quaternions, smooth at ``v = 0``: value, gradient and Hessian are exact
        there (``cos`` and ``sinc`` of :math:`|v|` evaluated from :math:`|v|^2`).
        A real part ``-inf`` gives 0 (:math:`e^{-\infty}`, as ``torch.exp``); any other
        non-finite component gives NaN or inf.

    Example:
        >>> exp(torch.tensor([0., torch.pi / 4, 0., 0.]))  # 90 degrees about x
        tensor([0.7071, 0.7071, 0.0000, 0.0000])
    """
    _checks.tensor("quat.exp", "q", q, 4)
    return lower(_exp(lift(q)), q.dtype)


def log(q: Tensor) -> Tensor:
    r"""Quaternion logarithm :math:`(\log|q|, \frac{v}{|v|} \operatorname{atan2}(|v|, w))`.

    The principal branch, inverse of :func:`exp` for vector parts of norm below pi.
    For a unit ``q`` the real part is 0 and the vector part is half the rotation vector
    of the rotation by ``2 atan2(|v|, w)`` in [0, 2 pi] (no sign canonicalisation).

    Args:
        q: ``(..., 4)`` non-zero quaternions.

    Returns:
        ``(..., 4)``. Smooth at ``v = 0`` for ``w > 0`` (value, gradient and Hessian exact
        there: the scale :math:`\operatorname{atanc}(|v|^2 / w^2) / w`). On the
        negative real axis (``v = 0``, ``w < 0``) the direction is undefined and
        ``(log|w|, pi, 0, 0)`` is returned; ``q = 0`` gives ``(-inf, 0, 0, 0)``.

    Example:
        >>> log(torch.tensor([0., 0., 1., 0.]))  # 180 degrees about y
        tensor([0.0000, 0.0000, 1.5708, 0.0000])
    """
    _checks.tensor("quat.log", "q", q, 4)
    return lower(_log(lift(q)), q.dtype)


def from_matrix(R: Tensor, check: bool = False) -> Tensor:
    r"""Quaternion of a rotation matrix (Shepperd 1978, Markley 2008), scipy's canonical sign.

    Every entry of :math:`4 q q^T` is a sum of matrix entries; the row with the largest
    diagonal entry :math:`4 q_k^2 \ge 1` is normalised, so no division by a small number
    happens for any rotation, 180 degrees included.

    Args:
        R: ``(..., 3, 3)`` rotation matrices (orthogonality is not checked unless
            ``check``; a nearly orthogonal matrix gives a nearby unit quaternion, not the
            nearest rotation).
        check: raise ``ValueError`` unless every matrix is a rotation within 1e-3
            (``max |R^T R - I|``, determinant > 0): a reflection or a scaled matrix
            otherwise gives an unrelated unit quaternion (one device sync).

    Returns:
        ``(..., 4)`` unit quaternions with ``w >= 0``; for ``w == 0`` the first non-zero of
        ``x, y, z`` is positive (scipy's ``canonical=True``).

    Example:
        >>> from_matrix(torch.diag(torch.tensor([1., -1., -1.])))  # 180 degrees about x
        tensor([0., 1., 0., 0.])
    """
    _checks.tensor("quat.from_matrix", "R", R, (3, 3))
    if _checks.flag("quat.from_matrix", "check", check):
        _checks.rigid_matrix("quat.from_matrix", "R", R)
    dtype = R.dtype
    r = lift(R)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = (row.unbind(-1) for row in r.unbind(-2))
    tr = r00 + r11 + r22
    k = torch.stack((
        1.0 + tr, r21 - r12, r02 - r20, r10 - r01,
        r21 - r12, 1.0 + 2.0 * r00 - tr, r01 + r10, r02 + r20,
        r02 - r20, r01 + r10, 1.0 + 2.0 * r11 - tr, r12 + r21,
        r10 - r01, r02 + r20, r12 + r21, 1.0 + 2.0 * r22 - tr,
    ), dim=-1).unflatten(-1, (4, 4))
    pick = k.diagonal(dim1=-2, dim2=-1).argmax(-1)
    row = torch.gather(k, -2, pick[..., None, None].expand(*pick.shape, 1, 4)).squeeze(-2)
    n = torch.linalg.vector_norm(row, dim=-1, keepdim=True)
    return lower(canonical(row / _numerics.nan_unless(torch.isfinite(n), n)), dtype)


def to_matrix(q: Tensor) -> Tensor:
    """Rotation matrix of ``q``: ``to_matrix(q) @ v == rotate(q, v)`` for a unit ``q``.

    The result is the rotation matrix of ``q / |q|`` for any non-zero ``q`` (the factor
    ``2 / |q|^2`` replaces 2), so it is always orthogonal; ``to_matrix(q) == to_matrix(-q)``.

    Args:
        q: ``(..., 4)`` non-zero quaternions (any norm); ``q = 0`` or a non-finite ``q`` gives
            NaN.

    Returns:
        ``(..., 3, 3)`` rotation matrices.

    Example:
        >>> to_matrix(torch.tensor([0., 0., 0., 2.]))  # 180 degrees about z
        tensor([[-1.,  0.,  0.],
                [ 0., -1.,  0.],
                [ 0.,  0.,  1.]])
    """
    _checks.tensor("quat.to_matrix", "q", q, 4)
    ql = _numerics.unscaled(lift(q))
    w, x, y, z = ql.split(1, -1)  # (before n2: autograd's order of sums as with the prescale)
    n2 = (ql * ql).sum(-1, keepdim=True)
    m = _numerics.prescale(ql, n2)
    if m is None:  # every |q|^2 finite and far from under- or overflow
        n2 = _numerics.unscaled(n2)
    else:
        ql = ql / m  # exact; no square over- or underflows
        w, x, y, z = ql.split(1, -1)
        n2 = (ql * ql).sum(-1, keepdim=True)
        n2 = _numerics.nan_unless(torch.isfinite(n2), n2)
    s = 2.0 / n2
    xx, yy, zz = s * x * x, s * y * y, s * z * z
    wx, wy, wz, xy, xz, yz = s * w * x, s * w * y, s * w * z, s * x * y, s * x * z, s * y * z
    return lower(torch.cat((
        1.0 - yy - zz, xy - wz, xz + wy,
        xy + wz, 1.0 - xx - zz, yz - wx,
        xz - wy, yz + wx, 1.0 - xx - yy,
    ), dim=-1).unflatten(-1, (3, 3)), q.dtype)


def from_axis_angle(axis: Tensor, angle: Tensor | float) -> Tensor:
    r"""Rotation by ``angle`` about ``axis``: :math:`(\cos\frac{a}{2}, \sin\frac{a}{2} u)`.

    Args:
        axis: ``(..., 3)`` axes, normalised internally. A zero axis gives the identity
            (whatever the angle), with finite gradients.
        angle: ``(...)`` angles in radians (any real) or a Python float, broadcastable
            with the batch shape of ``axis``.

    Returns:
        ``(..., 4)`` unit quaternions (``w < 0`` for angles beyond pi: not canonicalised).

    Example:
        >>> from_axis_angle(torch.tensor([0., 2., 0.]), torch.pi / 2)
        tensor([0.7071, 0.0000, 0.7071, 0.0000])
    """
    fn = "quat.from_axis_angle"
    _checks.tensor(fn, "axis", axis, 3)
    angle = _checks.as_float_tensor(fn, "angle", angle, axis, "axis")
    shape = _checks.broadcast_batch(fn, axis=(axis, 1), angle=(angle, 0))
    dtype = axis.dtype
    axis, half = lift(axis).expand(*shape, 3), lift(angle).expand(shape)[..., None] / 2.0
    n = _numerics.safe_norm(axis)[..., None]
    zero = n == 0
    n = _numerics.nan_unless(torch.isfinite(n), torch.where(zero, 1.0, n))
    q = torch.cat((torch.cos(half), torch.sin(half) * axis / n), dim=-1)
    return lower(torch.where(zero, q.new_tensor([1.0, 0.0, 0.0, 0.0]), q), dtype)


def to_axis_angle(q: Tensor) -> tuple[Tensor, Tensor]:
    """Axis and angle in [0, pi] of the rotation ``q`` (the sign with ``w >= 0`` is used).

    Args:
        q: ``(..., 4)`` non-zero quaternions (need not be unit).

    Returns:
        ``(axis, angle)``: ``(..., 3)`` unit axes and ``(...)`` angles in [0, pi]. For
        the identity (angle 0) the axis is undefined and ``(1, 0, 0)`` is returned, with
        finite gradients. At 180 degrees the axis follows scipy's canonical sign.

    Example:
        >>> to_axis_angle(torch.tensor([0., 0., 0., 1.]))
        (tensor([0., 0., 1.]), tensor(3.1416))
    """
    _checks.tensor("quat.to_axis_angle", "q", q, 4)
    qc = canonical(lift(q))
    qc = qc / _numerics.power_of_two_scale(qc)  # exact; no square over- or underflows
    w, v = qc[..., 0], qc[..., 1:]
    s = _numerics.safe_norm(v)
    zero = (s == 0)[..., None]
    axis = torch.where(zero, v.new_tensor([1.0, 0.0, 0.0]),
                       v / _numerics.safe_denominator(s[..., None], zero))
    # Non-finite q: NaN, not the finite limits of atan2 (0 or pi) and of v / |v|.
    finite = torch.isfinite(s) & torch.isfinite(w)
    angle = _numerics.nan_unless(finite, 2.0 * torch.atan2(s, w))
    return _numerics.nan_unless(finite[..., None], axis).to(q.dtype), angle.to(q.dtype)


def from_rotvec(rotvec: Tensor) -> Tensor:
    r"""Unit quaternion of a rotation vector, :math:`\exp((0, \theta u / 2))`.

    Args:
        rotvec: ``(..., 3)`` rotation vectors ``angle * axis`` (radians, any length).

    Returns:
        ``(..., 4)`` unit quaternions; smooth at ``rotvec = 0`` (value, gradient and
        Hessian exact there: the Hessian of ``w`` is ``-I / 4``).

    Example:
        >>> from_rotvec(torch.tensor([0., 0., torch.pi / 2]))
        tensor([0.7071, 0.0000, 0.0000, 0.7071])
    """
    _checks.tensor("quat.from_rotvec", "rotvec", rotvec, 3)
    rv = lift(rotvec)
    return lower(_exp_pure(rv / 2.0), rotvec.dtype)


def to_rotvec(q: Tensor) -> Tensor:
    """Rotation vector ``angle * axis`` with angle in [0, pi]: twice the log of ``+-q``.

    Args:
        q: ``(..., 4)`` non-zero quaternions (need not be unit).

    Returns:
        ``(..., 3)`` rotation vectors. Smooth at the identity (exact Hessian there); value
        and gradient are finite at 180 degrees, where the sign follows scipy's canonical
        form (``as_rotvec``).

    Example:
        >>> to_rotvec(torch.tensor([0., 0., 1., 0.]))
        tensor([0.0000, 3.1416, 0.0000])
    """
    _checks.tensor("quat.to_rotvec", "q", q, 4)
    return lower(2.0 * _log(canonical(lift(q)), real=False), q.dtype)


def from_xyzw(q: Tensor) -> Tensor:
    """Quaternions from scipy's scalar-last order ``(x, y, z, w)`` to ``(w, x, y, z)``.

    Scalar-last is the order of scipy's ``Rotation.from_quat``/``as_quat``, ROS messages,
    Eigen's ``coeffs()`` and pypose. Components are only reordered: no normalisation and
    the sign is kept.

    Args:
        q: ``(..., 4)`` quaternions ``(x, y, z, w)``.

    Returns:
        ``(..., 4)`` quaternions ``(w, x, y, z)`` (a new tensor).

    Example:
        >>> from_xyzw(torch.tensor([0., 0., 1., 0.]))  # scipy's 180 degrees about z
        tensor([0., 0., 0., 1.])
    """
    _checks.tensor("quat.from_xyzw", "q", q, 4)
    return torch.cat((q[..., 3:], q[..., :3]), dim=-1)


def to_xyzw(q: Tensor) -> Tensor:
    """Quaternions from ``(w, x, y, z)`` to scipy's scalar-last order ``(x, y, z, w)``.

    The inverse of :func:`from_xyzw` (components reordered only).

    Args:
        q: ``(..., 4)`` quaternions ``(w, x, y, z)``.

    Returns:
        ``(..., 4)`` quaternions ``(x, y, z, w)`` (a new tensor).

    Example:
        >>> to_xyzw(torch.tensor([1., 0., 0., 0.]))  # identity
        tensor([0., 0., 0., 1.])
    """
    _checks.tensor("quat.to_xyzw", "q", q, 4)
    return torch.cat((q[..., 1:], q[..., :1]), dim=-1)

r"""Curves of rigid motions: De Casteljau and De Boor with screw interpolation (paper section 4).

Both algorithms are the Euclidean ones with the linear interpolation replaced by the
paper's eq. 11 (:func:`torch_dq.dualquat.sclerp` with ``shortest=True`` at every step:
before each interpolation the second point is replaced by its antipode when the real
parts' dot is negative, so that ``x`` and ``-x`` control points give the same motion).

- :func:`bezier`: De Casteljau (paper 4.1) over a ``domain`` ``[t0, t1]`` of the caller's time.
- :func:`bspline`: De Boor (paper 4.2), any non-decreasing knot vector in the caller's time
  (:func:`clamped_uniform_knots` by default), ``t`` in the knot domain.
- :func:`bezier_derivatives`, :func:`bspline_derivatives`: the pose and its exact time
  derivatives up to order 3, in the caller's time.
- :func:`kinematics`, :func:`imu`: angular and linear velocity and acceleration (world or
  body axes), and what an ideal IMU reads; :func:`velocity`, :func:`twists`,
  :func:`screw_axis`: forward-mode velocity of any curve function, body and spatial twists,
  and the instantaneous screw axis (whose trace over ``t`` is the fixed axode).

Time is the caller's: a Bézier curve's ``domain`` and a B-spline's knots are in seconds,
frames or whatever unit ``t`` is in, never silently rescaled, and derivatives are with
respect to that ``t``. Wide time: ``t``, ``knots`` and ``domain`` may have a wider floating
dtype than the control points (float64 UNIX timestamps with float32 control points). The
time arithmetic (spans, local parameters ``(t - u_i) / (u_j - u_i)`` and their slopes) then
runs in the widest dtype of ``ctrl``, ``t`` and the knots (or domain); only the local
parameters, in ``[0, 1]``, are rounded to ``ctrl``'s dtype. A *narrower* ``t`` or knots
are promoted the same way (the widest dtype wins), so mixing dtypes never raises here.

Shapes: control points ``(..., n, 8)`` and times ``(T,)`` or ``(..., T)``; the batch dims
(all but the last two of ``ctrl``, all but the last of ``t``) broadcast, and the curves
are ``(..., T, 8)``. Every evaluation is vectorised over the batch, the control points and
all ``T`` times at once (the only Python loop is over the levels of the scheme).
Per-trajectory times: a B-spline's knots may be ``(..., K)``, a row per trajectory whose
batch broadcasts with those of ``ctrl`` and ``t`` (e.g. ``ctrl (B, n, 8)``, ``t (B, T)``,
``knots (B, K)``): each trajectory is evaluated on its own knots, and the domain rules hold
per row (each row's tolerance from its own ends).

Two implementations of each scheme: the readable level loops of this module
(:func:`_de_casteljau`, :func:`_de_boor`, plain calls to ``sclerp``: the reference, exact to
any order of differentiation in any mode), and the fused op
:func:`torch_dq._kernels.pyramid.pyramid` (all levels in one autograd op, O(output) memory).
:func:`bezier` and :func:`bspline` run the fused op except under ``torch.func`` transforms
and forward-mode AD (:func:`torch_dq._dispatch.fused_path`), where a custom op cannot pass
nested tangents on.

The time derivatives (:func:`bezier_derivatives`, :func:`bspline_derivatives`) run the same
schemes on jets (truncated Taylor series in ``t``, :mod:`torch_dq._taylor`) in plain torch
ops: exact, differentiable again, and compilable with ``fullgraph=True``. Measured on one
CPU thread (float32, 100 control points, 10,000 times, cubic), forward + backward costs
about 4x (velocities), 10x (accelerations) and 18x (jerks) the pose-only forward + backward
of the fused op.

Three B-spline forms (``form=`` on :func:`bspline` and :func:`bspline_derivatives`):
``"de_boor"`` (the default, the paper's pyramid of sclerps, :math:`C^1` at simple knots),
``"cumulative"`` (Kim-Kim-Shin: :math:`X(t) = c_0 \prod_{j \ge 1} (c_{j-1}^{-1} c_j)^{\tilde
B_j(t)}` with the cumulative basis :math:`\tilde B_j = \sum_{l \ge j} B_{l,p}`, each power
on the shortest path; :math:`C^{p-1}` at simple knots, so a cubic's accelerations and IMU
readings are continuous; pypose's and basalt's form) and ``"split"`` (SO(3) x R^3: the
rotation the cumulative B-spline on SO(3), :math:`R(t) = R_0 \prod_{j \ge 1}
\mathrm{Exp}(\tilde B_j(t) \mathrm{Log}(R_{j-1}^T R_j))`, the translation the Euclidean
B-spline :math:`\sum_j B_{j,p}(t)\, p_j`; :math:`C^{p-1}`; kontiki's split spline and the
"linear"/"cubic" trajectories of BAD-NeRF and BAD-Gaussians). All read the same spans of the
same sign-aligned control polygon (:func:`_kim_kim_shin` and :func:`_split` are the readable
references of the second and third, :mod:`torch_dq._cumulative` their basis, jets and fused
op: the split form's rotation is the cumulative form of the rotations alone).

Time model and domain rules: every function locates its times through one object
(``torch_dq._time.KnotDomain``: spans, local parameters, domain checks). Times outside the
domain ``[t0, t1]`` by at most ``tol = max(1e-9 (t1 - t0), 4 eps(t.dtype) max(|t0|, |t1|))``
(roundings such as ``t0 + k dt``) are evaluated at the nearest end; times further out raise
``ValueError`` naming the domain and the way out, unless ``extrapolate=True``, which
continues the end spans (the end polynomials of the scheme, local parameters outside
``[0, 1]``). The value checks on knots, domain and times cost one device synchronisation;
``check=False`` skips them (tight loops), and so does ``torch.compile`` (a host sync would
break the graph: ``torch.compile(fn, fullgraph=True)`` works with the default arguments) and
meta tensors. Where they are skipped, times outside the tolerance give NaN poses (per
element), never a silent extrapolation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from . import _checks, _cumulative, _dispatch, dualquat, quat
from ._core import align_chain, qmul, translation
from ._curve_args import nan_safe, nan_where
from ._fused_curves import (
    fused_bezier,
    fused_bspline,
    fused_cumulative,
    jet_scheme,
    span_points,
)
from ._kinematics import Kinematics, imu, kinematics, screw_axis, twists, velocity
from ._numerics import compute_dtype
from ._split import poses as split_poses
from ._time import EXTRAPOLATE_HINT, KnotDomain, time_pair

__all__ = [
    "bezier",
    "bezier_derivatives",
    "bspline",
    "bspline_derivatives",
    "clamped_uniform_knots",
    "imu",
    "kinematics",
    "screw_axis",
    "twists",
    "velocity",
]

for _f in (Kinematics, imu, kinematics, screw_axis, twists, velocity):
    _f.__module__ = __name__  # documented and pickled as torch_dq.curves.<name>

_MAX_ORDER = 3  # highest time derivative of the *_derivatives functions
FORMS = ("de_boor", "cumulative", "split")  # the B-spline forms (module docstring)


# ----------------------------------------------------------------------------- checks

def check_form(fn: str, form) -> str:
    """``form`` if it names a B-spline form (:data:`FORMS`), else ``ValueError``."""
    if not isinstance(form, str) or form not in FORMS:
        _checks.fail(fn, f"form must be 'de_boor' (the paper's De Boor pyramid), "
                         f"'cumulative' (Kim-Kim-Shin, C^(p-1)) or 'split' (SO(3) x R^3, "
                         f"C^(p-1)), got {form!r}")
    return form


def _time_dtype(ctrl: Tensor, *times: Tensor) -> torch.dtype:
    """The widest compute dtype of ``ctrl`` and the time tensors (module docstring)."""
    dtype = compute_dtype(ctrl.dtype)
    for x in times:
        dtype = torch.promote_types(dtype, compute_dtype(x.dtype))
    return dtype


def _domain(fn: str, domain, ctrl: Tensor) -> tuple[Tensor | float, Tensor | float]:
    """``domain`` as two Python floats (checked here) or two 0-d tensors (checked with t)."""
    ends = time_pair(fn, "domain", domain, keep_tensors=True)
    for e in ends:
        if isinstance(e, Tensor):
            _checks.same_device(fn, ctrl, "ctrl", "domain", e)
    return ends


# ----------------------------------------------------------------------------- knots

def clamped_uniform_knots(n_ctrl: int, degree: int, dtype: torch.dtype | None = None,
                          device: torch.device | str | None = None,
                          domain: Sequence[float] = (0.0, 1.0)) -> Tensor:
    r"""Clamped uniform knot vector on ``domain = (t0, t1)`` for ``n_ctrl`` control points.

    ``degree + 1`` copies of ``t0``, the ``n_ctrl - degree - 1`` interior knots
    :math:`t_0 + i\,(t_1 - t_0) / (n_{ctrl} - degree)` and ``degree + 1`` copies of ``t1``:
    the B-spline then starts at the first and ends at the last control point, its domain is
    ``[t0, t1]`` and ``n_ctrl = degree + 1`` gives the Bézier curve on that domain.

    Args:
        n_ctrl: number of control points, ``> degree``.
        degree: polynomial degree ``>= 1`` (3 for cubic).
        dtype: floating dtype (default: ``torch.get_default_dtype()``); use float64 for
            absolute timestamps such as UNIX seconds (float32 resolves 128 s at 1.7e9).
        device: device of the result.
        domain: ``(t0, t1)``, two finite real numbers with ``t0 < t1`` (or a ``(2,)``
            tensor, read on the host), in the caller's time.

    Returns:
        ``(n_ctrl + degree + 1,)`` non-decreasing knots.

    Example:
        >>> clamped_uniform_knots(5, 2)
        tensor([0.0000, 0.0000, 0.0000, 0.3333, 0.6667, 1.0000, 1.0000, 1.0000])
        >>> clamped_uniform_knots(4, 3, dtype=torch.float64, domain=(10.0, 12.5))
        tensor([10.0000, 10.0000, 10.0000, 10.0000, 12.5000, 12.5000, 12.5000, 12.5000],
               dtype=torch.float64)
    """
    fn = "curves.clamped_uniform_knots"
    degree = _checks.integer(fn, "degree", degree, 1)
    n_ctrl = _checks.integer(fn, "n_ctrl", n_ctrl, degree + 1, rule=f"> degree = {degree}")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        _checks.fail(fn, f"expected a floating dtype, got {dtype!r}", TypeError)
    t0, t1 = time_pair(fn, "domain", domain)  # symbolic ends under compile(dynamic=True)
    inner = torch.linspace(t0, t1, n_ctrl - degree + 1, dtype=dtype, device=device)[1:-1]
    return torch.cat((inner.new_full((degree + 1,), t0), inner, inner.new_full((degree + 1,), t1)))


# ----------------------------------------------------------------------------- readable schemes

def _de_casteljau(ctrl: Tensor, s: Tensor) -> Tensor:
    r"""De Casteljau with eq. 11 (paper 4.1), one level per iteration: the reference.

    ``ctrl (..., m, 8)`` and local parameters ``s (..., T)`` (batches broadcast) ->
    ``(..., T, 8)``: :math:`q_i^{(j)} = \mathrm{sclerp}(q_i^{(j-1)}, q_{i+1}^{(j-1)}, s)`.
    """
    q = ctrl[..., None, :, :]  # (..., 1, m, 8): level 0, shared by the T times
    s = s[..., None]  # (..., T, 1): the same parameter at every level and index
    for _ in range(ctrl.shape[-2] - 1):
        q = dualquat.sclerp(q[..., :-1, :], q[..., 1:, :], s)
    return q[..., 0, :]


def _de_boor(d: Tensor, alphas: list[Tensor]) -> Tensor:
    r"""De Boor with eq. 11 (paper 4.2), one level per iteration: the reference.

    ``d (..., T, p + 1, 8)``: the control points :math:`d_{r-p}, \dots, d_r` of each time's
    span; ``alphas[j - 1] (..., T, p + 1 - j)``: the local parameters
    :math:`\alpha_i^j = (t - u_i) / (u_{i+p+1-j} - u_i)`, ``i = r-p+j .. r``. Returns
    :math:`d_r^p`, ``(..., T, 8)``, from
    :math:`d_i^j = \mathrm{sclerp}(d_{i-1}^{j-1}, d_i^{j-1}, \alpha_i^j)`.
    """
    for alpha in alphas:
        d = dualquat.sclerp(d[..., :-1, :], d[..., 1:, :], alpha)
    return d[..., 0, :]


def _kim_kim_shin(points: Tensor, weights: Tensor) -> Tensor:
    r"""The cumulative form (Kim-Kim-Shin), one power per iteration: the reference.

    ``points (..., T, p + 1, 8)``: the sign-aligned control points
    :math:`c_{r-p}, \dots, c_r` of each time's span; ``weights (..., T, p)``: the cumulative
    basis :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``. Returns ``(..., T, 8)``,
    :math:`c_{r-p} \prod_{j=1}^p (c_{r-p+j-1}^{-1} c_{r-p+j})^{\tilde B_{r-p+j}}` with
    :math:`x^w = \mathrm{sclerp}(1, x, w)` (shortest path).
    """
    x = points[..., 0, :]
    one = dualquat.identity(dtype=points.dtype, device=points.device)
    for j in range(1, points.shape[-2]):
        step = dualquat.mul(dualquat.conj(points[..., j - 1, :]), points[..., j, :])
        x = dualquat.mul(x, dualquat.sclerp(one, step, weights[..., j - 1]))
    return x


def _split(points: Tensor, weights: Tensor) -> Tensor:
    r"""The split form (SO(3) x R^3), one factor per iteration: the reference.

    ``points (..., T, p + 1, 8)``: the sign-aligned control points
    :math:`c_{r-p}, \dots, c_r` of each time's span, :math:`c_i = (q_i, p_i)` by
    :func:`~torch_dq.dualquat.to_rt`; ``weights (..., T, p)``: the cumulative basis
    :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``. Returns ``(..., T, 8)``,
    :func:`~torch_dq.dualquat.from_rt` of

    .. math::
        R(t) = q_{r-p} \prod_{j=1}^p \mathrm{slerp}\big(1,\, q_{r-p+j-1}^{*} q_{r-p+j},\,
        \tilde B_{r-p+j}\big),\qquad
        p(t) = p_{r-p} + \sum_{j=1}^p \tilde B_{r-p+j}\,(p_{r-p+j} - p_{r-p+j-1}),

    the cumulative B-spline on SO(3) (each factor :math:`\mathrm{Exp}(w \mathrm{Log}(\cdot))`
    on the shortest path: ``slerp`` from the identity with ``shortest=True``, composed on the
    right) and the ordinary B-spline :math:`\sum_m B_{r-p+m,p}\, p_{r-p+m}` of the
    translations (the same sum regrouped by Abel summation, :math:`B_{l,p} = \tilde B_l -
    \tilde B_{l+1}`).
    """
    q, p = dualquat.to_rt(points)
    one = quat.identity(dtype=points.dtype, device=points.device)
    rot, trans = q[..., 0, :], p[..., 0, :]
    for j in range(1, points.shape[-2]):
        step = quat.mul(quat.conj(q[..., j - 1, :]), q[..., j, :])
        rot = quat.mul(rot, quat.slerp(one, step, weights[..., j - 1]))
        trans = trans + weights[..., j - 1, None] * (p[..., j, :] - p[..., j - 1, :])
    return dualquat.from_rt(rot, trans)


# ----------------------------------------------------------------------------- public curves

def _prepare_bezier(fn: str, ctrl: Tensor, t: Tensor, domain, check: bool, extrapolate: bool):
    """Checked arguments of a Bézier curve: ``batch``, ``ctrl`` in its compute dtype, the
    local parameter ``s`` and its slope (:class:`~torch_dq._time.KnotDomain`: one span)."""
    _checks.flag(fn, "check", check)
    _checks.flag(fn, "extrapolate", extrapolate)
    _checks.control_points(fn, ctrl, 2, "at least 2 control points")
    batch = _checks.times(fn, t, ctrl)
    t0, t1 = _domain(fn, domain, ctrl)
    tdtype = _time_dtype(ctrl, t, *(e for e in (t0, t1) if isinstance(e, Tensor)))
    m = ctrl.shape[-2]
    lo, hi = (torch.as_tensor(e, dtype=tdtype, device=t.device) for e in (t0, t1))
    dom = KnotDomain(torch.stack((lo,) * m + (hi,) * m), m - 1)
    tensor_ends = any(isinstance(e, Tensor) for e in (t0, t1))
    rel = dom.prepare(fn, t, tdtype, check=check, extrapolate=extrapolate,
                      knots="domain" if tensor_ends else None,
                      fix=f"evaluate inside it, cover it by domain=(t0, t1), or {EXTRAPOLATE_HINT}")
    rel, bad = nan_safe(dom, rel)
    _, s, slope = dom.locate(rel, compute_dtype(ctrl.dtype))
    return batch, ctrl.to(compute_dtype(ctrl.dtype)), s, slope, bad


def bezier(ctrl: Tensor, t: Tensor, domain: Sequence[float | Tensor] | Tensor = (0.0, 1.0),
           check: bool = True, extrapolate: bool = False) -> Tensor:
    r"""Bézier curve of unit dual quaternions by De Casteljau's algorithm (paper 4.1).

    With :math:`q_i^{(0)} = q_i` (the control points) and the local parameter
    :math:`s = (t - t_0) / (t_1 - t_0)` of the ``domain`` :math:`[t_0, t_1]`,

    .. math::
        q_i^{(j)}(t) = \mathrm{sclerp}\big(q_i^{(j-1)}(t),\, q_{i+1}^{(j-1)}(t),\, s\big),
        \quad j = 1..n,\ i = 0..n-j,

    and the curve is :math:`q_0^{(n)}(t)`; ``sclerp`` is eq. 11 with the shortest-path sign
    choice at every step. The curve starts at ``ctrl[..., 0, :]`` (exactly, same sign) at
    :math:`t_0` and ends at ``±ctrl[..., -1, :]`` at :math:`t_1`. Rotation-only control
    points give Shoemake's quaternion Bézier curve; translation-only ones the Euclidean
    Bézier curve of the translations. Cost :math:`O(T n^2)` interpolations.

    Args:
        ctrl: ``(..., n + 1, 8)`` unit dual quaternions (not checked), ``n + 1 >= 2``.
        t: ``(T,)`` or ``(..., T)`` times in ``domain``, on ``ctrl``'s device, any floating
            dtype (module docstring, "wide time"); its batch dims broadcast with those of
            ``ctrl``. NaN times give NaN poses.
        domain: ``(t0, t1)`` with ``t0 < t1``, in the caller's time: two real numbers, two
            0-d tensors or a ``(2,)`` tensor (may be float64 with float32 ``ctrl``).
        check: verify that ``t`` lies in ``domain`` up to the tolerance of the module
            docstring (one device synchronisation); ``False`` skips it, and then times
            further out give NaN. Skipped under ``torch.compile``.
        extrapolate: evaluate De Casteljau's scheme at any ``t`` (local parameter outside
            ``[0, 1]``) instead of the domain rules.

    Returns:
        ``(..., T, 8)`` unit dual quaternions in ``ctrl``'s dtype. float16/bfloat16 are
        computed in float32.

    Raises:
        ValueError: ``ctrl`` not ``(..., n + 1, 8)`` with ``n + 1 >= 2``, ``t`` 0-d, batch
            shapes that do not broadcast, a malformed or empty ``domain``, ``t`` outside
            the domain beyond the tolerance (with ``check``, without ``extrapolate``).
        TypeError: non-floating tensors, tensors on another device than ``ctrl``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> a = dq.identity()
        >>> b = dq.from_rt(torch.tensor([1., 0., 0., 0.]), torch.tensor([2., 0., 0.]))
        >>> bezier(torch.stack((a, b, b)), torch.tensor([10.0, 15.0]), domain=(10.0, 20.0))[:, 5]
        tensor([0.0000, 0.7500])
    """
    fn = "curves.bezier"
    batch, ctrl_c, s, _, bad = _prepare_bezier(fn, ctrl, t, domain, check, extrapolate)
    fused = _dispatch.fused_path(ctrl_c, s)
    x = fused_bezier(ctrl_c, s, batch) if fused else _de_casteljau(ctrl_c, s)
    return nan_where(bad, x).to(ctrl.dtype)


def bezier_derivatives(ctrl: Tensor, t: Tensor, order: int = 2,
                       domain: Sequence[float | Tensor] | Tensor = (0.0, 1.0),
                       check: bool = True, extrapolate: bool = False) -> tuple[Tensor, ...]:
    r"""A Bézier curve (:func:`bezier`) and its exact time derivatives up to ``order``.

    Returns :math:`(x, \dot x, \dots, x^{(\mathrm{order})})` with derivatives with respect
    to the caller's time ``t`` (the chain rule through :math:`s = (t - t_0)/(t_1 - t_0)` is
    included: a curve on a domain of 10 s moves 10 times slower than on ``[0, 1]``).
    Exact, not finite differences: the time derivatives of every level of De Casteljau's
    scheme are propagated through eq. 11 in truncated Taylor arithmetic (the jets of the
    weights of eq. 11 in ``t``; :mod:`torch_dq._taylor`). The results are
    differentiable (reverse mode, twice; and in forward mode) with respect to ``ctrl``,
    ``t`` and a tensor ``domain``. Feed them to :func:`kinematics` or :func:`imu`.

    Args:
        ctrl: ``(..., n + 1, 8)`` unit dual quaternions (not checked), ``n + 1 >= 2``.
        t: ``(T,)`` or ``(..., T)`` times in ``domain`` (as :func:`bezier`).
        order: highest derivative, an int in ``0..3``.
        domain: ``(t0, t1)`` in the caller's time (as :func:`bezier`).
        check: verify that ``t`` lies in ``domain`` (as :func:`bezier`).
        extrapolate: as :func:`bezier`.

    Returns:
        ``order + 1`` tensors ``(..., T, 8)`` in ``ctrl``'s dtype: the poses (the same as
        :func:`bezier` to rounding) and their 1st, ..., ``order``-th derivatives, tangent to
        the unit dual quaternions (:math:`x^* \dot x` is pure).

    Raises:
        ValueError: as :func:`bezier`; ``order`` not an int in ``0..3``.
        TypeError: as :func:`bezier`.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> ctrl = torch.stack((dq.identity(), dq.from_rt(torch.tensor([1., 0, 0, 0]),
        ...                                                torch.tensor([2., 0, 0]))))
        >>> x, dx = bezier_derivatives(ctrl, torch.tensor([1.0]), order=1, domain=(0.0, 4.0))
        >>> kinematics(x, dx).linear_velocity  # 2 m over 4 s
        tensor([[0.5000, 0.0000, 0.0000]])
    """
    fn = "curves.bezier_derivatives"
    order = _checks.integer(fn, "order", order, 0, _MAX_ORDER)
    batch, ctrl_c, s, slope, bad = _prepare_bezier(fn, ctrl, t, domain, check, extrapolate)
    T, m = s.shape[-1], ctrl_c.shape[-2]
    points = ctrl_c[..., None, :, :].expand(*batch, T, m, 8)
    levels = [(s[..., None], slope[..., None])] * (m - 1)  # the same parameter at every level
    return tuple(nan_where(bad, x).to(ctrl.dtype) for x in jet_scheme(points, levels, order, batch))


def _prepare_bspline(fn: str, ctrl: Tensor, t: Tensor, degree, knots, check: bool,
                     extrapolate: bool, form) -> tuple[torch.Size, KnotDomain, Tensor, str]:
    """Checked arguments of a B-spline: ``batch``, the time model on the (checked) knots in
    the time dtype, the relative times to evaluate, the form."""
    _checks.flag(fn, "check", check)
    _checks.flag(fn, "extrapolate", extrapolate)
    form = check_form(fn, form)
    _checks.control_points(fn, ctrl, 2, "at least 2 control points")
    degree = _checks.integer(fn, "degree", degree, 1)
    n = int(ctrl.shape[-2])
    if degree >= n:
        _checks.fail(fn, f"degree must be < the number of control points n = {n}, "
                         f"got degree {degree}")
    fix = "evaluate inside it, pass knots that cover it"
    if knots is None:
        batch = _checks.times(fn, t, ctrl)
        tdtype = _time_dtype(ctrl, t)
        knots = clamped_uniform_knots(n, degree, dtype=tdtype, device=ctrl.device)
        fix += " (default knots: clamped uniform on [0, 1])"
        validate = None
    else:
        check_knots(fn, knots, ctrl, n + degree + 1)
        _checks.same_device(fn, ctrl, "ctrl", "knots", knots)
        batch = _checks.times(fn, t, ctrl)
        if knots.dim() > 1:
            batch = _checks.broadcast_batch(fn, ctrl=(ctrl, 2), t=(t, 1), knots=(knots, 1))
        tdtype = _time_dtype(ctrl, t, knots)
        validate = "knots"
    dom = KnotDomain(knots.to(tdtype), degree)
    rel = dom.prepare(fn, t, tdtype, check=check, extrapolate=extrapolate, knots=validate,
                      fix=f"{fix}, or {EXTRAPOLATE_HINT}")
    return batch, dom, rel, form


def check_knots(fn: str, knots, ctrl: Tensor, size: int) -> None:
    """Check the shape of ``knots`` for a B-spline on control points ``ctrl (..., n, 8)``:
    ``(K,)``, or ``(..., K)`` with a row per trajectory whose batch broadcasts with
    ``ctrl``'s, ``K = size = n + degree + 1``."""
    _checks.tensor(fn, "knots", knots)
    if knots.dim() <= 1 and (knots.dim() == 0 or knots.shape[0] != size):
        _checks.fail(fn, f"expected a 1-D knots tensor of n + degree + 1 = {size} entries, got "
                         f"shape {_checks.shape_str(knots.shape)}")
    if knots.shape[-1] != size:
        _checks.fail(fn, f"expected (..., n + degree + 1) = (..., {size}) knots (a row per "
                         f"trajectory), got shape {_checks.shape_str(knots.shape)}")
    if knots.dim() > 1:
        _checks.broadcast_batch(fn, ctrl=(ctrl, 2), knots=(knots, 1))


def _bspline_pose(ctrl: Tensor, dom: KnotDomain, rel: Tensor, form: str,
                  batch: torch.Size) -> Tensor:
    """The B-spline of ``form`` at the relative times ``rel`` of ``dom``, in ``ctrl``'s dtype.

    The control polygon is sign-aligned first (``ctrl[i]`` nearest to ``ctrl[i - 1]``): the
    motion is the same (every interpolation takes the shortest path), but neighbouring spans
    then start from representatives of one chain and the output sign does not jump at knots.
    """
    dtype = compute_dtype(ctrl.dtype)
    ctrl_c, p = align_chain(ctrl.to(dtype)), dom.degree
    r = dom.span(rel)
    if form == "split":
        return _split_jets(ctrl_c, dom, rel, r, 0, batch)[0].to(ctrl.dtype)
    if form == "cumulative":
        weights = dom.bases(rel, r, 0, cumulative=True)[0].to(dtype)
        if _dispatch.fused_path(ctrl_c, weights):
            return fused_cumulative(ctrl_c, r, [weights], p, batch)[0].to(ctrl.dtype)
        points = span_points(ctrl_c, r, p, batch)
        return _cumulative.jets(points, [weights], 0)[0].to(ctrl.dtype)
    alphas = [alpha for alpha, _ in dom.de_boor_levels(rel, r, dtype)]
    if _dispatch.fused_path(ctrl_c, *alphas):
        return fused_bspline(ctrl_c, r, alphas, p, batch).to(ctrl.dtype)
    return _de_boor(span_points(ctrl_c, r, p, batch), alphas).to(ctrl.dtype)


def _bspline_jets(ctrl: Tensor, dom: KnotDomain, rel: Tensor, form: str, order: int,
                  batch: torch.Size, r: Tensor | None = None) -> tuple[Tensor, ...]:
    """The B-spline of ``form`` and its time derivatives to ``order`` (as
    :func:`_bspline_pose`), each ``(*batch, T, 8)`` in ``ctrl``'s dtype; ``r`` the spans
    of ``rel`` where the caller fixed them (a time at a knot read from the span before it),
    else :meth:`KnotDomain.span`."""
    dtype = compute_dtype(ctrl.dtype)
    ctrl_c, p = align_chain(ctrl.to(dtype)), dom.degree
    r = dom.span(rel) if r is None else r
    if form == "cumulative":
        xs = _cumulative_jets(ctrl_c, dom, rel, r, order, batch)
    elif form == "split":
        xs = _split_jets(ctrl_c, dom, rel, r, order, batch)
    else:
        levels = dom.de_boor_levels(rel, r, dtype)
        xs = jet_scheme(span_points(ctrl_c, r, p, batch), levels, order, batch)
    return tuple(x.to(ctrl.dtype) for x in xs)


def _cumulative_jets(ctrl: Tensor, dom: KnotDomain, rel: Tensor, r: Tensor, order: int,
                     batch: torch.Size) -> list[Tensor]:
    """The cumulative form (:mod:`torch_dq._cumulative`): its basis in the time dtype, rounded
    to the compute dtype of the sign-aligned ``ctrl``, then the product of powers: through
    the span tables (:func:`fused_cumulative`) where the fused ops may run, else its jets."""
    weights = dom.bases(rel, r, order, cumulative=True)
    return _product_of_powers(ctrl, r, [w.to(ctrl.dtype) for w in weights], dom.degree, batch)


def _product_of_powers(ctrl: Tensor, r: Tensor, weights: list[Tensor], degree: int,
                       batch: torch.Size) -> list[Tensor]:
    """The cumulative form on the cumulative ``weights`` (and their derivatives) of the spans
    ``r``: through the span tables (:func:`fused_cumulative`) where the fused ops may run,
    else its jets."""
    if _dispatch.fused_path(ctrl, *weights):
        return fused_cumulative(ctrl, r, weights, degree, batch)
    return _cumulative.jets(span_points(ctrl, r, degree, batch), weights, len(weights) - 1)


def _split_jets(ctrl: Tensor, dom: KnotDomain, rel: Tensor, r: Tensor, order: int,
                batch: torch.Size) -> list[Tensor]:
    r"""The split form (:func:`_split`) and its time derivatives to ``order``, from the
    sign-aligned ``ctrl`` in its compute dtype, on the cumulative basis
    (:meth:`KnotDomain.bases`).

    The poses alone: :func:`torch_dq._split.poses` (component rows, plain ops). With
    derivatives, the rotation is the cumulative form of the rotations alone (control points
    :math:`(q_j, 0)`, whose screw powers are the slerps from the identity of :func:`_split`)
    by :func:`_product_of_powers`, the translation :math:`p^{(k)} = [k = 0]\, p_{r-p} +
    \sum_j \tilde B^{(k)}_{r-p+j}\,(p_{r-p+j} - p_{r-p+j-1})`, joined as
    :func:`~torch_dq.dualquat.from_rt` by the Leibniz rule, dual part
    :math:`d^{(k)} = \frac12 \sum_i \binom{k}{i} (0, p^{(i)})\, q^{(k-i)}`.
    """
    p, n, T = dom.degree, ctrl.shape[-2], r.shape[-1]
    weights = dom.bases(rel, r, order, cumulative=True)
    weights = [w.to(ctrl.dtype) for w in weights]
    if order == 0:
        B = batch.numel()
        rows = weights[0].expand(*batch, T, p).movedim(-1, 0).reshape(p, B, T)
        first = (r - p).expand(*batch, T).reshape(B, T)
        x = split_poses(ctrl.expand(*batch, n, 8).reshape(B, n, 8), first, rows)
        return [x.view(*batch, T, 8)]
    q = ctrl[..., :4]
    rots = [x[..., :4] for x in _product_of_powers(torch.cat((q, torch.zeros_like(q)), -1),
                                                   r, weights, p, batch)]
    trans = translation(q, ctrl[..., 4:])  # (..., n, 3)
    steps = span_points(trans.diff(dim=-2), r - 1, p - 1, batch)  # (*batch, T, p, 3)
    moves = [(w[..., None] * steps).sum(-2) for w in weights]  # not a matmul: tiny (p, 3)
    moves[0] = moves[0] + span_points(trans, r - p, 0, batch)[..., 0, :]
    pure = [torch.nn.functional.pad(v, (1, 0)) for v in moves]  # (0, p^(k))
    out = []
    for k, rot in enumerate(rots):
        dual = qmul(pure[0], rots[k])
        for i in range(1, k + 1):
            dual = dual + math.comb(k, i) * qmul(pure[i], rots[k - i])
        out.append(torch.cat((rot, 0.5 * dual), -1))
    return out


def bspline(ctrl: Tensor, t: Tensor, degree: int = 3, knots: Tensor | None = None,
            check: bool = True, extrapolate: bool = False, form: str = "de_boor") -> Tensor:
    r"""B-spline curve of unit dual quaternions by De Boor's algorithm (paper 4.2).

    For ``t`` in the span :math:`[u_r, u_{r+1})` of the knots :math:`u`, with ``p`` the
    degree: :math:`d_i^0 = q_i` for :math:`i = r-p..r` and, for :math:`j = 1..p`,
    :math:`i = r..r-p+j`,

    .. math::
        d_i^j = \mathrm{sclerp}\big(d_{i-1}^{j-1},\, d_i^{j-1},\, \alpha_i^j\big),\qquad
        \alpha_i^j = \frac{t - u_i}{u_{i+p+1-j} - u_i},

    and the curve is :math:`d_r^p` (the paper's :math:`T`, in its indexing with order
    :math:`k = p + 1`). Only the ``p + 1`` control points of the span are read:
    :math:`O(T p^2)` interpolations whatever ``n``, and moving ``ctrl[i]`` changes the motion
    only on :math:`[u_i, u_{i+p+1})` (local control; the sign of later samples may flip,
    see below). The domain is :math:`[u_p, u_n]` including its right end, evaluated as the
    limit from the left. The knots are in the caller's time (seconds, frames, ...).
    Interior knots may repeat (multiplicity ``m`` makes the curve jump at ``m = p + 1``,
    right-continuously). The control polygon is first sign-aligned (each point replaced by
    the representative nearest to its predecessor; the motion is unchanged), so that the
    output's sign follows ``ctrl[..., 0, :]`` and does not flip from one span to the next.
    With clamped knots the curve starts at ``ctrl[..., 0, :]`` and ends at
    ``±ctrl[..., -1, :]``; ``n = p + 1`` then gives :func:`bezier`. Rotation-only control
    points give the quaternion De Boor curve with slerp; translation-only ones the Euclidean
    B-spline of the translations.

    Smoothness (``form="de_boor"``; ``"cumulative"`` and ``"split"`` are :math:`C^{p-1}`,
    module docstring):
    inside a span the curve is analytic in ``t``; at a simple interior knot of
    degree ``p >= 2`` it is :math:`C^1` but in general not :math:`C^2` (the second derivative
    jumps; measured in ``tests/test_continuous_time.py``): each level of the scheme is a
    screw interpolation, not an affine combination, so the Euclidean :math:`C^{p-1}`
    argument only survives to first order. Pure translations, as in Euclidean space, are
    :math:`C^{p-1}`. Degree 1 is :math:`C^0`.

    Args:
        ctrl: ``(..., n, 8)`` unit dual quaternions (not checked), ``n > degree``.
        t: ``(T,)`` or ``(..., T)`` times in ``[knots[degree], knots[n]]``, on ``ctrl``'s
            device, any floating dtype (module docstring, "wide time"); its batch dims
            broadcast with those of ``ctrl``.
        degree: polynomial degree ``p >= 1`` (1: piecewise sclerp, 3: cubic).
        knots: ``(n + degree + 1,)`` non-decreasing knots in the caller's time, on
            ``ctrl``'s device, any floating dtype (float64 for UNIX seconds); or
            ``(..., n + degree + 1)``, a row per trajectory, whose batch dims broadcast with
            those of ``ctrl`` and ``t`` (each trajectory on its own knots and domain);
            default :func:`clamped_uniform_knots` on ``[0, 1]``. Differentiable (at times
            that are not knots).
        check: verify that the knots are finite, non-decreasing with a non-empty domain,
            and that ``t`` lies in the domain up to the tolerance of the module docstring
            (one device synchronisation); ``False`` skips these, and then times further
            out give NaN. Skipped under ``torch.compile``.
        extrapolate: continue the end spans beyond the domain (the first and last
            non-empty spans' polynomials) instead of the domain rules: accurate only a
            fraction of a knot spacing beyond the ends, no prediction of the motion.
        form: ``"de_boor"`` (De Boor's pyramid, the paper's; default), ``"cumulative"``
            (Kim-Kim-Shin, :math:`C^{p-1}`) or ``"split"`` (cumulative SO(3) rotation and
            Euclidean translation, :math:`C^{p-1}`; degree 1: slerp of the rotations and
            linear interpolation of the translations); module docstring. Every form has
            finite gradients (twice) at identity and at equal control points.

    Returns:
        ``(..., T, 8)`` unit dual quaternions in ``ctrl``'s dtype. float16/bfloat16 are
        computed in float32.

    Raises:
        ValueError: ``ctrl`` not ``(..., n, 8)``, ``degree`` not an int in ``[1, n)``, knots
            not ``(n + degree + 1,)`` or ``(..., n + degree + 1)``, batch shapes (of
            ``ctrl``, ``t`` and the knots' rows) that do not broadcast;
            with ``check``: decreasing or non-finite knots, ``knots[degree] == knots[n]``,
            ``t`` outside the domain.
        TypeError: non-floating tensors, tensors on another device than ``ctrl``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> q = torch.tensor([1., 0., 0., 0.])
        >>> ctrl = dq.from_rt(q, torch.tensor([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]))
        >>> knots = clamped_uniform_knots(4, 3, domain=(0.0, 2.0))  # seconds
        >>> x = bspline(ctrl, torch.tensor([0.0, 1.0, 2.0]), knots=knots)
        >>> dq.to_rt(x)[1]
        tensor([[0.0000, 0.0000, 0.0000],
                [0.7500, 0.5000, 0.0000],
                [0.0000, 1.0000, 0.0000]])
    """
    fn = "curves.bspline"
    batch, dom, rel, form = _prepare_bspline(fn, ctrl, t, degree, knots, check, extrapolate, form)
    rel, bad = nan_safe(dom, rel)
    return nan_where(bad, _bspline_pose(ctrl, dom, rel, form, batch))


def bspline_derivatives(ctrl: Tensor, t: Tensor, order: int = 2, degree: int = 3,
                        knots: Tensor | None = None, check: bool = True,
                        extrapolate: bool = False, form: str = "de_boor",
                        ) -> tuple[Tensor, ...]:
    r"""A B-spline (:func:`bspline`) and its exact time derivatives up to ``order``.

    Returns :math:`(x, \dot x, \dots, x^{(\mathrm{order})})` with derivatives with respect
    to the caller's time ``t``, the time of the knots. Exact, not finite differences: the
    time derivatives of every level of De Boor's scheme are propagated through eq. 11, with
    the local parameters' slopes :math:`d\alpha_i^j/dt = 1 / (u_{i+p+1-j} - u_i)`, in
    truncated Taylor arithmetic (:mod:`torch_dq._taylor`). At a knot the
    derivatives are those of the span that contains ``t`` (right-hand derivatives; the
    left-hand ones at the domain's right end). The results are differentiable (reverse
    mode, twice; and in forward mode) with respect to ``ctrl``, ``t`` and the knots.

    Smoothness at simple interior knots (:func:`bspline`): with ``form="de_boor"``
    :math:`C^1` for degree ``p >= 2``, so the velocities are continuous but the
    accelerations (second derivatives) jump at the knots, even for cubic and quartic
    B-splines (only pure translations keep the Euclidean :math:`C^{p-1}`); with
    ``form="cumulative"`` or ``"split"`` :math:`C^{p-1}`, accelerations continuous for
    cubics. The split form's rotation derivatives are the cumulative form's (of the
    rotations alone), its translation's the derivatives of the Euclidean basis.

    Rounding near a short knot span: with ``form="de_boor"``, at times whose span (or a
    neighbouring knot interval that enters its local parameters) has a length ``g`` much
    shorter than the others, the linear acceleration carries a rounding error of about
    ``10 eps L / g**2`` (``eps`` of ``ctrl``'s dtype, ``L`` the size of the control points'
    translations; the local parameters' slopes ``1 / g`` multiply differences of rounded
    control points) and the angular acceleration about ``4 eps / g`` (measured in
    ``tests/test_continuous_time.py``; 0.2's figure: 3e-3 at ``g = 1e-6`` in float64).
    ``form="cumulative"`` and ``"split"`` do not amplify rounding this way (their basis
    derivatives are computed in the time dtype): prefer them for accelerations on nearly
    repeated knots.

    Args:
        ctrl: ``(..., n, 8)`` unit dual quaternions (not checked), ``n > degree``.
        t: ``(T,)`` or ``(..., T)`` times in the knot domain (as :func:`bspline`).
        order: highest derivative, an int in ``0..3``.
        degree: polynomial degree ``p >= 1``.
        knots: ``(n + degree + 1,)`` knots in the caller's time, or ``(..., n + degree +
            1)`` with a row per trajectory (as :func:`bspline`).
        check: the value checks of :func:`bspline` (one device synchronisation).
        extrapolate: as :func:`bspline`.
        form: ``"de_boor"``, ``"cumulative"`` or ``"split"`` (as :func:`bspline`).

    Returns:
        ``order + 1`` tensors ``(..., T, 8)`` in ``ctrl``'s dtype: the poses (the same as
        :func:`bspline` to rounding) and their 1st, ..., ``order``-th derivatives.

    Raises:
        ValueError: as :func:`bspline`; ``order`` not an int in ``0..3``.
        TypeError: as :func:`bspline`.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> ctrl = dq.from_rt(dq.identity((4,))[:, :4], torch.tensor([[0., 0, 0], [1, 0, 0],
        ...                                                            [2, 0, 0], [3, 0, 0]]))
        >>> knots = clamped_uniform_knots(4, 3, domain=(0.0, 6.0))  # 3 m in 6 s
        >>> x, dx, ddx = bspline_derivatives(ctrl, torch.tensor([3.0]), knots=knots)
        >>> kinematics(x, dx, ddx).linear_velocity
        tensor([[0.5000, 0.0000, 0.0000]])
    """
    fn = "curves.bspline_derivatives"
    order = _checks.integer(fn, "order", order, 0, _MAX_ORDER)
    batch, dom, rel, form = _prepare_bspline(fn, ctrl, t, degree, knots, check, extrapolate, form)
    rel, bad = nan_safe(dom, rel)
    return tuple(nan_where(bad, x) for x in _bspline_jets(ctrl, dom, rel, form, order, batch))

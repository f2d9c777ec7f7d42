r"""Curves of rigid motions: De Casteljau and De Boor with screw interpolation (paper section 4).

Both algorithms are the Euclidean ones with the linear interpolation replaced by the
paper's eq. 11 (:func:`torch_dq.dualquat.sclerp` with ``shortest=True`` at every step:
before each interpolation the second point is replaced by its antipode when the real
parts' dot is negative, so that ``x`` and ``-x`` control points give the same motion).

- :func:`bezier`: De Casteljau (paper 4.1), ``n + 1`` control points, ``t`` in ``[0, 1]``.
- :func:`bspline`: De Boor (paper 4.2), any non-decreasing knot vector
  (:func:`clamped_uniform_knots` by default), ``t`` in the knot domain.
- :func:`velocity`, :func:`twists`, :func:`screw_axis`: derivative along a curve, body and
  spatial twists, and the instantaneous screw axis (whose trace over ``t`` is the fixed
  axode of the motion).

Shapes: control points ``(..., n, 8)`` and times ``(T,)`` or ``(..., T)``; the batch dims
(all but the last two of ``ctrl``, all but the last of ``t``) broadcast, and the curves
are ``(..., T, 8)``. Every evaluation is vectorised over the batch, the control points and
all ``T`` times at once (the only Python loop is over the ``degree`` levels), and its
gradients with respect to the control points, the times and the knots come from the
analytic autograd op behind ``sclerp`` (finite at equal and antipodal control points).

Value checks on knots and times cost one device synchronisation; ``check=False`` skips them
(for ``torch.compile`` and tight loops).
"""

from __future__ import annotations

import numbers
from collections.abc import Callable

import torch
from torch import Tensor

from . import _checks, dualquat
from ._core import align_chain, dq_mul
from ._kernels.pyramid import pyramid
from ._numerics import compute_dtype, safe_denominator

__all__ = [
    "bezier",
    "bspline",
    "clamped_uniform_knots",
    "screw_axis",
    "twists",
    "velocity",
]

_ULPS = 4.0  # tolerance of the domain check on t, in units of eps * scale of the domain


# ----------------------------------------------------------------------------- checks

def _check_degree(fn: str, degree) -> int:
    if isinstance(degree, bool) or not isinstance(degree, numbers.Integral) or degree < 1:
        _checks.fail(fn, f"degree must be an int >= 1, got {degree!r}")
    return int(degree)


def _check_ctrl(fn: str, ctrl, min_points: int, what: str) -> None:
    _checks.tensor(fn, "ctrl", ctrl, 8)
    if ctrl.dim() < 2 or ctrl.shape[-2] < min_points:
        got = _checks.shape_str(ctrl.shape)
        _checks.fail(fn, f"expected a (..., n, 8) tensor for ctrl with n >= {min_points} "
                         f"({what}), got shape {got}")


def _check_times(fn: str, t, ctrl: Tensor) -> torch.Size:
    _checks.tensor(fn, "t", t)
    if t.dim() < 1:
        _checks.fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
    _checks.same_dtype_device(fn, ctrl=ctrl, t=t)
    return _checks.broadcast_batch(fn, ctrl=(ctrl, 2), t=(t, 1))


def _check_values(fn: str, t: Tensor, lo: Tensor, hi: Tensor, knots: Tensor | None) -> None:
    """All value checks with one synchronisation (``.tolist()`` of a few bools)."""
    flags = []
    if knots is not None:
        flags += [~torch.isfinite(knots).all(), (knots[1:] < knots[:-1]).any(), ~(lo < hi)]
    tol = _ULPS * torch.finfo(t.dtype).eps * torch.maximum(lo.abs(), hi.abs())
    flags.append(((t < lo - tol) | (t > hi + tol)).any())
    try:
        bad = torch.stack(flags).tolist()
    except RuntimeError as e:  # a transform with no host values, e.g. vmap over t
        raise RuntimeError(f"{fn}: the value checks read t (and knots) on the host, which "
                           f"this transform does not allow; pass check=False") from e
    if knots is not None:
        if bad[0]:
            _checks.fail(fn, "knots must be finite")
        if bad[1]:
            _checks.fail(fn, f"knots must be non-decreasing, got {knots.tolist()}")
        if bad[2]:
            _checks.fail(fn, f"knots give an empty domain [knots[degree], knots[n]] = "
                             f"[{lo.item():g}, {hi.item():g}]")
    if bad[-1]:
        finite = t[torch.isfinite(t)]
        seen = (f"[{finite.min().item():g}, {finite.max().item():g}]" if finite.numel()
                else "none finite")
        _checks.fail(fn, f"t must lie in the domain [{lo.item():g}, {hi.item():g}], got "
                         f"values in {seen} (non-finite: {int((~torch.isfinite(t)).sum())})")


# ----------------------------------------------------------------------------- knots

def clamped_uniform_knots(n_ctrl: int, degree: int, dtype: torch.dtype | None = None,
                          device=None) -> Tensor:
    r"""Clamped uniform knot vector on ``[0, 1]`` for ``n_ctrl`` control points.

    ``degree + 1`` zeros, the ``n_ctrl - degree - 1`` interior knots
    :math:`i / (n_{ctrl} - degree)` and ``degree + 1`` ones: the B-spline then starts at
    the first and ends at the last control point, and ``n_ctrl = degree + 1`` gives the
    Bézier curve.

    Args:
        n_ctrl: number of control points, ``> degree``.
        degree: polynomial degree ``>= 1`` (3 for cubic).
        dtype: floating dtype (default: ``torch.get_default_dtype()``).
        device: device of the result.

    Returns:
        ``(n_ctrl + degree + 1,)`` non-decreasing knots.

    Example:
        >>> clamped_uniform_knots(5, 2)
        tensor([0.0000, 0.0000, 0.0000, 0.3333, 0.6667, 1.0000, 1.0000, 1.0000])
    """
    fn = "curves.clamped_uniform_knots"
    degree = _check_degree(fn, degree)
    if isinstance(n_ctrl, bool) or not isinstance(n_ctrl, numbers.Integral) or n_ctrl <= degree:
        _checks.fail(fn, f"n_ctrl must be an int > degree = {degree}, got {n_ctrl!r}")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        _checks.fail(fn, f"expected a floating dtype, got {dtype!r}", TypeError)
    n_ctrl = int(n_ctrl)
    inner = torch.linspace(0.0, 1.0, n_ctrl - degree + 1, dtype=dtype, device=device)
    return torch.cat((inner.new_zeros(degree), inner, inner.new_ones(degree)))


# ----------------------------------------------------------------------------- evaluation

def _bezier(ctrl: Tensor, t: Tensor, batch: torch.Size) -> Tensor:
    """Unchecked De Casteljau: every curve's ``m`` control points are level 0 of the fused
    scheme of :func:`torch_dq._kernels.pyramid.pyramid`, with ``alpha = t`` at every level."""
    T, m, B = t.shape[-1], ctrl.shape[-2], batch.numel()
    flat = ctrl.expand(*batch, m, 8).reshape(B * m, 8)
    # idx[i, b T + k] = b m + i: the i-th control point of curve b, for each of its T times
    idx = (torch.arange(B, device=t.device)[:, None] * m + torch.arange(m, device=t.device))
    idx = idx.T[:, :, None].expand(m, B, T).reshape(m, B * T)
    tt = t.expand(*batch, T).reshape(1, B * T)
    out = pyramid(flat, idx, [tt.expand(m - j, B * T) for j in range(1, m)])
    return out.view(*batch, T, 8)


def bezier(ctrl: Tensor, t: Tensor, check: bool = True) -> Tensor:
    r"""Bézier curve of unit dual quaternions by De Casteljau's algorithm (paper 4.1).

    With :math:`q_i^{(0)} = q_i` (the control points),

    .. math::
        q_i^{(j)}(t) = \mathrm{sclerp}\big(q_i^{(j-1)}(t),\, q_{i+1}^{(j-1)}(t),\, t\big),
        \quad j = 1..n,\ i = 0..n-j,

    and the curve is :math:`q_0^{(n)}(t)`; ``sclerp`` is eq. 11 with the shortest-path sign
    choice at every step. The curve starts at ``ctrl[..., 0, :]`` (exactly, same sign) and
    ends at ``±ctrl[..., -1, :]``. Rotation-only control points give Shoemake's quaternion
    Bézier curve; translation-only ones the Euclidean Bézier curve of the translations.
    Cost :math:`O(T n^2)` interpolations.

    Args:
        ctrl: ``(..., n + 1, 8)`` unit dual quaternions (not checked), ``n + 1 >= 2``.
        t: ``(T,)`` or ``(..., T)`` times in ``[0, 1]``, same dtype and device as ``ctrl``;
            its batch dims broadcast with those of ``ctrl``. NaN times give NaN poses.
        check: verify that ``t`` lies in ``[0, 1]`` up to a few ulps (one device
            synchronisation); ``False`` skips it (e.g. under ``torch.compile``).

    Returns:
        ``(..., T, 8)`` unit dual quaternions. float16/bfloat16 are computed in float32.

    Raises:
        ValueError: ``ctrl`` not ``(..., n + 1, 8)`` with ``n + 1 >= 2``, ``t`` 0-d, batch
            shapes that do not broadcast, ``t`` outside ``[0, 1]`` (with ``check``).
        TypeError: non-floating tensors, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> a = dq.identity()
        >>> b = dq.from_rt(torch.tensor([1., 0., 0., 0.]), torch.tensor([2., 0., 0.]))
        >>> bezier(torch.stack((a, b, b)), torch.tensor([0.0, 0.5]))[:, 5]  # half x-shift
        tensor([0.0000, 0.7500])
    """
    fn = "curves.bezier"
    _check_ctrl(fn, ctrl, 2, "at least 2 control points")
    batch = _check_times(fn, t, ctrl)
    if check:
        _check_values(fn, t, t.new_zeros(()), t.new_ones(()), None)
    dtype = compute_dtype(ctrl.dtype)
    return _bezier(ctrl.to(dtype), t.to(dtype), batch).to(ctrl.dtype)


def _bspline(ctrl: Tensor, t: Tensor, degree: int, knots: Tensor, batch: torch.Size) -> Tensor:
    """Unchecked De Boor: span search, gather of ``degree + 1`` points, ``degree`` levels."""
    p, n, T = degree, ctrl.shape[-2], t.shape[-1]
    # Span r with knots[r] <= t < knots[r + 1], r in [p, n - 1]; at t >= knots[n] the last
    # non-empty span (so the right end of the domain is the left limit of the curve).
    inner = knots[p + 1:n]
    r = p + torch.searchsorted(inner, t.detach().contiguous(), right=True)
    r_end = p + torch.searchsorted(inner, knots[n:n + 1].detach(), right=False)
    r = torch.minimum(r, r_end)
    # Sign-align the control polygon (ctrl[i] nearest to ctrl[i - 1]): the motion is the
    # same (sclerp with shortest=True is sign-equivariant), but neighbouring spans then
    # start from representatives of one chain and the output sign does not jump at knots.
    ctrl = align_chain(ctrl)
    # The degree + 1 control points of each time, through one flat index (the backward
    # accumulates into (batch, n, 8), never into (batch, T, n, 8)).
    B = batch.numel()
    flat = ctrl.expand(*batch, n, 8).reshape(B * n, 8)
    offsets = (torch.arange(B, device=t.device) * n).reshape(*batch, 1, 1)
    idx = r[..., None] + torch.arange(-p, 1, device=t.device) + offsets  # (*batch, T, p + 1)
    # K[..., m] = knots[r - p + 1 + m], m = 0 .. 2p - 1.
    K = knots[r[..., None] + torch.arange(1 - p, p + 1, device=t.device)]
    te = t[..., None]
    alphas = []
    for j in range(1, p + 1):
        # d_i^j = sclerp(d_{i-1}^{j-1}, d_i^{j-1}, alpha_i), i = r-p+j .. r (local k = j .. p)
        # alpha_i = (t - knots[i]) / (knots[i + p + 1 - j] - knots[i])
        left, right = K[..., j - 1:p], K[..., p:2 * p - j + 1]
        denom = right - left
        empty = denom <= 0  # never inside a non-empty span; guards 0 / 0 all the same
        alpha = torch.where(empty, 0.0, (te - left) / safe_denominator(denom, empty))
        alphas.append(alpha.expand(*batch, T, p + 1 - j).reshape(B * T, p + 1 - j).T)
    # The fused scheme gathers the degree + 1 points of each time itself and recomputes
    # the levels in its backward (memory O(output), gradients accumulate into (B n, 8)).
    out = pyramid(flat, idx.expand(*batch, T, p + 1).reshape(B * T, p + 1).T, alphas)
    return out.view(*batch, T, 8)


def bspline(ctrl: Tensor, t: Tensor, degree: int = 3, knots: Tensor | None = None,
            check: bool = True) -> Tensor:
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
    limit from the left.
    Interior knots may repeat (multiplicity ``m`` lowers the smoothness there to
    :math:`C^{p-m}`; ``m = p + 1`` makes the curve jump, right-continuously). The control
    polygon is first sign-aligned (each point replaced by the representative nearest to
    its predecessor; the motion is unchanged), so that the output's sign follows
    ``ctrl[..., 0, :]`` and does not flip from one span to the next. With the
    default clamped knots the curve starts at ``ctrl[..., 0, :]`` and ends at
    ``±ctrl[..., -1, :]``; ``n = p + 1`` then gives :func:`bezier`. Rotation-only control
    points give the quaternion De Boor curve with slerp; translation-only ones the Euclidean
    B-spline of the translations.

    Args:
        ctrl: ``(..., n, 8)`` unit dual quaternions (not checked), ``n > degree``.
        t: ``(T,)`` or ``(..., T)`` times in ``[knots[degree], knots[n]]``, same dtype and
            device as ``ctrl``; its batch dims broadcast with those of ``ctrl``.
        degree: polynomial degree ``p >= 1`` (1: piecewise sclerp, 3: cubic).
        knots: ``(n + degree + 1,)`` non-decreasing knots, same dtype and device as
            ``ctrl``; default :func:`clamped_uniform_knots` on ``[0, 1]``. Differentiable
            (at times that are not knots).
        check: verify that the knots are finite, non-decreasing with a non-empty domain,
            and that ``t`` lies in the domain up to a few ulps (one device
            synchronisation); ``False`` skips these (e.g. under ``torch.compile``).

    Returns:
        ``(..., T, 8)`` unit dual quaternions. float16/bfloat16 are computed in float32.

    Raises:
        ValueError: ``ctrl`` not ``(..., n, 8)``, ``degree`` not an int in ``[1, n)``, knots
            not 1-D with ``n + degree + 1`` entries, batch shapes that do not broadcast;
            with ``check``: decreasing or non-finite knots, ``knots[degree] == knots[n]``,
            ``t`` outside the domain.
        TypeError: non-floating tensors, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> q = torch.tensor([1., 0., 0., 0.])
        >>> ctrl = dq.from_rt(q, torch.tensor([[0., 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]))
        >>> x = bspline(ctrl, torch.tensor([0.0, 0.5, 1.0]))
        >>> dq.to_rt(x)[1]
        tensor([[0.0000, 0.0000, 0.0000],
                [0.7500, 0.5000, 0.0000],
                [0.0000, 1.0000, 0.0000]])
    """
    fn = "curves.bspline"
    _check_ctrl(fn, ctrl, 2, "at least 2 control points")
    degree = _check_degree(fn, degree)
    n = int(ctrl.shape[-2])  # a Python int even under torch.jit.trace
    if degree >= n:
        _checks.fail(fn, f"degree must be < the number of control points n = {n}, "
                         f"got degree {degree}")
    batch = _check_times(fn, t, ctrl)
    dtype = compute_dtype(ctrl.dtype)
    if knots is None:
        knots = clamped_uniform_knots(n, degree, dtype=dtype, device=ctrl.device)
        if check:
            _check_values(fn, t, knots[degree].to(t.dtype), knots[n].to(t.dtype), None)
    else:
        _checks.tensor(fn, "knots", knots)
        _checks.same_dtype_device(fn, ctrl=ctrl, knots=knots)
        if knots.dim() != 1 or knots.shape[0] != n + degree + 1:
            _checks.fail(fn, f"expected a 1-D knots tensor of n + degree + 1 = "
                             f"{n + degree + 1} entries, got shape "
                             f"{_checks.shape_str(knots.shape)}")
        if check:
            _check_values(fn, t, knots[degree], knots[n], knots)
    out = _bspline(ctrl.to(dtype), t.to(dtype), degree, knots.to(dtype), batch)
    return out.to(ctrl.dtype)


# ----------------------------------------------------------------------------- derivatives

def velocity(fn: Callable[[Tensor], Tensor], t: Tensor) -> tuple[Tensor, Tensor]:
    r"""Pose and its time derivative along a curve, by forward-mode differentiation.

    ``torch.func.jvp`` of ``fn`` at ``t`` with tangent ones: exact to rounding (no finite
    differences), one pass, and differentiable again. ``fn`` must act pointwise in time:
    output sample ``k`` may depend on ``t[..., k]`` only (true of :func:`bezier` and
    :func:`bspline`); the derivative of a B-spline at a knot is the one of the span that
    contains it (the right-hand derivative, the left-hand one at the domain's right end).

    Args:
        fn: callable ``t -> (..., T, 8)``, e.g. ``lambda t: bspline(ctrl, t)``.
        t: ``(T,)`` or ``(..., T)`` times.

    Returns:
        ``(x, dx)``: ``fn(t)`` and :math:`dx/dt`, both ``(..., T, 8)``; feed them to
        :func:`twists`.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> ctrl = torch.stack((dq.identity(), dq.from_rt(torch.tensor([1., 0, 0, 0]),
        ...                                                torch.tensor([2., 0, 0]))))
        >>> x, dx = velocity(lambda t: bezier(ctrl, t), torch.tensor([0.5]))
        >>> twists(x, dx)  # constant speed 2 along x
        tensor([[0., 0., 0., 2., 0., 0.]])
    """
    name = "curves.velocity"
    if not callable(fn):
        _checks.fail(name, f"expected a callable for fn, got {type(fn).__name__}", TypeError)
    _checks.tensor(name, "t", t)
    return torch.func.jvp(fn, (t,), (torch.ones_like(t),))


def twists(x: Tensor, dx: Tensor, frame: str = "body") -> Tensor:
    r"""Body or spatial twists :math:`(\omega, v)` of a motion from its pose and derivative.

    For :math:`x(t) = ` ``from_rt(q(t), p(t))``, i.e. :math:`T(t) = [[R, p], [0, 1]]`:

    - ``frame="body"``: :math:`T^{-1}\dot T = [[\,[\omega_b]_\times, v_b], [0, 0]]`, i.e.
      :math:`\dot R = R\,[\omega_b]_\times` and :math:`\dot p = R\, v_b` (velocities in the
      moving frame). From :math:`x^* \dot x = \tfrac12 (0, \omega_b)
      + \epsilon\, \tfrac12 (0, v_b)`.
    - ``frame="spatial"``: :math:`\dot T T^{-1} = [[\,[\omega_s]_\times, v_s], [0, 0]]`, i.e.
      :math:`\omega_s = R\,\omega_b` and :math:`v_s = \dot p - \omega_s \times p` (the
      velocity of the body point momentarily at the origin). From
      :math:`\dot x x^* = \tfrac12 (0, \omega_s) + \epsilon\, \tfrac12 (0, v_s)`.

    Both are twice the vector parts of those products; ``(x, dx)`` and ``(-x, -dx)`` give
    the same twist.

    Args:
        x: ``(..., 8)`` unit dual quaternions (not checked).
        dx: ``(..., 8)`` their time derivatives (tangent to the unit dual quaternions),
            batch broadcastable with ``x``; see :func:`velocity`.
        frame: ``"body"`` or ``"spatial"``.

    Returns:
        ``(..., 6)`` twists ``(omega_x, omega_y, omega_z, v_x, v_y, v_z)``, the convention of
        :func:`torch_dq.dualquat.exp` (a constant twist ``xi`` gives
        ``x(t) = x(0) exp(t xi)`` in the body frame, ``exp(t xi) x(0)`` in the spatial one).

    Example:
        >>> import torch_dq.dualquat as dq
        >>> x = dq.identity()
        >>> dx = torch.tensor([0., 0., 0., 0.5, 0., 0., 0., 0.])  # d/dt of exp(t (0,0,1,0,0,0))
        >>> twists(x, dx)
        tensor([0., 0., 1., 0., 0., 0.])
    """
    fn = "curves.twists"
    _checks.tensor(fn, "x", x, 8)
    _checks.tensor(fn, "dx", dx, 8)
    _checks.same_dtype_device(fn, x=x, dx=dx)
    _checks.broadcast_batch(fn, x=(x, 1), dx=(dx, 1))
    if frame not in ("body", "spatial"):
        _checks.fail(fn, f"frame must be 'body' or 'spatial', got {frame!r}")
    dtype = compute_dtype(x.dtype)
    xc, dx = dualquat.conj(x.to(dtype)), dx.to(dtype)
    # body: conj(x) dx; spatial: dx conj(x); both pure (zero scalar parts) for unit x.
    prod = dq_mul(xc, dx) if frame == "body" else dq_mul(dx, xc)
    return (2.0 * torch.cat((prod[..., 1:4], prod[..., 5:]), dim=-1)).to(x.dtype)


def screw_axis(omega: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r"""Instantaneous screw axis of a spatial twist :math:`(\omega, v)`.

    The motion is momentarily a rotation about a line with angular velocity :math:`\omega`
    plus a translation along it at speed :math:`h|\omega|`:

    - direction :math:`l = \omega / |\omega|`;
    - pitch :math:`h = \omega \cdot v / |\omega|^2`;
    - point of the axis nearest to the origin :math:`c = \omega \times v / |\omega|^2`
      (``= cross(direction, moment)``); points on the axis move along it:
      :math:`v + \omega \times c = h\,\omega`;
    - moment :math:`m = c \times l = (v - h\,\omega) / |\omega|` (Plücker coordinates
      ``(l, m)``, the convention of :func:`torch_dq.dualquat.from_screw`).

    Pure translation (:math:`|\omega| \le \epsilon |v|` with :math:`\epsilon` the dtype's
    machine epsilon: the axis would lie beyond ``1 / eps`` lengths): direction
    :math:`v / |v|`, moment 0, pitch ``inf``. At rest (:math:`\omega = v = 0`) there is no
    axis: all three outputs are NaN, as for a non-finite twist. Tracing the axis over the
    times of a curve (with the spatial twists of :func:`twists`) gives the fixed axode.

    Args:
        omega: ``(..., 3)`` angular velocity of a spatial twist.
        v: ``(..., 3)`` its linear part, batch broadcastable with ``omega``.

    Returns:
        ``(direction (..., 3), moment (..., 3), pitch (...))``.

    Example:
        >>> l, m, h = screw_axis(torch.tensor([0., 0., 2.]), torch.tensor([2., 0., 1.]))
        >>> l, torch.linalg.cross(l, m), h  # z-parallel axis through (0, 1, 0), pitch 1/2
        (tensor([0., 0., 1.]), tensor([0., 1., 0.]), tensor(0.5000))
    """
    fn = "curves.screw_axis"
    _checks.tensor(fn, "omega", omega, 3)
    _checks.tensor(fn, "v", v, 3)
    _checks.same_dtype_device(fn, omega=omega, v=v)
    batch = _checks.broadcast_batch(fn, omega=(omega, 1), v=(v, 1))
    dtype = compute_dtype(omega.dtype)
    w, u = omega.to(dtype).expand(*batch, 3), v.to(dtype).expand(*batch, 3)
    w2 = (w * w).sum(-1, keepdim=True)
    v2 = (u * u).sum(-1, keepdim=True)
    eps = torch.finfo(dtype).eps
    translation = w2 <= (eps * eps) * v2  # includes rest (0 <= 0)
    # At rest, and for a non-finite twist, there is no axis: NaN (never a finite limit).
    rest = (translation & (v2 <= 0)) | ~(torch.isfinite(w2) & torch.isfinite(v2))
    # Safe where: the rotation branch divides by |omega|, the translation one by |v|.
    w2s = safe_denominator(w2, translation)
    wn = torch.sqrt(w2s)
    vn = torch.sqrt(safe_denominator(v2, v2 <= 0))
    pitch = (w * u).sum(-1, keepdim=True) / w2s
    direction = torch.where(translation, u / vn, w / wn)
    moment = torch.where(translation, 0.0, (u - pitch * w) / wn)
    pitch = torch.where(translation, torch.inf, pitch)
    nan = torch.full_like(pitch, torch.nan)
    direction = torch.where(rest, nan, direction)
    moment = torch.where(rest, nan, moment)
    pitch = torch.where(rest, nan, pitch)
    out = omega.dtype
    return direction.to(out), moment.to(out), pitch[..., 0].to(out)

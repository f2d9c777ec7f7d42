r"""Closed-form Jacobians of the inertial residuals (:mod:`torch_dq.fitting._imu`) with
respect to the trajectory's derivatives at the samples and to the bias and gravity steps:
the rows that :func:`~torch_dq.fitting._local.sample_jacobians` gets by a reverse pass over
``k`` copies of the residual code (about five evaluations' cost), for the Gauss-Newton
system of :mod:`torch_dq.fitting._linearize`.

The pose is :math:`x = r + \epsilon d` with derivatives :math:`\dot x, \ddot x`; products
are quaternion products, :math:`{}^*` the conjugate, :math:`C` the conjugation map and
:math:`e_j` the pure unit quaternions (a residual component ``j`` is the scalar product
with :math:`e_j`). The rows are the cotangents of :math:`e_j` (divided by the sigmas):

- gyroscope, :math:`\omega_b = 2\,\mathrm{vec}(r^* \dot r)`: :math:`\partial_{\dot r} =
  2 r e_j`, :math:`\partial_r = 2 C(e_j \dot r^*)`;
- accelerometer, :math:`f = \mathrm{vec}(r^* U r)`, :math:`U = (0, \ddot t - g)`,
  :math:`\ddot t = 2\,\mathrm{vec}(S)`, :math:`S = \ddot d r^* + 2 \dot d \dot r^* + d
  \ddot r^*` (the second derivative of :math:`t = 2\,\mathrm{vec}(d r^*)`): with
  :math:`G_j = \mathrm{vec}(r e_j r^*)` (:math:`R e_j`) and :math:`H = (0, 2 G_j)`,
  :math:`\partial_{\ddot d} = H r`, :math:`\partial_{\dot d} = 2 H \dot r`,
  :math:`\partial_d = H \ddot r`, :math:`\partial_{\ddot r} = C(d^* H)`,
  :math:`\partial_{\dot r} = 2 C(\dot d^* H)`, :math:`\partial_r = C(\ddot d^* H) - C(e_j
  r^* U) - U r e_j`; gravity's step :math:`-G_j\,\partial g / \partial \delta` (the
  chart's derivative, :meth:`~torch_dq.fitting._charts.Direction.report`); the bias's
  :math:`e_j`.

Both hold on unit dual quaternions and their derivatives, where they equal the residual
code's formulas (:mod:`torch_dq._kinematics`); the Jacobians chained through the spans are
then the same (``tests/test_term_jacobians.py`` compares them).

Where the compiled kernels run (``torch_dq._kernels.native``), the rows are computed sample
by sample in C (``csrc/imu_rows.c``: the same formulas, no per-component temporaries), and
so are the residuals themselves (:func:`imu_residuals`, for the terms' ``_residual``); the
PyTorch code here and in the terms is the reference they are tested against.
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from .._kernels import native

__all__ = ["accel_rows", "gyro_rows", "imu_residuals"]

# the compiled functions (csrc/imu_rows.c): names and argument types
_p, _i = ctypes.c_void_p, ctypes.c_int64
_GYRO = ("tdq_gyro_rows", (_i, _p, _i, _p, _i, _p, _i, _p))
_ACCEL = ("tdq_accel_rows", (_i, _p, _i, _p, _i, _p, _i, _p, _i, _p, _i, _p, _p))
_RESIDUALS = ("tdq_imu_residuals", (_i, _p, _i, _p, _i, _p, _i, _p, _i, _p, _i, _p, _i, _p))

# q e_j for the pure unit quaternions e_j: component c of row j is SIGN[j, c] q[INDEX[j, c]]
_INDEX = ((1, 0, 3, 2), (2, 3, 0, 1), (3, 2, 1, 0))
_SIGN = ((-1.0, 1.0, 1.0, -1.0), (-1.0, -1.0, 1.0, 1.0), (-1.0, 1.0, -1.0, 1.0))


def _times_units(q: Tensor, scale: Tensor | float) -> Tensor:
    """``(..., 3, 4)``: :math:`q e_j` of quaternions ``q (..., 4)``, times ``scale``
    (broadcast against the rows ``(3, 4)``): a signed permutation of the components."""
    index = torch.tensor(_INDEX, device=q.device)
    return q[..., index] * (scale * q.new_tensor(_SIGN))


def gyro_rows(x: Tensor, dx: Tensor, scale: Tensor | None = None,
              out: Tensor | None = None) -> Tensor:
    r"""``(..., N, 3, 2, 8)``: the body rate's rows with respect to ``x`` and ``dx`` ``(...,
    N, 8)`` (module doc: :math:`\partial_{\dot r} = 2 r e_j`, :math:`\partial_r = 2 C(e_j
    \dot r^*) = -2 \dot r e_j`; the dual parts zero), row ``j`` times ``scale[..., j]``
    (``(..., N, 3)``, the whitening's mask / sigma; None: 1); component-major in memory
    (``(3, 2, 8, ...)`` permuted, as :func:`accel_rows`); written into orders 0 and 1 of
    ``out`` where it is given (:func:`_target`) and returned as a view of it."""
    lead, into = x.shape[:-1], _target(out, x.shape[:-1], 2)
    if native.enabled(x, dx, *_given(scale)):
        O = 2 if into is None else into.shape[1]
        rows = x.new_empty(3, 2, 8, *lead) if into is None else into
        xs, dxs, ws = _samples(x), _samples(dx), _scales(scale, lead)
        native.function(*_GYRO)(lead.numel(), *_at(xs), *_at(dxs), *_at(ws), O,
                                 native.address(rows))
        return _view(rows, 2)
    rows = x.new_zeros(3, 2, 8, *lead).movedim((0, 1, 2), (-3, -2, -1))
    q = torch.stack((dx[..., :4], x[..., :4]), -2)  # (..., N, 2, 4)
    twice = x.new_tensor([-2.0, 2.0])[:, None, None]
    rows[..., :4] = _times_units(q, twice).transpose(-3, -2)
    rows = rows if scale is None else rows.mul_(scale[..., None, None])
    return rows if into is None else _view(into, 2).copy_(rows)


def _rotation(r: Tensor) -> Tensor:
    r"""``(3, 3, N)``: :math:`2 G_j = 2\,\mathrm{vec}(r e_j r^*)` as columns ``j`` (twice
    the rotation matrix of a unit ``r (4, N)``, component-major)."""
    P = r[:, None] * r[None]  # (4, 4, N) products r_a r_b
    h = torch.empty(3, 3, r.shape[-1], dtype=r.dtype, device=r.device)
    half = P[0, 0] - P[1, 1] - P[2, 2] - P[3, 3]
    for i in range(3):
        torch.add(half, P[i + 1, i + 1], alpha=2.0, out=h[i, i]).mul_(2.0)
        j, m = (i + 1) % 3, (i + 2) % 3  # R_ij = 2 (r_i r_j - w r_m), R_ji = 2 (r_i r_j + w r_m)
        torch.sub(P[i + 1, j + 1], P[0, m + 1], out=h[i, j]).mul_(4.0)
        torch.add(P[i + 1, j + 1], P[0, m + 1], out=h[j, i]).mul_(4.0)
    return h


def _vec_conj(a: Tensor, b: Tensor) -> Tensor:
    r"""``(3, N)``: the vector part of :math:`a b^*`, :math:`b_0 a_v - a_0 b_v - a_v \times
    b_v`, of quaternions ``(4, N)``."""
    return torch.linalg.cross(b[1:], a[1:], dim=0).addcmul_(a[1:], b[0]).addcmul_(
        b[1:], a[0], value=-1.0)


def accel_rows(x: Tensor, dx: Tensor, ddx: Tensor, gravity: Tensor,
               scale: Tensor | None = None, out: Tensor | None = None,
               ) -> tuple[Tensor, Tensor]:
    r"""``(..., N, 3, 3, 8)``: the specific force's rows with respect to ``x``, ``dx``,
    ``ddx`` ``(..., N, 8)``, row ``j`` times ``scale[..., j]`` (as :func:`gyro_rows`, and
    ``out`` as there: orders 0 to 2), and
    ``(..., N, 3, 3)``: with respect to gravity ``(..., N, 3)`` (world axes; module doc;
    unscaled). With :math:`H = (0, h)` pure
    (:math:`C(a^* H) = -H a`, :math:`C(e_j r^* U) = U r e_j`) every row is :math:`H` times
    one of ``Q`` below, :math:`(-h \cdot q_v,\ q_0 h + h \times q_v)`, in component-major
    rows (``(3, 6, 4, N)``, returned as a permuted view: the span's vector-Jacobian
    products read them component-major), and :math:`\partial_r` adds :math:`-2 U r e_j`."""
    lead, into = x.shape[:-1], _target(out, x.shape[:-1], 3)
    if native.enabled(x, dx, ddx, gravity, *_given(scale)):
        S = lead.numel()
        rows = x.new_empty(3, 3, 8, *lead) if into is None else into
        toward = x.new_empty(3, 3, S)
        held: list[Tensor | None] = [_samples(v) for v in (x, dx, ddx,
                                                           gravity.expand(*lead, 3))]
        held.append(_scales(scale, lead))  # the arrays held until the call returns
        native.function(*_ACCEL)(S, *(a for v in held for a in _at(v)), rows.shape[1],
                                  native.address(rows), native.address(toward))
        return (_view(rows, 3),
                toward.permute(2, 0, 1).reshape(*lead, 3, 3))
    X = torch.cat((x, dx, ddx), -1).reshape(-1, 24).T.contiguous()
    r, d, rd, dd, rdd, ddd = X.view(6, 4, -1)
    h = _rotation(r)  # (3 i, 3 j, N): h_j = 2 R e_j
    # (4, 6, N): the blocks (x, dx, ddx) x (real, dual) of the rows
    Q = torch.stack((-ddd, rdd, -2.0 * dd, 2.0 * rd, -d, r), 1)
    rows = X.new_empty(3, 6, 4, X.shape[-1])
    out = rows.permute(2, 0, 1, 3)  # (4, 3, 6, N)
    hi, Qv = h[:, :, None], Q[1:, None]
    torch.mul(hi[0], Qv[0], out=out[0]).addcmul_(hi[1], Qv[1]).addcmul_(hi[2], Qv[2]).neg_()
    for c in range(3):
        j, m = (c + 1) % 3, (c + 2) % 3
        torch.mul(Q[0, None], hi[c], out=out[1 + c]).addcmul_(hi[j], Qv[m]).addcmul_(
            hi[m], Qv[j], value=-1.0)
    g = gravity.expand(*lead, 3).reshape(-1, 3).T
    u = (_vec_conj(ddd, r).add_(_vec_conj(dd, rd), alpha=2.0).add_(_vec_conj(d, rdd))
         ).mul_(2.0).sub_(g)
    p = X.new_empty(4, X.shape[-1])  # U r
    torch.mul(u, r[1:], out=p[1:])
    torch.sum(p[1:], 0, out=p[0]).neg_()
    torch.linalg.cross(u, r[1:], dim=0, out=p[1:]).addcmul_(u, r[0])
    out[:, :, 0] += _times_units(p.T, -2.0).permute(2, 1, 0)
    rows = rows.view(72, -1).T.view(*lead, 3, 3, 8)
    rows = rows if scale is None else rows.mul_(scale[..., None, None])
    return (rows if into is None else _view(into, 3).copy_(rows),
            (-0.5 * h).permute(2, 1, 0).reshape(*lead, 3, 3))


def _target(out: Tensor | None, lead: torch.Size, orders: int) -> Tensor | None:
    """``out (..., N, 3, O, 8)``, ``O >= orders``, as the ``(3, O, 8, ...)`` array it is a
    permuted view of (the rows' component-major layout, the samples' stride 1), or None
    where it is None or not so (the rows then in an array of their own)."""
    if out is None or out.shape[:-3] != lead or out.shape[-3] != 3 or out.shape[-2] < orders:
        return None
    base = out.movedim((-3, -2, -1), (0, 1, 2))
    return base if base.is_contiguous() else None


def imu_residuals(x: Tensor, dx: Tensor, ddx: Tensor | None, gravity: Tensor | None,
                  bias: Tensor, readings: Tensor) -> Tensor | None:
    r"""``(..., N, 3)``: the inertial residuals before whitening by the compiled loop
    (``csrc/imu_rows.c``), from ``x``, ``dx`` (and ``ddx``) ``(..., N, 8)``: the
    gyroscope's :math:`2\,\mathrm{vec}(r^* \dot r) + b - y` (``ddx`` None) or the
    accelerometer's :math:`R^T (\ddot t - g) + b - y`, ``bias`` ``(..., 1, 3)``, ``readings``
    ``(..., N, 3)`` and ``gravity`` broadcasting; None where the compiled kernels do not
    apply (the terms' PyTorch code, the reference, then runs)."""
    args = (x, dx, ddx, gravity, bias, readings)
    given = [v for v in args if v is not None]
    if not native.enabled(*given):
        return None
    lead = torch.broadcast_shapes(*(v.shape[:-1] for v in given))
    held = [None if v is None else _samples(v.expand(*lead, v.shape[-1])) for v in args]
    out = x.new_empty(*lead, 3)
    native.function(*_RESIDUALS)(lead.numel(), *(a for v in held for a in _at(v)),
                                 native.address(out))
    return out


def _view(rows: Tensor, orders: int) -> Tensor:
    """``(..., N, 3, orders, 8)``: the first ``orders`` orders of component-major ``rows (3,
    O, 8, ..., N)``, as the builders return them."""
    return rows[:, :orders].movedim((0, 1, 2), (-3, -2, -1))


def _given(scale: Tensor | None) -> tuple[Tensor, ...]:
    """``scale`` as the tensors ``native.enabled`` checks (none where None)."""
    return () if scale is None else (scale,)


def _scales(scale: Tensor | None, lead: torch.Size) -> Tensor | None:
    """The rows' scales ``(..., N, 3)`` as ``(S, 3)`` rows for :func:`_at` (None: None)."""
    return None if scale is None else _samples(scale.expand(*lead, 3))


def _samples(x: Tensor) -> Tensor:
    """``x (..., c)`` as ``(S, c)`` with unit component stride (a view where it can be)."""
    x = x.reshape(-1, x.shape[-1])
    return x if x.stride(-1) == 1 else x.contiguous()


def _at(x: Tensor | None) -> tuple[ctypes.c_void_p | None, int]:
    """The address of ``(S, c)`` rows of unit component stride and their sample stride (None:
    a null pointer). The caller holds ``x`` until the call returns (a copy of
    :func:`_samples` lives no longer)."""
    return (None, 0) if x is None else (ctypes.c_void_p(x.data_ptr()), x.stride(0))

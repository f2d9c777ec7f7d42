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
"""

from __future__ import annotations

import torch
from torch import Tensor

from .._core import qconj, qmul

__all__ = ["accel_rows", "gyro_rows"]


def _units(like: Tensor) -> Tensor:
    """``(3, 4)``: the pure unit quaternions :math:`e_j`."""
    return torch.eye(4, dtype=like.dtype, device=like.device)[1:]


def gyro_rows(x: Tensor, dx: Tensor) -> Tensor:
    """``(..., N, 3, 2, 8)``: the body rate's rows with respect to ``x`` and ``dx`` ``(...,
    N, 8)`` (module doc; the dual parts and the sigmas left to the caller: zero, 1)."""
    E = _units(x)
    r, rd = x[..., None, :4], dx[..., None, :4]
    zero = torch.zeros_like(E.expand(*x.shape[:-1], 3, 4))
    d_r = 2.0 * qconj(qmul(E, qconj(rd)))
    d_rd = 2.0 * qmul(r, E)
    return torch.stack((torch.cat((d_r, zero), -1), torch.cat((d_rd, zero), -1)), -2)


def accel_rows(x: Tensor, dx: Tensor, ddx: Tensor, gravity: Tensor) -> tuple[Tensor, Tensor]:
    """``(..., N, 3, 3, 8)``: the specific force's rows with respect to ``x``, ``dx``,
    ``ddx`` ``(..., N, 8)``, and ``(..., N, 3, 3)``: with respect to gravity ``(..., N, 3)``
    (world axes; module doc; the sigmas left to the caller)."""
    E = _units(x)
    r, d = x[..., None, :4], x[..., None, 4:]
    rd, dd = dx[..., None, :4], dx[..., None, 4:]
    rdd, ddd = ddx[..., None, :4], ddx[..., None, 4:]
    S = qmul(ddd, qconj(r)) + 2.0 * qmul(dd, qconj(rd)) + qmul(d, qconj(rdd))
    U = torch.cat((torch.zeros_like(S[..., :1]), 2.0 * S[..., 1:] - gravity[..., None, :]), -1)
    G = qmul(qmul(r, E), qconj(r))  # (0, R e_j)
    H = 2.0 * G
    d_r = (qconj(qmul(qconj(ddd), H)) - qconj(qmul(qmul(E, qconj(r)), U))
           - qmul(qmul(U, r), E))
    rows = torch.stack((torch.cat((d_r, qmul(H, rdd)), -1),
                        torch.cat((2.0 * qconj(qmul(qconj(dd), H)), 2.0 * qmul(H, rd)), -1),
                        torch.cat((qconj(qmul(qconj(d), H)), qmul(H, r)), -1)), -2)
    return rows, -G[..., 1:]

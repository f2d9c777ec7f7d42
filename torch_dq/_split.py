r"""The split B-spline form's poses in component rows (private; :mod:`torch_dq.curves`).

The split form (SO(3) x R^3, readable reference :func:`torch_dq.curves._split`): for ``t``
in the span :math:`u_r \le t < u_{r+1}` with the cumulative basis :math:`w_j = \tilde
B_{r-p+j}(t)` (:meth:`torch_dq._time.KnotDomain.bases`),

.. math::
    R(t) = q_{r-p} \prod_{j=1}^p \exp(w_j h_{r-p+j}),\qquad
    p(t) = p_{r-p} + \sum_{j=1}^p w_j\, \delta_{r-p+j},

with :math:`h_i = \log(q_{i-1}^* q_i)` (half the relative rotation vector; the sign-aligned
chain makes every relative rotation's real part non-negative: the shortest path) and
:math:`\delta_i = p_i - p_{i-1}`, computed once per pair of neighbours; the pose is
``(R, 1/2 (0, p) R)``.

:func:`poses` evaluates it for many times at once in plain torch ops on component rows
(``(C, N)``: every op runs over contiguous rows of times, several times faster on CPU than a
trailing dim of 4 whose backward scatters into zero-filled copies). Plain ops: differentiable
to any order in every autograd mode, compilable, and exact at the identity: the exponential's
``cos`` and ``sinc`` are evaluated from the squared norm (:func:`torch_dq._numerics.even`) and
the logarithm is :func:`torch_dq.quat.log`, smooth at the identity, so equal neighbours (a
camera at rest) have exact, finite gradients and Hessians without any epsilon.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import quat
from ._core import qconj, qmul, translation
from ._numerics import even
from ._taylor import qmul_rows

__all__ = ["poses"]


def _tables(ctrl: Tensor) -> tuple[Tensor, Tensor]:
    r"""Rows per control point ``(7, B n)``: :math:`q_i` (4 rows) and :math:`p_i` (3 rows);
    and per pair of neighbours of each curve ``(6, B (n - 1))``: :math:`h_i` (3 rows) and
    :math:`\delta_i` (3 rows), curve by curve (no pair straddles two curves, so a NaN of
    one curve stays in it); ``ctrl (B, n, 8)`` sign-aligned."""
    q = ctrl[..., :4]
    trans = translation(q, ctrl[..., 4:])
    half = quat.log(qmul(qconj(q[:, :-1]), q[:, 1:]))[..., 1:]
    points = torch.cat((q, trans), -1).reshape(-1, 7).T
    return points, torch.cat((half, trans.diff(dim=1)), -1).reshape(-1, 6).T


def poses(ctrl: Tensor, first: Tensor, weights: Tensor) -> Tensor:
    r"""The split form's poses ``(N, 8)``.

    Args:
        ctrl: ``(B, n, 8)`` sign-aligned control points of ``B`` curves.
        first: ``(B, T)`` int64 first control point :math:`r - p` of each time's span
            (within its curve).
        weights: ``(p, B, T)`` cumulative weights :math:`w_j`, ``j = 1..p``, in ``ctrl``'s
            dtype (rows: :meth:`torch_dq._time.KnotDomain.bases`'s layout moved back).

    Returns:
        ``(B T, 8)`` unit dual quaternions, time-major within each curve.
    """
    B, n, _ = ctrl.shape
    p, N = weights.shape[0], first.numel()
    curve = torch.arange(B, device=first.device)[:, None]
    start = (first + curve * n).reshape(N)
    pair = (first + curve * (n - 1)).reshape(N)
    points, pairs = _tables(ctrl)
    # index_select, not advanced indexing: its backward is an index_add, not a sorting put
    c = points.index_select(1, start)  # (7, N): q_{r-p}, p_{r-p}
    idx = (pair + torch.arange(p, device=first.device)[:, None]).reshape(-1)
    g = pairs.index_select(1, idx).view(6, p, N)
    w = weights.reshape(p, N)
    v = g[:3] * w  # (3, p, N): w_j h_j
    v2 = (v * v).sum(0)
    powers = torch.cat((even("cos", v2)[None], even("sinc", v2) * v))  # exp(w_j h_j)
    x = c[:4]
    for j in range(p):
        x = qmul_rows(x, powers[:, j])
    move = c[4:] + (g[3:] * w).sum(1)  # (3, N)
    return torch.cat((x, _dual(move, x))).T


def _dual(t: Tensor, r: Tensor) -> Tensor:
    r"""Rows ``(4, N)`` of :math:`\frac12 (0, t)\, r` for translations ``t (3, N)`` and
    rotations ``r (4, N)``: :math:`\frac12 (-t \cdot v, w t + t \times v)`."""
    w, v = r[0], r[1:]
    return 0.5 * torch.cat(((-(t * v).sum(0))[None], w * t + torch.linalg.cross(t, v, dim=0)))

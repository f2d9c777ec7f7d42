r"""The cumulative B-spline form of rigid motions (Kim, Kim & Shin 1995) (private).

For control points :math:`c_0, \dots, c_{n-1}` (unit dual quaternions, sign-aligned by
:func:`torch_dq._core.align_chain`) and non-decreasing knots :math:`u`,

.. math::
    X(t) = c_0 \prod_{j \ge 1} \big(c_{j-1}^{-1} c_j\big)^{\tilde B_j(t)},\qquad
    \tilde B_j = \sum_{l \ge j} B_{l,p},

with :math:`B_{l,p}` the B-spline basis of degree ``p`` and each power
:math:`x^w = \exp(w \log x)` the screw motion on the shortest path, i.e. eq. 11 from the
identity, :math:`x^w = \mathrm{sclerp}(1, x, w)`. For ``t`` in the span
:math:`u_r \le t < u_{r+1}` the cumulative weights are 1 for :math:`j \le r - p` and 0 for
:math:`j > r`, and whole powers telescope (:math:`c_0 \prod_{j \le r-p} c_{j-1}^{-1} c_j =
c_{r-p}`, exact because the chain is sign-aligned), so only the span's ``p + 1`` control
points matter:

.. math::
    X(t) = c_{r-p} \prod_{j=1}^{p}
        \big(c_{r-p+j-1}^{-1} c_{r-p+j}\big)^{\tilde B_{r-p+j}(t)}.

The weights are polynomials of degree ``p`` on each span, and the curve is
:math:`C^{p-1}` at a simple interior knot (the cumulative basis is, and each power is
analytic in its weight): a cubic's accelerations are continuous, unlike the De Boor form's.

- :func:`basis`: the cumulative weights of each time's span and their time derivatives.
- :func:`jets`: the curve and its exact time derivatives from the span's control points and
  the weights, in truncated Taylor arithmetic (:mod:`torch_dq._taylor`): the power's jets
  are eq. 11's (:func:`torch_dq._taylor.sclerp` from the identity; the derivative of
  :math:`x^{w(t)}` is :math:`x^w \log(x)\, \dot w`), their product a Leibniz product.

The readable reference is :func:`torch_dq.curves._kim_kim_shin`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from . import _taylor
from ._kernels.layout import chunks
from ._numerics import safe_denominator

__all__ = ["basis", "jets"]

JET_CHUNK = 16384  # times per eager chunk of the jets (their temporaries stay in cache)


def _span_basis(knots: Tensor, r: Tensor, t: Tensor, degree: int,
                order: int) -> list[Tensor]:
    r"""Taylor coefficients in ``t`` (``0..order``) of :math:`B_{r-p+m,p}`, ``m = 0..p``,
    each ``(..., T, p + 1)``: the polynomial pieces of span ``r``, evaluated at ``t``.

    Cox-de Boor on the span's knots :math:`u_{r-p+1}, \dots, u_{r+p}`: with
    :math:`V_0 = (1)` and, for ``k = 1..p``,
    :math:`\alpha_i = (t - u_i) / (u_{i+k} - u_i)`, ``i = r-k+1..r`` (0 where the
    denominator is 0: the 0/0 terms of repeated knots),

    .. math::
        B_{i,k} = \alpha_i B_{i,k-1} + (1 - \alpha_{i+1}) B_{i+1,k-1},

    i.e. :math:`V_k = (0, \alpha V_{k-1}) + ((1 - \alpha) V_{k-1}, 0)`. Every step is a
    polynomial in ``t``, so ``t`` outside the span gives the pieces' continuation.
    """
    p = degree
    K = knots[r[..., None] + torch.arange(1 - p, p + 1, device=r.device)]  # u_{r-p+1..r+p}
    te = t[..., None]
    V = [torch.ones_like(te)] + [torch.zeros_like(te) for _ in range(order)]
    for k in range(1, p + 1):
        left, right = K[..., p - k:p], K[..., p:p + k]
        denom = right - left
        empty = denom <= 0  # never inside a non-empty span; 0 / 0 = 0 all the same
        safe = safe_denominator(denom, empty)
        alpha = torch.where(empty, 0.0, (te - left) / safe)
        slope = torch.where(empty, 0.0, 1.0 / safe)
        # (alpha + slope h) V, truncated: the product by an affine function of t
        aV = [alpha * V[0]] + [alpha * V[i] + slope * V[i - 1] for i in range(1, order + 1)]
        zero = torch.zeros_like(te)
        V = [torch.cat((zero, a), -1) + torch.cat((v - a, zero), -1)
             for a, v in zip(aV, V, strict=True)]
    return V


def basis(knots: Tensor, r: Tensor, t: Tensor, degree: int, order: int) -> list[Tensor]:
    r"""The cumulative basis of each time's span and its time derivatives.

    :math:`\tilde B_{r-p+j}(t) = \sum_{m=j}^{p} B_{r-p+m,p}(t)`, ``j = 1..p``
    (:math:`\tilde B_{r-p} = 1` by the partition of unity, and :math:`\tilde B_l = 0` for
    ``l > r``, so neither is returned).

    Args:
        knots: ``(K,)`` non-decreasing knots (uniform or not, clamped or not, repeated
            interior knots allowed), in the time dtype.
        r: ``(..., T)`` int64 spans, ``knots[r] <= t < knots[r + 1]``, ``r`` in
            ``[p, n - 1]`` (:func:`torch_dq._core.knot_span`).
        t: ``(..., T)`` times in ``knots``' dtype. Times outside their span give the
            polynomial continuation of the span's pieces (extrapolation).
        degree: ``p >= 1``.
        order: highest time derivative, ``>= 0``.

    Returns:
        ``order + 1`` tensors ``(..., T, p)``:
        :math:`[\tilde B, d\tilde B/dt, \dots, d^{order}\tilde B/dt^{order}]` with
        ``Bt[..., j - 1]`` :math:`= \tilde B_{r-p+j}(t)`; differentiable (any order) with
        respect to ``t`` and ``knots``.
    """
    V = _span_basis(knots, r, t, degree, order)
    return [math.factorial(k) * v[..., 1:].flip(-1).cumsum(-1).flip(-1)
            for k, v in enumerate(V)]


def _identity_rows(like: Tensor) -> Tensor:
    """The identity as component rows ``(8, 1, 1)`` in ``like``'s dtype and device."""
    one = torch.zeros(8, 1, 1, dtype=like.dtype, device=like.device)
    one[0] = 1.0
    return one


def _conj_rows(x: Tensor) -> Tensor:
    """Quaternion conjugate of both halves of component rows ``(8, ...)``."""
    sign = x.new_tensor([1.0, -1.0, -1.0, -1.0] * 2).view(8, *[1] * (x.dim() - 1))
    return x * sign


def _chunk_jets(P: Tensor, w: _taylor.Jet) -> _taylor.Jet:
    """The product of powers on one chunk: ``P (8, p + 1, N)`` control-point rows, ``w``
    the normalised Taylor coefficients ``(p, N)`` of the weights -> the curve's jet
    ``(8, N)`` per coefficient."""
    order = len(w) - 1
    rel = _taylor.dq_rows(_conj_rows(P[:, :-1]), P[:, 1:])  # c_{j-1}^-1 c_j, (8, p, N)
    powers = _taylor.sclerp([_identity_rows(P), *[None] * order], [rel, *[None] * order], w)
    x: _taylor.Jet = [P[:, 0], *[None] * order]
    for j in range(P.shape[1] - 1):
        x = _taylor.dq_mul(x, [None if e is None else e[:, j] for e in powers])
    return x


def jets(points: Tensor, weights: list[Tensor], order: int) -> list[Tensor]:
    r"""The cumulative form and its exact time derivatives at each time.

    :math:`X = c_{r-p} \prod_{j=1}^p (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}` (module
    docstring) in truncated Taylor arithmetic: each power is eq. 11 from the identity on
    jets (its derivative is :math:`x^w \log(x)\, \dot w`), the product a Leibniz product
    of dual-quaternion jets. Plain torch ops: differentiable (twice, reverse and forward
    mode, ``torch.func`` transforms) with respect to ``points`` and ``weights``,
    compilable with ``fullgraph=True``. Equal neighbours (a static segment) have finite
    derivatives; at a half turn between neighbours (orthogonal real parts) the sign of the
    zero dot picks the path, and the derivatives are that side's.

    Args:
        points: ``(..., T, p + 1, 8)`` the sign-aligned control points
            :math:`c_{r-p}, \dots, c_r` of each time's span.
        weights: ``order + 1`` tensors ``(..., T, p)`` as :func:`basis` returns them
            (rounded to ``points``' dtype): the weights :math:`w_j = \tilde B_{r-p+j}(t)`
            and their time derivatives.
        order: highest time derivative, ``0 <= order < len(weights)``; ``0`` is the
            pose-only path.

    Returns:
        ``order + 1`` tensors ``(..., T, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`.
    """
    *batch, T, m, _ = points.shape
    n = math.prod(batch) * T
    rows = points.reshape(n, m * 8).T.reshape(m, 8, n).transpose(0, 1)  # (8, m, n)
    w_rows = [w.expand(*batch, T, m - 1).reshape(n, m - 1).T / math.factorial(k)
              for k, w in enumerate(weights[:order + 1])]
    outs = []
    for part in chunks(n, JET_CHUNK):
        coefs: _taylor.Jet = [w[:, part].contiguous() for w in w_rows]
        x = _chunk_jets(rows[..., part].contiguous(), coefs)
        outs.append([v.T for v in _taylor.derivatives(x)])
    return [torch.cat(xs).view(*batch, T, 8) for xs in zip(*outs, strict=True)]

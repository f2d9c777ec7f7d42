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
:math:`j > r`. A whole power is the relative motion itself when its real part is
non-negative (the shortest path), which sign alignment guarantees, so the whole powers
telescope (:math:`c_0 \prod_{j \le r-p} c_{j-1}^{-1} c_j = c_{r-p}`) and only the span's
``p + 1`` control points matter:

.. math::
    X(t) = c_{r-p} \prod_{j=1}^{p}
        \big(c_{r-p+j-1}^{-1} c_{r-p+j}\big)^{\tilde B_{r-p+j}(t)}.

The weights are polynomials of degree ``p`` on each span, and the curve is
:math:`C^{p-1}` at a simple interior knot, :math:`C^{p-m}` at a knot of multiplicity ``m``
(as the cumulative basis, since each power is analytic in its weight): a cubic's
accelerations are continuous, unlike those of the De Boor form (:math:`C^1`).

- the cumulative weights of each time's span and their time derivatives come from the
  time model (:meth:`torch_dq._time.KnotDomain.bases` with ``cumulative=True``).
- :func:`jets`: the curve and its exact time derivatives from the span's control points and
  the weights, in truncated Taylor arithmetic (:mod:`torch_dq._taylor`): the power's jets
  are eq. 11's (:func:`torch_dq._kernels.jet_sclerp.sclerp` from the identity; the derivative of
  :math:`x^{w(t)}` is :math:`x^w \log(x)\, \dot w`), their product a Leibniz product.
- :func:`poses`: the poses alone, eagerly and compiled as one fused autograd op
  (:mod:`torch_dq._kernels.cumulative`): each power from the identity is
  :math:`\beta + \alpha x` with dual numbers :math:`\alpha, \beta` (eq. 11's weights), so
  the product expands into a sum of per-span products of control points (span tables,
  computed once per span) with per-time dual weights, one weighted sum of table rows per
  time; analytic backward.
- :func:`derivatives`: the poses and their time derivatives the same way: the tables are
  constant on a span, so the derivatives fall on the scalar dual weights alone (jets of
  ``(L, 2, p, n)`` rows instead of dual-quaternion jets), each order one weighted sum of
  table rows with an analytic backward (:mod:`torch_dq._kernels.cumulative_jets`);
  :func:`jets` is its plain-op reference.

The readable reference is :func:`torch_dq.curves._kim_kim_shin`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from . import _taylor
from ._dispatch import per_time_jets
from ._kernels import cumulative as _poses_kernel
from ._kernels import cumulative_jets as _derivatives_kernel
from ._kernels import jet_sclerp
from ._kernels.layout import chunks

__all__ = ["derivatives", "jets", "poses"]

JET_CHUNK = 16384  # times per eager chunk of the jets (their temporaries stay in cache)


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
    powers = jet_sclerp.sclerp([_identity_rows(P), *[None] * order], [rel, *[None] * order], w)
    x: _taylor.Jet = [P[:, 0], *[None] * order]
    factors = [[None] * (P.shape[1] - 1) if e is None else e.unbind(1) for e in powers]
    for j in range(P.shape[1] - 1):
        x = _taylor.dq_mul(x, [f[j] for f in factors])
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
        weights: ``order + 1`` tensors ``(..., T, p)`` as
            :meth:`torch_dq._time.KnotDomain.bases` returns them (cumulative; rounded to
            ``points``' dtype): the weights :math:`w_j = \tilde B_{r-p+j}(t)`
            and their time derivatives.
        order: highest time derivative, ``0 <= order < len(weights)``; ``0`` gives the
            poses alone (the plain-op reference of :func:`poses`, whose fused op is faster
            in eager reverse mode: it computes each pair's relative motion once).

    Returns:
        ``order + 1`` tensors ``(..., T, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`.
    """
    *batch, T, m, _ = points.shape
    n = math.prod(batch) * T
    rows = points.reshape(n, m * 8).T.reshape(m, 8, n).transpose(0, 1)  # (8, m, n)
    w_rows = [w.expand(*batch, T, m - 1).reshape(n, m - 1).T / math.factorial(k)
              for k, w in enumerate(weights[:order + 1])]
    outs = []
    for part in chunks(n, JET_CHUNK, points.device):
        coefs: _taylor.Jet = [w[:, part].contiguous() for w in w_rows]
        x = _chunk_jets(rows[..., part].contiguous(), coefs)
        outs.append([v.T for v in _taylor.derivatives(x)])
    return [torch.cat(xs).view(*batch, T, 8) for xs in zip(*outs, strict=True)]


def _span_points(ctrl: Tensor, first: Tensor, p: int) -> Tensor:
    """``(N, p + 1, 8)``: the control points ``ctrl[first .. first + p]`` of each time."""
    return ctrl[first[:, None] + torch.arange(p + 1, device=first.device)]


def poses(ctrl: Tensor, first: Tensor, weights: Tensor) -> Tensor:
    r"""The cumulative form's poses, through the span tables where they pay.

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened
            into one ``M``).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`; the time
            reads ``ctrl[first .. first + p]``.
        weights: ``(p, N)`` the cumulative basis :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``
            (:meth:`torch_dq._time.KnotDomain.bases`, transposed), in ``ctrl``'s dtype.

    Returns:
        ``(N, 8)``: :math:`c_{r-p} \prod_j (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}`. Differentiable
        twice (reverse mode) with respect to ``ctrl`` and ``weights``. Under ``torch.func``
        transforms and forward AD (:func:`torch_dq._dispatch.fused_path` false) use
        :func:`jets` instead, which this does not check. Where the span tables cost more
        than they save (:func:`torch_dq._dispatch.per_time_jets`; e.g. the estimator's
        one-span copies of each sample, where every time has a span of its own) the product
        of powers runs per time (:func:`jets` at order 0), elsewhere the fused op
        (:func:`torch_dq._kernels.cumulative.poses`).
    """
    p = weights.shape[0]
    if first.shape[0] == 0:  # no times (an empty batch): an empty output tied to ctrl
        return ctrl[:0] * 1
    if per_time_jets(ctrl, first, p):
        return jets(_span_points(ctrl, first, p), [weights.T], 0)[0]
    return _poses_kernel.poses(ctrl, first, weights)


def derivatives(ctrl: Tensor, first: Tensor, weights: list[Tensor]) -> list[Tensor]:
    r"""The cumulative form and its time derivatives, through the span tables where they pay
    (eager reverse mode and ``torch.compile``; :func:`poses` for the poses alone).

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`.
        weights: ``order + 1`` tensors ``(p, N)``, the cumulative basis and its time
            derivatives (:meth:`torch_dq._time.KnotDomain.bases`, transposed), in ``ctrl``'s dtype.

    Returns:
        ``order + 1`` tensors ``(N, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`,
        differentiable twice (reverse mode) with respect to ``ctrl`` and ``weights``; per
        time (:func:`jets`) where the tables do not pay
        (:func:`torch_dq._dispatch.per_time_jets`), else
        :func:`torch_dq._kernels.cumulative_jets.derivatives` (the estimation's evaluations,
        where nothing is differentiated, take :func:`torch_dq._cumulative_lie.derivatives`
        instead: :meth:`torch_dq.nn.BSpline.span_derivatives`). Under ``torch.func``
        transforms and forward AD (:func:`torch_dq._dispatch.fused_path` false) use
        :func:`jets`.
    """
    p, N = weights[0].shape
    order = len(weights) - 1
    if order == 0:
        return [poses(ctrl, first, weights[0])]
    if N == 0:
        return [ctrl[:0] * 1 for _ in weights]
    if per_time_jets(ctrl, first, p):
        return jets(_span_points(ctrl, first, p), [w.T for w in weights], order)
    return _derivatives_kernel.derivatives(ctrl, first, weights)

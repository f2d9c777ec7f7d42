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

- :func:`basis`: the cumulative weights of each time's span and their time derivatives.
- :func:`jets`: the curve and its exact time derivatives from the span's control points and
  the weights, in truncated Taylor arithmetic (:mod:`torch_dq._taylor`): the power's jets
  are eq. 11's (:func:`torch_dq._taylor.sclerp` from the identity; the derivative of
  :math:`x^{w(t)}` is :math:`x^w \log(x)\, \dot w`), their product a Leibniz product.
- :func:`poses`: the poses alone as one fused autograd op (eager reverse mode), with each
  pair's relative motion and angle computed once and an analytic backward.

The readable reference is :func:`torch_dq.curves._kim_kim_shin`.
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor

from . import _taylor
from ._kernels.layout import chunks, from_rows, rows_into, to_rows
from ._kernels.sclerp import Frame, combine, frame, vjp_rows
from ._kernels.sclerp import weights as screw_weights
from ._kernels.weights import Angle, WeightSlopes, angle
from ._numerics import safe_denominator

__all__ = ["basis", "jets", "poses"]

JET_CHUNK = 16384  # times per eager chunk of the jets (their temporaries stay in cache)
POSES_CHUNK = 16384  # times per eager chunk of the fused poses (fewer, larger ops than 8192)


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
            ``[p, n - 1]`` (``torch_dq._time.KnotDomain.span``).
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
        order: highest time derivative, ``0 <= order < len(weights)``; ``0`` gives the
            poses alone (the plain-op reference of :func:`poses`, which is faster in
            eager reverse mode: it computes each pair's relative motion once).

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


# ----------------------------------------------------------------------------- fused poses

def _mul_vjp(U: Tensor, V: Tensor, G: Tensor) -> tuple[Tensor, Tensor]:
    r"""Cotangents of ``U`` and ``V`` for :math:`Z = UV` (rows ``(8, ...)``) at ``G``:
    with :math:`a \cdot (bc) = (a c^*) \cdot b = (b^* a) \cdot c`,
    :math:`\bar U = (g_r v_r^* + g_d v_d^*,\ g_d v_r^*)` and
    :math:`\bar V = (u_r^* g_r + u_d^* g_d,\ u_r^* g_d)`."""
    q = _taylor.qmul_rows
    Vc, Uc = _conj_rows(V), _conj_rows(U)
    gr, gd = G[:4], G[4:]
    gU = torch.cat((q(gr, Vc[:4]) + q(gd, Vc[4:]), q(gd, Vc[:4])))
    gV = torch.cat((q(Uc[:4], gr) + q(Uc[4:], gd), q(Uc[:4], gd)))
    return gU, gV


def _pair_table(rows: Tensor) -> tuple[Tensor, Tensor]:
    """Relative motions :math:`c_i^{-1} c_{i+1}` ``(8, M - 1)`` of consecutive rows
    ``(8, M)``, and their :class:`Frame` and :class:`Angle` from the identity ``(6, M - 1)``:
    computed once per pair, gathered for every time that reads it."""
    rel = _taylor.dq_rows(_conj_rows(rows[:, :-1]), rows[:, 1:])
    fr = frame(_identity_rows(rows)[:, 0], rel, True)
    return rel, torch.stack((*fr, *angle(fr.c)))


def _chunk_powers(rel: Tensor, table: Tensor, first: Tensor, w: Tensor,
                  derivatives: bool = False, need_w: bool = False):
    """The powers of one chunk: the gathered relative motions ``(p, 8, N)`` (``first`` the
    index of each time's :math:`c_{r-p}`), their frames, weights and powers ``(p, 8, N)``."""
    p, n = w.shape
    idx = (first + torch.arange(p, device=first.device)[:, None]).reshape(-1)
    R = rel.index_select(1, idx).view(8, p, n).transpose(0, 1)
    pairs = table.index_select(1, idx).view(6, p, n)
    fr = Frame(*pairs[:3])
    ws = screw_weights(fr, w, derivatives, need_w, Angle(*pairs[3:]))
    return R, fr, ws, combine(_identity_rows(rel)[:, 0], R, fr, ws)


class _Poses(torch.autograd.Function):
    r"""The cumulative form's poses, fused: :math:`c_f \prod_{j=1}^p E_j`,
    :math:`E_j = (c_{f+j-1}^{-1} c_{f+j})^{w_j}` (eq. 11 from the identity).

    Inputs: ``ctrl (M, 8)`` sign-aligned control points (flattened over curves),
    ``first (N,)`` int64 (``f``, each time's first control point), ``w (p, N)``. Output
    ``(N, 8)``. Component rows over cache-sized chunks; the relative motions and their
    angles are computed once per pair of control points; the backward recomputes the
    powers chunk by chunk (memory O(output)) and sums the pairs' sensitivities before
    expanding them into control-point rows. Twice differentiable (the backward is plain
    torch ops).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(ctrl: Tensor, first: Tensor, w: Tensor) -> Tensor:
        rows = to_rows(ctrl)
        rel, table = _pair_table(rows)
        out = ctrl.new_empty(first.shape[0], 8)
        for i in chunks(first.shape[0], POSES_CHUNK):
            E = _chunk_powers(rel, table, first[i], w[:, i])[-1]
            x = rows.index_select(1, first[i])
            for j in range(E.shape[0]):
                x = _taylor.dq_rows(x, E[j])
            rows_into(out[i], x)
        return out

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctrl, first, w = inputs
        ctx.save_for_backward(ctrl, first, w)

    @staticmethod
    def backward(ctx, grad):
        ctrl, first, w = ctx.saved_tensors
        need_w = ctx.needs_input_grad[2]
        rows = to_rows(ctrl)
        rel, table = _pair_table(rows)
        # accumulated as component rows, per control point (8, M) and per pair (8, M - 1)
        grad_rows, grad_rel = torch.zeros_like(rows), torch.zeros_like(rel)
        used = torch.zeros_like(rel[0], dtype=torch.bool)
        grad_w = []
        for i in chunks(first.shape[0], POSES_CHUNK):
            R, fr, ws, E = _chunk_powers(rel, table, first[i], w[:, i], True, need_w)
            prefix = [rows.index_select(1, first[i])]
            for j in range(E.shape[0] - 1):
                prefix.append(_taylor.dq_rows(prefix[-1], E[j]))
            G, gE = to_rows(grad[i]), []
            for j in range(E.shape[0] - 1, -1, -1):
                G, g = _mul_vjp(prefix[j], E[j], G)
                gE.append(g)
            ct = vjp_rows(_identity_rows(rel)[:, 0], R, fr, cast(WeightSlopes, ws),
                          torch.stack(gE[::-1]), frame_terms=False)
            # From the identity, c = sigma R_w and delta = sigma S_w: the frame terms are
            # the (sigma-scaled) sensitivities added to the real and dual scalar parts.
            g_rel = ct.b.index_add(1, ct.c.new_tensor([0, 4], dtype=torch.long),
                                   torch.stack((ct.c, ct.delta), 1))
            for j in range(E.shape[0]):  # pair first + j of each time
                grad_rel = grad_rel.index_add(1, first[i] + j, g_rel[j])
                used = used.index_fill(0, first[i] + j, True)
            grad_rows = grad_rows.index_add(1, first[i], G)
            if need_w:
                grad_w.append(cast(Tensor, ct.t))
        # rel = c_i^* c_{i+1}; pairs that no time reads are zeroed (a NaN stays in its curve)
        A, B = (torch.where(used, x, 0.0) for x in (rows[:, :-1], rows[:, 1:]))
        g_conj, g_next = _mul_vjp(_conj_rows(A), B, grad_rel)
        zero = torch.zeros_like(g_next[:, :1])
        grad_rows = (grad_rows + torch.cat((_conj_rows(g_conj), zero), 1)
                     + torch.cat((zero, g_next), 1))
        grad_ctrl = from_rows(grad_rows)
        return grad_ctrl, None, torch.cat(grad_w, -1) if need_w else None


def poses(ctrl: Tensor, first: Tensor, weights: Tensor) -> Tensor:
    r"""The cumulative form's poses through the fused op (pose only, eager reverse mode).

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened
            into one ``M``).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`; the time
            reads ``ctrl[first .. first + p]``.
        weights: ``(p, N)`` the cumulative basis :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``
            (:func:`basis`, transposed), in ``ctrl``'s dtype.

    Returns:
        ``(N, 8)``: :math:`c_{r-p} \prod_j (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}`. Differentiable
        twice (reverse mode) with respect to ``ctrl`` and ``weights``. Under ``torch.func``
        transforms and forward AD (:func:`torch_dq._kernels.fused_path` false) use
        :func:`jets` instead, which this does not check.
    """
    return _Poses.apply(ctrl, first, weights)

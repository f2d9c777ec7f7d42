r"""The cumulative B-spline form in its Lie algebra: its vector-Jacobian products and, where
nothing is differentiated, its evaluation (private).

On one span (:mod:`torch_dq._cumulative`) the cumulative form is

.. math::
    X = c_0 \prod_{j=1}^{p} \mathrm{Exp}(\lambda_j d_j),\qquad
    d_j = \mathrm{Log}(c_{j-1}^{-1} c_j),

twists :math:`\xi = (\omega, v)` (:func:`torch_dq.dualquat.log`), :math:`\lambda_j` the
cumulative weights. With :math:`h(\xi) = (0, \omega/2, 0, v/2)` the pure dual quaternion of a
twist, :math:`\dot X = X h(V)` and :math:`\ddot X = X (h(V)^2 + h(\dot V))`, where the body
twist and its rate follow the recursions of Sommer, Usenko, Schubert, Demmel and Cremers
("Efficient derivative computation for cumulative B-splines on Lie groups", CVPR 2020), from
:math:`V_0 = \dot V_0 = 0`:

.. math::
    V_j = M_j V_{j-1} + \dot\lambda_j d_j,\qquad
    \dot V_j = M_j \dot V_{j-1} + \ddot\lambda_j d_j + \dot\lambda_j [V_j, d_j],\qquad
    M_j = \mathrm{Ad}_{\mathrm{Exp}(-\lambda_j d_j)}.

Their differentials with respect to the steps :math:`c_i \mathrm{Exp}(\delta_i)`
(:func:`torch_dq.fitting._local.tangent_step`): a change of :math:`d_j` moves
:math:`\mathrm{Exp}(\lambda_j d_j)` by :math:`\lambda_j J_r(\lambda_j d_j)\, \mathrm d d_j` on the
right, so :math:`\mathrm d(M_j y) = \mathrm{ad}_{M_j y}\, \lambda_j J_r\, \mathrm d d_j`;
:math:`\mathrm d d_j = J_r^{-1}(d_j)(\delta_j - \mathrm{Ad}_{\mathrm{Exp}(-d_j)} \delta_{j-1})`.
:func:`vjp` runs these backwards from cotangents of :math:`X, \dot X, \ddot X`: rows of
6-vectors through ``p`` steps, no autograd graph, exact.

The SE(3) matrices are SO(3)'s formulas over dual numbers: :math:`\mathrm{ad}_\xi = \Phi =
[\omega]_\times + \varepsilon [v]_\times` and :math:`\Phi^3 = -s\,\Phi` with the dual square
:math:`s = |\omega|^2 + 2\varepsilon\, \omega \cdot v`, so :math:`\mathrm{Ad}_{\mathrm{Exp}(\xi)}
= I + \sigma \Phi + \alpha \Phi^2`, :math:`J_r = I - \alpha \Phi + \beta \Phi^2`,
:math:`J_r^{-1} = I + \frac12 \Phi + \gamma \Phi^2` with the even functions ``sinc``,
``se3_c1``, ``se3_c2``, ``se3_c3`` of ``torch_dq._numerics`` at the dual number :math:`s`
(:math:`f(s_0) + \varepsilon f'(s_0) s_1`, ``even_slope``): exact at :math:`\omega = 0`.
What is constant on a span (its twists, their powers, :math:`J_r^{-1}` and :math:`J_l^{-1} =
J_r^{-1} \mathrm{Ad}_{\mathrm{Exp}(-d)}`) is taken once per distinct span and gathered per
sample (:func:`span_parts`); the rest is per sample, in a component-major layout (below),
as fused multiply-adds into preallocated arrays (at the estimator's ~10^4 samples a torch op
costs as much in dispatch and fresh allocations as in arithmetic).

:func:`derivatives` evaluates the form itself by the same recursions (:math:`X = c_0 \prod_j
\mathrm{Exp}(\lambda_j d_j)`, :math:`\dot X`, :math:`\ddot X` from :math:`V, \dot V`) where
nothing is differentiated, in float64 on unit control points (:func:`applies`): 1.5 to 2
times as fast as the span tables (:mod:`torch_dq._kernels.cumulative_jets`), which reverse mode
keeps differentiating; both agree to rounding (``tests/test_perf9_cumulative_lie.py``, with
an mpmath reference).

Where the compiled kernels are built (``torch_dq._kernels.native``), :func:`vjp` and
:func:`derivatives` run the same mathematics as one C loop over the samples
(``torch_dq._kernels.lie_native``, ``csrc/cumulative_lie.c``); the code here is its reference.

The readable reference is reverse mode through the span's evaluation
(:meth:`torch_dq.nn.Curve.evaluate_span`, ``fitting._linearize``); the tests compare both
with reverse mode through the public ``derivatives`` (``tests/test_span_jacobians.py``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import dualquat
from ._core import dq_mul
from ._kernels import lie_native
from ._numerics import even_slopes, evens

__all__ = ["applies", "derivatives", "right_jacobian_inverse", "span_parts", "vjp"]

Rows = Tensor | tuple[Tensor, ...]  # a component-major tensor or its rows (``unbind(0)``)

# Component-major layout: every per-sample quantity is ``(components..., S)`` (``S`` the
# samples), so each operation below is one elementwise pass over contiguous rows (batched
# 6 x 6 products of tiny matrices are several times slower). A dual 3 x 3 matrix
# ``A + eps B`` acting on twists ``(omega, v)`` as ``[[A, 0], [B, A]]`` is the pair
# ``(A, B)``, each ``(3, 3, S)``.


def _cross_into(out: Rows, a: Rows, b: Rows, acc: bool = False, base: Rows | None = None,
                ) -> Rows:
    r"""``out`` :math:`{} = a \times b` (``acc``: :math:`{} \mathrel{+}=`; ``base``:
    :math:`{} = \mathrm{base} + a \times b`, the bits of ``base`` copied to ``out`` then
    ``acc``, without the copy) in place, for component-major ``(3, ...)`` vectors ``a, b``
    (broadcasting), each a tensor or its rows (``unbind(0)``, which callers reading the rows
    of one tensor several times take once): six fused multiply-adds into ``out`` and no
    temporaries (``torch.linalg.cross`` over the first dim of broadcast rows is several
    times slower, a stack of component products allocates each)."""
    o, x, y = (t.unbind(0) if isinstance(t, Tensor) else t for t in (out, a, b))
    for i in range(3):
        j, m = (i + 1) % 3, (i + 2) % 3
        if base is not None:
            torch.addcmul(base[i], x[j], y[m], out=o[i])
        elif acc:
            o[i].addcmul_(x[j], y[m])
        else:
            torch.mul(x[j], y[m], out=o[i])
        o[i].addcmul_(x[m], y[j], value=-1.0)
    return out


def _shape(a: Tensor, b: Tensor) -> tuple[int, ...]:
    """The broadcast shape of ``a`` and ``b`` of one rank (``torch.broadcast_shapes`` is a
    Python loop several times slower)."""
    return tuple(max(x, y) for x, y in zip(a.shape, b.shape, strict=True))


def _hat(u: Tensor) -> Tensor:
    """``(3, 3, S)`` cross-product matrices of ``(3, S)``."""
    out = u.new_zeros(3, 3, *u.shape[1:])
    for i in range(3):
        j, m = (i + 1) % 3, (i + 2) % 3
        out[i, j], out[j, i] = -u[m], u[m]
    return out


def _powers(d: Tensor) -> tuple[Tensor, ...]:
    r"""The parts of :math:`\Phi` and :math:`\Phi^2` of twists ``d (6, S)``: ``W, V,
    W2, WV (3, 3, S)`` with :math:`\Phi = W + \varepsilon V`, :math:`\Phi^2 = W_2 +
    \varepsilon\, WV` (:math:`W_2 = w w^T - |w|^2 I`, :math:`WV = w v^T + v w^T - 2 (w
    \cdot v) I`), and the dual square ``s0, s1 (S,)``."""
    w, v = d[:3], d[3:]
    s0, c = (w * w).sum(0), (w * v).sum(0)
    W2, WV = w[:, None] * w[None], w[:, None] * v[None]
    WV += WV.transpose(0, 1).clone()
    for i in range(3):
        W2[i, i] -= s0
        WV[i, i] -= 2.0 * c
    return _hat(w), _hat(v), W2, WV, s0, 2.0 * c


def _scalars(names: tuple[str, ...], powers: tuple[Tensor, ...], scale: Tensor | float = 1.0,
             ) -> list[tuple[Tensor, Tensor]]:
    """The even functions ``names`` at the dual square of ``scale`` times the twists of
    ``powers``: real and dual parts (one :func:`~torch_dq._numerics.even_slopes` pass)."""
    square = scale * scale
    return [(f, slope * (square * powers[5]))
            for f, slope in even_slopes(names, square * powers[4])]


def _polynomial(powers: tuple[Tensor, ...], c0: Tensor | float, c1: tuple[Tensor, Tensor],
                c2: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor]:
    r"""The dual matrix :math:`c_0 I + c_1 \Phi + c_2 \Phi^2` (``c0`` real, ``c1, c2`` dual
    scalars: real and dual parts) of :func:`_powers`."""
    W, V, W2, WV = powers[:4]
    (a1, b1), (a2, b2) = c1, c2
    real = (W2 * a2).addcmul_(W, a1)
    for i in range(3):
        real[i, i] += c0
    return real, (W * b1).addcmul_(V, a1).addcmul_(W2, b2).addcmul_(WV, a2)


def _apply(m: tuple[Tensor, Tensor], x: Tensor) -> Tensor:
    """The dual matrix ``m`` times twists ``x (6, S)``: fused multiply-adds into one fresh
    array (products and sums over ``(3, 3, S)`` arrays cost several times more)."""
    A, B = m
    out = torch.empty_like(x)
    w, v = out[:3], out[3:]
    for i in range(3):
        if i:
            w.addcmul_(A[:, i], x[i])
            v.addcmul_(A[:, i], x[3 + i]).addcmul_(B[:, i], x[i])
        else:
            torch.mul(A[:, 0], x[0], out=w)
            torch.mul(A[:, 0], x[3], out=v).addcmul_(B[:, 0], x[0])
    return out


def _rows(a: Tensor, m: tuple[Tensor, Tensor], out: Tensor | None = None, acc: bool = False,
          value: float = 1.0) -> Tensor:
    r"""Rows ``a (6, k, S)`` times the dual matrix ``m``: :math:`(a_\omega A + a_v B,\ a_v
    A)`, into ``out`` (fresh if None), or with ``acc`` added to it times ``value``: fused
    multiply-adds in place (broadcast products into fresh ``(3, 3, k, S)`` arrays cost
    several times more)."""
    A, B = (x.unsqueeze(2).unbind(0) for x in m)  # rows (3, 1, S)
    out = torch.empty_like(a) if out is None else out
    w, v = out[:3], out[3:]
    r = a.unsqueeze(1).unbind(0)  # (1, k, S) each
    for i in range(3):
        if i or acc:
            w.addcmul_(r[i], A[i], value=value)
            v.addcmul_(r[3 + i], A[i], value=value)
        else:
            torch.mul(r[0], A[0], out=w)
            torch.mul(r[3], A[0], out=v)
        w.addcmul_(r[3 + i], B[i], value=value)
    return out


def _bracket(a: Tensor, b: Tensor) -> Tensor:
    r""":math:`[a, b] = \mathrm{ad}_a b` of twists ``(6, ...)`` (broadcasting)."""
    out = a.new_empty(_shape(a, b))
    o, x, y = out.unbind(0), a.unbind(0), b.unbind(0)
    _cross_into(o[:3], x[:3], y[:3])
    _cross_into(o[3:], x[:3], y[3:])
    _cross_into(o[3:], x[3:], y[:3], acc=True)
    return out


def _row_ad(a: Tensor, z: Tensor, out: Tensor, base: Tensor | None = None) -> Tensor:
    r"""``out`` :math:`\mathrel{+}=` rows ``a (6, k, S)`` times :math:`\mathrm{ad}_z` (``z
    (6, S)``): :math:`(a_\omega \times z_\omega + a_v \times z_v,\ a_v \times z_\omega)`, in
    place (``base``: ``out`` :math:`{} = \mathrm{base} + {}` the same, the bits of a copy
    of ``base`` into ``out`` first)."""
    o, x, y = out.unbind(0), a.unbind(0), z.unsqueeze(1).unbind(0)
    b = (None, None) if base is None else (base[:3].unbind(0), base[3:].unbind(0))
    _cross_into(o[:3], x[:3], y[:3], acc=True, base=b[0])
    _cross_into(o[:3], x[3:], y[3:], acc=True)
    _cross_into(o[3:], x[3:], y[:3], acc=True, base=b[1])
    return out


def _conj_vec(out: Tensor, q: tuple[Tensor | None, Tensor], u: Tensor, left: bool,
              acc: bool = False) -> Tensor:
    r"""``out (3, k, S)`` :math:`{} = ` (``acc``: :math:`{} \mathrel{+}=`) the vector part of
    :math:`q^* u` (``left``) or of :math:`u q^*`, :math:`q_0 u_v - u_0 q_v \pm u_v \times
    q_v`, of per-sample quaternions ``q = (q_0 (1, S), q_v (3, 1, S))`` (``q_0`` None: a
    pure one) and rows ``u (4, k, S)``, in place."""
    q0, qv = q
    if acc:
        if q0 is not None:
            out.addcmul_(u[1:], q0)
        out.addcmul_(u[0], qv, value=-1.0)
    elif q0 is None:
        torch.mul(u[0], qv, out=out).neg_()
    else:
        torch.mul(u[1:], q0, out=out).addcmul_(u[0], qv, value=-1.0)
    if left:
        _cross_into(out, u[1:], qv, acc=True)
    else:
        _cross_into(out, qv, u[1:], acc=True)
    return out


def _halves(X: Tensor) -> tuple[tuple[Tensor, Tensor], tuple[Tensor, Tensor]]:
    """The real and dual quaternions of per-sample ``X (8, S)`` as :func:`_conj_vec`'s
    ``(q_0 (1, S), q_v (3, 1, S))``."""
    X = X[:, None]
    return (X[0], X[1:4]), (X[4], X[5:8])


def _left_t(X: Tensor, g: Tensor) -> Tensor:
    r""":math:`L(X)^T g` (``X (8, S)``, rows ``g (8, n, S)``): the cotangent of ``y`` through
    :math:`y \mapsto X y`, :math:`(r^* g_a + d^* g_b,\ r^* g_b)`."""
    r, d = _halves(X)
    out = torch.empty_like(g)
    ga, gb = g[:4], g[4:]
    _conj_vec(out[1:4], r, ga, True)
    _conj_vec(out[1:4], d, gb, True, acc=True)
    _conj_vec(out[5:8], r, gb, True)
    for o, terms in ((0, ((r, ga), (d, gb))), (4, ((r, gb),))):  # q0 u0 + q_v . u_v
        torch.mul(terms[0][1][0], terms[0][0][0], out=out[o])
        for i, (q, u) in enumerate(terms):
            if i:
                out[o].addcmul_(u[0], q[0])
            for c in range(3):
                out[o].addcmul_(u[1 + c], q[1][c])
    return out


def _forward(d: Tensor, powers: tuple[Tensor, ...], lam: list[Tensor]) -> dict[str, list]:
    r"""The recursions of the module docstring on the samples' span twists ``d (p, 6, S)``
    (their :func:`_powers`, all steps at once: ``(3, 3, p, S)`` and ``(p, S)``) and
    cumulative weights ``lam`` (``O`` tensors ``(p, S)``: :math:`\lambda` and its time
    derivatives): per step ``j`` :math:`M_j = I - \lambda \sigma \Phi + \lambda^2 \alpha
    \Phi^2`, :math:`\lambda_j J_r(\lambda_j d_j) = \lambda I - \lambda^2 \alpha \Phi +
    \lambda^3 \beta \Phi^2` (:math:`\Phi = \mathrm{ad}_{d_j}`, the coefficients at
    :math:`\lambda^2 s`; the matrices of all steps in one pass, views per step), :math:`z_j
    = M_j V_{j-1}`, :math:`\dot z_j = M_j \dot V_{j-1}` (None at ``j = 0``, where they
    vanish), :math:`V_j`; the last :math:`V, \dot V` (those the weights' orders reach)."""
    O = len(lam)
    l1 = lam[0]
    l2 = l1 * l1
    l3 = l2 * l1
    sig, alp, bet = _scalars(("sinc", "se3_c1", "se3_c2"), powers, l1)
    M = _polynomial(powers, 1.0, (-l1 * sig[0], -l1 * sig[1]), (l2 * alp[0], l2 * alp[1]))
    Jr = _polynomial(powers, l1, (-l2 * alp[0], -l2 * alp[1]), (l3 * bet[0], l3 * bet[1]))
    out: dict[str, list] = {"M": [(M[0][:, :, j], M[1][:, :, j]) for j in range(d.shape[0])],
                            "Jr": [(Jr[0][:, :, j], Jr[1][:, :, j]) for j in range(d.shape[0])],
                            "z": [], "zd": [], "V": []}
    V = Vd = d.new_zeros(d.shape[1:])
    for j, dj in enumerate(d):
        if O > 1:  # from V_0 = lam'_0 d_0, Vd_0 = lam''_0 d_0: z_0 = zd_0 = 0 (None)
            out["z"].append(_apply(out["M"][j], V) if j else None)
            V = out["z"][j] + lam[1][j] * dj if j else lam[1][j] * dj
            out["V"].append(V)
        if O > 2:
            out["zd"].append(_apply(out["M"][j], Vd) if j else None)
            Vd = out["zd"][j] + lam[2][j] * dj if j else lam[2][j] * dj
            if j:  # the bracket's product into its own array, added in place
                Vd += _bracket(V, dj).mul_(lam[1][j])
    out["last"] = [V, Vd]
    return out


def _algebra_cotangents(X: Tensor, V: Tensor, Vd: Tensor, g: Tensor, second: slice,
                        out: Tensor) -> Tensor:
    r"""Cotangent rows ``(6, O, k, S)`` of the pose's right step, of :math:`V` and of
    :math:`\dot V` (the orders there are) from those ``g (8, O, k, S)`` of :math:`X, \dot X,
    \ddot X`: :math:`\mathrm d X = X h(\xi)`, :math:`\mathrm d\dot X = X h(\xi) h(V) + X
    h(\mathrm dV)`, :math:`\mathrm d\ddot X = X h(\xi) (h(V)^2 + h(\dot V)) + X (h(\mathrm
    dV) h(V) + h(V) h(\mathrm dV) + h(\mathrm d\dot V))` (:math:`\dot X = X h(V)`,
    :math:`\ddot X = X (h(V)^2 + h(\dot V))`). With :math:`u_o = L(X)^T g_o` and
    :math:`P` the vector parts of both halves times 1/2 (the cotangent of :math:`h`): pose
    :math:`P(u_0 + R(h(V))^T u_1 + R(h(V)^2 + h(\dot V))^T u_2)`, :math:`V`:
    :math:`P(u_1 + (R + L)(h(V))^T u_2)`, :math:`\dot V`: :math:`P u_2`; the vector parts
    alone are formed, and :math:`P (R + L)(h)^T u = -\frac12 (u_{a0} \omega + u_{b0} v,\
    u_{b0} \omega)` for a pure :math:`h = h(\omega, v)` (the cross terms cancel). The
    second order's terms are taken for the rows ``second`` alone (the others' cotangents
    there are zero, :func:`vjp`), whose rows of :math:`\dot V` alone are set; into ``out``,
    returned."""
    O = g.shape[1]
    r, d = _halves(X)
    pw, pv = out[:3, 0], out[3:, 0]
    _conj_vec(pw, r, g[:4, 0], True)
    _conj_vec(pw, d, g[4:, 0], True, acc=True)
    _conj_vec(pv, r, g[4:, 0], True)
    if O > 1:
        u = _left_t(X, g[:, 1])
        out[:3, 1], out[3:, 1] = u[1:4], u[5:8]
        w, v = 0.5 * V[:3, None], 0.5 * V[3:, None]
        _conj_vec(pw, (None, w), u[:4], False, acc=True)
        _conj_vec(pw, (None, v), u[4:], False, acc=True)
        _conj_vec(pv, (None, w), u[4:], False, acc=True)
    if O > 2:
        u = _left_t(X, g[:, 2, second])
        out[:3, 2, second], out[3:, 2, second] = u[1:4], u[5:8]
        pw, pv = pw[:, second], pv[:, second]
        hr = (-(w * w).sum(0), 0.5 * Vd[:3, None])  # h(V)^2 + h(Vd)
        hd = (-2.0 * (w * v).sum(0), 0.5 * Vd[3:, None])
        _conj_vec(pw, hr, u[:4], False, acc=True)
        _conj_vec(pw, hd, u[4:], False, acc=True)
        _conj_vec(pv, hr, u[4:], False, acc=True)
        rw, rv = out[:3, 1, second], out[3:, 1, second]
        rw.addcmul_(u[0], V[:3, None], value=-1.0).addcmul_(u[4], V[3:, None], value=-1.0)
        rv.addcmul_(u[4], V[:3, None], value=-1.0)
    return out.mul_(0.5)


def _backward(fw: dict[str, list], d: Tensor, lam: list[Tensor], a: Tensor, second: slice,
              first: Tensor, cd: Tensor, spare: Tensor) -> None:
    r"""The recursions run backwards from the cotangent rows ``a (6, O, k, S)``
    (:func:`_algebra_cotangents`, updated in place; of :math:`\dot V` the rows ``second``
    alone are read): those of every :math:`d_j`, written to ``cd (p, 6, k, S)``, and of
    the first point's step (through the pose alone), written to ``first``; ``spare``, an
    array like ``a``, and ``a`` take the rows of the steps in turn (the rows two steps back
    are dead)."""
    O, p = a.shape[1], d.shape[0]
    for j in reversed(range(p)):
        dj, lj = d[j], [w[j] for w in lam]
        a2 = a[:, 2, second] if O > 2 else a
        if O > 2:
            _row_ad(a2, -lj[1] * dj, a[:, 1, second])
        # the pose's rows, plus the bracket's where V's reach them (a fresh array: then
        # updated in place), else as they are (only read)
        t = (_row_ad(a[:, 1], fw["z"][j], torch.empty_like(a[:, 0]), a[:, 0])
             if O > 1 and j else a[:, 0])
        if O > 2 and j:
            _row_ad(a2, fw["zd"][j], t[:, second])
        c = _rows(t, fw["Jr"][j], cd[j])
        if O > 1:
            c.addcmul_(a[:, 1], lj[1])
        if O > 2:
            _row_ad(a2, lj[1] * fw["V"][j], c[:, second].addcmul_(a2, lj[2]))
        # at the first step only the pose's rows go on (to the first point's step)
        if not j:
            _rows(a[:, 0], fw["M"][j], first)
            continue
        b, S = spare, a.shape[-1]
        _rows(a[:, :2].view(6, -1, S), fw["M"][j], b[:, :2].view(6, -1, S))
        if O > 2:
            _rows(a2, fw["M"][j], b[:, 2, second])
        spare, a = a, b


def _inverse_jacobians(powers: tuple[Tensor, ...], signs: tuple[int, ...],
                       ) -> list[tuple[Tensor, Tensor]]:
    r"""The dual matrices :math:`I \pm \frac12 \Phi + \gamma \Phi^2` (``+``:
    :math:`J_r^{-1}`, ``-``: :math:`J_l^{-1}`), one per sign, of the twists of ``powers``
    (:func:`_powers`)."""
    (c3,), half = _scalars(("se3_c3",), powers), torch.full_like(powers[4], 0.5)
    return [_polynomial(powers, 1.0, (s * half, 0.0 * half), c3) for s in signs]


def right_jacobian_inverse(d: Tensor) -> Tensor:
    r"""``(..., 6, 6)``: :math:`J_r^{-1}(d)`, the derivative of :math:`\mathrm{Log}(
    \mathrm{Exp}(d)\, \mathrm{Exp}(\delta))` at :math:`\delta = 0`, for twists ``d (...,
    6)`` :math:`(\omega, v)` (exact at :math:`\omega = 0`)."""
    ((A, B),) = _inverse_jacobians(_powers(d.reshape(-1, 6).T.contiguous()), (1,))
    J = d.new_zeros(A.shape[-1], 6, 6)
    J[:, :3, :3], J[:, 3:, 3:], J[:, 3:, :3] = (m.permute(2, 0, 1) for m in (A, A, B))
    return J.reshape(*d.shape, 6)


def span_parts(points: Tensor) -> Tensor:
    r"""``(80, p, U)`` per step ``j`` and distinct span: the twist :math:`d_j` (6 rows), its
    :func:`_powers` (38 rows: ``W, V, W2, WV`` flat, ``s0, s1``) and the dual matrices
    :math:`J_r^{-1}(d_j) = I + \frac12 \Phi + \gamma \Phi^2` and :math:`J_l^{-1}(d_j) =
    J_r^{-1}(d_j)\, \mathrm{Ad}_{\mathrm{Exp}(-d_j)} = I - \frac12 \Phi + \gamma \Phi^2`
    (36 rows: ``(2, 2, 3, 3)`` flat, matrix, real and dual part), from the span's control
    points ``(U, p + 1, 8)``: what is constant on a span, once per span and for all steps
    at once (:func:`_unpack`)."""
    rel = dq_mul(dualquat.conj(points[:, :-1]), points[:, 1:])
    d = dualquat.log(rel).permute(2, 1, 0).reshape(6, -1)  # (6, p U)
    pw = _powers(d)
    mats = [torch.stack(m) for m in _inverse_jacobians(pw, (1, -1))]
    return torch.cat((d, torch.stack(pw[:4]).flatten(0, -2), torch.stack(pw[4:]),
                      torch.stack(mats).flatten(0, -2))).view(80, *rel.shape[1::-1])


def _unpack(span: Tensor) -> tuple[Tensor, tuple[Tensor, ...], Tensor]:
    """:func:`span_parts`' rows (gathered per sample, ``(80, p, S)``): the twists ``(p, 6,
    S)``, the steps' :func:`_powers` (``(3, 3, p, S)`` and ``(p, S)``) and the matrices
    ``(p, 2, 2, 3, 3, S)`` (views)."""
    powers = (*span[6:42].unflatten(0, (4, 3, 3)), *span[42:44])
    return span[:6].transpose(0, 1), powers, span[44:].movedim(1, 0).unflatten(1, (2, 2, 3, 3))


def vjp(span: Tensor, inverse: Tensor, weights: list[Tensor], cot: Tensor, pose: Tensor,
        second: slice | None = None) -> Tensor:
    r"""Cotangents of the span's control-point steps from those of the span's derivatives.

    Args:
        span: ``(80, p, U)`` :func:`span_parts` of the spans' sign-aligned control points
            (:func:`torch_dq._curve.span_points`; the spans the samples read, or all of a
            curve's, once for several calls).
        inverse: ``(S,)`` int64: sample ``i`` is in span ``inverse[i]``.
        weights: ``O`` tensors ``(S, p)``: the cumulative weights at the samples' times and
            their time derivatives (:meth:`torch_dq._time.KnotDomain.bases`), ``O <= 3``.
        cot: ``(S, k, O, 8)`` cotangents of :math:`X, \dot X, \ddot X` (``k`` rows).
        pose: ``(S, 8)`` the curve :math:`X` at the samples.
        second: the rows whose cotangents of :math:`\ddot X` may be nonzero (None: all);
            the others' are zero (a group's lower-order term) and neither read nor carried
            through the recursions.

    Returns:
        ``(S, k, p + 1, 6)``: :math:`\sum_o \mathrm{cot}_o \cdot \partial X^{(o)} /
        \partial \delta_i` for the right steps :math:`c_i \mathrm{Exp}(\delta_i)`; a
        permuted view of a component-major array (contiguous from the compiled loop,
        ``torch_dq._kernels.lie_native``, where it applies).
    """
    p, (S, k) = span.shape[1], cot.shape[:2]
    if lie_native.applies(p, span, inverse, cot, pose, *weights):  # the same, compiled
        return lie_native.vjp(span, inverse, weights, cot, pose, second)
    span = span.view(80, -1)  # (80, p U): column j U + u of step j, span u
    at = torch.arange(0, span.shape[1], span.shape[1] // p, device=inverse.device)
    steps = cot.new_empty(p + 1, 6, k, S)
    rows = cot.reshape(S, -1).T.contiguous()  # (k O 8, S): a 2-d transpose is the fastest
    size = VJP_CHUNK if cot.device.type == "cpu" else max(S, 1)  # parts for the CPU cache
    # every part's gathered span parts, cotangent rows of the twists and of the recursions
    n = min(size, S)
    buffers = (span.new_empty(80 * p * n), cot.new_empty(p * 6 * k * n),
               cot.new_empty(2 * 6 * cot.shape[2] * k * n))
    for a in range(0, S, size):
        c = slice(a, a + size)
        _vjp_part(span, at, inverse[c], [w[c] for w in weights],
                  rows[:, c].view(k, cot.shape[2], 8, -1).permute(2, 1, 0, 3), pose[c],
                  steps[..., c], slice(None) if second is None else second, buffers)
    return steps.permute(3, 2, 0, 1)


#: Samples per part of :func:`vjp` on the CPU: its per-sample arrays stay in the cache (-10
#: to -25 % a call at 12,000 samples; :func:`derivatives` measured no better in parts).
#: Other devices take all samples in one part (no more launches).
VJP_CHUNK = 4096


def _vjp_part(span: Tensor, at: Tensor, inverse: Tensor, weights: list[Tensor], cot: Tensor,
              pose: Tensor, steps: Tensor, second: slice, buffers: tuple[Tensor, ...],
              ) -> None:
    r""":func:`vjp` on some samples, their cotangents component-major ``(8, O, k, S)`` (of
    :math:`\ddot X` the rows ``second``), into their ``steps (p + 1, 6, k, S)``: the span
    parts ``(80, p U)`` gathered (faster than ``index_select`` on the last dim) at the
    columns ``at + inverse`` (``at``: each step's first) into the front of ``buffers[0]``,
    the twists' cotangent rows into ``buffers[1]``, the recursions' into ``buffers[2]``
    (flat, shared by the parts of a call: no fresh mapping a part)."""
    p, idx = at.shape[0], (at[:, None] + inverse).view(1, -1)
    out = buffers[0][:80 * idx.shape[1]].view(80, -1)
    d, powers, fin = _unpack(torch.gather(span, 1, idx.expand(80, -1), out=out).view(80, p, -1))
    lam = [w.T.contiguous() for w in weights]
    fw = _forward(d, powers, lam)
    V, Vd = fw["last"]
    shape = (6, *cot.shape[1:])  # (6, O, k, S)
    two = buffers[2][:2 * cot[0].numel() * 6].view(2, *shape)
    rows = _algebra_cotangents(pose.T.contiguous(), V, Vd, cot, second, two[0])
    cd = buffers[1][:steps[0].numel() * p].view(p, *steps.shape[1:])
    _backward(fw, d, lam, rows, second, steps[0], cd, two[1])
    # d_j = Log(c_{j-1}^-1 c_j): J_r^-1 (delta_j - Ad_{Exp(-d_j)} delta_{j-1})
    for j, c in enumerate(cd):
        _rows(c, (fin[j, 1, 0], fin[j, 1, 1]), steps[j], acc=True, value=-1.0)
        _rows(c, (fin[j, 0, 0], fin[j, 0, 1]), steps[j + 1])


# ----------------------------------------------------------------------------- evaluation

#: How far from unit (:func:`torch_dq.dualquat.is_unit`'s measure) the control points of
#: :func:`derivatives` may be: its logarithms and exponentials read unit dual quaternions,
#: where the span tables multiply the points as they are (the two differ by about the
#: defect times the translation over the knot spacing squared in an acceleration).
UNIT_ATOL = 64 * torch.finfo(torch.float64).eps


def applies(ctrl: Tensor, weights: list[Tensor]) -> bool:
    """Whether :func:`derivatives` evaluates: float64 on the CPU, orders 0 to 2, nothing
    differentiated (no autograd graph is recorded: reverse mode goes through the span
    tables), eagerly, and unit control points to :data:`UNIT_ATOL` (one read of a flag;
    non-finite ones aside: they give NaN in their own spans either way, and the other
    elements of a batch keep this path's bits)."""
    grad = torch.is_grad_enabled() and any(x.requires_grad for x in (ctrl, *weights))
    return (ctrl.dtype == torch.float64 and ctrl.device.type == "cpu" and len(weights) <= 3
            and not grad and not torch.compiler.is_compiling()
            and bool((dualquat.is_unit(ctrl, UNIT_ATOL)
                      | ~torch.isfinite(ctrl).all(-1)).all()))


def _pair_twists(ctrl: Tensor, first: Tensor, p: int) -> Tensor:
    r"""``(6, p, N)``: the twists :math:`d_j = \mathrm{Log}(c_{f+j}^{-1} c_{f+j+1})` of each
    time's span (``first`` ``f``), from every neighbouring pair of ``ctrl (M, 8)`` once
    where the times read most of them, else per time."""
    steps = torch.arange(p + 1, device=first.device)
    if ctrl.shape[0] - 1 <= p * first.shape[0]:
        rel = dq_mul(dualquat.conj(ctrl[:-1]), ctrl[1:])
        idx = (first + steps[:-1, None]).flatten()
        twists = dualquat.log(rel).T.contiguous()
        return twists.gather(1, idx.expand(6, -1)).view(6, p, -1)
    pts = ctrl[first[:, None] + steps]
    rel = dq_mul(dualquat.conj(pts[:, :-1]), pts[:, 1:])
    return dualquat.log(rel).permute(2, 1, 0).contiguous()


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """Cross products of component-major ``(3, ...)`` vectors (broadcasting)."""
    out = a.new_empty(_shape(a, b))
    _cross_into(out, a, b)
    return out


#: The Hamilton product's terms per output component: ``(i, j, sign)`` of :math:`a_i b_j`.
_HAMILTON = (((0, 0, 1.0), (1, 1, -1.0), (2, 2, -1.0), (3, 3, -1.0)),
             ((0, 1, 1.0), (1, 0, 1.0), (2, 3, 1.0), (3, 2, -1.0)),
             ((0, 2, 1.0), (1, 3, -1.0), (2, 0, 1.0), (3, 1, 1.0)),
             ((0, 3, 1.0), (1, 2, 1.0), (2, 1, -1.0), (3, 0, 1.0)))


def _dq_rows(a: Tensor, b: Tensor, pure: bool = False) -> Tensor:
    r"""Dual-quaternion products :math:`(r_a r_b, r_a d_b + d_a r_b)` of component rows
    ``(8, N)``: :func:`torch_dq._taylor.dq_rows` as fused multiply-adds into one fresh
    array (no per-term temporaries, no stack); ``pure``: ``b``'s scalar parts are zero and
    their terms skipped (the same sums: a zero first term adds nothing)."""
    out = torch.empty_like(a)
    o, x, y = out.unbind(0), a.unbind(0), b.unbind(0)
    for half, pairs in ((o[:4], ((x[:4], y[:4]),)), (o[4:], ((x[:4], y[4:]),
                                                             (x[4:], y[:4])))):
        for c, terms in enumerate(_HAMILTON):
            first = True
            for u, w in pairs:
                for i, j, sign in terms:
                    if pure and j == 0:
                        continue
                    if first:
                        torch.mul(u[i], w[j], out=half[c])
                        if sign < 0:
                            half[c].neg_()
                        first = False
                    else:
                        half[c].addcmul_(u[i], w[j], value=sign)
    return out


def _exp_rows(xi: Tensor, x2: Tensor, c1: Tensor, c2: Tensor) -> Tensor:
    r""":math:`\mathrm{Exp}(\xi)` ``(8, ...)`` of twists ``xi (6, ...)`` as
    :func:`torch_dq.dualquat.exp`: :math:`r = (\cos\frac\theta2, \mathrm{sinc}\frac\theta2\,
    \frac\omega2)`, :math:`t = v + c_1 \omega \times v + c_2 \omega \times (\omega \times v)`,
    dual part :math:`\frac12 (0, t)\, r`; ``x2`` :math:`= \theta^2`, ``c1, c2`` ``se3_c1,
    se3_c2`` there."""
    w, v = xi[:3], xi[3:]
    out = xi.new_empty(8, *xi.shape[1:])
    out[0], sinc = evens(("cos", "sinc"), 0.25 * x2)
    torch.mul(w, 0.5 * sinc, out=out[1:4])
    wxv = _cross(w, v)
    t = (v + c1 * wxv).addcmul_(_cross(w, wxv), c2)
    out[4] = -0.5 * (t * out[1:4]).sum(0)
    _cross_into(out[5:], t, out[1:4])
    out[5:].addcmul_(t, out[0]).mul_(0.5)
    return out


def _adjoint(d: Tensor, c1: tuple[Tensor, Tensor], c2: tuple[Tensor, Tensor], y: Tensor,
             ) -> Tensor:
    r""":math:`M y = y + c_1 [d, y] + c_2 [d, [d, y]]` (:func:`_forward`'s :math:`M_j` without
    its matrices) for twists ``d (6, 1, N)``, ``y (6, n, N)`` and dual scalars ``c1, c2``
    (:math:`(a + \varepsilon b) y = (a y_\omega, a y_v + b y_\omega)`), into ``y`` (updated
    in place once its brackets are taken; returned)."""
    b = _bracket(d, y)
    for (a, e), z in ((c1, b), (c2, _bracket(d, b))):
        y.addcmul_(z, a)
        y[3:].addcmul_(z[:3], e)
    return y


def _pure_rows(xi: Tensor) -> Tensor:
    r""":math:`h(\xi) = (0, \omega/2, 0, v/2)` ``(8, N)`` of twists ``(6, N)``."""
    out = xi.new_zeros(8, xi.shape[1])
    torch.mul(xi[:3], 0.5, out=out[1:4])
    torch.mul(xi[3:], 0.5, out=out[5:])
    return out


def _rates(d: Tensor, weights: list[Tensor], sig: tuple[Tensor, Tensor],
           alp: tuple[Tensor, Tensor]) -> Tensor:
    r""":math:`V` and (order 2) :math:`\dot V`, ``(6, order, N)``, by the
    recursions of the module docstring with :math:`M_j y = y - \lambda \sigma [d_j, y] +
    \lambda^2 \alpha [d_j, [d_j, y]]` (:func:`_adjoint`; ``sig, alp`` at the dual squares
    :math:`\lambda^2 s`, ``(p, N)`` each); :math:`V_0 = \dot\lambda_0 d_0`, :math:`\dot
    V_0 = \ddot\lambda_0 d_0` (:math:`[V_0, d_0] = 0`)."""
    w, v = d[:3], d[3:]
    dual = 2.0 * weights[0] * weights[0] * (w * v).sum(0)
    c1 = (-weights[0] * sig[0], -weights[0] * sig[1] * dual)
    c2 = (weights[0] * weights[0] * alp[0], weights[0] * weights[0] * alp[1] * dual)
    lam = torch.stack(weights[1:])  # (order, p, N)
    R = d[:, None, 0] * lam[None, :, 0]
    for j in range(1, d.shape[1]):
        dj = d[:, j, None]
        R = _adjoint(dj, (c1[0][j], c1[1][j]), (c2[0][j], c2[1][j]), R)
        R.addcmul_(dj, lam[None, :, j])
        if len(weights) > 2:
            R[:, 1].addcmul_(_bracket(R[:, 0], d[:, j]), lam[0, j])
    return R


def derivatives(ctrl: Tensor, first: Tensor, weights: list[Tensor]) -> list[Tensor]:
    r"""The cumulative form and its time derivatives to order 2 by the recursions of the
    module docstring, without the span tables (:func:`applies`; the values of
    :func:`torch_dq._cumulative.derivatives` to rounding): :math:`X = c_f \prod_j
    \mathrm{Exp}(\lambda_j d_j)`, :math:`\dot X = X h(V)`, :math:`\ddot X = X (h(V)^2 +
    h(\dot V))`, every :math:`d_j` from one logarithm per neighbouring pair, the weights'
    functions of all steps at once.

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`.
        weights: ``order + 1 <= 3`` tensors ``(p, N)``: the cumulative basis and its time
            derivatives, float64.

    Returns:
        ``order + 1`` tensors ``(N, 8)``.
    """
    d = _pair_twists(ctrl, first, weights[0].shape[0])  # (6, p, N)
    if lie_native.applies(d.shape[1], ctrl, first, d, *weights):  # the same, compiled
        return lie_native.derivatives(ctrl, first, d, weights)
    x2 = weights[0] * weights[0] * (d[:3] * d[:3]).sum(0)
    sig, alp, bet = even_slopes(("sinc", "se3_c1", "se3_c2"), x2)
    E = _exp_rows(d * weights[0], x2, alp[0], bet[0])
    X = ctrl.index_select(0, first).T.contiguous()
    for j in range(E.shape[1]):
        X = _dq_rows(X, E[:, j])
    out = [X]
    if len(weights) > 1:
        R = _rates(d, weights, sig, alp)
        hV = _pure_rows(R[:, 0])
        out.append(_dq_rows(X, hV, pure=True))
        if len(weights) > 2:
            H = _pure_rows(R[:, 1])  # h(V)^2 + h(Vd): (-|w|^2, h_w; -2 w.v, h_v), w = V_w / 2
            H[0] = -(hV[1:4] * hV[1:4]).sum(0)
            H[4] = -2.0 * (hV[1:4] * hV[5:]).sum(0)
            out.append(_dq_rows(X, H))
    return [x.T.contiguous() for x in out]

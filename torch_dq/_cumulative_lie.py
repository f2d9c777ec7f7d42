r"""Vector-Jacobian products of the cumulative B-spline form in its Lie algebra (private).

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
The span's twists are taken once per distinct span; the rest is per sample, in a
component-major layout (below).

The readable reference is reverse mode through the span's evaluation
(:meth:`torch_dq.nn.Curve.evaluate_span`, ``fitting._linearize``); the tests compare both
with reverse mode through the public ``derivatives`` (``tests/test_span_jacobians.py``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import dualquat
from ._core import dq_mul
from ._cumulative import _conj_rows
from ._numerics import even_slope
from ._taylor import dq_rows, qmul_rows

__all__ = ["vjp"]

# Component-major layout: every per-sample quantity is ``(components..., S)`` (``S`` the
# samples), so each operation below is one elementwise pass over contiguous rows (batched
# 6 x 6 products of tiny matrices are several times slower). A dual 3 x 3 matrix
# ``A + eps B`` acting on twists ``(omega, v)`` as ``[[A, 0], [B, A]]`` is the pair
# ``(A, B)``, each ``(3, 3, S)``.


def _cross(a: Tensor, b: Tensor) -> Tensor:
    """Cross products of component-major ``(3, ...)`` vectors (broadcasting)."""
    return torch.stack((a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                        a[0] * b[1] - a[1] * b[0]))


def _hat(u: Tensor) -> Tensor:
    """``(3, 3, S)`` cross-product matrices of ``(3, S)``."""
    o = torch.zeros_like(u[0])
    return torch.stack((o, -u[2], u[1], u[2], o, -u[0], -u[1], u[0], o)).unflatten(0, (3, 3))


def _powers(d: Tensor) -> tuple[Tensor, ...]:
    r"""The parts of :math:`\Phi` and :math:`\Phi^2` of twists ``d (6, S)``: ``W, V,
    W2, WV (3, 3, S)`` with :math:`\Phi = W + \varepsilon V`, :math:`\Phi^2 = W_2 +
    \varepsilon\, WV` (:math:`W_2 = w w^T - |w|^2 I`, :math:`WV = w v^T + v w^T - 2 (w
    \cdot v) I`), and the dual square ``s0, s1 (S,)``."""
    w, v = d[:3], d[3:]
    eye = torch.eye(3, dtype=d.dtype, device=d.device)[..., None]
    s0, c = (w * w).sum(0), (w * v).sum(0)
    return (_hat(w), _hat(v), w[:, None] * w[None] - s0 * eye,
            w[:, None] * v[None] + v[:, None] * w[None] - 2.0 * c * eye, s0, 2.0 * c)


def _scalar(name: str, powers: tuple[Tensor, ...], scale: Tensor | float = 1.0,
            ) -> tuple[Tensor, Tensor]:
    """The even function ``name`` at the dual square of ``scale`` times the twists of
    ``powers``: real and dual parts."""
    f, slope = even_slope(name, scale * scale * powers[4])
    return f, slope * (scale * scale * powers[5])


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
    """The dual matrix ``m`` times twists ``x (6, S)``."""
    A, B = m
    w = (A * x[None, :3]).sum(1)
    return torch.cat((w, (B * x[None, :3]).sum(1) + (A * x[None, 3:]).sum(1)))


def _rows(a: Tensor, m: tuple[Tensor, Tensor]) -> Tensor:
    r"""Rows ``a (6, k, S)`` times the dual matrix ``m``: :math:`(a_\omega A + a_v B,\ a_v
    A)`, accumulated in place (broadcast products into fresh ``(3, 3, k, S)`` arrays cost
    several times more)."""
    A, B = m
    out = torch.empty_like(a)
    w, v = out[:3], out[3:]
    torch.mul(a[0, None], A[0, :, None], out=w)
    torch.mul(a[3, None], A[0, :, None], out=v)
    for i in range(3):
        if i:
            w.addcmul_(a[i, None], A[i, :, None])
            v.addcmul_(a[3 + i, None], A[i, :, None])
        w.addcmul_(a[3 + i, None], B[i, :, None])
    return out


def _bracket(a: Tensor, b: Tensor) -> Tensor:
    r""":math:`[a, b] = \mathrm{ad}_a b` of twists ``(6, ...)``."""
    return torch.cat((_cross(a[:3], b[:3]), _cross(a[:3], b[3:]) + _cross(a[3:], b[:3])))


def _row_ad(a: Tensor, z: Tensor) -> Tensor:
    r"""Rows ``a (6, k, S)`` times :math:`\mathrm{ad}_z` (``z (6, S)``):
    :math:`(a_\omega \times z_\omega + a_v \times z_v,\ a_v \times z_\omega)`."""
    z = z[:, None]
    return torch.cat((_cross(a[:3], z[:3]) + _cross(a[3:], z[3:]), _cross(a[3:], z[:3])))


def _left_t(x: Tensor, g: Tensor) -> Tensor:
    r""":math:`L(x)^T g` (``x (8, 1, S)``, rows ``g (8, k, S)``): the cotangent of ``y``
    through :math:`y \mapsto x y`, :math:`(r^* g_a + d^* g_b,\ r^* g_b)`."""
    c = _conj_rows(x)
    return torch.cat((qmul_rows(c[:4], g[:4]) + qmul_rows(c[4:], g[4:]), qmul_rows(c[:4], g[4:])))


def _right_t(x: Tensor, u: Tensor) -> Tensor:
    r""":math:`R(x)^T u`: the cotangent of ``y`` through :math:`y \mapsto y x`,
    :math:`(u_a r^* + u_b d^*,\ u_b r^*)`."""
    c = _conj_rows(x)
    return torch.cat((qmul_rows(u[:4], c[:4]) + qmul_rows(u[4:], c[4:]), qmul_rows(u[4:], c[:4])))


def _pure(xi: Tensor) -> Tensor:
    r""":math:`h(\xi) = (0, \omega/2, 0, v/2)` ``(8, ...)`` of twists ``(6, ...)``."""
    zero = torch.zeros_like(xi[:1])
    return torch.cat((zero, 0.5 * xi[:3], zero, 0.5 * xi[3:]))


def _forward(d: Tensor, powers: list[tuple[Tensor, ...]], lam: list[Tensor],
             ) -> dict[str, list]:
    r"""The recursions of the module docstring on the samples' span twists ``d (p, 6, S)``
    (their :func:`_powers`) and cumulative weights ``lam`` (``O`` tensors ``(p, S)``:
    :math:`\lambda` and its time derivatives): per step ``j`` :math:`M_j = I - \lambda
    \sigma \Phi + \lambda^2 \alpha \Phi^2`, :math:`\lambda_j J_r(\lambda_j d_j) = \lambda I
    - \lambda^2 \alpha \Phi + \lambda^3 \beta \Phi^2` (:math:`\Phi = \mathrm{ad}_{d_j}`, the
    coefficients at :math:`\lambda^2 s`), :math:`z_j = M_j V_{j-1}`, :math:`\dot z_j = M_j
    \dot V_{j-1}`, :math:`V_j`; the last :math:`V, \dot V` (those the weights' orders
    reach)."""
    O = len(lam)
    out: dict[str, list] = {"M": [], "Jr": [], "z": [], "zd": [], "V": []}
    V = Vd = d.new_zeros(d.shape[1:])
    for j, dj in enumerate(d):
        pw, l1 = powers[j], lam[0][j]
        l2 = l1 * l1
        sig, alp = _scalar("sinc", pw, l1), _scalar("se3_c1", pw, l1)
        bet = _scalar("se3_c2", pw, l1)
        out["M"].append(_polynomial(pw, 1.0, (-l1 * sig[0], -l1 * sig[1]),
                                    (l2 * alp[0], l2 * alp[1])))
        out["Jr"].append(_polynomial(pw, l1, (-l2 * alp[0], -l2 * alp[1]),
                                     (l2 * l1 * bet[0], l2 * l1 * bet[1])))
        if O > 1:
            out["z"].append(_apply(out["M"][j], V))
            V = out["z"][j] + lam[1][j] * dj
            out["V"].append(V)
        if O > 2:
            out["zd"].append(_apply(out["M"][j], Vd))
            Vd = out["zd"][j] + lam[2][j] * dj + lam[1][j] * _bracket(V, dj)
    out["last"] = [V, Vd]
    return out


def _algebra_cotangents(X: Tensor, V: Tensor, Vd: Tensor, g: Tensor) -> list[Tensor]:
    r"""Cotangent rows ``(6, k, S)`` of the pose's right step, of :math:`V` and of
    :math:`\dot V` (the orders there are) from those ``g (O, 8, k, S)`` of :math:`X, \dot X,
    \ddot X`: :math:`\mathrm d X = X h(\xi)`, :math:`\mathrm d\dot X = X h(\xi) h(V) + X
    h(\mathrm dV)`, :math:`\mathrm d\ddot X = X h(\xi) (h(V)^2 + h(\dot V)) + X (h(\mathrm
    dV) h(V) + h(V) h(\mathrm dV) + h(\mathrm d\dot V))` (:math:`\dot X = X h(V)`,
    :math:`\ddot X = X (h(V)^2 + h(\dot V))`)."""
    O = g.shape[0]
    u = [_left_t(X[:, None], g[o]) for o in range(O)]
    pose, rates = u[0], []
    if O > 1:
        hV = _pure(V)[:, None]
        pose = pose + _right_t(hV, u[1])
        rate = u[1]
        if O > 2:
            H2 = dq_rows(hV, hV) + _pure(Vd)[:, None]
            pose = pose + _right_t(H2, u[2])
            rate = rate + _right_t(hV, u[2]) + _left_t(hV, u[2])
        rates.append(rate)
        if O > 2:
            rates.append(u[2])
    return [0.5 * torch.cat((c[1:4], c[5:8])) for c in [pose, *rates]]


def _backward(fw: dict[str, list], d: Tensor, lam: list[Tensor], rows: list[Tensor],
              ) -> tuple[list[Tensor], Tensor]:
    r"""The recursions run backwards from the cotangent ``rows`` (:func:`_algebra_cotangents`):
    those ``(6, k, S)`` of every :math:`d_j` and of the first point's step (through the
    pose alone)."""
    O, p = len(rows), d.shape[0]
    a = list(rows)  # pose, V, Vd
    out: list[Tensor] = []  # from the last step back
    for j in reversed(range(p)):
        dj, lj = d[j], [w[j] for w in lam]
        if O > 2:
            a[1] = a[1] - lj[1] * _row_ad(a[2], dj)
        t = a[0]
        if O > 1:
            t = t + _row_ad(a[1], fw["z"][j])
        if O > 2:
            t = t + _row_ad(a[2], fw["zd"][j])
        c = _rows(t, fw["Jr"][j])
        if O > 1:
            c = c + lj[1] * a[1]
        if O > 2:
            c = c + lj[2] * a[2] + lj[1] * _row_ad(a[2], fw["V"][j])
        out.append(c)
        a = [_rows(r, fw["M"][j]) for r in a]
    return out[::-1], a[0]


def vjp(points: Tensor, inverse: Tensor, weights: list[Tensor], cot: Tensor, pose: Tensor,
        ) -> Tensor:
    r"""Cotangents of the span's control-point steps from those of the span's derivatives.

    Args:
        points: ``(U, p + 1, 8)`` the distinct spans' sign-aligned control points
            (:func:`torch_dq._curve.span_points`).
        inverse: ``(S,)`` int64: sample ``i`` is in span ``inverse[i]``.
        weights: ``O`` tensors ``(S, p)``: the cumulative weights at the samples' times and
            their time derivatives (:meth:`torch_dq._time.KnotDomain.bases`), ``O <= 3``.
        cot: ``(S, k, O, 8)`` cotangents of :math:`X, \dot X, \ddot X` (``k`` rows).
        pose: ``(S, 8)`` the curve :math:`X` at the samples.

    Returns:
        ``(S, k, p + 1, 6)``: :math:`\sum_o \mathrm{cot}_o \cdot \partial X^{(o)} /
        \partial \delta_i` for the right steps :math:`c_i \mathrm{Exp}(\delta_i)`.
    """
    p = points.shape[-2] - 1
    rel = dq_mul(dualquat.conj(points[:, :-1]), points[:, 1:])
    d = dualquat.log(rel).permute(1, 2, 0).index_select(-1, inverse)  # (p, 6, S)
    powers = [_powers(dj) for dj in d]
    lam = [w.T.contiguous() for w in weights]
    fw = _forward(d, powers, lam)
    V, Vd = fw["last"]
    rows = _algebra_cotangents(pose.T.contiguous(), V, Vd, cot.permute(2, 3, 1, 0).contiguous())
    cd, first = _backward(fw, d, lam, rows)
    steps = [first] + [torch.zeros_like(first)] * p
    for j, c in enumerate(cd):  # d_j = Log(c_{j-1}^-1 c_j): J_r^-1 (delta_j - Ad delta_{j-1})
        pw = powers[j]
        half = torch.full_like(pw[4], 0.5)
        sig, alp = _scalar("sinc", pw), _scalar("se3_c1", pw)
        y = _rows(c, _polynomial(pw, 1.0, (half, torch.zeros_like(half)),
                                 _scalar("se3_c3", pw)))
        steps[j + 1] = steps[j + 1] + y
        steps[j] = steps[j] - _rows(y, _polynomial(pw, 1.0, (-sig[0], -sig[1]), alp))
    return torch.stack(steps).permute(3, 2, 0, 1)

r"""Truncated Taylor arithmetic ("jets") and eq. 11's weights on jets (private; used by
:mod:`torch_dq.curves` for exact time derivatives; eq. 11 itself on jets, with the
weights' custom op: :mod:`torch_dq._kernels.jet_sclerp`).

A jet of order ``K`` is a list of ``K + 1`` tensors, the normalised Taylor coefficients
:math:`x_k = x^{(k)}(t) / k!` of a quantity along time. Sums are coefficient-wise; the other
operations are the classical recurrences of automatic Taylor expansion (Griewank & Walther,
*Evaluating Derivatives*, ch. 13): a product is a Cauchy product, and a quotient,
:math:`\sin`/:math:`\cos` and :math:`\arccos` follow from the first-order ODE each
satisfies. Every step is plain torch ops, so the jets are differentiable again (reverse
mode, twice) with respect to everything they were computed from.

:func:`torch_dq._kernels.jet_sclerp.sclerp` is the paper's eq. 11 on jets, in the notation of
:func:`torch_dq.dualquat.sclerp` (readable reference): with :math:`a = P + \epsilon Q`,
:math:`b = R + \epsilon S`, :math:`c = P \cdot R` and :math:`\delta = P\cdot S + R\cdot Q`,

.. math::
    q = F_0\, a + F_1\, b - \epsilon\,\delta\,(G_0 P + G_1 R),\qquad
    F(s) = \frac{\sin s\theta}{\sin\theta},\quad
    G(s) = \frac{s\cos s\theta - F\cos\theta}{\sin^2\theta},

``s = 1 - t`` for ``a`` and ``s = t`` for ``b``. Far from equal rotations the weights come
from the jets of :math:`\theta = \arccos c`, :math:`\sin\theta`, :math:`\sin s\theta` and
:math:`\cos s\theta`; near them (a removable singularity) from the power series
:math:`F = \sum_k a_k(s)\,y^k`, :math:`G = \partial_y F`, :math:`y = 1 - c`,
:math:`a_0 = s`, :math:`a_k = a_{k-1}(k^2 - s^2)/(k(2k + 1))`, with enough terms for the
derivatives in :math:`y` that the jets need
(:func:`torch_dq._numerics.screw_series_terms`).

This is the one implementation of eq. 11's weights (:func:`weight_parts`; :func:`series`,
:func:`closed`, :func:`angle`): a jet of order 0 is what the fused kernels evaluate, and
:mod:`torch_dq._kernels.weights` calls these functions with one coefficient, adding the
slopes their analytic backward needs.

:func:`dq_mul` is the Leibniz product of dual-quaternion jets (component rows), which the
cumulative B-spline form (:mod:`torch_dq._cumulative`) needs for its product of powers.
"""

from __future__ import annotations

import math
from typing import NamedTuple, cast

import torch
from torch import Tensor

from ._dispatch import fused_path
from ._numerics import piecewise, screw_series_terms, series_mask, threshold

__all__ = ["corr", "dq_mul", "dq_rows", "mul", "qmul_rows", "weight_parts", "weights_vjp"]

Jet = list[Tensor | None]  # None: a coefficient known to be zero (skipped, never computed)


def _dot(pairs, init: Tensor | None = None, value: float = 1.0) -> Tensor | None:
    r""":math:`init + value \sum a b` over the pairs whose factors are both nonzero."""
    acc = init
    for x, y in pairs:
        if x is None or y is None:
            continue
        if acc is None:
            acc = x * y if value == 1.0 else value * (x * y)
        else:
            acc = torch.addcmul(acc, x, y, value=value)
    return acc


def _lin(x: Tensor | None, a: float, y: Tensor | None = None, b: float = 1.0) -> Tensor | None:
    """``a x + b y`` for coefficients that may be zero (``None``)."""
    if x is None:
        return None if y is None else (y if b == 1.0 else b * y)
    x = x if a == 1.0 else a * x
    if y is None:
        return x
    return x + y if b == 1.0 else x - y if b == -1.0 else torch.add(x, y, alpha=b)


def mul(a: Jet, b: Jet) -> Jet:
    r"""Cauchy product :math:`(ab)_k = \sum_{i + j = k} a_i b_j` of two jets (coefficients
    broadcast)."""
    if len(a) == 1:  # order 0 (the fused kernels' weights): one product, no Python loop
        return [None if a[0] is None or b[0] is None else a[0] * b[0]]
    return [_dot((a[i], b[k - i]) for i in range(k + 1)) for k in range(len(a))]


def _over(x: Tensor | None, d: Tensor) -> Tensor | None:
    return None if x is None else x / d


def div(a: Jet, b: Jet) -> Jet:
    r""":math:`q = a / b`: :math:`q_k = (a_k - \sum_{i=1}^k b_i q_{k-i}) / b_0`."""
    b0 = cast(Tensor, b[0])
    if len(a) == 1:  # order 0: one quotient, no Python loop
        return [_over(a[0], b0)]
    q: Jet = []
    for k in range(len(a)):
        q.append(_over(_dot(((b[i], q[k - i]) for i in range(1, k + 1)), a[k], -1.0), b0))
    return q


def _sin_cos_next(phi: Jet, s: Jet, c: Jet) -> None:
    """Appends the coefficient ``k = len(s)`` of :func:`sin_cos` to ``s`` and ``c`` (``phi``
    known through ``k``)."""
    k = len(s)
    dphi = [_lin(phi[j], float(j)) for j in range(k + 1)]
    s.append(_lin(_dot((dphi[j], c[k - j]) for j in range(1, k + 1)), 1.0 / k))
    c.append(_lin(_dot((dphi[j], s[k - j]) for j in range(1, k + 1)), -1.0 / k))


def sin_cos(phi: Jet) -> tuple[Jet, Jet]:
    r""":math:`\sin\varphi, \cos\varphi` from :math:`(\sin\varphi)' = \varphi' \cos\varphi`,
    :math:`(\cos\varphi)' = -\varphi' \sin\varphi`:
    :math:`s_k = \frac1k \sum_{j=1}^k j \varphi_j c_{k-j}`,
    :math:`c_k = -\frac1k \sum_{j=1}^k j \varphi_j s_{k-j}`."""
    phi0 = cast(Tensor, phi[0])
    s: Jet = [torch.sin(phi0)]
    c: Jet = [torch.cos(phi0)]
    for _ in range(1, len(phi)):
        _sin_cos_next(phi, s, c)
    return s, c


def _rsub(value: float, jet: Jet) -> Jet:
    """The jet of ``value - x``."""
    return [value - cast(Tensor, jet[0])] + [_lin(x, -1.0) for x in jet[1:]]


def _plus(jet: Jet, value: float) -> Jet:
    """The jet of ``x + value``."""
    return [cast(Tensor, jet[0]) + value, *jet[1:]]


def _scale(jet: Jet, value: float | Tensor) -> Jet:
    """The jet of ``value x`` for a constant ``value``."""
    if isinstance(value, float) and value == -1.0:
        return [None if x is None else -x for x in jet]
    return [None if x is None else value * x for x in jet]


def _sub(a: Jet, b: Jet) -> Jet:
    """The jet of ``a - b``."""
    return [_lin(x, 1.0, y, -1.0) for x, y in zip(a, b, strict=True)]


def _stack(pairs, dim: int = 0) -> Jet:
    """Coefficient-wise ``torch.stack`` (a zero beside a nonzero coefficient is filled in)."""
    out: Jet = []
    for pair in pairs:
        known = [x for x in pair if x is not None]
        if not known:
            out.append(None)
        else:
            ref = torch.broadcast_tensors(*known)[0]
            out.append(torch.stack([ref.new_zeros(()).expand(ref.shape) if x is None
                                    else x.expand(ref.shape) for x in pair], dim))
    return out


# ----------------------------------------------------------------------------- eq. 11's weights

class AngleJets(NamedTuple):
    r"""Jets of :math:`\theta = \arccos c`, :math:`\sin\theta`, :math:`\cos\theta`."""

    theta: Jet
    sin: Jet
    cos: Jet


def angle(c: Jet, guard: Tensor) -> AngleJets:
    r""":class:`AngleJets` of the cosines ``c``, replaced by 0 (:math:`\theta = \pi/2`) where
    the float 0/1 ``guard`` holds (the closed forms' safe inputs). From
    :math:`c' = -\theta' \sin\theta`:
    :math:`\theta_k = -(k c_k + \sum_{j=1}^{k-1} j \theta_j S_{k-j}) / (k S_0)`, interleaved
    with :func:`sin_cos` of :math:`\theta` (order 0: ``acos``, then ``sin``, ``cos`` of the
    same angle, so that the weights are exact at the ends, ``F(1) = 1``, ``G(1) = 0``)."""
    c = _scale(c, 1.0 - guard)
    theta0 = torch.acos(cast(Tensor, c[0]))
    theta: Jet = [theta0]
    S: Jet = [torch.sin(theta0)]
    C: Jet = [torch.cos(theta0)]
    for k in range(1, len(c)):
        acc = _dot(((_lin(theta[j], float(j)), S[k - j]) for j in range(1, k)),
                   _lin(c[k], float(k)))
        theta.append(_over(_lin(acc, -1.0), k * cast(Tensor, S[0])))
        _sin_cos_next(theta, S, C)
    return AngleJets(theta, S, C)


class Series(NamedTuple):
    """Jets of the series branch (:func:`series`)."""

    F: Jet
    G: Jet  # [] without G
    a1: Jet  # s (1 - s^2) / 3
    u: list[Jet]  # u_k = (k^2 - s^2) y for k = 1 .. N - 1


def nested(u: list[Jet], j: int) -> Jet:
    r""":math:`\partial_y^j F / (j!\,a_j)` as a nested product (``u``: :attr:`Series.u`).

    The recurrence of :math:`a_k` gives :math:`\sum_{k \ge j} \frac{k!}{(k-j)!} a_k y^{k-j}
    = j!\,a_j \big(1 + \frac{u_{j+1}}{1 \cdot (2j + 3)} \big(1 + \frac{u_{j+2}}{2 (2j + 5)}
    (\dots)\big)\big)`: one fused multiply-add per term and coefficient.
    """
    last = len(u)  # u_k for k = 1 .. N - 1
    out: Jet = _plus(_scale(u[-1], 1.0 / ((last - j) * (2 * last + 1))), 1.0)
    one = cast(Tensor, out[0]).new_ones(())
    for k in range(last - 1, j, -1):
        scale = 1.0 / ((k - j) * (2 * k + 1))  # (k / (k - j)) / (k (2k + 1))
        uk = u[k - 1]
        head = torch.addcmul(one, uk[0], out[0], value=scale)  # type: ignore[arg-type]
        out = [head] if len(out) == 1 else [head, *(
            _dot(((uk[i], out[m - i]) for i in range(m + 1)), value=scale)
            for m in range(1, len(out)))]
    return out


def series(y: Jet, s: Jet, s2: Jet, terms: int, with_G: bool = True) -> Series:
    r"""The series branch: jets of ``F`` (and ``G``) from ``terms`` terms of
    :math:`F = \sum_k a_k y^k` (:mod:`torch_dq._kernels.weights`), ``y = 1 - c``,
    ``s2 = s^2``: :math:`F = s\,` :func:`nested` ``(u, 0)``,
    :math:`G = a_1\,` :func:`nested` ``(u, 1)``."""
    s2ny = mul(s2, _scale(y, -1.0))
    u = [[_lin(a, 1.0, b, float(k * k)) for a, b in zip(s2ny, y, strict=True)]
         for k in range(1, terms)]
    F = mul(s, nested(u, 0))
    if not with_G:
        return Series(F, [], [], u)
    a1 = [None if x is None else x / 3.0 for x in mul(s, _rsub(1.0, s2))]
    return Series(F, mul(a1, nested(u, 1)), a1, u)


class Closed(NamedTuple):
    """Jets of the closed forms (:func:`closed`) and the intermediates the kernels reuse."""

    F: Jet
    G: Jet  # [] without G
    st: Jet  # s theta
    sin_st: Jet
    cos_st: Jet  # [] without G
    sin2: Jet  # sin^2 theta ([] without G)


def closed(s: Jet, ang: AngleJets, with_G: bool = True) -> Closed:
    r"""The closed forms :math:`F = \sin s\theta / \sin\theta`,
    :math:`G = (s \cos s\theta - F \cos\theta) / \sin^2\theta` on the guarded angles
    ``ang`` (without ``with_G``: ``F`` alone, order 0 only)."""
    st = mul(s, ang.theta)
    if not with_G:
        sin_st: Jet = [torch.sin(cast(Tensor, st[0]))]
        return Closed(div(sin_st, ang.sin), [], st, sin_st, [], [])
    sin_st, cos_st = sin_cos(st)
    F = div(sin_st, ang.sin)
    sin2 = mul(ang.sin, ang.sin)
    G = div(_sub(mul(s, cos_st), mul(F, ang.cos)), sin2)
    return Closed(F, G, st, sin_st, cos_st, sin2)


def weight_parts(c: Jet, s: Jet, with_H: bool) -> tuple[Jet, Jet, Jet]:
    r"""Jets of the weights ``F, G`` of eq. 11 (module docstring) at ``cos(theta) = c``
    ``(...)`` for ``s (2, ...)`` (rows ``1 - t`` and ``t``), ``c >= 0``: the series where
    ``y max(1, s^2)`` is below the switch point of their order, the closed forms elsewhere
    (:func:`torch_dq._numerics.piecewise`; on guarded inputs: pairs in the series in both
    rows see ``c = 0``), in plain ops; and, ``with_H``, the jets of :math:`H = \partial_y G`
    (``[]`` without): the series' :math:`2 a_2\,` :func:`nested` ``(u, 2)``, the closed
    form :math:`((1 - s^2) F - 3 G \cos\theta) / \sin^2\theta`
    (:mod:`torch_dq._kernels.weights`)."""
    order = len(c) - 1
    c0, s0 = cast(Tensor, c[0]), cast(Tensor, s[0])
    y, s2 = _rsub(1.0, c), mul(s, s)
    small = series_mask(cast(Tensor, y[0]), cast(Tensor, s2[0]),
                        threshold("screw_series", c0.dtype, order))
    host = (small.device.type == "cpu" and not torch.compiler.is_compiling()
            and fused_path(c0, s0))

    def series_parts(pick) -> list[Tensor | None]:
        y_, s_, s2_ = ([None if x is None else pick(x) for x in jet] for jet in (y, s, s2))
        out = series(y_, s_, s2_, screw_series_terms(order))
        H = mul(mul(_scale(out.a1, 0.2), _rsub(4.0, s2_)), nested(out.u, 2)) if with_H else []
        return [*out.F, *out.G, *H]

    def closed_parts() -> list[Tensor | None]:
        # Guard the pairs whose rows both take the series: the others have y >= switch /
        # max(s^2), so their closed forms are finite (one angle per pair, not per row).
        ang = angle(c, small[0] * small[1])
        out = closed(s, ang)
        H = (div(_sub(mul(_rsub(1.0, s2), out.F), _scale(mul(out.G, ang.cos), 3.0)), out.sin2)
             if with_H else [])
        return [*out.F, *out.G, *H]

    parts = piecewise(small, host, series_parts, closed_parts)
    n = order + 1
    return parts[:n], parts[n:2 * n], parts[2 * n:]


def corr(terms, i: int, value: float = 1.0) -> Tensor | None:
    r"""The adjoint of Cauchy products :math:`z = x * y` (:func:`mul`), coefficient ``i``:
    ``value`` :math:`\sum_{(\bar z, y)} \sum_{k \ge i} \bar z_k\, y_{k - i}` over the
    pairs ``(z_bar, y)`` of jets (``None``: zero)."""
    return _dot(((z[k], y[k - i]) for z, y in terms for k in range(i, len(z))), value=value)


def weights_vjp(Fb: Jet, Gb: Jet, G: Jet, H: Jet, need: list[bool]) -> Jet:
    r"""The cotangents of the jets of :math:`y = 1 - c` from those of :func:`weight_parts`'
    ``F, G`` (:class:`torch_dq._kernels.jet_sclerp._WeightJets`):
    :math:`\bar y_i = \sum_{k \ge i} \bar F_k G_{k - i}
    + \bar G_k H_{k - i}`, per row of ``s`` (``G, H``: the forward's jets), for the
    coefficients ``i`` where ``need`` holds (``None`` elsewhere)."""
    return [corr([(Fb, G), (Gb, H)], i) if wanted else None for i, wanted in enumerate(need)]


def derivatives(jet: Jet) -> list[Tensor]:
    """The derivatives ``x^(k) = k! x_k`` of a jet (zeros where a coefficient is zero)."""
    x0 = cast(Tensor, jet[0])
    return [torch.zeros_like(x0) if x is None else math.factorial(k) * x
            for k, x in enumerate(jet)]


def _qmul(a, b) -> list[Tensor]:
    """Hamilton product of quaternions given as 4 component tensors each (``w, x, y, z``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw]


def qmul_rows(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of quaternions as component rows ``(4, ...)`` (``w, x, y, z``)."""
    return torch.stack(_qmul(a.unbind(0), b.unbind(0)))


def dq_rows(a: Tensor, b: Tensor) -> Tensor:
    r"""Dual-quaternion product :math:`(r_a r_b, r_a d_b + d_a r_b)` of component rows
    ``(8, ...)`` (broadcast). The rows are read by one ``unbind`` each (reverse mode: one
    node stacking the cotangents, not a zero-filled full-size cotangent per slice)."""
    A, B = a.unbind(0), b.unbind(0)
    dual = [x + y for x, y in zip(_qmul(A[:4], B[4:]), _qmul(A[4:], B[:4]), strict=True)]
    return torch.stack(_qmul(A[:4], B[:4]) + dual)


def dq_mul(a: Jet, b: Jet) -> Jet:
    r"""Leibniz (Cauchy) product of two dual-quaternion jets of component rows ``(8, ...)``:
    :math:`(ab)_k = \sum_{i + j = k} a_i b_j` with the dual-quaternion product (not
    commutative: ``a`` on the left). All nonzero pairs ``(a_i, b_j)`` go through one
    product of stacked rows (a few large ops instead of many small ones)."""
    pairs = [(i, k - i) for k in range(len(a)) for i in range(k + 1)
             if a[i] is not None and b[k - i] is not None]
    if not pairs:
        return [None] * len(a)
    shape = torch.broadcast_shapes(*(x.shape for x in (*a, *b) if x is not None))
    prod = dq_rows(torch.stack([cast(Tensor, a[i]).expand(shape) for i, _ in pairs], 1),
                   torch.stack([cast(Tensor, b[j]).expand(shape) for _, j in pairs], 1))
    parts = prod.unbind(1)  # one node in reverse mode (not a full-size cotangent per pick)
    out: Jet = []
    for k in range(len(a)):
        at = [parts[m] for m, (i, j) in enumerate(pairs) if i + j == k]
        out.append(None if not at else sum(at[1:], at[0]))
    return out

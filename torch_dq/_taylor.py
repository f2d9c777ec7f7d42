r"""Truncated Taylor arithmetic ("jets") and eq. 11 on jets (private; used by
:mod:`torch_dq.curves` for exact time derivatives).

A jet of order ``K`` is a list of ``K + 1`` tensors, the normalised Taylor coefficients
:math:`x_k = x^{(k)}(t) / k!` of a quantity along time. Sums are coefficient-wise; the other
operations are the classical recurrences of automatic Taylor expansion (Griewank & Walther,
*Evaluating Derivatives*, ch. 13): a product is a Cauchy product, and a quotient, a square
root, :math:`\sin`/:math:`\cos` and :math:`\arccos` follow from the first-order ODE each
satisfies. Every step is plain torch ops, so the jets are differentiable again (reverse
mode, twice) with respect to everything they were computed from.

:func:`sclerp` is the paper's eq. 11 on jets, in the notation of
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
derivatives in :math:`y` that the jets need (:func:`_series`).

:func:`dq_mul` is the Leibniz product of dual-quaternion jets (component rows), which the
cumulative B-spline form (:mod:`torch_dq._cumulative`) needs for its product of powers.
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor

from ._kernels import fused_path

__all__ = ["dq_mul", "dq_rows", "mul", "qmul_rows", "sclerp"]

def _series(order: int, dtype: torch.dtype) -> tuple[int, float]:
    r"""Number of series terms and switch point in :math:`y = 1 - \cos\theta` for jets of
    order ``K``.

    Jets of ``G`` of order ``K`` need :math:`j = K + 1` derivatives of ``F`` in ``y``. With
    ``N`` terms (:math:`a_k \approx s (y/2)^k`) the series loses about
    :math:`N^j (y/2)^{N-j}` in them, the closed forms :math:`\epsilon / y^j`
    (:math:`\sin^2\theta \approx 2y` divides once per derivative): balanced at
    :math:`y^N = \epsilon\, 2^N / N^j`. ``N = 6 + 2K`` puts the switch at ``y`` 0.007 to
    0.04 in float64 (0.08 to 0.2 in float32), with relative errors from ``3e-14`` (values)
    to ``1e-10`` (third derivatives) in float64.
    """
    terms = 6 + 2 * order
    eps = torch.finfo(dtype).eps
    return terms, float((eps * 2.0**terms / terms ** (order + 2)) ** (1.0 / terms))


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
    return x if y is None else (x + y if b == 1.0 else torch.add(x, y, alpha=b))


def mul(a: Jet, b: Jet) -> Jet:
    r"""Cauchy product :math:`(ab)_k = \sum_{i + j = k} a_i b_j` of two jets (coefficients
    broadcast)."""
    return [_dot((a[i], b[k - i]) for i in range(k + 1)) for k in range(len(a))]


def _over(x: Tensor | None, d: Tensor) -> Tensor | None:
    return None if x is None else x / d


def div(a: Jet, b: Jet) -> Jet:
    r""":math:`q = a / b`: :math:`q_k = (a_k - \sum_{i=1}^k b_i q_{k-i}) / b_0`."""
    b0 = cast(Tensor, b[0])
    q: Jet = []
    for k in range(len(a)):
        q.append(_over(_dot(((b[i], q[k - i]) for i in range(1, k + 1)), a[k], -1.0), b0))
    return q


def sqrt(a: Jet) -> Jet:
    r""":math:`r = \sqrt a`: :math:`r_k = (a_k - \sum_{i=1}^{k-1} r_i r_{k-i}) / (2 r_0)`."""
    r0 = torch.sqrt(cast(Tensor, a[0]))
    r: Jet = [r0]
    for k in range(1, len(a)):
        r.append(_over(_dot(((r[i], r[k - i]) for i in range(1, k)), a[k], -1.0), 2.0 * r0))
    return r


def sin_cos(phi: Jet) -> tuple[Jet, Jet]:
    r""":math:`\sin\varphi, \cos\varphi` from :math:`(\sin\varphi)' = \varphi' \cos\varphi`,
    :math:`(\cos\varphi)' = -\varphi' \sin\varphi`:
    :math:`s_k = \frac1k \sum_{j=1}^k j \varphi_j c_{k-j}`,
    :math:`c_k = -\frac1k \sum_{j=1}^k j \varphi_j s_{k-j}`."""
    phi0 = cast(Tensor, phi[0])
    s: Jet = [torch.sin(phi0)]
    c: Jet = [torch.cos(phi0)]
    for k in range(1, len(phi)):
        dphi = [_lin(phi[j], float(j)) for j in range(k + 1)]
        s.append(_lin(_dot((dphi[j], c[k - j]) for j in range(1, k + 1)), 1.0 / k))
        c.append(_lin(_dot((dphi[j], s[k - j]) for j in range(1, k + 1)), -1.0 / k))
    return s, c


def acos(c: Jet, sin_theta: Jet) -> Jet:
    r""":math:`\theta = \arccos c` given the jet of :math:`\sin\theta > 0`, from
    :math:`c' = -\theta' \sin\theta`:
    :math:`\theta_k = -(k c_k + \sum_{j=1}^{k-1} j \theta_j S_{k-j}) / (k S_0)`."""
    S0 = cast(Tensor, sin_theta[0])
    theta: Jet = [torch.atan2(S0, cast(Tensor, c[0]))]
    for k in range(1, len(c)):
        acc = _dot(((_lin(theta[j], float(j)), sin_theta[k - j]) for j in range(1, k)),
                   _lin(c[k], float(k)))
        theta.append(_over(_lin(acc, -1.0), k * S0))
    return theta


def _rsub(value: float, jet: Jet) -> Jet:
    """The jet of ``value - x``."""
    return [value - cast(Tensor, jet[0])] + [_lin(x, -1.0) for x in jet[1:]]


def _plus(jet: Jet, value: float) -> Jet:
    """The jet of ``x + value``."""
    return [cast(Tensor, jet[0]) + value, *jet[1:]]


def _scale(jet: Jet, value: float | Tensor) -> Jet:
    """The jet of ``value x`` for a constant ``value``."""
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


def _select(mask: Tensor, x: Jet, y: Jet) -> Jet:
    """``where(mask, x, y)`` coefficient-wise for a float 0/1 ``mask`` and finite ``x, y``:
    exact (``x * 1 + y * 0``) and several times faster than ``torch.where`` on CPU."""
    keep = 1.0 - mask
    return [_dot(((a, mask),), _dot(((b, keep),))) for a, b in zip(x, y, strict=True)]


def _series_weights(y: Jet, s: Jet, terms: int) -> tuple[Jet, Jet]:
    r"""Jets of ``F, G`` from ``terms`` terms of their power series in :math:`y = 1 - c`.

    Nested: with :math:`u_k = (k^2 - s^2) y` the recurrence of :math:`a_k` gives
    :math:`F = s (1 + u_1 / (1 \cdot 3) (1 + u_2 / (2 \cdot 5) (\dots)))` and
    :math:`G = \partial_y F = a_1 (1 + u_2 / (1 \cdot 5) (1 + u_3 / (2 \cdot 7) (\dots)))`,
    :math:`a_1 = s (1 - s^2) / 3`: one jet product per term.
    """
    s2 = mul(s, s)
    s2y = mul(s2, y)
    u = {k: [_lin(a, float(k * k), b, -1.0) for a, b in zip(y, s2y, strict=True)]
         for k in range(1, terms)}
    nested = []
    for j in (0, 1):
        out: Jet | None = None
        for k in range(terms - 1, j, -1):
            term = u[k] if out is None else mul(u[k], out)
            out = _plus(_scale(term, 1.0 / ((k - j) * (2 * k + 1))), 1.0)
        assert out is not None  # terms >= 6: the loop ran
        nested.append(out)
    return mul(s, nested[0]), mul(_scale(mul(s, _rsub(1.0, s2)), 1.0 / 3.0), nested[1])


def _put(x: Jet, at: tuple[Tensor, ...], values: Jet) -> Jet:
    """``x`` with ``values`` put at the indices ``at`` (out of place), coefficient-wise."""
    out: Jet = []
    for e, v in zip(x, values, strict=True):
        if e is None and v is None:
            out.append(None)
        else:
            full = torch.zeros_like(cast(Tensor, v)) if e is None else e
            out.append(torch.index_put(full, at, torch.zeros_like(cast(Tensor, e))
                                       if v is None else v))
    return out


def _weights(c: Jet, s: Jet) -> tuple[Jet, Jet]:
    """Jets of the weights ``F, G`` of eq. 11 (module docstring) at ``cos(theta) = c``
    ``(...)`` for ``s (2, ...)`` (rows ``1 - t`` and ``t``), ``c >= 0``.

    The series branch runs where ``y max(1, s^2)`` is below the switch point. In eager mode
    on CPU (one host read of a count) it is skipped when no element needs it and evaluated
    on those elements alone when they are few; elsewhere (compiled, under ``torch.func``
    transforms or forward AD, on other devices) on every element, selected arithmetically.
    """
    y = _rsub(1.0, c)
    c0, s0, y0 = cast(Tensor, c[0]), cast(Tensor, s[0]), cast(Tensor, y[0])
    terms, threshold = _series(len(c) - 1, c0.dtype)
    # Non-finite cosines take the closed forms (NaN there): a bad element must not change
    # which branches the others are computed with (their values and gradients stay bitwise).
    small = ((y0 * torch.clamp(s0 * s0, min=1.0) < threshold) & y0.isfinite()).to(c0.dtype)
    host = (small.device.type == "cpu" and not torch.compiler.is_compiling()
            and fused_path(c0, s0))
    n_small = int(small.count_nonzero()) if host else -1

    # Closed forms on safe inputs: the series elements see c = 0 (theta = pi / 2). Scaled
    # even when no element is small, so that the backward sums the gradients of ``c`` in
    # one order whatever the count (a NaN element must not change the others' bits).
    c_safe = _scale(c, 1.0 - small)
    y_safe = _rsub(1.0, c_safe)
    sin_t = sqrt(mul(y_safe, _rsub(2.0, y_safe)))  # sin^2 = (1 - c)(1 + c)
    theta = acos(c_safe, sin_t)
    sin_st, cos_st = sin_cos(mul(s, theta))
    F = div(sin_st, sin_t)
    G = div(_sub(mul(s, cos_st), mul(F, c_safe)),
            mul(sin_t, sin_t))
    if n_small == 0:
        return F, G
    if 0 < n_small < small.numel() // 4:
        # A few series elements: the series on those alone, put into the closed forms.
        at = (small > 0).nonzero(as_tuple=True)
        F_series, G_series = _series_weights(
            [None if x is None else x.expand(small.shape)[at] for x in y],
            [None if x is None else x.expand(small.shape)[at] for x in s], terms)
        return _put(F, at, F_series), _put(G, at, G_series)
    F_series, G_series = _series_weights(y, s, terms)
    return _select(small, F_series, F), _select(small, G_series, G)


def sclerp(A: Jet, B: Jet, alpha: Jet) -> Jet:
    r"""Eq. 11 (shortest path) on jets of component rows: ``A, B (8, ...)``, ``alpha (...)``
    per coefficient (module docstring). The sign choice is the one of the current value
    (constant nearby). Components first: every product runs over contiguous rows and every
    dot product is a sum over the leading dim (fast on CPU, unlike a trailing dim of 4 or 8).
    """
    A0, B0 = cast(Tensor, A[0]), cast(Tensor, B[0])
    flip = ((A0[:4] * B0[:4]).sum(0) < 0).to(B0.dtype)
    B = _scale(B, 1.0 - 2.0 * flip)  # b's representative nearest to a
    # c = P.R and delta = P.S + Q.R in one product: a against b and against b's halves swapped
    dots = mul(A, [None if b is None else torch.stack((b, torch.cat((b[4:], b[:4]))))
                   for b in B])
    c = [None if d is None else d[0, :4].sum(0) for d in dots]
    delta = [None if d is None else d[1].sum(0) for d in dots]
    # s = 1 - t for a, t for b
    s = _stack(zip(_rsub(1.0, alpha), alpha, strict=True))
    F, G = ([None if w is None else w[:, None] for w in jet] for jet in _weights(c, s))
    X = _stack(zip(A, B, strict=True))
    q = [None if x is None else x.sum(0) for x in mul(F, X)]  # F_0 a + F_1 b
    GP = mul(G, [None if x is None else x[:, :4] for x in X])
    correction = mul(delta, [None if x is None else x.sum(0) for x in GP])
    return [None if x is None else torch.cat((x[:4], cast(Tensor, _lin(x[4:], 1.0, corr, -1.0))))
            for x, corr in zip(q, correction, strict=True)]


def derivatives(jet: Jet) -> list[Tensor]:
    """The derivatives ``x^(k) = k! x_k`` of a jet (zeros where a coefficient is zero)."""
    x0 = cast(Tensor, jet[0])
    return [torch.zeros_like(x0) if x is None else math.factorial(k) * x
            for k, x in enumerate(jet)]


def qmul_rows(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product of quaternions as component rows ``(4, ...)`` (``w, x, y, z``)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return torch.stack((aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw))


def dq_rows(a: Tensor, b: Tensor) -> Tensor:
    r"""Dual-quaternion product :math:`(r_a r_b, r_a d_b + d_a r_b)` of component rows
    ``(8, ...)`` (broadcast)."""
    return torch.cat((qmul_rows(a[:4], b[:4]),
                      qmul_rows(a[:4], b[4:]) + qmul_rows(a[4:], b[:4])))


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
    out: Jet = []
    for k in range(len(a)):
        at = [m for m, (i, j) in enumerate(pairs) if i + j == k]
        out.append(None if not at else prod[:, at[0]] if len(at) == 1
                   else prod[:, at[0]:at[-1] + 1].sum(1))
    return out

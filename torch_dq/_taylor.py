r"""Truncated Taylor arithmetic ("jets") and eq. 11 on jets (private; used by
:mod:`torch_dq.curves` for exact time derivatives).

A jet of order ``K`` is a tensor ``(K + 1, ...)`` of normalised Taylor coefficients
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
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import Tensor

__all__ = ["mul", "sclerp"]

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


def mul(a: Tensor, b: Tensor) -> Tensor:
    r"""Cauchy product :math:`(ab)_k = \sum_{i + j = k} a_i b_j` of two jets (batch dims
    after the first broadcast)."""
    # ``sum`` of tensors is a tensor (typeshed types it ``Tensor | Literal[0]``).
    return torch.stack([cast(Tensor, sum(a[i] * b[k - i] for i in range(k + 1)))
                        for k in range(a.shape[0])])


def div(a: Tensor, b: Tensor) -> Tensor:
    r""":math:`q = a / b`: :math:`q_k = (a_k - \sum_{i=1}^k b_i q_{k-i}) / b_0`."""
    q: list[Tensor] = []
    for k in range(a.shape[0]):
        acc = a[k]
        for i in range(1, k + 1):
            acc = acc - b[i] * q[k - i]
        q.append(acc / b[0])
    return torch.stack(q)


def sqrt(a: Tensor) -> Tensor:
    r""":math:`r = \sqrt a`: :math:`r_k = (a_k - \sum_{i=1}^{k-1} r_i r_{k-i}) / (2 r_0)`."""
    r = [torch.sqrt(a[0])]
    for k in range(1, a.shape[0]):
        acc = a[k]
        for i in range(1, k):
            acc = acc - r[i] * r[k - i]
        r.append(acc / (2.0 * r[0]))
    return torch.stack(r)


def sin_cos(phi: Tensor) -> tuple[Tensor, Tensor]:
    r""":math:`\sin\varphi, \cos\varphi` from :math:`(\sin\varphi)' = \varphi' \cos\varphi`,
    :math:`(\cos\varphi)' = -\varphi' \sin\varphi`:
    :math:`s_k = \frac1k \sum_{j=1}^k j \varphi_j c_{k-j}`,
    :math:`c_k = -\frac1k \sum_{j=1}^k j \varphi_j s_{k-j}`."""
    s, c = [torch.sin(phi[0])], [torch.cos(phi[0])]
    for k in range(1, phi.shape[0]):
        s.append(cast(Tensor, sum(j * phi[j] * c[k - j] for j in range(1, k + 1))) / k)
        c.append(-cast(Tensor, sum(j * phi[j] * s[k - j] for j in range(1, k + 1))) / k)
    return torch.stack(s), torch.stack(c)


def acos(c: Tensor, sin_theta: Tensor) -> Tensor:
    r""":math:`\theta = \arccos c` given the jet of :math:`\sin\theta > 0`, from
    :math:`c' = -\theta' \sin\theta`:
    :math:`\theta_k = -(k c_k + \sum_{j=1}^{k-1} j \theta_j S_{k-j}) / (k S_0)`."""
    theta = [torch.atan2(sin_theta[0], c[0])]
    for k in range(1, c.shape[0]):
        acc = k * c[k]
        for j in range(1, k):
            acc = acc + j * theta[j] * sin_theta[k - j]
        theta.append(-acc / (k * sin_theta[0]))
    return torch.stack(theta)


def _rsub(value: float, jet: Tensor) -> Tensor:
    """The jet of ``value - x``."""
    return torch.cat((value - jet[:1], -jet[1:]))


def _plus(jet: Tensor, value: float) -> Tensor:
    """The jet of ``x + value``."""
    return torch.cat((jet[:1] + value, jet[1:]))


def _weights(c: Tensor, s: Tensor) -> tuple[Tensor, Tensor]:
    """Jets of the weights ``F, G`` of eq. 11 (module docstring) at ``cos(theta) = c``
    ``(K + 1, ...)`` for ``s (K + 1, 2, ...)`` (rows ``1 - t`` and ``t``), ``c >= 0``."""
    c = c[:, None]
    y = _rsub(1.0, c)
    terms, threshold = _series(c.shape[0] - 1, c.dtype)
    small = y[0] * torch.clamp(s[0] * s[0], min=1.0) < threshold

    # Series branch, nested: with u_k = (k^2 - s^2) y the recurrence of a_k gives
    # F = s (1 + u_1 / (1 3) (1 + u_2 / (2 5) (...))) and G = dF/dy = a_1 (1 + u_2 / (1 5)
    # (1 + u_3 / (2 7) (...))), a_1 = s (1 - s^2) / 3: one jet product per term.
    s2 = mul(s, s)
    s2y = mul(s2, y)
    u = {k: k * k * y - s2y for k in range(1, terms)}
    nested = []
    for j in (0, 1):
        out: Tensor | None = None
        for k in range(terms - 1, j, -1):
            term = u[k] if out is None else mul(u[k], out)
            out = _plus(term / ((k - j) * (2 * k + 1)), 1.0)
        assert out is not None  # terms >= 6: the loop ran
        nested.append(out)
    F_series = mul(s, nested[0])
    G_series = mul(mul(s, _rsub(1.0, s2)) / 3.0, nested[1])

    # Closed forms on safe inputs: the series elements see c = 0 (theta = pi / 2).
    c_safe = torch.where(small, torch.zeros_like(c), c)
    y_safe = _rsub(1.0, c_safe)
    sin_t = sqrt(mul(y_safe, _rsub(2.0, y_safe)))  # sin^2 = (1 - c)(1 + c)
    theta = acos(c_safe, sin_t)
    sin_st, cos_st = sin_cos(mul(s, theta))
    F = div(sin_st, sin_t)
    G = div(mul(s, cos_st) - mul(F, c_safe), mul(sin_t, sin_t))
    return torch.where(small, F_series, F), torch.where(small, G_series, G)


def sclerp(A: Tensor, B: Tensor, alpha: Tensor) -> Tensor:
    r"""Eq. 11 (shortest path) on jets: ``A, B (K + 1, ..., 8)``, ``alpha (K + 1, ...)``
    (module docstring). The sign choice is the one of the current value (constant nearby).
    """
    sigma = torch.where((A[0, ..., :4] * B[0, ..., :4]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    B = sigma.to(B.dtype) * B  # b's representative nearest to a
    # c = P.R and delta = P.S + Q.R in one product: a against b and against b's halves swapped
    dots = mul(A[:, None], torch.stack((B, torch.cat((B[..., 4:], B[..., :4]), -1)), 1))
    c, delta = dots[:, 0, ..., :4].sum(-1), dots[:, 1].sum(-1)
    s = torch.stack((_rsub(1.0, alpha), alpha), 1)  # s = 1 - t for a, t for b
    F, G = (w[..., None] for w in _weights(c, s))  # (K + 1, 2, ..., 1): rows for a and b
    X = torch.stack((A, B), 1)
    q = mul(F, X).sum(1)  # F_0 a + F_1 b
    correction = mul(delta[..., None], mul(G, X[..., :4]).sum(1))  # delta (G_0 P + G_1 R)
    return torch.cat((q[..., :4], q[..., 4:] - correction), -1)


def derivatives(jet: Tensor) -> list[Tensor]:
    """The derivatives ``x^(k) = k! x_k`` of a jet, as a list."""
    return [math.factorial(k) * x for k, x in enumerate(jet.unbind(0))]

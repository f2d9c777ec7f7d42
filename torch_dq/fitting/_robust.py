r"""Robust kernels on a sample's whitened residual norm :math:`s` and their default scale.

The cost of a sample is :math:`\rho(s)` with :math:`\rho(s) = s^2` near zero (the squared
loss), and the weight of iteratively reweighted least squares is
:math:`w = \rho'(s) / (2 s)`:

- ``None``: :math:`\rho = s^2`, :math:`w = 1`.
- ``"huber"``: :math:`\rho = s^2` for :math:`s \le k`, :math:`2 k s - k^2` beyond;
  :math:`w = \min(1, k / s)`.
- ``"cauchy"``: :math:`\rho = k^2 \log(1 + s^2 / k^2)`, :math:`w = 1 / (1 + s^2 / k^2)`.

The default ``k`` is the 95 % quantile of the chi distribution with the residual's
dimension ``d`` (the norm of ``d`` standard normal components): 2.7955 for ``d = 3``,
3.5485 for ``d = 6``, from :func:`chi_quantile`.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["KERNELS", "chi_quantile", "rho", "weight"]

KERNELS = (None, "huber", "cauchy")


def _chi2_cdf(x: float, d: int) -> float:
    r"""Regularized lower incomplete gamma :math:`P(d/2, x/2)` by its power series
    :math:`P(a, z) = z^a e^{-z} / \Gamma(a + 1) \sum_{j \ge 0} z^j / ((a+1) \cdots (a+j))`
    (Abramowitz and Stegun 6.5.29; converges for every ``z``)."""
    a, z = 0.5 * d, 0.5 * x
    if z <= 0.0:
        return 0.0
    term = total = 1.0
    j = 0
    while term > 1e-17 * total:
        j += 1
        term *= z / (a + j)
        total += term
    return math.exp(a * math.log(z) - z - math.lgamma(a + 1.0)) * total


def chi_quantile(d: int, q: float = 0.95) -> float:
    """Quantile ``q`` of the chi distribution with ``d`` degrees of freedom (bisection on
    the chi-squared CDF; agrees with ``scipy.stats.chi.ppf`` to 1e-12)."""
    lo, hi = 0.0, float(d) + 20.0 * math.sqrt(d) + 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _chi2_cdf(mid, d) < q:
            lo = mid
        else:
            hi = mid
    return math.sqrt(0.5 * (lo + hi))


def rho(kind: str | None, s: Tensor, k: float) -> Tensor:
    """Cost of whitened residual norms ``s`` (any shape) under the kernel ``kind``."""
    if kind is None:
        return s * s
    if kind == "huber":
        return torch.where(s <= k, s * s, 2.0 * k * s - k * k)
    return k * k * torch.log1p((s / k) ** 2)


def weight(kind: str | None, s: Tensor, k: float) -> Tensor:
    """IRLS weight ``rho'(s) / (2 s)`` of whitened residual norms ``s``."""
    if kind is None:
        return torch.ones_like(s)
    if kind == "huber":
        return torch.where(s <= k, torch.ones_like(s), k / s.clamp_min(k))
    return 1.0 / (1.0 + (s / k) ** 2)

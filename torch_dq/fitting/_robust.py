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

With a kernel the sigmas describe the inliers, and a term's chi-square counts only them
(``inliers``): the samples whose squared norm is within the 99.9 % quantile of the
chi-square distribution of ``d`` degrees of freedom, scaled by the term's own chi2/dof
(a self-consistent cutoff), their sum divided by the mean of that truncated distribution.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["INLIER_QUANTILE", "KERNELS", "chi_quantile", "inliers", "rho", "weight"]

KERNELS = (None, "huber", "cauchy")
INLIER_QUANTILE = 0.999  # inliers: squared norm within this chi-square quantile (scaled)
_PASSES = 100  # at most this many passes of the cutoff's fixed point (a few in practice)


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


def inliers(s2: Tensor, mask: Tensor, d: int, taken: Tensor | float) -> tuple[Tensor, float]:
    r"""The inliers of a robust term, for its chi-square: samples whose squared whitened
    norm is at most :math:`q f`, ``q`` the ``INLIER_QUANTILE`` quantile of the
    chi-square distribution with ``d`` degrees of freedom and ``f`` the term's chi2/dof
    found with them (a fixed point, from the median's estimate
    :math:`\mathrm{median}(s^2) / \mathrm{median}(\chi^2_d)`):

    .. math::
        f = \frac{\sum_{s_i^2 \le q f} s_i^2 / \kappa}{d\, n_{in} - \tau},\qquad
        \kappa = \frac{P(\chi^2_{d+2} \le q)}{P(\chi^2_d \le q)},

    ``kappa`` the mean of :math:`\chi^2_d / d` truncated at ``q`` (0.9939 for ``d = 3``):
    with sigmas that describe the inliers ``f`` is 1 whatever the outliers (those beyond
    ``q f``), and the cutoff scales with sigmas that are off (2x too small: ``f`` about 4, a
    fixed cutoff at ``q`` would keep only the smaller 75 % and read 2.5).

    Args:
        s2: ``(..., N)`` squared whitened residual norms.
        mask: ``(..., N)`` bool, the samples counted.
        d: the residual's dimension.
        taken: ``(...)`` or float, the residual components that the estimated parameters
            take from the term, :math:`\tau` (its leverages summed,
            :attr:`~torch_dq.fitting.Estimate.dof`).

    Returns:
        ``(keep, kappa)``: ``(..., N)`` bool, the inliers among ``mask``, and ``kappa``.
    """
    q = chi_quantile(d, INLIER_QUANTILE) ** 2
    kappa = _chi2_cdf(q, d + 2) / _chi2_cdf(q, d)
    tau = torch.as_tensor(taken, dtype=s2.dtype, device=s2.device)
    f = s2.masked_fill(~mask, math.nan).nanmedian(-1).values / chi_quantile(d, 0.5) ** 2
    keep = torch.zeros_like(mask)
    for _ in range(_PASSES):
        new = mask & (s2 <= q * f[..., None])
        if torch.equal(new, keep):
            break
        keep = new
        nu = (d * keep.sum(-1).clamp_min(1) - tau).clamp_min(1e-12 * d)
        f = torch.where(keep, s2, 0.0).sum(-1) / (kappa * nu)
    return keep, kappa

r"""The parameters each term's residuals take: the per-term degrees of freedom of
:attr:`~torch_dq.fitting.Estimate.dof` (private).

With the data-only Gauss-Newton matrix ``H = sum_t H_t`` at the optimum (``H_t = J_t^T W_t
J_t`` term ``t``'s, robust weights as converged) and the covariance ``Sigma`` of
:mod:`torch_dq.fitting._uncertainty` (the inverse of ``H`` plus the Gaussian priors of
:class:`~torch_dq.fitting.Free` on the directions the data determine; none along the others),
term ``t``'s residuals take :math:`\mathrm{tr}(H_t \Sigma)` of the parameters: its samples'
leverages summed (the diagonal of the hat matrix :math:`W^{1/2} J \Sigma J^T W^{1/2}` over
its rows), which sum over the terms to the parameters the data determine. Its expected
:math:`\chi^2` is :math:`N_t - \mathrm{tr}(H_t \Sigma)` (Seber and Lee, "Linear Regression
Analysis", 2003, sec. 10.2: the residuals' covariance is ``I`` less the hat matrix), whatever
share of the residual count it has: 20 Hz poses beside a 200 Hz IMU determine far more of
the trajectory than their tenth of the residuals.

With the blocks of ``Sigma`` of :mod:`torch_dq.fitting._uncertainty`
(:math:`\Sigma_{cc} = A^{-1} + Z \Sigma_{nn} Z^T`, :math:`\Sigma_{cn} = -Z \Sigma_{nn}`)
and ``H_t``'s (``A_t`` banded, ``C_t``, ``N_t``):

.. math::
    \mathrm{tr}(H_t \Sigma) = \mathrm{tr}(A_t A^{-1}) + \mathrm{tr}(\Sigma_{nn} M_t),\qquad
    M_t = N_t - C_t^T Z - Z^T C_t + Z^T A_t Z,

the first from the band of ``A^{-1}`` alone (``BandedCholesky.trace_products``), the second
``m x m``: no dense inverse, no per-sample Jacobian. The blocks of every term but the last
are summed apart during the linearisation (``System.own``); the last term's trace is the
total's less theirs.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._banded import BandedCholesky
from ._prior import band_apply

__all__ = ["decouple", "taken"]


def decouple(band: Tensor, cn: Tensor, free: Tensor) -> tuple[Tensor, Tensor]:
    """The band ``(Bf, n, w, 6, 6)`` and coupling ``(Bf, n, 6, m)`` with every block that
    touches a control point of ``free (Bf, n)`` (no data information: a time gap, an end
    without samples) zeroed."""
    if not bool(free.any()):
        return band, cn
    n, w = band.shape[1], band.shape[2]
    col = torch.arange(n, device=band.device)[:, None] + torch.arange(w, device=band.device)
    hit = free[:, :, None] | free.gather(1, col.clamp(max=n - 1).reshape(1, -1).expand(
        free.shape[0], -1)).reshape(-1, n, w)
    return band.masked_fill(hit[..., None, None], 0.0), cn.masked_fill(free[..., None, None],
                                                                       0.0)


def taken(chol: BandedCholesky, Z: Tensor, cov_nn: Tensor, free: Tensor,
          system) -> list[Tensor]:
    r"""Per term ``(Bf,)``: :math:`\mathrm{tr}(H_t \Sigma)`, the parameters its residuals take
    (module doc).

    Args:
        chol: the control-point band factored (:math:`A^{-1}`), its undetermined control
            points decoupled.
        Z: ``(Bf, n, 6, m)`` :math:`A^{-1} C`.
        cov_nn: ``(Bf, m, m)`` :math:`\Sigma_{nn}` on the determined nuisance directions
            (zero along those without information).
        free: ``(Bf, n)`` bool, the control points without data information.
        system: the data-only ``System`` at the optimum (its ``own`` blocks: every term's
            but the last).
    """
    blocks = [*system.own, (system.band, system.cn, system.nn)]
    parts = [decouple(band, cn, free) for band, cn, _ in blocks]
    out = chol.trace_products([band for band, _ in parts])
    if cov_nn.shape[-1]:
        for k, ((band, cn), (_, _, nn)) in enumerate(zip(parts, blocks, strict=True)):
            CZ = torch.einsum("bnim,bniq->bmq", cn, Z)
            M = nn - CZ - CZ.mT + torch.einsum("bnim,bniq->bmq", Z, band_apply(band, Z))
            out[k] = out[k] + (cov_nn * M).sum((-1, -2))
    *own, total = out
    return [*own, total - sum(own, torch.zeros_like(total))]

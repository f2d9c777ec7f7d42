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
share of the residual count it has: 20 Hz poses beside a 200 Hz IMU take far fewer of the
parameters than their tenth of the residuals (the IMU determines the trajectory's shape, the
poses little more than its placement: 209 against 656 on the 60 s benchmark job).

With the blocks of ``Sigma`` of :mod:`torch_dq.fitting._uncertainty`
(:math:`\Sigma_{cc} = A^{-1} + Z \Sigma_{nn} Z^T`, :math:`\Sigma_{cn} = -Z \Sigma_{nn}`)
and ``H_t``'s (``A_t`` banded, ``C_t``, ``N_t``):

.. math::
    \mathrm{tr}(H_t \Sigma) = \langle A_t, \Sigma_{cc} \rangle
    - 2 \langle C_t, Z \Sigma_{nn} \rangle + \langle N_t, \Sigma_{nn} \rangle,

elementwise products where ``H_t`` is nonzero: ``Sigma_cc`` only on the band, from the
selected inverse of ``A`` and the band of :math:`Z \Sigma_{nn} Z^T`
(``BandedCholesky.trace_products``): no dense inverse, no per-sample Jacobian. The blocks
of every term but the last are summed apart during the linearisation (``System.own``); the
last term's trace is the total's less theirs.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._banded import BandedCholesky

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
    W = Z @ cov_nn[:, None]  # Z Sigma_nn = -Sigma_cn
    out = chol.trace_products([band for band, _ in parts], Z, W)
    out = [x + (cov_nn * nn).sum((-1, -2)) - 2.0 * (cn * W).sum((-1, -2, -3))
           for x, (_, cn), (_, _, nn) in zip(out, parts, blocks, strict=True)]
    *own, total = out
    return [*own, total - sum(own, torch.zeros_like(total))]

r"""The observed information of a time offset: the marginal variance from the exact
Hessian of the data cost at the estimate, where the Gauss-Newton one is overconfident
(private; :meth:`~torch_dq.fitting.Estimate.std` of a time offset; not of a line delay, whose
exact rows scatter 0.65 to 1.36 times Gauss-Newton's and turn negative over the 30 draws of
``test_reprojections``' Monte Carlo, where Gauss-Newton's std matches the scatter).

Why. A time parameter (a sensor's clock offset, a line delay) moves its samples along the
trajectory: its Jacobian is the time derivative of the predictions (an accelerometer's
:math:`\partial_t (R^T (\ddot p - g))`), read on the *estimated* trajectory, which carries
the part of the noise its control points fit. That part enters the Gauss-Newton
information :math:`J^T J` squared: with hundreds of control points beside one clock whose
information is what is left after they are marginalised (a time shift of the IMU is nearly
a time shift of the curve), it can multiply that information (GNSS + IMU with a lever arm,
``benchmarks/gnss_clock_profile.py``: 4x its value at the truth, the reported std about half
the estimator's spread). The exact Hessian adds :math:`\sum_i r_i \nabla^2 r_i` (the
residuals times the predictions' second time derivatives and the cross terms
:math:`\partial^2 r / \partial t\, \partial \theta`), which cancels that inflation in the mean:
its marginal is the local curvature of the clock's profile likelihood.

How. The Hessian with the time offset's row exact: its column (coupling ``C`` and block
``N``, the :class:`~torch_dq.fitting.Free` priors added) by a forward difference of the
Gauss-Newton gradient :math:`g = J^T W r` (half the robust cost's gradient, on the
Gauss-Newton matrix's scale) along that coordinate (a step of ``_STEP`` of its
standard deviation: one linearisation, no new estimate, whatever the number of nuisance
parameters: a random-walk bias has hundreds), the other nuisance columns and the
control-point block ``A`` Gauss-Newton's (its factor, as the uncertainties'); the marginal
variance from the Schur complement :math:`N - C^T A^{-1} C`, against the same with the
Gauss-Newton ``C`` and ``N``. The second-order terms that matter here
(:math:`r\, \partial^2 r / \partial t^2`, :math:`r\, \partial^2 r / \partial t\, \partial c`)
lie in that row (a bias enters linearly: no cross term with it); the control-point
block's own are left out: along combinations of control points that the data hardly
determine they are of either sign and of no meaning (the numerical ``prior`` of
:func:`~torch_dq.fitting.estimate` holds those), and a conjugate-gradient solve with the full
exact Hessian, preconditioned by the Gauss-Newton covariance, diverged there (a 1.2 s GNSS +
IMU rig) while it agreed with this on the 8 s one. Where the inverse Schur complement's
entry for the parameter is not positive (directions of negative curvature outweigh the
others), the estimate is no minimum along it: the std is inf.
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

from ._prior import NULL, scaled_eigh

__all__ = ["FACTOR", "honest_std", "observed_ratio"]

FACTOR = 1.4  # the exact marginal std above this many GN stds: the GN one is overconfident
# (1.2 flagged a camera + gyroscope clock at 1.20, test_chi13_bound_stop, 1.25 a quartic's
# gyroscope clock at 1.25, test_estimation_montecarlo; the GNSS rig's seeds at 1.47 and
# above)
_STEP = 1e-4  # the difference step, in conditional standard deviations


def _gradient(problem, ctrl: Tensor, values: list[Tensor], w: int, dn: Tensor,
              ) -> tuple[Tensor, Tensor]:
    """The Gauss-Newton gradient ``(gc (Bf, n, 6), gn (Bf, m))`` with the nuisance values
    moved by ``dn (Bf, m)``."""
    s = problem.system(ctrl, problem.moved(values, dn.reshape(*problem.batch, problem.m)), w)
    return s.gc, s.gn


def observed_ratio(problem, ctrl: Tensor, values: list[Tensor], system, chol, free: Tensor,
                   k: int) -> Tensor:
    r"""``(Bf,)`` the marginal std of nuisance coordinate ``k`` from the Hessian with its row
    ``k`` exact over the Gauss-Newton one (inf where the former is not positive:
    ``_marginal``).

    Args:
        problem: the ``torch_dq.fitting._problem.Problem``; ``ctrl``, ``values`` the
            estimate; ``system`` its data-only Gauss-Newton system there.
        chol: the banded factor of the control-point block (as the uncertainties').
        free: ``(Bf, n)`` bool, the control points without data information (decoupled).
        k: the coordinate.
    """
    m = problem.m
    keep = ~free[..., None, None]
    prior = torch.diag(problem.prior_information()).to(system.nn)
    w = problem.width(values)
    h = _STEP * system.nn[:, k, k].clamp_min(1e-300).rsqrt()  # (Bf,) a scale
    gc, gn = _gradient(problem, ctrl, values, w, torch.eye(m).to(h)[k] * h[:, None])
    cn, nn = system.cn.clone(), system.nn.clone()  # column and row k exact, the rest GN's
    cn[..., k] = (gc - system.gc) / h[:, None, None]  # the gradient at the estimate: system's
    nn[:, :, k] = nn[:, k, :] = (gn - system.gn) / h[:, None]
    out = []
    for c, n in ((system.cn, system.nn), (cn, nn)):
        c = torch.where(keep, c, 0.0)
        out.append(_marginal(n + prior - torch.einsum("bnim,bniq->bmq", c, chol.solve(c)), k))
    return (out[1] / out[0]).sqrt()


def _marginal(S: Tensor, k: int) -> Tensor:
    r"""``(Bf,)`` :math:`[S^{-1}]_{kk}` of ``S (Bf, m, m)`` on the directions with information
    (as the uncertainties': scaled eigenvalues beyond ``NULL`` of the largest in magnitude),
    inf where it is not positive (directions of negative curvature outweigh the others
    along ``k``: no minimum; a small negative share, a weak intrinsics direction in 3 of
    ``test_reprojections``' 30 draws, only lowers it)."""
    lam, V, d = scaled_eigh(S)
    null = lam.abs() <= NULL * lam.abs().amax(-1, keepdim=True)
    var = torch.where(null, 0.0, V[:, k, :] ** 2 / torch.where(null, 1.0, lam)).sum(-1)
    return torch.where(var > 0, var / d[:, k], torch.inf)


def honest_std(name: str, s: Tensor, ratio: Tensor, observed: bool) -> Tensor:
    """``s (Bf, 1)``, the Gauss-Newton std as reported (``scaled`` or not), with a warning
    naming ``name`` (``"Term.parameter"``) where the exact Hessian's marginal std is more
    than ``FACTOR`` times it (``ratio (Bf,)``, ``observed_ratio``); with ``observed``, the
    larger of the two: ``s`` times ``max(ratio, 1)`` (inf, with the warning, where that
    Hessian has no minimum along it). Not the observed one where it is smaller: its
    second-order terms are themselves a noise draw (the GNSS rig's seeds 3 and 8 of
    ``benchmarks/gnss_clock_profile.py`` with session 16's released pulls: 2.8 and 2.4 ms
    against Gauss-Newton's 3.4 and 3.5, errors of 4.0 and 4.9 of the former)."""
    over = torch.isfinite(s[:, 0]) & (ratio > (1.0 if observed else FACTOR))
    none = over & ~torch.isfinite(ratio)
    if bool(none.any()) or (bool(over.any()) and not observed):
        worst = float(ratio[over].max())
        where = (f"{float(s[over, 0].max()):.3g} against "
                 f"{float((s[:, 0] * ratio)[over].max()):.3g}" if worst < torch.inf else
                 "inf: the estimate is no minimum along it")
        advice = ("std(..., observed=True) reports it" if not observed else
                  "its observed standard deviation is inf")
        warnings.warn(f"fitting.Estimate: {name}'s Gauss-Newton standard deviation is "
                      f"{worst:.3g} times smaller than its observed information's (the Hessian "
                      f"with its row exact at the estimate; {where}): its Jacobian is read "
                      f"on the estimated trajectory, whose fitted noise inflates the "
                      f"Gauss-Newton information; {advice}", RuntimeWarning, stacklevel=4)
    return s * ratio.clamp_min(1.0)[:, None] if observed else s

r"""Whether a term's :math:`\chi^2` is far from its degrees of freedom (private): the test
behind :class:`~torch_dq.fitting.Estimate`'s warnings and ``summary`` marks.

A term's :math:`\chi^2` (its whitened residuals' squared norm at the optimum) has in the mean
the chi-square distribution with :math:`\nu` (:attr:`~torch_dq.fitting.Estimate.dof`)
degrees of freedom: a quadratic form of the residuals whose eigenvalues are between 0 and 1,
its variance at most that distribution's, so the distribution's band is conservative.
"""

from __future__ import annotations

from torch import Tensor

__all__ = ["FAR", "Z999", "band", "far"]

Z999 = 3.2905  # the standard normal's 99.95 % quantile (two-sided 99.9 % band)
FAR = 1.5  # chi2/dof above which (and above the band) a term's sigmas are too small: the
# standard deviations 20 % too small at least (2 let an accelerometer at 1.57 on knots too
# far apart for it pass silently, its bias 2.4 std off along a weak direction)


def band(nu: Tensor, z: float) -> Tensor:
    r"""The chi-square distribution's quantile at the standard normal's ``z`` for ``nu``
    degrees of freedom (Wilson and Hilferty's cube-root approximation):
    :math:`\nu (1 - 2 / (9 \nu) + z \sqrt{2 / (9 \nu)})^3`."""
    a = 2.0 / (9.0 * nu)
    return nu * (1.0 - a + z * a.sqrt()).clamp_min(0.0) ** 3


def far(chi2: dict, dof: dict) -> dict:
    r"""Per term of ``chi2`` (term -> :math:`\chi^2`, ``(...)``, and ``dof`` alike): ``(ratio,
    "above" | "below" | None)``, ``ratio`` the largest (above) or smallest (below)
    :math:`\chi^2 / \nu` over the batch.

    Far above 1: :math:`\chi^2` beyond both :data:`FAR` times :math:`\nu` and the upper end
    of the two-sided 99.9 % band of the chi-square distribution with :math:`\nu` degrees of
    freedom (:func:`band`): its sigmas too small for its residuals, or, for an IMU term, the
    knots too far apart for its readings. Far below 1: :math:`\chi^2` below both
    :math:`\nu` over :data:`FAR` and the lower end of that band: its sigmas are too large,
    its standard deviations too."""
    out: dict = {}
    for term, c in chi2.items():
        nu = dof[term].clamp_min(1.0)
        ratio = c / nu
        if bool(((c > band(nu, Z999)) & (ratio > FAR)).any()):
            out[term] = (float(ratio.max()), "above")
        elif bool(((c < band(nu, -Z999)) & (ratio < 1.0 / FAR)).any()):
            out[term] = (float(ratio.min()), "below")
        else:
            out[term] = (float(ratio.max()), None)
    return out

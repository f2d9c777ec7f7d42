r"""Does Levenberg-Marquardt pay after the least-squares start? The ``fit`` command's test.

The least-squares start (:meth:`torch_dq.nn.BSpline.from_poses`) solves the fit linearised
in local charts; :func:`torch_dq.nn.fit` then minimises the fitted poses' cost
:math:`f = \sum_i \theta_i^2 + |p_i - \hat p_i|^2` (:func:`torch_dq.losses.pose_loss`,
radians and the poses' length unit) by Gauss-Newton steps
:math:`\delta = -H^{-1} g` in the control points' body-frame charts
:math:`c_k \exp(\delta_k)`. One such step from the start lowers :math:`f` by the Newton
decrement :math:`g^T H^{-1} g` (:math:`g = J^T r`, half the gradient, :math:`H = J^T J`).
Where the start is already at the nonlinear optimum to within the noise (fine knots,
small turns per knot span: e.g. TUM's 200 Hz motion capture, decrements of 0.4-0.9 % of
:math:`f`), the step moves the curve by a small fraction of the residuals and the held-out
errors by less than 1 % either way; where the charts' linearisation is off (large turns per
knot span, sparse poses) the step removes a bias, and the held-out errors drop.

:func:`predicted_gain` estimates that decrement for the rotation and the translation parts
of :math:`f` separately (a part with a small share of the cost, e.g. millimetre translations
next to degree rotations, must not hide behind the other) at the cost of one evaluation of
the curve with its gradient and one banded solve:

- :math:`g` exactly, by reverse mode through the curve at the start
  (``module(times, ctrl=c exp(delta))`` at ``delta = 0``);
- :math:`H \approx (B^T B) \otimes I_6` in the frames where the residuals live: the
  rotation residual (sensor axes) moves with a control point's body-frame rotation by
  :math:`B_{ik} R(t_i)^T R_k \approx B_{ik} I`, the translation (world axes) with its
  body-frame translation by :math:`B_{ik} R_k`, so the translation part of :math:`g_k` is
  rotated to world axes by :math:`R_k` first (``B`` the Euclidean basis, :meth:`basis`;
  the linearisation of every form, as in :mod:`torch_dq._start`). A shift of ``1e-3`` of
  the mean diagonal keeps control points without samples of their own (gaps) finite, as
  LM's prior does;
- per part, :math:`\sum_{c} g_c^T (B^T B)^{-1} g_c` over its three columns, over that
  part's cost at the start.

The neglected terms are of the order of the turn per knot span and of the residuals: the
estimate of the whole decrement is within 2 % of the decrease one LM step achieves on the
TUM files, and within 4-16 % of it (or of a finite-difference Gauss-Newton decrement,
``tests/test_fit9_refine.py``) on synthetic motion turning 0.5-0.7 rad per knot span.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .. import dualquat, losses, quat
from ..fitting._banded import BandedCholesky

__all__ = ["predicted_gain"]

_SHIFT = 1e-3  # of the Gram's mean diagonal: control points in gaps stay finite


def _gram_band(first: Tensor, values: Tensor, n: int) -> Tensor:
    """``(n, w)`` upper band of :math:`B^T B` (entry ``(k, d)``: columns ``k, k + d``) of the
    basis ``(first (N,), values (N, w))``."""
    w = values.shape[1]
    band = values.new_zeros(n, w)
    for d in range(w):
        for i in range(w - d):
            band[:, d].index_add_(0, first + i, values[:, i] * values[:, i + d])
    return band


def predicted_gain(module, times: Tensor, poses: Tensor) -> tuple[float, float]:
    r"""What one Gauss-Newton step from ``module``'s control points would gain (module doc).

    Args:
        module: a single-curve :class:`torch_dq.nn.BSpline` (or Bézier) layer, ``(n, 8)``
            control points.
        times: ``(N,)`` times in its domain (float64 seconds welcome).
        poses: ``(N, 8)`` unit dual quaternions of the module's dtype.

    Returns:
        ``(rotation, translation)``: the predicted decrease of each part of the fitted
        poses' cost over that part (``>= 0``; ``inf`` where the gradient or the solve is not
        finite, so that the caller refines; a part whose cost is 0 counts as ``0`` when its
        gradient is 0 too).
    """
    ctrl = module.control_points.detach()
    n = ctrl.shape[-2]
    with torch.enable_grad():
        delta = ctrl.new_zeros(n, 6, requires_grad=True)
        pred = module(times, ctrl=dualquat.mul(ctrl, dualquat.exp(delta)))
        cost = losses.pose_loss(pred, poses, reduction="sum")
        (g,) = torch.autograd.grad(0.5 * cost, delta)
    g = torch.cat((g[:, :3], quat.rotate(ctrl[:, :4], g[:, 3:])), -1).double()
    first, values = module.basis(times)
    band = _gram_band(first, values, n)
    shift = (_SHIFT * band[:, 0].mean()).expand(n, 1)
    chol = BandedCholesky(band[:, :, None, None], shift)
    x = chol.solve(g[:, None, :])[:, 0, :]
    dec = (g * x).sum(0)
    pred = pred.detach()
    parts = (losses.squared_rotation_angle(pred, poses).double().sum(),
             losses.translation_error(pred, poses).double().pow(2).sum())
    out: list[float] = []
    for drop, cost_part in zip((dec[:3].sum(), dec[3:].sum()), parts, strict=True):
        d, c = float(drop), float(cost_part)
        if not (bool(chol.ok) and math.isfinite(d) and math.isfinite(c)):
            out.append(math.inf)
        else:
            out.append(d / c if c > 0 else (0.0 if d <= 0 else math.inf))
    return out[0], out[1]

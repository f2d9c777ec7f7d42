r"""Pose losses between unit dual quaternions, invariant to the sign of either argument.

``x`` and ``-x`` are the same rigid transform, so every function here gives the same value
(and the same gradient up to that sign) for either representative.

- :func:`rotation_angle`: geodesic angle in ``[0, pi]`` between the rotations (radians).
- :func:`squared_rotation_angle`: its square, a smooth function at zero error (the angle
  itself is a cone there), for losses and second-order methods.
- :func:`translation_error`: Euclidean distance between the translations (length units).
- :func:`pose_loss`: ``rot_weight * angle**2 + trans_weight * |dt|**2``, reduced.

All accept ``(..., 8)`` tensors whose batch shapes broadcast, and are differentiable with
finite gradients everywhere, including at zero error (the zero subgradient at the kink of
the angle and of the distance). The squared errors (:func:`squared_rotation_angle`,
:func:`pose_loss`) are twice differentiable at zero error: their Hessian there is the
Gauss-Newton one (``2 I`` for the rotation block in a chart ``b = a exp(xi)``).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from . import _checks
from ._core import translation
from ._numerics import compute_dtype, even, power_of_two_scale, safe_norm

__all__ = ["pose_loss", "rotation_angle", "squared_rotation_angle", "translation_error"]

_REDUCTIONS = ("mean", "sum", "none")


def _unit_real(x: Tensor) -> Tensor:
    r = x[..., :4]
    r = r / power_of_two_scale(r)  # exact; no square over- or underflows
    return r / torch.linalg.vector_norm(r, dim=-1, keepdim=True)


def _translation(x: Tensor) -> Tensor:
    """``2 vec(d r*) / |r|^2``: the translation kept by ``dualquat.normalize``."""
    x = x / power_of_two_scale(x[..., :4])  # both parts: the ratio is unchanged
    r, d = x[..., :4], x[..., 4:]
    return translation(r, d) / (r * r).sum(-1, keepdim=True)


def _rotation_angle(a: Tensor, b: Tensor) -> Tensor:
    ra, rb = _unit_real(a), _unit_real(b)
    minus, plus = safe_norm(rb - ra), safe_norm(rb + ra)
    # |rb - ra| = 2 sin(phi / 2), |rb + ra| = 2 cos(phi / 2) with phi the angle between the
    # unit quaternions in R^4; the rotation angle is 2 min(phi, pi - phi) =
    # 4 atan2(min, max): accurate at 0 and at pi (no acos), and the same for -ra or -rb.
    return 4.0 * torch.atan2(torch.minimum(minus, plus), torch.maximum(minus, plus))


def _squared_rotation_angle(a: Tensor, b: Tensor) -> Tensor:
    ra, rb = _unit_real(a), _unit_real(b)
    dm, dp = rb - ra, rb + ra
    minus, plus = (dm * dm).sum(-1), (dp * dp).sum(-1)
    # The angle is 4 atan(sqrt(z2)) with z2 = min / max of |rb -+ ra|^2 = tan^2(angle / 4)
    # in [0, 1], so angle^2 = 16 z2 atanc(z2)^2: a smooth function of z2, itself smooth
    # (a ratio of squared norms, the larger one >= 2) except at the tie (angle pi).
    z2 = torch.minimum(minus, plus) / torch.maximum(minus, plus)
    return 16.0 * z2 * even("atanc", z2) ** 2


def _pairwise(fn: str, metric: Callable[[Tensor, Tensor], Tensor], a: Tensor,
              b: Tensor) -> Tensor:
    """Check a pair of ``(..., 8)`` tensors, evaluate ``metric`` in the compute dtype."""
    _checks.pair(fn, a, b, 8)
    dtype = compute_dtype(a.dtype)
    return metric(a.to(dtype), b.to(dtype)).to(a.dtype)


def rotation_angle(a: Tensor, b: Tensor) -> Tensor:
    r"""Geodesic angle in ``[0, pi]`` between the rotations of two dual quaternions.

    The magnitude of the relative rotation :math:`R_a^{-1} R_b` (scipy's
    ``(Ra.inv() * Rb).magnitude()``), evaluated as
    :math:`4\,\mathrm{atan2}(\min(|r_b - r_a|, |r_b + r_a|), \max(|r_b - r_a|, |r_b + r_a|))`
    on the real parts normalised to unit length: accurate near 0 and pi (no ``acos``) and
    invariant to the sign of ``a`` and of ``b``. At zero error the gradient is the zero
    subgradient (finite, no NaN); at pi (the maximum) one of the two tied branches is
    differentiated.

    Args:
        a: ``(..., 8)`` dual quaternions with non-zero real parts (normally unit).
        b: ``(..., 8)``, batch broadcastable with ``a``, same dtype and device.

    Returns:
        ``(...)`` angles in radians, in ``[0, pi]``. float16/bfloat16 compute in float32.

    Raises:
        ValueError: trailing dimension not 8, batch shapes that do not broadcast.
        TypeError: non-floating tensors, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> q = torch.tensor([0.0, 0.0, 0.0, 1.0])  # 180 degrees about z
        >>> rotation_angle(dq.identity(), dq.from_rt(q, torch.zeros(3)))
        tensor(3.1416)
    """
    return _pairwise("losses.rotation_angle", _rotation_angle, a, b)


def squared_rotation_angle(a: Tensor, b: Tensor) -> Tensor:
    r"""Square of :func:`rotation_angle`, smooth at zero error (radians²).

    The angle is a cone at zero error (like :math:`|x|`, no second derivative), so squaring
    it after the fact gives a zero Hessian there; this function evaluates
    :math:`\theta^2 = 16 z\,\mathrm{atanc}(z)^2` from :math:`z = \tan^2(\theta / 4) =
    \min(|r_b - r_a|^2, |r_b + r_a|^2) / \max(\dots)`, a smooth function of the inputs, so
    its Hessian at ``a == b`` is exact: ``2 I`` in a chart ``b = a exp(xi)`` (Gauss-Newton
    and Laplace approximations get the right curvature). At pi (the maximum) the two tied
    branches meet in a kink, as for the angle. Arguments, dtypes and errors as for
    :func:`rotation_angle`; returns ``(...)`` squared angles in ``[0, pi**2]``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> turn = dq.exp(torch.tensor([0.5, 0.0, 0.0, 0.0, 0.0, 0.0]))  # 0.5 rad about x
        >>> squared_rotation_angle(dq.identity(), turn)
        tensor(0.2500)
    """
    return _pairwise("losses.squared_rotation_angle", _squared_rotation_angle, a, b)


def translation_error(a: Tensor, b: Tensor) -> Tensor:
    r"""Euclidean distance :math:`|t_a - t_b|` between the translations.

    :math:`t = 2\,\mathrm{vec}(d\, r^*) / |r|^2` (exact for unit dual quaternions, and the
    translation that :func:`torch_dq.dualquat.normalize` keeps for others); the same for
    ``x`` and ``-x``. At zero distance the gradient is the zero subgradient.

    Args:
        a: ``(..., 8)`` dual quaternions with non-zero real parts (normally unit).
        b: ``(..., 8)``, batch broadcastable with ``a``, same dtype and device.

    Returns:
        ``(...)`` distances in the units of the translations.

    Raises:
        ValueError: trailing dimension not 8, batch shapes that do not broadcast.
        TypeError: non-floating tensors, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> q = torch.tensor([1.0, 0.0, 0.0, 0.0])
        >>> translation_error(dq.from_rt(q, torch.tensor([3., 0, 0])),
        ...                   dq.from_rt(q, torch.tensor([0., 4, 0])))
        tensor(5.)
    """
    return _pairwise("losses.translation_error",
                     lambda x, y: safe_norm(_translation(x) - _translation(y)), a, b)


def _weight(fn: str, name: str, w) -> float:
    return _checks.real(fn, name, w, "a finite real number >= 0", lambda v: v >= 0)


def pose_loss(a: Tensor, b: Tensor, rot_weight: float = 1.0, trans_weight: float = 1.0,
              reduction: str = "mean") -> Tensor:
    r"""Squared pose error :math:`w_r\,\theta^2 + w_t\,|t_a - t_b|^2`, reduced.

    :math:`\theta^2` is :func:`squared_rotation_angle` (radians², smooth at zero error, so
    Hessians there are exact: ``2 rot_weight I`` for the rotation block in a chart
    ``b = a exp(xi)``) and :math:`t` the translations, so
    the two terms are in rad² and length² respectively: choose
    ``trans_weight = 1 / scale**2`` for a typical translation scale ``scale`` of the data
    to weigh one scale unit like one radian (e.g. ``1 / 0.1**2 = 100`` for a 10 cm
    workspace in metres). Smooth at zero error (gradient zero there), sign invariant.

    Args:
        a: ``(..., 8)`` predicted dual quaternions (normally unit).
        b: ``(..., 8)`` targets, batch broadcastable with ``a``, same dtype and device.
        rot_weight: weight of the squared angle, a real number ``>= 0``.
        trans_weight: weight of the squared distance, a real number ``>= 0``.
        reduction: ``"mean"`` (default) or ``"sum"`` over the broadcast batch, or
            ``"none"`` for the per-element ``(...)`` losses.

    Returns:
        A 0-d tensor (``"mean"``, ``"sum"``) or the ``(...)`` per-element losses.

    Raises:
        ValueError: bad shapes (see :func:`rotation_angle`), negative or non-finite
            weights, unknown ``reduction``.
        TypeError: non-floating tensors, mixed dtypes or devices.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> q = torch.tensor([1.0, 0.0, 0.0, 0.0])
        >>> pose_loss(dq.identity(), dq.from_rt(q, torch.tensor([0., 0., 2.])))
        tensor(4.)
    """
    fn = "losses.pose_loss"
    _checks.pair(fn, a, b, 8)
    wr = _weight(fn, "rot_weight", rot_weight)
    wt = _weight(fn, "trans_weight", trans_weight)
    if reduction not in _REDUCTIONS:
        _checks.fail(fn, f"reduction must be one of {_REDUCTIONS}, got {reduction!r}")
    out, dtype = a.dtype, compute_dtype(a.dtype)
    a, b = a.to(dtype), b.to(dtype)
    dt = _translation(a) - _translation(b)
    per = wr * _squared_rotation_angle(a, b) + wt * (dt * dt).sum(-1)
    if reduction == "mean":
        per = per.mean()
    elif reduction == "sum":
        per = per.sum()
    return per.to(out)

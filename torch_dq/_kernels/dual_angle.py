r"""The dual angle's eqs. 4-5 as a custom autograd op (private).

The readable reference is :func:`torch_dq.dualquat._eqs4_5` (with eq. 6 and the docs in
:func:`torch_dq.dualquat.angle`); this op computes the same formulas and saves only its
inputs and one output for an analytic backward, instead of autograd's intermediates.

Notation: :math:`a = P + \epsilon Q`, :math:`b = R + \epsilon S`, :math:`u = |R - P|`,
:math:`v = |R + P|`, :math:`\delta = P\cdot S + R\cdot Q` (the dual part of eq. 1). For unit
real parts :math:`u v = 2\sin\theta`, so

.. math::
    \theta = 2\,\mathrm{atan2}(u, v), \qquad \hat\theta = -\frac{\delta}{\sin\theta}
    = -\frac{2\delta}{u v}.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from .._numerics import nan_unless, safe_denominator, threshold


class Chords(NamedTuple):
    r"""The chords :math:`R \mp P` of the real parts and the other quantities eqs. 4-5 are
    built from, for a broadcast pair ``a, b (..., 8)``."""

    P: Tensor  #: real part of ``a``
    Q: Tensor  #: dual part of ``a``
    R: Tensor  #: real part of ``b``
    S: Tensor  #: dual part of ``b``
    u: Tensor  #: ``|R - P|``
    v: Tensor  #: ``|R + P|``
    dm_hat: Tensor  #: ``(R - P) / u`` (0 where ``u = 0``)
    dp_hat: Tensor  #: ``(R + P) / v`` (0 where ``v = 0``)
    degenerate: Tensor  #: ``sin θ = u v / 2`` below the eq. 6 threshold


class Partials(NamedTuple):
    """Partial derivatives of ``θ(u, v)`` and ``θ̂(δ, u, v)``, finite in the eq. 6 region."""

    theta_u: Tensor
    theta_v: Tensor
    hat_delta: Tensor
    hat_u: Tensor
    hat_v: Tensor


class DualAngle(NamedTuple):
    """Output of :func:`dual_angle`."""

    theta: Tensor  #: eq. 4, in ``[0, π]``
    theta_hat: Tensor  #: eq. 5, 0 where ``degenerate``
    degenerate: Tensor  #: where eq. 6 replaces eq. 5 (bool)


def chords(a: Tensor, b: Tensor) -> Chords:
    """The :class:`Chords` of a broadcast pair ``a, b (..., 8)``."""
    P, Q, R, S = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    dm, dp = R - P, R + P
    u = torch.linalg.vector_norm(dm, dim=-1)
    v = torch.linalg.vector_norm(dp, dim=-1)
    dm_hat = dm / safe_denominator(u, u == 0)[..., None]
    dp_hat = dp / safe_denominator(v, v == 0)[..., None]
    degenerate = 0.5 * u * v <= threshold("dual_angle_degenerate", a.dtype)
    return Chords(P, Q, R, S, u, v, dm_hat, dp_hat, degenerate)


def partials(f: Chords, theta_hat: Tensor) -> Partials:
    r""":math:`\partial\theta/\partial(u, v) = (2v, -2u) / (u^2 + v^2)` and
    :math:`\partial\hat\theta/\partial(\delta, u, v) = (-2/(uv), -\hat\theta/u, -\hat\theta/v)`,
    zero in the eq. 6 region (where ``theta_hat`` is 0)."""
    k = 2.0 / (f.u * f.u + f.v * f.v)
    us, vs = safe_denominator(f.u, f.degenerate), safe_denominator(f.v, f.degenerate)
    hat_delta = torch.where(f.degenerate, 0.0, -2.0 / (us * vs))
    return Partials(k * f.v, -k * f.u, hat_delta, -theta_hat / us, -theta_hat / vs)


class _DualAngle(torch.autograd.Function):
    r"""Eqs. 4-5 with an analytic backward: :math:`(\theta, \hat\theta)` and the eq. 6 mask.

    At :math:`\theta \in \{0, \pi\}` (a kink, like ``|x|``) the gradient of :math:`\theta`
    is the zero subgradient; in the eq. 6 region :math:`\hat\theta = 0` with zero gradient
    (the caller substitutes eq. 6). Infinite real parts give :math:`\theta =` NaN, not
    ``atan2``'s finite limit.

    No forward-mode rule: a custom ``jvp`` would be first order only (nested forward mode
    would give zeros), so :func:`torch_dq._dispatch.fused_path` sends forward mode and every
    ``torch.func`` transform to the plain-op reference instead.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        f = chords(a, b)
        delta = (f.P * f.S).sum(-1) + (f.R * f.Q).sum(-1)
        theta = nan_unless(torch.isfinite(f.u) & torch.isfinite(f.v), 2.0 * torch.atan2(f.u, f.v))
        sin_theta = 0.5 * safe_denominator(f.u * f.v, f.degenerate)
        theta_hat = torch.where(f.degenerate, 0.0, -delta / sin_theta)
        return theta, theta_hat, f.degenerate

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.mark_non_differentiable(output[2])
        ctx.save_for_backward(*inputs, output[1])

    @staticmethod
    def backward(ctx, g_theta, g_hat, _):
        a, b, theta_hat = ctx.saved_tensors
        f = chords(a, b)
        p = partials(f, theta_hat)
        # Scalar sensitivities to u = |R - P|, v = |R + P| and delta = P.S + R.Q, as columns.
        g_u = (g_theta * p.theta_u + g_hat * p.hat_u)[..., None]
        g_v = (g_theta * p.theta_v + g_hat * p.hat_v)[..., None]
        g_d = (g_hat * p.hat_delta)[..., None]
        grad_P = -g_u * f.dm_hat + g_v * f.dp_hat + g_d * f.S
        grad_R = g_u * f.dm_hat + g_v * f.dp_hat + g_d * f.Q
        return torch.cat((grad_P, g_d * f.R), -1), torch.cat((grad_R, g_d * f.P), -1)


def dual_angle(a: Tensor, b: Tensor) -> DualAngle:
    """Unchecked eqs. 4-5 on broadcast ``a, b (..., 8)``: see :class:`DualAngle`."""
    return DualAngle(*_DualAngle.apply(a, b))

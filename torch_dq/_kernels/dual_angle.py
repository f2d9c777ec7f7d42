r"""The dual angle (eqs. 4-5) as a custom autograd op (private).

The readable eqs. 4-7 are :func:`torch_dq.dualquat.angle`.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .._numerics import nan_unless


def degenerate_threshold(dtype: torch.dtype) -> float:
    r"""``sin θ`` below which two rotations count as equal or opposite (eq. 6 branch):
    :math:`\sqrt{\epsilon}` of the dtype, where eq. 5's error :math:`\epsilon|t|/\sin\theta`
    reaches :math:`\sqrt{\epsilon}|t|`."""
    return float(torch.finfo(dtype).eps ** 0.5)


def _angle_frame(a: Tensor, b: Tensor):
    """Halves, ``u = |R - P|``, ``v = |R + P|`` with unit directions, and the eq. 6 mask."""
    P, Q, R, S = a[..., :4], a[..., 4:], b[..., :4], b[..., 4:]
    dm, dp = R - P, R + P
    u = torch.linalg.vector_norm(dm, dim=-1)
    v = torch.linalg.vector_norm(dp, dim=-1)
    dm_hat = dm / torch.where(u > 0, u, 1.0)[..., None]
    dp_hat = dp / torch.where(v > 0, v, 1.0)[..., None]
    degenerate = u * v <= 2.0 * degenerate_threshold(a.dtype)  # u v = 2 sin(theta)
    return P, Q, R, S, u, v, dm_hat, dp_hat, degenerate


class _DualAngleVJP(torch.autograd.Function):
    r"""Dual angle (eqs. 4, 5): :math:`\theta = 2\,\mathrm{atan2}(|R - P|, |R + P|)`
    (equal to :math:`\arccos(P \cdot R)` for unit inputs, but accurate near 0 and pi) and
    :math:`\hat\theta = -\delta / \sin\theta = -2\delta / (|R - P|\,|R + P|)`.

    Returns ``(theta, theta_hat)``; ``theta_hat`` is 0 where ``sin θ`` is below
    :func:`degenerate_threshold` (the caller substitutes eq. 6 there). At ``θ = 0`` or
    ``π`` the gradient of ``θ`` (a kink, like ``|x|``) is the zero subgradient.
    As for sclerp, the subclass :class:`_DualAngle` adds the forward-mode rule.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
        P, Q, R, S, u, v, _, _, degenerate = _angle_frame(a, b)
        delta = (P * S).sum(-1) + (R * Q).sum(-1)
        # Infinite real parts: NaN, not atan2's finite limit pi / 2.
        theta = nan_unless(torch.isfinite(u) & torch.isfinite(v), 2.0 * torch.atan2(u, v))
        theta_hat = torch.where(degenerate, 0.0, -2.0 * delta / torch.where(degenerate, 1.0, u * v))
        return theta, theta_hat

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs, output[1])
        ctx.save_for_forward(*inputs, output[1])

    @staticmethod
    def _partials(a: Tensor, b: Tensor, theta_hat: Tensor):
        """d theta / d(u, v) and d theta_hat / d(delta, u, v), safe in the eq. 6 region."""
        P, Q, R, S, u, v, dm_hat, dp_hat, degenerate = _angle_frame(a, b)
        k = 2.0 / (u * u + v * v)
        us, vs = torch.where(degenerate, 1.0, u), torch.where(degenerate, 1.0, v)
        d_delta = torch.where(degenerate, 0.0, -2.0 / (us * vs))
        return P, Q, R, S, dm_hat, dp_hat, k * v, -k * u, d_delta, -theta_hat / us, -theta_hat / vs

    @staticmethod
    def backward(ctx, g_theta, g_hat):
        a, b, theta_hat = ctx.saved_tensors
        P, Q, R, S, dm_hat, dp_hat, th_u, th_v, h_d, h_u, h_v = _DualAngleVJP._partials(
            a, b, theta_hat)
        # Scalar sensitivities to u = |R - P|, v = |R + P| and delta = P.S + R.Q, as columns.
        g_u = (g_theta * th_u + g_hat * h_u)[..., None]
        g_v = (g_theta * th_v + g_hat * h_v)[..., None]
        g_d = (g_hat * h_d)[..., None]
        grad_P = -g_u * dm_hat + g_v * dp_hat + g_d * S
        grad_R = g_u * dm_hat + g_v * dp_hat + g_d * Q
        return torch.cat((grad_P, g_d * R), -1), torch.cat((grad_R, g_d * P), -1)


class _DualAngle(_DualAngleVJP):
    """:class:`_DualAngleVJP` with the forward-mode rule."""

    @staticmethod
    def jvp(ctx, ta, tb):
        a, b, theta_hat = ctx.saved_tensors
        P, Q, R, S, dm_hat, dp_hat, th_u, th_v, h_d, h_u, h_v = _DualAngleVJP._partials(
            a, b, theta_hat)
        ta = torch.zeros_like(a) if ta is None else ta
        tb = torch.zeros_like(b) if tb is None else tb
        tP, tQ, tR, tS = ta[..., :4], ta[..., 4:], tb[..., :4], tb[..., 4:]
        du = (dm_hat * (tR - tP)).sum(-1)
        dv = (dp_hat * (tR + tP)).sum(-1)
        dd = (tP * S + P * tS + tR * Q + R * tQ).sum(-1)
        return th_u * du + th_v * dv, h_d * dd + h_u * du + h_v * dv


def dual_angle(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Unchecked ``(theta, theta_hat)`` of eqs. 4-5 on broadcast inputs (0 in the eq. 6 region)."""
    op = _DualAngleVJP if torch.compiler.is_compiling() else _DualAngle
    return op.apply(a, b)


def degenerate(a: Tensor, b: Tensor) -> Tensor:
    """Where eq. 6 replaces eq. 5: ``sin θ`` below :func:`degenerate_threshold`."""
    return _angle_frame(a, b)[-1]

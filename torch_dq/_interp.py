r"""Custom autograd ops for the dual angle and screw interpolation (private).

Notation (paper section 3): for unit dual quaternions :math:`a = P + \epsilon Q` and
:math:`b = R + \epsilon S`, the dual scalar product (eq. 1) is
:math:`c + \epsilon\delta` with :math:`c = P\cdot R = \cos\theta` and
:math:`\delta = P\cdot S + R\cdot Q = -\hat\theta \sin\theta` (eqs. 4, 5, 7).

Interpolation (eq. 11) uses the dual weight :math:`F(s, \bar\theta)` with
:math:`F(s, \theta) = \sin(s\theta)/\sin\theta`, :math:`s = 1 - t` for ``a`` and
:math:`s = t` for ``b``. Its dual part is :math:`\hat\theta\, \partial_\theta F
= -\delta\, G` with :math:`G = \partial_\theta F / \sin\theta`, so that

.. math::
    q(t) = F_0 a + F_1 b - \epsilon\, \delta\, (G_0 P + G_1 R)

and no :math:`\hat\theta = -\delta/\sin\theta` (a 0/0 when the rotations agree) is ever
formed. In the variable :math:`y = 1 - \cos\theta` every weight is one power series,

.. math::
    F = \sum_k a_k(s)\, y^k, \quad a_0 = s, \quad
    a_k = a_{k-1}\,\frac{k^2 - s^2}{k (2k + 1)},

and :math:`G = \partial_y F`, :math:`H = \partial_y G` (needed by the gradients, together
with :math:`F_s = \partial_s F`, :math:`G_s = \partial_s G`). Near :math:`y = 0` the
truncated series is used, elsewhere the closed forms

.. math::
    G = \frac{s\cos s\theta - F\cos\theta}{\sin^2\theta},\quad
    H = \frac{(1 - s^2) F - 3 G \cos\theta}{\sin^2\theta},\quad
    F_s = \frac{\theta\cos s\theta}{\sin\theta},\quad
    G_s = \frac{\cos s\theta - s\theta\sin s\theta - F_s\cos\theta}{\sin^2\theta}.
"""

from __future__ import annotations

import torch
from torch import Tensor

_TERMS = 5  # a_0 .. a_4: truncation error ~ (y / 2) ** 5 for |s| <= 1


def _series_threshold(dtype: torch.dtype) -> float:
    r"""Switch point in :math:`y`: series error :math:`\sqrt y (y/2)^4` (of :math:`\delta G`)
    against the closed form's :math:`\epsilon / \sqrt y`, balanced at :math:`y^5 = 16\epsilon`."""
    return float((16.0 * torch.finfo(dtype).eps) ** (1.0 / _TERMS))


def _horner(coeffs: list[Tensor], y: Tensor) -> Tensor:
    out = coeffs[-1]
    for a in reversed(coeffs[:-1]):
        out = a + y * out
    return out


def _weights(c: Tensor, s: Tensor, derivatives: bool) -> tuple[Tensor, ...]:
    r"""Interpolation weights at :math:`\cos\theta = c` for the parameters ``s``.

    Args:
        c: ``(...)`` cosines, in ``[-1, 1]`` up to rounding.
        s: ``(2, ...)`` parameters ``(1 - t, t)``.
        derivatives: also return :math:`H, F_s, G_s` (for the gradients).

    Returns:
        ``F, G`` (and ``H, Fs, Gs``), each ``(2, ...)``.
    """
    y = 1.0 - c
    s2 = s * s
    small = y * torch.clamp(s2, min=1.0) < _series_threshold(c.dtype)

    # Series branch: a_k and da_k = d a_k / ds by the recurrence of the module docstring.
    a, da = [s], [torch.ones_like(s)]
    for k in range(1, _TERMS):
        r = (k * k - s2) / (k * (2 * k + 1))
        da.append(da[-1] * r - a[-1] * (2.0 * s / (k * (2 * k + 1))))
        a.append(a[-1] * r)
    F = _horner(a, y)
    G = _horner([k * a[k] for k in range(1, _TERMS)], y)

    # Closed forms on safe inputs: the series elements see theta = pi / 2 instead. Using
    # sin and cos of the same theta makes the endpoints exact (s = 1: F = 1, G = 0).
    theta = torch.acos(torch.where(small, torch.zeros_like(c), c).clamp(-1.0, 1.0))
    sin_t, cs = torch.sin(theta), torch.cos(theta)
    sin2 = sin_t * sin_t
    st = s * theta
    sin_st, cos_st = torch.sin(st), torch.cos(st)
    F_exact = sin_st / sin_t
    G_exact = (s * cos_st - F_exact * cs) / sin2
    F = torch.where(small, F, F_exact)
    G = torch.where(small, G, G_exact)
    if not derivatives:
        return F, G

    H = _horner([k * (k - 1) * a[k] for k in range(2, _TERMS)], y)
    Fs = _horner(da, y)
    Gs = _horner([k * da[k] for k in range(1, _TERMS)], y)
    Fs_exact = theta * cos_st / sin_t
    H = torch.where(small, H, ((1.0 - s2) * F_exact - 3.0 * G_exact * cs) / sin2)
    Gs = torch.where(small, Gs, (cos_st - st * sin_st - Fs_exact * cs) / sin2)
    Fs = torch.where(small, Fs, Fs_exact)
    return F, G, H, Fs, Gs


def _frame(a: Tensor, b: Tensor, t: Tensor, shortest: bool):
    """Halves, sign, cosine ``c``, dual dot ``delta`` and parameters ``s`` of a pair."""
    P, Q = a[..., :4], a[..., 4:]
    c = (P * b[..., :4]).sum(-1)
    sigma = None
    if shortest:
        sigma = torch.where(c < 0, -1.0, 1.0).to(c.dtype)
        b = b * sigma[..., None]
        c = c * sigma
    R, S = b[..., :4], b[..., 4:]
    delta = (P * S).sum(-1) + (R * Q).sum(-1)
    s = torch.stack((1.0 - t, t))
    return P, Q, R, S, b, c, delta, s, sigma


class _SclerpVJP(torch.autograd.Function):
    """Screw linear interpolation (eq. 11) with an analytic backward.

    Inputs are already broadcast: ``a, b (..., 8)``, ``t (...)``. Saves only the inputs;
    the backward recomputes the weights (cheaper in memory than keeping intermediates).
    TorchDynamo cannot trace a Function that defines ``jvp``, so compiled code uses this
    class and eager code the subclass :class:`_Sclerp` that adds forward mode.
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
        P, _, R, _, b, c, delta, s, _ = _frame(a, b, t, shortest)
        (F0, F1), (G0, G1) = _weights(c, s, derivatives=False)
        out = F0[..., None] * a + F1[..., None] * b
        out[..., 4:] -= delta[..., None] * (G0[..., None] * P + G1[..., None] * R)
        return out

    @staticmethod
    def setup_context(ctx, inputs, output):
        a, b, t, shortest = inputs
        ctx.save_for_backward(a, b, t)
        ctx.save_for_forward(a, b, t)
        ctx.shortest = shortest

    @staticmethod
    def backward(ctx, grad):
        a, b, t = ctx.saved_tensors
        P, Q, R, S, b, c, delta, s, sigma = _frame(a, b, t, ctx.shortest)
        (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = _weights(c, s, True)
        gr, gd = grad[..., :4], grad[..., 4:]
        pa, pb = (grad * a).sum(-1), (grad * b).sum(-1)
        gP, gR = (gd * P).sum(-1), (gd * R).sum(-1)
        # Sensitivities to c = P.R, delta = P.S + R.Q and t (module docstring).
        L_c = delta * (H0 * gP + H1 * gR) - G0 * pa - G1 * pb
        L_d = -(G0 * gP + G1 * gR)
        L_t = Fs1 * pb - Fs0 * pa + delta * (Gs0 * gP - Gs1 * gR)
        e = lambda x: x[..., None]  # noqa: E731
        grad_a = torch.cat((e(F0) * gr - e(delta * G0) * gd + e(L_c) * R + e(L_d) * S,
                            e(F0) * gd + e(L_d) * R), dim=-1)
        grad_b = torch.cat((e(F1) * gr - e(delta * G1) * gd + e(L_c) * P + e(L_d) * Q,
                            e(F1) * gd + e(L_d) * P), dim=-1)
        if sigma is not None:
            grad_b = grad_b * sigma[..., None]
        return grad_a, grad_b, L_t, None


class _Sclerp(_SclerpVJP):
    """:class:`_SclerpVJP` with the forward-mode rule (``torch.func.jvp``, forward AD)."""

    @staticmethod
    def jvp(ctx, ta, tb, tt, _):
        a, b, t = ctx.saved_tensors
        P, Q, R, S, b, c, delta, s, sigma = _frame(a, b, t, ctx.shortest)
        (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = _weights(c, s, True)
        ta = torch.zeros_like(a) if ta is None else ta
        tb = torch.zeros_like(b) if tb is None else tb
        tt = torch.zeros_like(t) if tt is None else tt
        if sigma is not None:
            tb = tb * sigma[..., None]
        tP, tQ, tR, tS = ta[..., :4], ta[..., 4:], tb[..., :4], tb[..., 4:]
        dc = (tP * R + P * tR).sum(-1)
        dd = (tP * S + P * tS + tR * Q + R * tQ).sum(-1)
        dF0, dF1 = -G0 * dc - Fs0 * tt, Fs1 * tt - G1 * dc
        dG0, dG1 = -H0 * dc - Gs0 * tt, Gs1 * tt - H1 * dc
        e = lambda x: x[..., None]  # noqa: E731
        out = e(F0) * ta + e(F1) * tb + e(dF0) * a + e(dF1) * b
        out[..., 4:] -= (e(delta) * (e(G0) * tP + e(G1) * tR + e(dG0) * P + e(dG1) * R)
                         + e(dd) * (e(G0) * P + e(G1) * R))
        return out


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
        theta = 2.0 * torch.atan2(u, v)
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
        e = lambda x: x[..., None]  # noqa: E731
        g_u, g_v, g_d = g_theta * th_u + g_hat * h_u, g_theta * th_v + g_hat * h_v, g_hat * h_d
        # u = |R - P|, v = |R + P|, delta = P.S + R.Q
        grad_P = -e(g_u) * dm_hat + e(g_v) * dp_hat + e(g_d) * S
        grad_R = e(g_u) * dm_hat + e(g_v) * dp_hat + e(g_d) * Q
        return torch.cat((grad_P, e(g_d) * R), -1), torch.cat((grad_R, e(g_d) * P), -1)


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


def sclerp(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Unchecked eq. 11 on broadcast inputs ``a, b (..., 8)``, ``t (...)``."""
    op = _SclerpVJP if torch.compiler.is_compiling() else _Sclerp
    return op.apply(a, b, t, shortest)


def dual_angle(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Unchecked ``(theta, theta_hat)`` of eqs. 4-5 on broadcast inputs (0 in the eq. 6 region)."""
    op = _DualAngleVJP if torch.compiler.is_compiling() else _DualAngle
    return op.apply(a, b)

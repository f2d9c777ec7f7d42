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

from ._numerics import nan_unless

_TERMS = 5  # a_0 .. a_4: truncation error ~ (y / 2) ** 5 for |s| <= 1


def _series_threshold(dtype: torch.dtype) -> float:
    r"""Switch point in :math:`y`: series error :math:`\sqrt y (y/2)^4` (of :math:`\delta G`)
    against the closed form's :math:`\epsilon / \sqrt y`, balanced at :math:`y^5 = 16\epsilon`."""
    return float((16.0 * torch.finfo(dtype).eps) ** (1.0 / _TERMS))


def _horner(coeffs: list[Tensor], y: Tensor) -> Tensor:
    out = coeffs[-1]
    for a in reversed(coeffs[:-1]):
        out = torch.addcmul(a, y, out)
    return out


def _nested(u: list[Tensor], j: int) -> Tensor:
    r""":math:`\partial_y^j F / (j!\,a_j)` as a nested product.

    With :math:`u_k = (k^2 - s^2) y` the recurrence gives
    :math:`\sum_{k \ge j} \frac{k!}{(k-j)!} a_k y^{k-j} = j!\,a_j \big(1 + \frac{j+1}{1}
    r_{j+1} y \big(1 + \frac{j+2}{2} r_{j+2} y (\dots)\big)\big)`,
    :math:`r_k y = u_k / (k (2k + 1))`: one fused multiply-add per term.
    """
    out = None
    for k in range(_TERMS - 1, j, -1):
        scale = 1.0 / ((k - j) * (2 * k + 1))  # (k / (k - j)) / (k (2k + 1))
        out = 1.0 + scale * u[k] if out is None else torch.addcmul(u[0], u[k], out, value=scale)
    return out


def _weights(c: Tensor, t: Tensor, derivatives: bool) -> tuple[Tensor, ...]:
    r"""Interpolation weights at :math:`\cos\theta = c` for ``s = (1 - t, t)``.

    Args:
        c: ``(N,)`` cosines, in ``[-1, 1]`` up to rounding.
        t: ``(N,)`` interpolation parameters.
        derivatives: also return :math:`H, F_s, G_s` (for the gradients).

    Returns:
        ``F, G`` (and ``H, Fs, Gs``), each ``(2, N)``: row 0 for ``a`` (``s = 1 - t``), row 1
        for ``b`` (``s = t``).
    """
    s = torch.stack((1.0 - t, t))
    s2 = s * s
    y = 1.0 - c
    # The series is accurate while y max(1, s^2) is small (its terms scale like (s^2 y)^k).
    small = y * torch.clamp(s2.amax(0), min=1.0) < _series_threshold(c.dtype)

    # Series branch (module docstring): u[k] = (k^2 - s^2) y, u[0] holds ones for addcmul.
    s2ny = s2 * -y
    u = [torch.ones_like(s)] + [torch.add(s2ny, y, alpha=k * k) for k in range(1, _TERMS)]
    a1 = s * (1.0 - s2) / 3.0
    F = s * _nested(u, 0)
    G = a1 * _nested(u, 1)

    # Closed forms on safe inputs: the series elements see theta = pi / 2 instead. Using
    # sin and cos of the same theta makes the endpoints exact (s = 1: F = 1, G = 0). No
    # clamp: c > 1 only occurs in the series branch, and c < -1 (opposite real parts with
    # shortest=False, undefined) or an infinite c must give NaN, not a finite theta = pi.
    theta = torch.acos(torch.where(small, 0.0, c))
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

    # d a_k / ds by differentiating the recurrence a_k = a_{k-1} (k^2 - s^2) / (k (2k + 1)).
    a, da = [s], [torch.ones_like(s)]
    for k in range(1, _TERMS):
        d = k * (2 * k + 1)
        da.append((da[-1] * (k * k - s2) - 2.0 * s * a[-1]) / d)
        a.append(a[-1] * (k * k - s2) / d)
    H = torch.where(small, 0.2 * a1 * (4.0 - s2) * _nested(u, 2),
                    ((1.0 - s2) * F_exact - 3.0 * G_exact * cs) / sin2)
    Fs_exact = theta * cos_st / sin_t
    Fs = torch.where(small, _horner(da, y), Fs_exact)
    Gs = torch.where(small, _horner([k * da[k] for k in range(1, _TERMS)], y),
                     (cos_st - st * sin_st - Fs_exact * cs) / sin2)
    return F, G, H, Fs, Gs


_CHUNK = 65536  # pairs per eager chunk: temporaries stay in cache, ops still use 2 threads
# The fused curve scheme keeps ~m (m + 1) / 2 slabs of 8 rows alive per chunk: smaller chunks
# keep its forward+backward peak memory a small multiple of the output.
_PYRAMID_CHUNK = 8192


def _chunks(n: int, size: int | None = None) -> list[slice]:
    """Slices of the flattened batch evaluated one after the other.

    In eager mode each op of the kernel allocates a fresh temporary; over cache-sized chunks
    those stay in cache and are recycled by the allocator (about 3x faster on CPU for 1e6
    pairs). Under ``torch.compile`` the whole batch is one graph.
    """
    size = _CHUNK if size is None else size
    if torch.compiler.is_compiling() or n <= size:
        return [slice(None)]
    return [slice(i, i + size) for i in range(0, n, size)]


def _rows(x: Tensor) -> Tensor:
    """``(N, k)`` -> contiguous ``(k, N)`` component rows.

    The kernels below work on such rows, ``(..., 8, N)``: every elementwise op then runs over
    contiguous length-N rows and every dot product is a sum of rows, instead of broadcasting
    over a trailing dim of 4 or 8 (several times slower on CPU). The copy goes through a
    3-d permutation, which torch's CPU copy runs 2-3x faster than a 2-d transpose.
    """
    return x.unsqueeze(-1).permute(1, 2, 0).contiguous().squeeze(1)


def _unrows(x: Tensor) -> Tensor:
    """Inverse of :func:`_rows`: ``(k, N)`` rows -> contiguous ``(N, k)``."""
    return x.unsqueeze(1).permute(2, 0, 1).contiguous().squeeze(-1)


def _u(x: Tensor) -> Tensor:
    """An ``(..., N)`` coefficient broadcast over the component axis of ``(..., k, N)`` rows."""
    return x.unsqueeze(-2)


def _frame(A: Tensor, B: Tensor, shortest: bool):
    """Halves, cosine ``c``, dual dot ``delta`` and sign of pairs of ``(..., 8, N)`` rows.

    ``B`` is *not* sign-aligned: the sign ``sigma`` (all ones when not ``shortest``) is folded
    into the N-sized coefficients instead, saving a pass over ``B``; ``c`` and ``delta`` are
    those of the sign-aligned pair.
    """
    P, Q, R, S = A[..., :4, :], A[..., 4:, :], B[..., :4, :], B[..., 4:, :]
    c = (P * R).sum(-2)
    sigma = torch.where(c < 0, -1.0, 1.0).to(c.dtype) if shortest else torch.ones_like(c)
    delta = sigma * ((P * S).sum(-2) + (R * Q).sum(-2))
    return P, Q, R, S, sigma * c, delta, sigma


def _forward(A: Tensor, B: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Eq. 11 on ``(..., 8, N)`` rows and ``(..., N)`` parameters."""
    P, _, R, _, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1) = _weights(c, t, derivatives=False)
    out = torch.addcmul(_u(F0) * A, _u(sigma * F1), B)
    out[..., 4:, :] -= torch.addcmul(_u(delta * G0) * P, _u(delta * sigma * G1), R)
    return out


def _backward(A: Tensor, B: Tensor, t: Tensor, grad: Tensor, shortest: bool):
    """Vector-Jacobian product of :func:`_forward`: rows of ``a`` and ``b``, and ``t``.

    Written for the sign-aligned ``b' = sigma b`` (``R, S`` below), then mapped back.
    """
    P, Q, R, S, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = _weights(c, t, True)
    R, S = _u(sigma) * R, _u(sigma) * S
    gr, gd = grad[..., :4, :], grad[..., 4:, :]
    pa, pb = (grad * A).sum(-2), sigma * (grad * B).sum(-2)
    gP, gR = (gd * P).sum(-2), (gd * R).sum(-2)
    # Sensitivities to c = P.R, delta = P.S + R.Q and t (module docstring).
    L_c = delta * (H0 * gP + H1 * gR) - G0 * pa - G1 * pb
    L_d = -(G0 * gP + G1 * gR)
    L_t = Fs1 * pb - Fs0 * pa + delta * (Gs0 * gP - Gs1 * gR)
    F0, F1, L_c, L_d = _u(F0), _u(F1), _u(L_c), _u(L_d)
    grad_a = torch.cat((F0 * gr - _u(delta * G0) * gd + L_c * R + L_d * S, F0 * gd + L_d * R), -2)
    grad_b = torch.cat((F1 * gr - _u(delta * G1) * gd + L_c * P + L_d * Q, F1 * gd + L_d * P), -2)
    return grad_a, _u(sigma) * grad_b, L_t


def _jvp(A, B, t, TA, TB, tt, shortest: bool) -> Tensor:
    """Jacobian-vector product of :func:`_forward` (tangents of the same shapes)."""
    P, Q, R, S, c, delta, sigma = _frame(A, B, shortest)
    (F0, F1), (G0, G1), (H0, H1), (Fs0, Fs1), (Gs0, Gs1) = _weights(c, t, True)
    B, R, S, TB = _u(sigma) * B, _u(sigma) * R, _u(sigma) * S, _u(sigma) * TB
    tP, tQ, tR, tS = TA[..., :4, :], TA[..., 4:, :], TB[..., :4, :], TB[..., 4:, :]
    dc = (tP * R + P * tR).sum(-2)
    dd = (tP * S + P * tS + tR * Q + R * tQ).sum(-2)
    dF0, dF1 = -G0 * dc - Fs0 * tt, Fs1 * tt - G1 * dc
    dG0, dG1 = -H0 * dc - Gs0 * tt, Gs1 * tt - H1 * dc
    out = _u(F0) * TA + _u(F1) * TB + _u(dF0) * A + _u(dF1) * B
    out[..., 4:, :] -= (_u(delta) * (_u(G0) * tP + _u(G1) * tR + _u(dG0) * P + _u(dG1) * R)
                        + _u(dd) * (_u(G0) * P + _u(G1) * R))
    return out


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
        a2, b2, t1 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1)
        parts = [_unrows(_forward(_rows(a2[i]), _rows(b2[i]), t1[i], shortest))
                 for i in _chunks(len(t1))]
        return torch.cat(parts).view(a.shape)

    @staticmethod
    def setup_context(ctx, inputs, output):
        a, b, t, shortest = inputs
        ctx.save_for_backward(a, b, t)
        ctx.save_for_forward(a, b, t)
        ctx.shortest = shortest

    @staticmethod
    def backward(ctx, grad):
        a, b, t = ctx.saved_tensors
        a2, b2, t1, g2 = a.reshape(-1, 8), b.reshape(-1, 8), t.reshape(-1), grad.reshape(-1, 8)
        parts = [_backward(_rows(a2[i]), _rows(b2[i]), t1[i], _rows(g2[i]), ctx.shortest)
                 for i in _chunks(len(t1))]
        ga, gb, gt = (torch.cat(p, dim=-1) for p in zip(*parts, strict=True))
        return _unrows(ga).view(a.shape), _unrows(gb).view(b.shape), gt.view(t.shape), None


class _Sclerp(_SclerpVJP):
    """:class:`_SclerpVJP` with the forward-mode rule (``torch.func.jvp``, forward AD)."""

    @staticmethod
    def jvp(ctx, ta, tb, tt, _):
        a, b, t = ctx.saved_tensors
        ta = torch.zeros_like(a) if ta is None else ta
        tb = torch.zeros_like(b) if tb is None else tb
        tt = torch.zeros_like(t) if tt is None else tt
        A, B, TA, TB = (_rows(x.reshape(-1, 8)) for x in (a, b, ta, tb))
        out = _jvp(A, B, t.reshape(-1), TA, TB, tt.reshape(-1), ctx.shortest)
        return _unrows(out).view(a.shape)


def _gather(rows: Tensor, idx: Tensor) -> Tensor:
    """Control-point rows ``(8, M)`` gathered straight into level 0, ``(m, 8, n)``."""
    m, n = idx.shape
    return rows.index_select(1, idx.reshape(-1)).view(8, m, n).transpose(0, 1)


def _pyramid_levels(rows: Tensor, idx: Tensor, alphas: tuple[Tensor, ...]) -> list[Tensor]:
    """All levels of the triangular scheme for one chunk, each ``(m - j, 8, n)``."""
    levels = [_gather(rows, idx)]
    for alpha in alphas:
        D = levels[-1]
        levels.append(_forward(D[:-1], D[1:], alpha, True))
    return levels


class _PyramidVJP(torch.autograd.Function):
    r"""The triangular scheme of De Casteljau and De Boor, fused (paper section 4).

    Level 0 holds ``m`` control points per output, ``ctrl[idx[i, k]]``; level ``j`` holds
    :math:`d^{(j)}_i = \mathrm{sclerp}(d^{(j-1)}_i, d^{(j-1)}_{i+1}, \alpha_j[i])`
    (shortest path), and the output is the single point of level ``m - 1``.

    Inputs: ``ctrl (M, 8)``, ``idx (m, N)`` int64, and ``m - 1`` tensors
    ``alpha_j (m - j, N)``. Output ``(N, 8)``. All levels run in component-row layout over
    cache-sized chunks of ``N``; the backward recomputes them chunk by chunk, so nothing but
    the (small) inputs is saved: fused memory is O(output) instead of O(m^2 output).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(ctrl: Tensor, idx: Tensor, *alphas: Tensor) -> Tensor:
        rows = _rows(ctrl)
        parts = [_unrows(_pyramid_levels(rows, idx[:, i], tuple(a[:, i] for a in alphas))[-1][0])
                 for i in _chunks(idx.shape[1], _PYRAMID_CHUNK)]
        return torch.cat(parts)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)
        ctx.save_for_forward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        ctrl, idx, *alphas = ctx.saved_tensors
        rows = _rows(ctrl)
        grad_rows = torch.zeros_like(rows)
        grad_alphas = [[] for _ in alphas]
        for i in _chunks(idx.shape[1], _PYRAMID_CHUNK):
            chunk_alphas = tuple(a[:, i] for a in alphas)
            levels = _pyramid_levels(rows, idx[:, i], chunk_alphas)
            G = _rows(grad[i]).unsqueeze(0)
            for j in range(len(alphas), 0, -1):
                D = levels[j - 1]
                gA, gB, g_alpha = _backward(D[:-1], D[1:], chunk_alphas[j - 1], G, True)
                grad_alphas[j - 1].append(g_alpha)
                # d_i^(j-1) feeds d_(i-1)^(j) as b and d_i^(j) as a
                zero = torch.zeros_like(gA[:1])
                G = torch.cat((gA, zero)) + torch.cat((zero, gB))
            grad_rows = grad_rows.index_add(1, idx[:, i].reshape(-1),
                                            G.transpose(0, 1).reshape(8, -1))
        return (_unrows(grad_rows), None, *(torch.cat(g, dim=-1) for g in grad_alphas))


class _Pyramid(_PyramidVJP):
    """:class:`_PyramidVJP` with the forward-mode rule."""

    @staticmethod
    def jvp(ctx, t_ctrl, _, *t_alphas):
        ctrl, idx, *alphas = ctx.saved_tensors
        t_ctrl = torch.zeros_like(ctrl) if t_ctrl is None else t_ctrl
        D, TD = _gather(_rows(ctrl), idx), _gather(_rows(t_ctrl), idx)
        for alpha, t_alpha in zip(alphas, t_alphas, strict=True):
            t_alpha = torch.zeros_like(alpha) if t_alpha is None else t_alpha
            D, TD = (_forward(D[:-1], D[1:], alpha, True),
                     _jvp(D[:-1], D[1:], alpha, TD[:-1], TD[1:], t_alpha, True))
        return _unrows(TD[0])


def pyramid(ctrl: Tensor, idx: Tensor, alphas: list[Tensor]) -> Tensor:
    """Unchecked fused De Casteljau / De Boor scheme (:class:`_PyramidVJP`), ``(N, 8)``."""
    op = _PyramidVJP if torch.compiler.is_compiling() else _Pyramid
    return op.apply(ctrl, idx, *alphas)


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


def sclerp(a: Tensor, b: Tensor, t: Tensor, shortest: bool) -> Tensor:
    """Unchecked eq. 11 on broadcast inputs ``a, b (..., 8)``, ``t (...)``."""
    op = _SclerpVJP if torch.compiler.is_compiling() else _Sclerp
    return op.apply(a, b, t, shortest)


def dual_angle(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
    """Unchecked ``(theta, theta_hat)`` of eqs. 4-5 on broadcast inputs (0 in the eq. 6 region)."""
    op = _DualAngleVJP if torch.compiler.is_compiling() else _DualAngle
    return op.apply(a, b)

r"""Exact per-sample Jacobians of a curve layer from its spans (reverse mode).

A pose of a degree-``p`` B-spline at ``t`` in the knot span ``[u_r, u_{r+1})`` depends on
the control points ``r - p .. r`` and the knots ``u_{r-p+1} .. u_{r+p}`` only: it is the
value of a one-span B-spline (``p + 1`` control points, knots ``u_{r-p} .. u_{r+p+1}``
shifted to ``u_r = 0``, the same ``form``) at ``t - u_r``. Giving every sample its own copy
of its span's control points, moved by its own local step ``c_j exp(delta_{i,j})``, makes
the samples independent: reverse passes over all samples at once give every sample's
Jacobian with respect to its span's steps, exactly (:class:`SpanEvaluator` evaluates all
samples as one batch of one-span curves, each with its own span's knots; per-trajectory
knots give each trajectory's spans their own). A Bézier curve is its own one-span curve
(every pose depends on every control point).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from .. import curves, dualquat

__all__ = ["SpanEvaluator"]

_COPY_ELEMENTS = 1 << 21  # leaf elements times copies above which rows are separate passes


class SpanEvaluator:
    """Span structure of a curve layer (B-spline or Bézier) and per-sample evaluation.

    Reads the layer's time model (:class:`torch_dq._time.KnotDomain`): knots ``(K,)``
    shared by every trajectory, or ``(..., K)`` with per-trajectory origins (each
    trajectory's spans with their own knots). Span ids: ``row (n - p) + first``. Every
    sample is evaluated as a one-span curve with its span's knots (shifted to ``u_r = 0``),
    all samples in one call whatever their spans.

    Args:
        trajectory: a :class:`torch_dq.nn.BSpline` or :class:`torch_dq.nn.Bezier`.

    Attributes:
        n: number of control points; support: control points per span (``p + 1`` or ``n``).
    """

    def __init__(self, trajectory) -> None:
        from ..nn import BSpline
        self.domain = dom = trajectory.time_model
        self.n, p = dom.n, dom.degree
        self.bspline = isinstance(trajectory, BSpline)
        self.form = getattr(trajectory, "form", "de_boor")
        self.support = p + 1
        self.device = trajectory.control_points.device
        K = dom.knots.detach().to(torch.float64)
        self.rows = torch.arange(K[..., 0].numel(), device=K.device).reshape(K.shape[:-1])
        K = K.reshape(-1, K.shape[-1])
        origin = torch.as_tensor(dom.origin, dtype=torch.float64, device=K.device)
        self.origin = origin.reshape(-1).expand(K.shape[0])  # per row
        win = K.unfold(-1, 2 * p + 2, 1)  # (rows, n - p, 2 p + 2): span r = p + first
        self.start = win[..., p].reshape(-1)  # u_r relative to its row's origin
        self.knots = win.reshape(-1, 2 * p + 2) - self.start[:, None]  # per span id
        self.length = self.knots[:, p + 1]

    def first(self, t: Tensor) -> Tensor:
        """First control point ``(..., T)`` int64 of the span of each time ``t (..., T)``
        (batched knots broadcast into the leading dims)."""
        if not self.bspline:
            return torch.zeros(t.shape, dtype=torch.int64, device=t.device)
        dom = self.domain
        return dom.span(dom.relative(t.detach(), torch.float64)) - dom.degree

    def derivatives(self, points: Tensor, t: Tensor, first: Tensor, order: int,
                    ) -> tuple[Tensor, ...]:
        """Derivatives ``order + 1`` x ``(..., 8)`` at ``t (...)`` of the span whose control
        points are ``points (..., support, 8)`` and first index ``first``.

        ``first``'s shape (from :meth:`first`) is the samples' shape: the trailing dims of
        ``points.shape[:-2]``; leading dims beyond it (copies, a shared batch) are evaluated
        with the same spans. ``t`` broadcasts against ``points.shape[:-2]``.
        """
        lead = points.shape[:-2]
        first = first.expand(lead[len(lead) - first.dim():])
        S = first.numel()
        pts = points.reshape(-1, S, self.support, 8)
        row = self.rows[..., None].expand(first.shape).reshape(-1)
        sid = row * (self.n - self.support + 1) + first.reshape(-1)
        local = t.expand(lead).reshape(-1, S).to(torch.float64) - (
            self.origin[row] + self.start[sid])
        local = torch.minimum(local.clamp_min(0.0), self.length[sid])  # rounding
        ctrl, tt = pts.reshape(-1, self.support, 8), local.reshape(-1, 1)
        if self.bspline:
            knots = self.knots[sid].expand(pts.shape[0], S, self.knots.shape[-1])
            kw = dict(degree=self.support - 1, knots=knots.reshape(-1, knots.shape[-1]),
                      check=False, extrapolate=True, form=self.form)
            out = ((curves.bspline(ctrl, tt, **kw),) if order == 0 else
                   curves.bspline_derivatives(ctrl, tt, order=order, **kw))
        else:
            kw = dict(domain=(0.0, float(self.length[0])), check=False, extrapolate=True)
            out = ((curves.bezier(ctrl, tt, **kw),) if order == 0 else
                   curves.bezier_derivatives(ctrl, tt, order=order, **kw))
        return tuple(d.reshape(*lead, 8) for d in out)


def tangent_step(points: Tensor, delta: Tensor) -> Tensor:
    r"""``points exp(delta)`` to first order in ``delta``: :math:`c + c\,(0, \omega/2, 0,
    v/2)` (the derivative of the rigid-motion exponential at zero), for Jacobians at
    ``delta = 0`` (exact there; cheaper than the exponential)."""
    zero = delta.new_zeros(*delta.shape[:-1], 1)
    lin = torch.cat((zero, 0.5 * delta[..., :3], zero, 0.5 * delta[..., 3:]), dim=-1)
    return points + dualquat.mul(points, lin)


def sample_jacobians(residual: Callable[[list[Tensor]], Tensor], leaves: list[Tensor],
                     k: int) -> tuple[Tensor, list[Tensor]]:
    r"""Residuals and their per-sample Jacobians by one reverse pass over ``k`` copies.

    Copy ``j`` of every leaf (a leading dim of size ``k``) feeds residual component ``j``
    only, so one backward pass of :math:`\sum_j r^{(j)}_{\cdot j}` gives all ``k`` rows
    (one batched evaluation instead of ``k`` passes with their per-call overheads).

    Args:
        residual: maps the leaves (each ``(k, ..., N, *event)``, copies of their values) to
            ``(k, ..., N, k)`` residuals, sample ``i`` depending on the leaves' sample ``i`` only.
        leaves: the per-sample inputs, ``(..., N, *event_j)`` (the residuals' sample
            shape, then any event shape).
        k: residual size.

    Returns:
        ``r (..., N, k)`` (detached) and per leaf ``(..., N, k, *event_j)``.
    """
    copies = k if leaves[0].numel() * k <= _COPY_ELEMENTS else 1
    with torch.enable_grad():
        lv = [x.detach().expand(copies, *x.shape).clone().requires_grad_() for x in leaves]
        r = residual(lv)
        if copies == k:  # one pass: copy j feeds component j
            picked = torch.stack([r[j, ..., j].sum() for j in range(k)]).sum()
            grads = torch.autograd.grad(picked, lv, allow_unused=True)
            rows = [[torch.zeros_like(x) if g is None else g for g, x in zip(grads, lv,
                                                                             strict=True)]]
        else:  # large inputs: k passes over one copy (its temporaries stay smaller)
            rows = []
            for j in range(k):
                grads = torch.autograd.grad(r[0, ..., j].sum(), lv, allow_unused=True,
                                            retain_graph=j < k - 1)
                rows.append([torch.zeros_like(x) if g is None else g
                             for g, x in zip(grads, lv, strict=True)])
    out = []
    for i in range(len(lv)):
        g = rows[0][i] if copies == k else torch.cat([row[i] for row in rows])
        out.append(g.movedim(0, r.dim() - 2))  # after the sample dims, before the event
    return r[0].detach(), out

r"""Exact per-sample Jacobians of a curve layer from its spans (reverse mode).

A pose of a degree-``p`` B-spline at ``t`` in the knot span ``[u_r, u_{r+1})`` depends on
the control points ``r - p .. r`` and the knots ``u_{r-p+1} .. u_{r+p}`` only: it is the
value of a one-span B-spline layer (``p + 1`` control points, knots
``u_{r-p} .. u_{r+p+1}`` shifted to ``u_r = 0``, the same ``form``) at ``t - u_r``. Giving
every sample its own copy of its span's control points, moved by its own local step
``c_j exp(delta_{i,j})``, makes the samples independent: ``k`` reverse passes (one per
residual component) give every sample's Jacobian with respect to its span's steps, exactly,
through the layer's public ``derivatives(t, order, ctrl=...)``. Spans with the same knot
pattern (to 1e-9 of the span, e.g. every interior span of uniform knots) share one layer;
a span's time is mapped onto its layer's span and the derivatives scaled back. A Bézier
curve is its own one-span layer (every pose depends on every control point).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from .. import dualquat

__all__ = ["SpanEvaluator"]

_COPY_ELEMENTS = 1 << 21  # leaf elements times copies above which rows are separate passes


class SpanEvaluator:
    """Span structure of a curve layer (B-spline or Bézier) and per-sample evaluation.

    Args:
        trajectory: a :class:`torch_dq.nn.BSpline` or :class:`torch_dq.nn.Bezier`.

    Attributes:
        n: number of control points; support: control points per span (``p + 1`` or ``n``).
    """

    def __init__(self, trajectory) -> None:
        from ..nn import BSpline
        self.trajectory = trajectory
        self.n = trajectory.n_ctrl
        self.bspline = isinstance(trajectory, BSpline)
        self.device = trajectory.control_points.device
        if not self.bspline:
            self.support = self.n
            return
        p = trajectory.degree
        self.support = p + 1
        K = trajectory.knots.detach().to(torch.float64).cpu()
        K = K - K[p]
        spans = torch.arange(self.n - p) + p  # r = p .. n - 1
        pattern = torch.stack([K[r - p:r + p + 2] - K[r] for r in spans.tolist()])
        h = (K[spans + 1] - K[spans])[:, None]
        key = torch.round(pattern / torch.where(h > 0, h, 1.0) * 1e9)
        uniq, group = torch.unique(key, dim=0, return_inverse=True)
        rep = [int((group == g).nonzero()[0]) for g in range(uniq.shape[0])]
        form = getattr(trajectory, "form", "de_boor")
        like = trajectory.control_points.detach()
        self.layers = [BSpline(dualquat.identity((p + 1,), dtype=torch.float64,
                                              device=like.device),
                            degree=p, knots=pattern[j].to(like.device), form=form)
                       for j in rep]
        dev = like.device
        self.group = group.to(dev)  # per span r - p
        self.scale = (h[rep][group, 0] / h[:, 0]).to(dev)  # rep span length / own
        self.start = (K[spans] + 0.0).to(dev)  # u_r relative to u_p
        self.length = h[rep, 0].to(dev)  # span length of each group's layer
        self.origin = float(trajectory.knots[p])

    def first(self, t: Tensor) -> Tensor:
        """First control point ``(...)`` int64 of the span of each time ``t (...)``."""
        if not self.bspline:
            return torch.zeros(t.shape, dtype=torch.int64, device=t.device)
        first, _ = self.trajectory.basis(t.detach().reshape(-1))
        return first.reshape(t.shape).to(t.device)

    def derivatives(self, points: Tensor, t: Tensor, first: Tensor, order: int,
                    ) -> tuple[Tensor, ...]:
        """Derivatives ``order + 1`` x ``(..., 8)`` at ``t (...)`` of the span whose control
        points are ``points (..., support, 8)`` and first index ``first (...)``."""
        shape = points.shape[:-2]
        pts = points.reshape(-1, self.support, 8)
        tt = t.expand(shape).reshape(-1)
        first = first.expand(shape)
        if not self.bspline:
            out = _evaluate(self.trajectory, tt[:, None], order, pts)
            return tuple(o[:, 0].reshape(*shape, 8) for o in out)
        f = first.reshape(-1)
        g = self.group[f]
        s = self.scale[f].to(tt.dtype)
        local = (tt - self.origin - self.start[f].to(tt.dtype)) * s
        local = torch.minimum(local.clamp_min(0.0), self.length[g].to(tt.dtype))  # rounding
        perm = torch.argsort(g)
        counts = torch.bincount(g, minlength=len(self.layers)).tolist()
        outs, pos = [], 0
        for j, c in enumerate(counts):
            if c:
                idx = perm[pos:pos + c]
                outs.append(_evaluate(self.layers[j], local[idx][:, None], order, pts[idx]))
                pos += c
        inv = torch.empty_like(perm)
        inv[perm] = torch.arange(perm.shape[0], device=perm.device)
        res = []
        for k in range(order + 1):
            d = torch.cat([o[k][:, 0] for o in outs])[inv]
            res.append((d * (s[:, None] ** k).to(d.dtype)).reshape(*shape, 8))
        return tuple(res)


def tangent_step(points: Tensor, delta: Tensor) -> Tensor:
    r"""``points exp(delta)`` to first order in ``delta``: :math:`c + c\,(0, \omega/2, 0,
    v/2)` (the derivative of the rigid-motion exponential at zero), for Jacobians at
    ``delta = 0`` (exact there; cheaper than the exponential)."""
    zero = delta.new_zeros(*delta.shape[:-1], 1)
    lin = torch.cat((zero, 0.5 * delta[..., :3], zero, 0.5 * delta[..., 3:]), dim=-1)
    return points + dualquat.mul(points, lin)


def _evaluate(layer, t: Tensor, order: int, ctrl: Tensor) -> tuple[Tensor, ...]:
    """``layer.derivatives`` (poses alone through ``forward``: the fused pose kernel)."""
    if order == 0:
        return (layer(t, ctrl=ctrl),)
    return layer.derivatives(t, order, ctrl=ctrl)


def sample_jacobians(residual: Callable[[list[Tensor]], Tensor], leaves: list[Tensor],
                     k: int) -> tuple[Tensor, list[Tensor]]:
    r"""Residuals and their per-sample Jacobians by one reverse pass over ``k`` copies.

    Copy ``j`` of every leaf (a leading dim of size ``k``) feeds residual component ``j``
    only, so one backward pass of :math:`\sum_j r^{(j)}_{\cdot j}` gives all ``k`` rows
    (one batched evaluation instead of ``k`` passes with their per-call overheads).

    Args:
        residual: maps the leaves (each ``(k, ..., N, *event)``, zero) to ``(k, ..., N, k)``
            residuals, sample ``i`` depending on the leaves' sample ``i`` only.
        leaves: the per-sample steps, ``(..., N, *event_j)``; the first has a 2-d event
            ``(w, 6)`` (a window of control points), the others a 1-d one.
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
        out.append(g.movedim(0, -3 if i == 0 else -2))
    return r[0].detach(), out

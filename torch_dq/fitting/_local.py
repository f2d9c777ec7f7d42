r"""Exact per-sample Jacobians of a curve layer from its spans (reverse mode).

Through the span contract of :class:`torch_dq.nn.Curve` and nothing else: the pose at ``t``
depends on the :attr:`~torch_dq.nn.Curve.span_size` control points from
:meth:`~torch_dq.nn.Curve.support` on, through :meth:`~torch_dq.nn.Curve.evaluate_span` at
the local time :meth:`~torch_dq.nn.Curve.local_times` (for a degree-``p`` B-spline: a
one-span B-spline with its span's knots; a Bézier curve is its own span). Giving every
sample its own copy of its span's control points, moved by its own local step
``c_j exp(delta_{i,j})``, makes the samples independent: reverse passes over all samples at
once give every sample's Jacobian with respect to its span's steps, exactly
(:class:`SpanEvaluator` evaluates all samples as one batch of one-span curves).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from .. import _checks, dualquat

__all__ = ["SpanEvaluator"]

_COPY_ELEMENTS = 1 << 21  # leaf elements times copies above which rows are separate passes


class SpanEvaluator:
    """Span structure of a curve layer and per-sample evaluation, through its contract.

    Args:
        trajectory: a :class:`torch_dq.nn.Curve`.

    Attributes:
        n: number of control points; support: control points per span
            (:attr:`~torch_dq.nn.Curve.span_size`); device: the control points' device;
        memo: what the layer keeps between the evaluator's calls (its ``memo``: the bases of
            the samples' times, computed once per estimate, not once per system and cost).
    """

    def __init__(self, trajectory) -> None:
        self.trajectory = trajectory
        self.n, self.support = trajectory.n_ctrl, trajectory.span_size
        self.device = trajectory.control_points.device
        self.memo: dict = {}

    def since_origin(self, t: Tensor, shift: Tensor | float = 0.0) -> Tensor:
        r"""The samples' times ``t (..., N)`` moved by ``shift`` (``(..., N)`` or
        broadcastable), as times since the trajectory's origin: float64 ``(t - origin) +
        shift``, the times every other method takes. At UNIX-time stamps (``~1.7e9`` s)
        ``t + shift`` would round to ``2.4e-7`` s, a staircase cost in a clock offset; the
        difference from the origin is exact there."""
        rel = self.trajectory.time_model.relative(t, torch.float64)
        return rel + shift if isinstance(shift, Tensor) or shift else rel

    def first(self, t: Tensor) -> Tensor:
        """First control point ``(..., T)`` int64 of the span of each time ``t (..., T)``
        (:meth:`since_origin`; batched knots broadcast into the leading dims)."""
        return self.trajectory.support(t, since_origin=True)[0]

    def derivatives(self, points: Tensor, t: Tensor, first: Tensor, order: int,
                    ) -> tuple[Tensor, ...]:
        """Derivatives ``order + 1`` x ``(..., 8)`` at ``t (...)`` of the span whose control
        points are ``points (..., support, 8)`` and first index ``first``.

        ``first``'s shape (from :meth:`first`) is the samples' shape: the trailing dims of
        ``points.shape[:-2]``; leading dims beyond it (copies, a shared batch) are evaluated
        with the same spans. ``t`` broadcasts against ``points.shape[:-2]``.
        """
        local = self.trajectory.local_times(t, first, True)
        return self.trajectory.evaluate_span(points, local, first, order)

    def vjp(self, points: Tensor, t: Tensor, first: Tensor, cotangents: Tensor, pose: Tensor,
            second: slice | None = None, tables: Tensor | None = None) -> Tensor | None:
        """The layer's closed-form :meth:`~torch_dq.nn.Curve.span_vjp` at ``t`` of the spans
        ``first`` with points ``points (..., support, 8)`` and poses ``pose (..., 8)``:
        ``(..., k, support, 6)`` from ``cotangents (..., k, O, 8)`` (of the second order
        the rows ``second`` may be nonzero, None: all; ``tables``: :meth:`tables` of the
        control points the spans are of, None: from ``points``), or None (no closed form:
        reverse passes)."""
        local = self.trajectory.local_times(t, first, True)
        return self.trajectory.span_vjp(points, local, first, cotangents, pose, second, tables,
                                        memo=self.memo)

    def tables(self, ctrl: Tensor) -> Tensor | None:
        """The layer's :meth:`~torch_dq.nn.Curve.span_vjp_tables` of the control points
        ``ctrl (..., n, 8)``: what :meth:`vjp` computes per span, once for every call at
        these points (None where the layer has none)."""
        return self.trajectory.span_vjp_tables(ctrl)

    def shared(self, ctrl: Tensor, t: Tensor, first: Tensor, order: int,
               ) -> tuple[Tensor, ...]:
        """Derivatives ``order + 1`` x ``(..., 8)`` at ``t (..., N)`` of the spans ``first``,
        every sample reading the shared control points ``ctrl (..., n, 8)``
        (:meth:`~torch_dq.nn.Curve.span_derivatives`): the costs and the linearisation
        points, without per-sample copies."""
        traj = self.trajectory
        return traj.span_derivatives(ctrl, traj.local_times(t, first, True), first, order,
                                     memo=self.memo)

    def time_rate(self, t: Tensor, first: Tensor) -> Tensor:
        r"""``d local / d t`` ``(...)`` of :meth:`~torch_dq.nn.Curve.local_times` at ``t``
        (``t``'s and ``first``'s broadcast shape): 1 inside a span, 0 where the local time is
        clamped, what reverse mode gives at a clamp's edge.

        The span derivatives' Jacobian with respect to a sample's time is then the next
        derivative times this rate (:meth:`derivatives` are time derivatives of the
        contract), with no time in an autograd graph of the span.
        """
        shift = t.detach().new_zeros(_checks.broadcast_shapes(t.shape, first.shape))
        with torch.enable_grad():
            shift.requires_grad_()
            local = self.trajectory.local_times(t.detach() + shift, first, True)
            return torch.autograd.grad(local.sum(), shift)[0]


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

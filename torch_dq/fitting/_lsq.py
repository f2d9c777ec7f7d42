r"""The least-squares start of the curve layers and the argument checks they share
(moving to :mod:`torch_dq._start`): :func:`check_times`, :func:`check_determined`,
:func:`bspline_basis`, :func:`least_squares_start`."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from .. import _checks, dualquat
from .._core import align_chain, knot_span, twist_translation

__all__ = ["bspline_basis", "check_determined", "check_times", "least_squares_start"]

_MAX_WINDOW_ELEMENTS = 1 << 22  # bound on (windows x samples x unknowns) per chunk
_START_PRIOR = 1e-3  # pull of the windowed least squares towards the anchors (see below)

# ----------------------------------------------------------------------------- checks

def check_times(fn: str, times: Tensor, n: int | None = None) -> Tensor:
    """Check ``(N,)`` finite strictly increasing times (``N >= 2``, ``N == n`` if given).

    Returns:
        ``times`` unchanged.
    """
    _checks.tensor(fn, "times", times)
    if times.dim() != 1:
        _checks.fail(fn, f"expected a 1-D (N,) tensor for times, got shape "
                         f"{_checks.shape_str(times.shape)}")
    if n is not None and times.shape[0] != n:
        _checks.fail(fn, f"times must hold one time per pose: expected shape ({n},) for the "
                         f"N = {n} poses, got shape {_checks.shape_str(times.shape)}")
    if times.shape[0] < 2:
        _checks.fail(fn, f"at least 2 timestamped poses are needed, got N = {times.shape[0]}")
    tt = times.detach()
    bad = torch.stack((~torch.isfinite(tt).all(), (tt[1:] <= tt[:-1]).any())).tolist()
    if bad[0]:
        _checks.fail(fn, "times must be finite")
    if bad[1]:
        hint = ""
        if times.dtype != torch.float64:  # absolute timestamps collapse in float32
            ulp = float(tt.abs().max()) * torch.finfo(times.dtype).eps
            hint = (f" ({times.dtype} rounds these times to steps of {ulp:.3g}; pass absolute "
                    f"timestamps such as UNIX seconds as float64)")
        _checks.fail(fn, "times must be strictly increasing" + hint)
    return times


def check_determined(fn: str, first: Tensor, values: Tensor, n: int,
                     knots: Tensor | None = None) -> None:
    r"""Raise ``ValueError`` unless the least-squares problem on the basis is well posed.

    Schoenberg-Whitney: the ``(N, n)`` design matrix of samples ``i`` (sorted by time)
    with basis values ``values[i, j]`` at control points ``first[i] + j`` has full column
    rank iff there are samples :math:`i_0 < i_1 < \dots < i_{n-1}` with a non-zero basis
    value of control point ``k`` at :math:`i_k`; found greedily in :math:`O(N + n)`.

    Args:
        fn: public name of the caller, for the message.
        first: ``(N,)`` non-decreasing int64 first control point of each sample's support.
        values: ``(N, w)`` basis values (see ``BSpline.basis``).
        n: number of control points.
        knots: optional ``(n + w,)`` knots in the caller's units, to name the support of a
            control point in the message.
    """
    N, w = values.shape
    if n > N:
        _checks.fail(fn, f"the fit is underdetermined: {n} control points for N = {N} "
                         f"samples; use at most {N} control points")
    first_l = first.tolist()
    positive = (values > 1e-12).tolist()
    ks = torch.arange(n, device=first.device)
    lo = torch.searchsorted(first, ks - (w - 1), right=False).tolist()
    hi = torch.searchsorted(first, ks, right=True).tolist()
    ptr = 0
    for k in range(n):
        i = max(ptr, lo[k])
        while i < hi[k] and not positive[i][k - first_l[i]]:
            i += 1
        if i >= hi[k]:
            where = ""
            if knots is not None:
                where = (f" [knots[{k}], knots[{k + w}]] = [{float(knots[k])!r}, "
                         f"{float(knots[k + w])!r}]")
            _checks.fail(fn, f"the fit is underdetermined: control point {k} has no sample of "
                             f"its own in its support{where} (Schoenberg-Whitney condition: "
                             f"the samples must interlace the control points' supports); use "
                             f"fewer control points or add samples there")
        ptr = i + 1


# ----------------------------------------------------------------------------- bases

def bspline_basis(t: Tensor, knots: Tensor, degree: int) -> tuple[Tensor, Tensor]:
    r"""Euclidean B-spline basis functions at ``t``, local form (Cox-de Boor).

    For ``t`` in the span :math:`[u_r, u_{r+1})` (the last non-empty span at the right end
    of the domain; the span search of De Boor's scheme), the ``degree + 1`` functions
    :math:`N_{r-p..r,\,p}(t)` that can be non-zero there (Piegl and Tiller, *The NURBS
    Book*, A2.2).

    Args:
        t: ``(T,)`` times in ``[knots[degree], knots[n]]``.
        knots: ``(n + degree + 1,)`` non-decreasing knots, ``t``'s dtype and device.
        degree: ``p >= 1``.

    Returns:
        ``(first, values)``: ``first = r - p`` ``(T,)`` int64 (the first control point the
        time depends on) and ``values`` ``(T, p + 1)``, non-negative, summing to 1.
    """
    p = degree
    r = knot_span(knots, t, p)
    values = torch.ones_like(t)[:, None]
    for j in range(1, p + 1):
        # N_{r-j..r, j} from N_{r-j+1..r, j-1} (A2.2's saved-term recursion)
        new = torch.zeros(t.shape[0], j + 1, dtype=t.dtype, device=t.device)
        for m in range(j):
            lm = t - knots[r - j + 1 + m]  # t - u_{r-j+1+m}
            rm = knots[r + 1 + m] - t  # u_{r+1+m} - t
            denom = rm + lm
            temp = values[:, m] / torch.where(denom > 0, denom, 1.0)
            new[:, m] = new[:, m] + rm * temp
            new[:, m + 1] = lm * temp
        values = new
    return r - p, values


# ----------------------------------------------------------------------------- start

def _chart_twists(ref: Tensor, x: Tensor) -> Tensor:
    r"""Twists :math:`\xi` with :math:`\exp(\xi) = \pm ref^{-1} x`, continuous along a chain.

    ``x`` and ``ref`` must be sign-aligned along the trajectory (neighbours with
    non-negative real dots): the rotation angle ``2 atan2(|v|, w)`` of the relative real
    part then runs continuously over ``[0, 2 pi)`` without the jump at pi of the principal
    logarithm (relative rotations up to a full turn).
    """
    y = dualquat.mul(dualquat.conj(ref), x)
    r, t = dualquat.to_rt(y)
    w, v = r[..., 0], r[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)
    theta = 2.0 * torch.atan2(s, w)  # in [0, 2 pi]
    axis = v / torch.where(s > 0, s, 1.0)[..., None]
    theta = torch.where(theta > 2.0 * math.pi - 1e-6, theta - 2.0 * math.pi, theta)
    omega = theta[..., None] * axis
    return torch.cat((omega, twist_translation(omega, t)), dim=-1)


def _interpolate(x: Tensor, times: Tensor, at: Tensor) -> Tensor:
    """Poses at times ``at`` by ``sclerp`` between the neighbouring samples (clamped)."""
    j = (torch.searchsorted(times, at, right=True) - 1).clamp(0, times.shape[0] - 2)
    alpha = ((at - times[j]) / (times[j + 1] - times[j])).clamp(0.0, 1.0)
    return dualquat.sclerp(x[..., j, :], x[..., j + 1, :], alpha)


def least_squares_start(x: Tensor, times: Tensor, first: Tensor, values: Tensor, n: int,
                        anchors: Tensor) -> Tensor:
    r"""Control points fit to poses by windowed least squares in local charts.

    The anchors :math:`a_j` are the poses interpolated (``sclerp`` between the neighbouring
    samples) at the times ``anchors[j]``. Control point ``k`` is :math:`c_k \exp(C_k)`: the
    chart :math:`c_k` is the pose interpolated at the middle time of a window of samples
    around ``k`` (those whose support overlaps control points ``k - p .. k + p``, ``p + 1``
    the support width; all samples for a global basis), and :math:`C_k` the coefficient of
    control point ``k`` in the linear least-squares fit
    :math:`\min \sum_i |\sum_j B_j(t_i) C_j - \log(c_k^{-1} x_i)|^2` over that window
    (relative rotations up to a full turn either side of the chart). A weak prior pulls every
    unknown ``C_j`` towards its anchor :math:`\log(c_k^{-1} a_j)` with weight ``1e-3``
    of the mean data weight per control point: negligible where samples determine the
    curve, it keeps the control points that they barely or do not determine (at the ends
    of and inside a time gap longer than a knot span) on the screw-motion bridge between
    the neighbouring samples instead of letting them run off. Exact for a constant screw
    motion (its anchors are the exact control points).

    Args:
        x: ``(..., N, 8)`` unit dual quaternions, float64 (any signs).
        times: ``(N,)`` float64 strictly increasing times.
        first: ``(N,)`` int64 first control point of each sample's support.
        values: ``(N, w)`` float64 basis values (see ``BSpline.basis``).
        n: number of control points.
        anchors: ``(n,)`` float64 anchor times (Greville abscissae), in ``times``' units.

    Returns:
        ``(..., n, 8)`` float64 unit dual quaternions.
    """
    N, w = values.shape
    h = w - 1
    x = align_chain(x)
    anchor = _interpolate(x, times, anchors)  # (..., n, 8)
    dev = x.device
    ks = torch.arange(n, device=dev)
    lo = torch.searchsorted(first, ks - 2 * h, right=False)
    hi = torch.searchsorted(first, ks + h, right=True)
    # The chart of each window: the pose interpolated at the middle time of its samples (the
    # lifted twists hold relative rotations up to a full turn either side of it; a Bézier
    # curve's window is every sample, charted at the middle of the trajectory).
    mid = torch.where(hi > lo, 0.5 * (times[lo.clamp(max=N - 1)] + times[(hi - 1).clamp(min=0)]),
                      anchors)
    centre = _interpolate(x, times, mid)  # (..., n, 8)
    M = int((hi - lo).max())
    U = min(4 * h + 1, n)
    weight = _START_PRIOR * float((values * values).sum()) / n  # of the mean data weight
    chunk = max(1, _MAX_WINDOW_ELEMENTS // max(1, M * (U + 8)))
    coeffs = []
    for start in range(0, n, chunk):
        k = ks[start:start + chunk]
        idx = lo[k, None] + torch.arange(M, device=dev)
        mask = idx < hi[k, None]
        idx = idx.clamp(max=N - 1)
        base = (k - 2 * h).clamp(0, n - U)
        cols = first[idx][..., None] - base[:, None, None] + torch.arange(w, device=dev)
        cols = torch.where(mask[..., None], cols, torch.arange(w, device=dev))
        A = torch.zeros(len(k), M, U, dtype=x.dtype, device=dev)
        A.scatter_(2, cols, values[idx] * mask[..., None])
        chart = centre[..., k, None, :]
        xi = _chart_twists(chart, x[..., idx, :])  # (..., K, M, 6)
        # prior: unknown j at its own anchor, seen from the chart of anchor k
        near = anchor[..., base[:, None] + torch.arange(U, device=dev), :]  # (..., K, U, 8)
        prior = _chart_twists(chart, near)
        G = A.mT @ A + weight * torch.eye(U, dtype=x.dtype, device=dev)
        rhs = A.mT @ xi + weight * prior
        sol = torch.cholesky_solve(rhs, torch.linalg.cholesky(G))  # (..., K, U, 6)
        coeffs.append(sol[..., torch.arange(len(k), device=dev), k - base, :])
    C = torch.cat(coeffs, dim=-2)
    ctrl = dualquat.mul(centre, dualquat.exp(C))
    # the representative of each control point nearest to its anchor (the samples' chain)
    dots = (ctrl[..., :4] * anchor[..., :4]).sum(-1, keepdim=True)
    return torch.where(dots < 0, -ctrl, ctrl)

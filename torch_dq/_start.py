r"""The least-squares start of the curve layers: control points from timestamped poses (private).

Below the layers (:mod:`torch_dq.nn` builds ``from_poses`` on it) and used again by the
estimation (:mod:`torch_dq.fitting`):

- :func:`check_sample_times`: validation of sample times (finite, strictly increasing);
- :func:`check_determined`: the Schoenberg-Whitney test of a least-squares problem on a
  B-spline basis (an underdetermined fit raises ``ValueError``, never a garbage fit);
- :func:`least_squares_start`: control points from windowed least squares in local charts.

The start is the same for both B-spline forms (:mod:`torch_dq.curves`, ``form=``): inside a
chart :math:`c`, with control points :math:`c \exp(C_j)` close to it, both the De Boor pyramid
of sclerps and the cumulative product of screw powers are, to first order in the
:math:`C_j`, the Euclidean B-spline :math:`\exp(\sum_j B_j(t) C_j)` of the chart
coordinates (each sclerp is affine in the chart coordinates to first order, and so is
:math:`\prod_j \exp(\tilde B_j \log(c_{j-1}^{-1} c_j))` with
:math:`\sum_{l \ge j} B_l = \tilde B_j`). The windowed least squares fit that linearization,
so the start is exact for a constant screw motion and accurate to second order in the
motion per window for either form; refinement (:func:`torch_dq.fitting.fit`) then
minimises the form's own residuals. The split form (SO(3) x R^3) is fit in its own charts
(rotation vector about the chart's rotation, translation difference), where its
translation is exactly the Euclidean B-spline and its rotation is to first order.
"""

from __future__ import annotations

import math
import warnings

import torch
from torch import Tensor

from . import _checks, dualquat, quat
from ._core import align, align_chain, qconj, qmul, qrotate, translation, twist_translation
from ._numerics import threshold
from ._time import bspline_basis, time_step

__all__ = ["bspline_basis", "check_determined", "check_sample_times", "least_squares_start"]

_MAX_WINDOW_ELEMENTS = 1 << 22  # bound on the numbers held per chunk of windows
_START_PRIOR = 1e-3  # pull of the windowed least squares towards the anchors (see below)
# Largest rotation (rad) across one window of the start: the twists lifted into a window's
# chart hold rotations up to a full turn (2 pi) either side of it, but the translation part
# (V(omega)^-1, poles at 2 pi) and charts off the middle of windows cut at the ends of the
# trajectory leave less: measured on constant screw motions, windows of 8 rad are exact and
# of 8.5 rad not.
_MAX_WINDOW_TURN = 8.0


# ----------------------------------------------------------------------------- checks

def check_sample_times(fn: str, times: Tensor, n: int | None = None,
                       batched: bool = False) -> Tensor:
    """Check sample times: ``(N,)`` finite, strictly increasing (``N >= 2``; ``N == n`` if
    given). With ``batched``, ``(..., N)`` times are accepted too: a row per trajectory,
    each finite and strictly increasing (rows share ``N``).

    Returns:
        ``times`` unchanged.
    """
    _checks.tensor(fn, "times", times)
    if times.dim() != 1 and not (batched and times.dim() > 1):
        expected = "an (N,) or (..., N)" if batched else "a 1-D (N,)"
        _checks.fail(fn, f"expected {expected} tensor for times, got shape "
                         f"{_checks.shape_str(times.shape)}")
    N = times.shape[-1]
    if n is not None and N != n:
        shape = f"({n},)" if times.dim() == 1 else f"(..., {n})"
        _checks.fail(fn, f"times must hold one time per pose: expected shape {shape} for the "
                         f"N = {n} poses, got shape {_checks.shape_str(times.shape)}")
    if N < 2:
        _checks.fail(fn, f"at least 2 timestamped poses are needed, got N = {N}")
    tt = times.detach()
    finite, increasing = ~torch.isfinite(tt), tt[..., 1:] <= tt[..., :-1]
    bad = torch.stack((finite.any(), increasing.any())).tolist()
    if bad[0]:
        _checks.fail(fn, "times must be finite" + _row(finite, tt, 0))
    if bad[1]:
        hint = " (sort the samples, and drop or merge repeated times)"
        if times.dtype != torch.float64:  # absolute timestamps collapse in float32
            ulp = float(time_step(times.dtype, tt.abs().max().cpu()))  # at the largest time
            hint = (f" ({times.dtype} rounds these times to steps of {ulp:.3g} (the times' "
                    f"units); pass absolute "
                    f"timestamps such as UNIX seconds as float64)")
        _checks.fail(fn, "times must be strictly increasing" + _row(increasing, tt, 1) + hint)
    _warn_unit(fn, float(tt.abs().max()))
    return times


def _warn_unit(fn: str, last: float) -> None:
    """Warn where the times cannot be seconds (beyond 1e11 s, year 5138) but a finer unit
    gives a UNIX time (nanoseconds, microseconds, milliseconds): the curve keeps the
    caller's unit, so its velocities would be per nanosecond, its knot spacing in them."""
    unit = _checks.unix_unit(last) if last >= _checks.LATEST else None
    if unit:
        warnings.warn(f"{fn}: the times look like UNIX {unit[0]} (the latest {last:.6g}): the "
                      f"curve keeps the caller's unit, so its rates would be per "
                      f"{unit[0][:-1]}; pass seconds (times * {unit[1]:g})", UserWarning,
                      stacklevel=5)  # the caller of from_poses / from_dualquats / fit


def _row(bad: Tensor, times: Tensor, pair: int) -> str:
    """The message's tail naming where ``bad`` first holds: for batched times its row, for
    ``(N,)`` times the sample (``pair``: 1 where ``bad[i]`` compares ``times[i + 1]`` with
    ``times[i]``, 0 where it is about ``times[i]``), with the values."""
    if bad.dim() >= 2:
        row = _checks.first_index(bad.any(-1))
        return f" in each row, not so in row {row[0] if len(row) == 1 else row}"
    (i,) = _checks.first_index(bad)
    if not pair:
        return f": times[{i}] = {float(times[i])!r}"
    later, earlier = float(times[i + 1]), float(times[i])
    return f": times[{i + 1}] = {later!r} is not after times[{i}] = {earlier!r}"


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
    positive = (values > threshold("basis_nonzero", values.dtype)).tolist()
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


# ----------------------------------------------------------------------------- start

def _rt(x: Tensor) -> tuple[Tensor, Tensor]:
    """Rotation quaternion ``(..., 4)`` and translation ``(..., 3)`` of unit ``x (..., 8)``."""
    return x[..., :4], translation(x[..., :4], x[..., 4:])


def _rt_twists(rc: Tensor, pc: Tensor, rx: Tensor, px: Tensor, split: bool) -> Tensor:
    r"""Chart twists :math:`\xi` with :math:`\exp(\xi) = \pm ref^{-1} x`, continuous along
    a chain, of the poses ``x = (rx, px)`` about the charts ``ref = (rc, pc)`` (rotation
    quaternions and translations, broadcast): :math:`ref^{-1} x` is the rotation
    :math:`r_c^* r_x` and the translation :math:`R_c^T (p_x - p_c)`.

    ``x`` and ``ref`` must be sign-aligned along the trajectory (neighbours with
    non-negative real dots): the rotation angle ``2 atan2(|v|, w)`` of the relative real
    part then runs continuously over ``[0, 2 pi)`` without the jump at pi of the principal
    logarithm (relative rotations up to a full turn). With ``split`` the chart of the split
    form (SO(3) x R^3): the same rotation vector and the translation difference
    :math:`p_x - p_{ref}` (world axes) instead of the twist's linear part.
    """
    inv = qconj(rc)
    r = qmul(inv, rx)
    w, v = r[..., 0], r[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)
    theta = 2.0 * torch.atan2(s, w)  # in [0, 2 pi]
    axis = v / torch.where(s > 0, s, 1.0)[..., None]
    full = 2.0 * math.pi - threshold("full_turn", theta.dtype)  # a turn within rounding
    theta = torch.where(theta > full, theta - 2.0 * math.pi, theta)
    omega = theta[..., None] * axis
    if split:
        return torch.cat((omega, px - pc), dim=-1)
    return torch.cat((omega, twist_translation(omega, qrotate(inv, px - pc))), dim=-1)


def _from_chart(centre: Tensor, C: Tensor, split: bool) -> Tensor:
    """The poses of chart coordinates ``C (..., 6)`` about ``centre`` (:func:`_rt_twists`'
    inverse): ``centre exp(C)``, or with ``split`` the rotation ``R_c Exp(omega)`` and the
    translation ``p_c + v``."""
    if not split:
        return dualquat.mul(centre, dualquat.exp(C))
    r, t = dualquat.to_rt(centre)
    return dualquat.from_rt(quat.mul(r, quat.from_rotvec(C[..., :3])), t + C[..., 3:])


def _interpolate(x: Tensor, times: Tensor, at: Tensor) -> Tensor:
    """Poses at times ``at`` by ``sclerp`` between the neighbouring samples: the degree-1
    spline through the samples, located by the time model, continued by the end pairs'
    screw motions beyond the first and last samples (anchors in a margin of the domain)."""
    r = torch.searchsorted(times.contiguous(), at, right=True).clamp(1, times.shape[0] - 1)
    u = (at - times[r - 1]) / (times[r] - times[r - 1])  # beyond [0, 1] past the ends
    return dualquat.sclerp(x[..., r - 1, :], x[..., r, :], u)


def _window_reach(fn: str, x: Tensor, times: Tensor, anchors: Tensor, h: int) -> list[int]:
    """The reach ``a`` of the windows (:func:`least_squares_start`) of each trajectory of
    the sign-aligned ``x`` (flattened batch): the largest in ``0..h`` whose ``2a + h + 1``
    knot spans turn by less than ``_MAX_WINDOW_TURN`` at the trajectory's fastest rotation
    rate; warns where even ``a = 0`` does not."""
    count = x.shape[:-2].numel()
    if x.shape[-2] < 2 or anchors.shape[0] <= h + 1:  # a global basis (Bézier): one chart
        return [h] * count
    q = x[..., :4]
    spacing = float((anchors[1:] - anchors[:-1]).max())  # the knot spacing, about
    # Turn per knot span from samples one span apart (noise adds noise / spacing, not
    # noise / sample interval); past ~2 rad such pairs may alias (angles wrap at pi), and
    # then consecutive samples tell.
    j = torch.searchsorted(times.contiguous(), times + spacing).clamp(max=times.shape[0] - 1)
    pair = _angle_rate(q, q[..., j, :], times[j] - times) * spacing
    fine = _angle_rate(q[..., :-1, :], q[..., 1:, :], times[1:] - times[:-1]) * spacing
    turns = torch.where(pair < 2.0, pair, torch.maximum(pair, fine)).reshape(count)
    turn = float(turns.max())  # rad per knot span
    rate = turn / spacing
    if turn * (h + 1) > _MAX_WINDOW_TURN:
        ok = 0.9 * _MAX_WINDOW_TURN / (h + 1) / rate  # followed literally, it works
        warnings.warn(f"{fn}: the poses turn at up to {rate:.3g} rad per unit of time (rad/s for "
                      f"times in seconds), {turn:.3g} rad per knot span of {spacing:.3g}: the "
                      f"least-squares start is unreliable above "
                      f"{_MAX_WINDOW_TURN / (h + 1):.3g} rad per span; use knots at most "
                      f"{ok:.3g} apart (in the times' units)", UserWarning, stacklevel=6)
    return [max(0, min(h, int((_MAX_WINDOW_TURN / max(r, 1e-300) - h - 1) // 2)))
            for r in turns.tolist()]


def _angle_rate(a: Tensor, b: Tensor, dt: Tensor) -> Tensor:
    """Largest rotation rate ``angle(a_i, b_i) / dt_i`` over the samples (``dt > 0``) of
    each trajectory, ``(...)``, for unit quaternions ``a, b (..., N, 4)``."""
    dots = (a * b).sum(-1).abs().clamp(max=1.0)
    rate = 2.0 * torch.acos(dots) / torch.where(dt > 0, dt, 1.0)
    return torch.where(dt > 0, rate, 0.0).amax(-1)


def least_squares_start(fn: str, x: Tensor, times: Tensor, first: Tensor, values: Tensor,
                        n: int, anchors: Tensor, split: bool = False) -> Tensor:
    r"""Control points fit to poses by windowed least squares in local charts.

    The anchors :math:`a_j` are the poses interpolated (``sclerp`` between the neighbouring
    samples) at the times ``anchors[j]``. Control point ``k`` is :math:`c_k \exp(C_k)`: the
    chart :math:`c_k` is the pose interpolated at the middle time of a window of samples
    around ``k`` (those whose support starts at control points ``k - p - a .. k + a``,
    ``p + 1`` the support width; all samples for a global basis), and :math:`C_k` the
    coefficient of
    control point ``k`` in the linear least-squares fit
    :math:`\min \sum_i |\sum_j B_j(t_i) C_j - \log(c_k^{-1} x_i)|^2` over that window
    (relative rotations up to a full turn either side of the chart). A weak prior pulls every
    unknown ``C_j`` towards its anchor :math:`\log(c_k^{-1} a_j)` with weight ``1e-3``
    of the mean data weight per control point: negligible where samples determine the
    curve, it keeps the control points that they barely or do not determine (at the ends
    of and inside a time gap longer than a knot span) on the screw-motion bridge between
    the neighbouring samples instead of letting them run off. Exact for a constant screw
    motion (its anchors are the exact control points).

    The window reach ``a`` is ``p`` (windows of ``3p + 1`` knot spans) unless the poses
    turn fast: a window must turn less than about a full turn either side of its chart, so
    ``a`` shrinks down to 0 (``p + 1`` spans) where the samples turn by more than about
    1 rad per knot span, and beyond ``8 / (p + 1)`` rad per span (where even those
    windows wrap) a ``UserWarning`` names the rate found and the knot spacing that works.

    Args:
        x: ``(..., N, 8)`` unit dual quaternions, float64 (any signs).
        times: ``(N,)`` float64 strictly increasing times.
        first: ``(N,)`` int64 first control point of each sample's support.
        values: ``(N, w)`` float64 basis values (see ``BSpline.basis``).
        n: number of control points.
        anchors: ``(n,)`` float64 anchor times (Greville abscissae), in ``times``' units.
        split: chart coordinates of the split form (:func:`_rt_twists`): rotation vector
            and translation difference, which its rotation and translation are affine in to
            first order (its translation exactly).

    Returns:
        ``(..., n, 8)`` float64 unit dual quaternions.
    """
    x = align_chain(x)
    reach = _window_reach(fn, x, times, anchors, values.shape[1] - 1)
    if len(set(reach)) > 1:  # trajectories of a batch turning at different rates
        flat = x.reshape(-1, *x.shape[-2:])
        out = [_windowed(flat[b], times, first, values, n, anchors, a, split)
               for b, a in enumerate(reach)]
        return torch.stack(out).view(*x.shape[:-2], n, 8)
    return _windowed(x, times, first, values, n, anchors, reach[0], split)


def _windowed(x: Tensor, times: Tensor, first: Tensor, values: Tensor, n: int,
              anchors: Tensor, a: int, split: bool = False) -> Tensor:
    """:func:`least_squares_start` on the sign-aligned ``x`` with windows of reach ``a``."""
    N, w = values.shape
    h = w - 1
    anchor = _interpolate(x, times, anchors)  # (..., n, 8)
    ks = torch.arange(n, device=x.device)
    lo = torch.searchsorted(first, ks - h - a, right=False)
    hi = torch.searchsorted(first, ks + a, right=True)
    # The chart of each window: the pose interpolated at the middle time of its samples (the
    # lifted twists hold relative rotations up to a full turn either side of it; a Bézier
    # curve's window is every sample, charted at the middle of the trajectory).
    mid = torch.where(hi > lo, 0.5 * (times[lo.clamp(max=N - 1)] + times[(hi - 1).clamp(min=0)]),
                      anchors)
    centre = _interpolate(x, times, mid)  # (..., n, 8)
    window = _Windows(_rt(x), _rt(centre), _rt(anchor), first, values, lo, hi - lo, a,
                      _START_PRIOR * float((values * values).sum()) / n, split)
    # windows per chunk: each (window, sample) pair carries ~3 w + 16 numbers, each window
    # its system
    chunk = max(1, _MAX_WINDOW_ELEMENTS // (int((hi - lo).max()) * (3 * w + 16)
                                            + (window.U + w) ** 2))
    C = torch.cat([window.coefficients(ks[i:i + chunk]) for i in range(0, n, chunk)], dim=-2)
    ctrl = _from_chart(centre, C, split)
    # the representative of each control point nearest to its anchor (the samples' chain)
    return align(ctrl, anchor)


class _Windows:
    r"""The windows of :func:`_windowed`, solved for their own control point only.

    Window ``k`` holds the samples whose support starts at control points ``k - h - a ..
    k + a`` (``h`` the degree), which touch the ``U = 2 (a + h) + 1`` columns ``k - h - a ..
    k + a + h`` (those outside ``0 .. n - 1`` hold no data and no prior: zero, decoupled).
    With its design matrix ``A``, chart twists :math:`\xi` and prior twists ``P`` (weight
    ``weight``), the window's least squares is :math:`G C = A^T \xi + weight\,P` with
    :math:`G = A^T A + weight\,I`; only :math:`C_r` is kept (``r = h + a``, the window's own
    control point), so with :math:`z = G^{-1} e_r` (one solve per window, ``G`` symmetric)
    :math:`C_r = \sum_i (A z)_i \xi_i + weight\,z^T P`: the twists are weighted and summed
    per (window, sample) pair, without the padded ``A`` or a 6-column solve.
    """

    def __init__(self, rtx, rtc, rta, first, values, lo, count, a, weight, split):
        self.rtx, self.rtc, self.rta = rtx, rtc, rta
        self.first, self.values, self.lo, self.count = first, values, lo, count
        self.a, self.h, self.weight, self.split = a, values.shape[1] - 1, weight, split
        self.n, self.U = rtc[0].shape[-2], 2 * (a + self.h) + 1
        w = values.shape[1]  # the Gram of the samples of each span (first control point f),
        # after h + a zero blocks (spans before the first) and before as many (after the last)
        self.spans = values.new_zeros(self.n + 2 * a + self.h, w, w)
        for j in range(w):  # column by column: N x w numbers at a time
            self.spans[:, :, j].index_add_(0, first + self.h + a, values * values[:, j, None])

    def _pairs(self, k: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The (window, sample) pairs of windows ``k``: their window's position in ``k``,
        the sample and the column of its first basis value in the window."""
        dev = k.device
        count = self.count.index_select(0, k)
        kk = torch.repeat_interleave(torch.arange(len(k), device=dev), count)
        s = (self.lo.index_select(0, k) - torch.cumsum(count, 0) + count).index_select(0, kk) \
            + torch.arange(kk.shape[0], device=dev)
        return kk, s, self.first.index_select(0, s) - (k - self.h - self.a).index_select(0, kk)

    def _z(self, k: Tensor) -> Tensor:
        """``(K, U)``: :math:`G^{-1} e_r` of windows ``k``, ``G`` summed from the Grams of
        the spans ``k - h - a .. k + a`` that their samples start in."""
        U, w, spans, like = self.U, self.h + 1, self.spans, self.spans
        G = like.new_zeros(len(k), U, U)  # the last block ends at U = 2 a + 2 h + 1
        for d in range(2 * self.a + self.h + 1):  # span k - h - a + d, zero outside 0 .. n - h
            G[:, d:d + w, d:d + w] += spans.index_select(0, k + d)
        G.diagonal(dim1=-2, dim2=-1).add_(self.weight)
        e = like.new_zeros(len(k), U, 1)
        e[:, self.h + self.a] = 1.0
        return torch.cholesky_solve(e, torch.linalg.cholesky(G))[..., 0]

    def coefficients(self, k: Tensor) -> Tensor:
        """``(..., K, 6)`` the chart coordinates of control points ``k`` in their windows."""
        kk, s, c = self._pairs(k)  # gathers by index_select: ~3x faster than [..., s, :]
        vs = self.values.index_select(0, s)  # (P, w)
        cols = c[:, None] + torch.arange(self.h + 1, device=k.device)
        z = self._z(k)
        (rx, px), (rc, pc), (ra, pa) = self.rtx, self.rtc, self.rta
        rc, pc = rc.index_select(-2, k), pc.index_select(-2, k)
        xi = _rt_twists(rc.index_select(-2, kk), pc.index_select(-2, kk), rx.index_select(-2, s),
                        px.index_select(-2, s), self.split)  # (..., P, 6)
        zs = torch.gather(z.index_select(0, kk), 1, cols)  # z[kk, cols]
        weighted = (vs * zs).sum(-1)[:, None] * xi  # (A z)_i xi_i
        out = weighted.new_zeros(*weighted.shape[:-2], len(k), 6).index_add_(-2, kk, weighted)
        # prior: unknown j at its own anchor, seen from the window's chart
        near = (k - self.h - self.a)[:, None] + torch.arange(self.U, device=k.device)
        z = z * ((near >= 0) & (near < self.n))
        near = near.clamp(0, self.n - 1)
        prior = _rt_twists(rc[..., None, :], pc[..., None, :], ra[..., near, :],
                           pa[..., near, :], self.split)  # (..., K, U, 6)
        return out + self.weight * (z[..., None] * prior).sum(-2)

r"""Fitting curves of rigid motions to timestamped poses (used by :mod:`torch_dq.nn`).

- :func:`least_squares_start`: control points from local (windowed) least squares in
  local charts. Each control point ``k`` gets its own chart, the pose ``a_k`` interpolated
  from the samples at its Greville abscissa; the samples of a window of a few knot spans
  around it are lifted into that chart (:math:`\xi_i = \log(a_k^{-1} x_i)`), a Euclidean
  spline is fit to them by linear least squares, and its coefficient ``C_k`` gives the
  control point :math:`a_k \exp(C_k)`. Nothing is linearised about one global pose, so the
  start is sane on long trajectories with loops; time and memory are :math:`O(N)`
  (:math:`O(N n)` for a Bézier curve, whose basis is global); and the result does not
  depend on where the world origin is (each chart is relative).
- :func:`fit`: refines a curve module on timestamped poses and returns the best iterate
  seen. ``optimizer="lm"`` is Levenberg-Marquardt in local charts
  (``ctrl_k <- ctrl_k exp(delta_k)``, body-frame steps, so a rotation step never moves a
  control point's translation and the fit is the same wherever the world origin lies),
  with the banded Gauss-Newton matrix of the B-spline (each pose depends on
  ``degree + 1`` consecutive control points) solved block-tridiagonally in :math:`O(n)`;
  ``"adam"``, ``"sgd"``, ``"lbfgs"`` or any ``torch.optim`` optimizer step on the raw
  control points instead.
- :func:`bspline_basis`, :func:`check_times`, :func:`check_determined`: the Euclidean
  B-spline basis (Cox-de Boor), and the argument and Schoenberg-Whitney checks shared with
  the layers: an underdetermined fit (more control points than samples, or a control point
  whose support holds no sample of its own) raises a ``ValueError``, never a garbage fit.

Example (a 300 m loop 1e5 m from the origin, timestamped in UNIX seconds):
    >>> import math
    >>> import torch_dq.dualquat as dq
    >>> from torch_dq.losses import translation_error
    >>> from torch_dq.nn import BSpline
    >>> s = torch.linspace(0.0, 60.0, 601, dtype=torch.float64)  # 60 s at 10 Hz
    >>> xi = torch.tensor([0.0, 0.0, 2 * math.pi / 60, 5.0, 0.0, 0.2], dtype=torch.float64)
    >>> far = dq.from_rt(torch.tensor([1.0, 0, 0, 0], dtype=torch.float64),
    ...                  torch.tensor([1e5, -2e5, 30.0], dtype=torch.float64))
    >>> poses = dq.mul(far, dq.exp(s[:, None] * xi))  # a circle, climbing
    >>> wobble = dq.exp(0.01 * torch.sin(3 * s)[:, None] * torch.ones(6, dtype=torch.float64))
    >>> poses = dq.mul(poses, wobble)
    >>> times = 1.7e9 + s
    >>> spline = BSpline.from_dualquats(poses, times, n_ctrl=123)  # a knot every 0.5 s
    >>> history = fit(spline, times, poses, optimizer="lm", verbose=False)
    >>> bool(translation_error(spline(times), poses).max() < 1e-3)  # metres
    True
"""

from __future__ import annotations

import functools
import math
import numbers
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from . import _checks, dualquat, quat
from ._core import align_chain, knot_span, twist_translation
from .losses import pose_loss

__all__ = ["FitHistory", "bspline_basis", "check_determined", "check_times", "fit",
           "least_squares_start"]

_MAX_WINDOW_ELEMENTS = 1 << 22  # bound on (windows x samples x unknowns) per chunk
_MAX_REJECTIONS = 8  # damping increases (x10 each) before Levenberg-Marquardt stops
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


# ----------------------------------------------------------------------------- history

@dataclass
class FitHistory:
    """What :func:`fit` did.

    Attributes:
        loss: the loss before each optimizer step (``len(loss) == steps``); for ``"lm"``
            the regularised objective (the loss plus its ``prior`` term, see :func:`fit`).
        steps: number of optimizer steps taken.
        final_loss: the loss of the returned parameters (the best iterate seen).
        converged: True when the stopping test held (the loop stopped there).
        seconds: wall-clock time of the loop.
        best_step: how many optimizer steps led to the returned parameters (0: the start
            was the best; ``steps``: the last iterate).
        optimizer: the optimizer used (``"lm"``, ``"adam"``, ... or its class name).
    """

    loss: list[float] = field(default_factory=list)
    steps: int = 0
    final_loss: float = math.nan
    converged: bool = False
    seconds: float = 0.0
    best_step: int = 0
    optimizer: str = ""


# ----------------------------------------------------------------------------- optimizers

_DEFAULT_LR = {"adam": 1e-2, "sgd": 1e-2, "lbfgs": 1.0}
_NAMES = "'auto', 'lm', 'adam', 'sgd', 'lbfgs', a torch.optim optimizer or a callable(params)"


def _make_optimizer(fn: str, optimizer, params: list, lr: float | None):
    if isinstance(optimizer, str):
        name = optimizer.lower()
        lr = _DEFAULT_LR[name] if lr is None else lr
        if isinstance(lr, bool) or not isinstance(lr, numbers.Real) or not lr > 0:
            _checks.fail(fn, f"lr must be a real number > 0, got {lr!r}")
        if name == "adam":
            return torch.optim.Adam(params, lr=lr)
        if name == "sgd":
            return torch.optim.SGD(params, lr=lr, momentum=0.9)
        return torch.optim.LBFGS(params, lr=lr, line_search_fn="strong_wolfe")
    if lr is not None:
        _checks.fail(fn, "lr applies to named optimizers only; set it in the optimizer or "
                         "factory")
    if isinstance(optimizer, torch.optim.Optimizer):
        return optimizer
    if callable(optimizer):
        opt = optimizer(params)
        if not isinstance(opt, torch.optim.Optimizer):
            _checks.fail(fn, f"the optimizer factory must return a torch.optim.Optimizer, "
                             f"got {type(opt).__name__}", TypeError)
        return opt
    _checks.fail(fn, f"optimizer must be {_NAMES} -> optimizer, got "
                     f"{type(optimizer).__name__}")


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=total, desc="torch_dq.fit", leave=False)


def _pose_loss_weights(loss) -> tuple[float, float] | None:
    """``(rot_weight, trans_weight)`` when ``loss`` is :func:`pose_loss` (possibly a
    ``functools.partial`` of it with those keywords), else None."""
    if loss is pose_loss:
        return 1.0, 1.0
    if (isinstance(loss, functools.partial) and loss.func is pose_loss and not loss.args
            and set(loss.keywords) <= {"rot_weight", "trans_weight"}):
        wr = loss.keywords.get("rot_weight", 1.0)
        wt = loss.keywords.get("trans_weight", 1.0)
        if all(isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
               and float(v) >= 0 for v in (wr, wt)):
            return float(wr), float(wt)
    return None


# ----------------------------------------------------------------------------- LM

def _pose_residuals(x: Tensor, target: Tensor, weights: tuple[float, float]) -> Tensor:
    r"""``(..., 6)`` residuals whose squared norm is ``pose_loss``'s per-pose term:
    :math:`\sqrt{w_r}` times the rotation vector of :math:`R_{target}^{-1} R_x`, then
    :math:`\sqrt{w_t}\,(t_x - t_{target})`."""
    qx, tx = dualquat.to_rt(x)
    qy, ty = dualquat.to_rt(target)
    rot = quat.to_rotvec(quat.mul(quat.conj(qy), qx))
    return torch.cat((math.sqrt(weights[0]) * rot, math.sqrt(weights[1]) * (tx - ty)), -1)


def _banded_to_block_tridiagonal(band: Tensor, g: int) -> tuple[Tensor, Tensor]:
    """Diagonal and sub-diagonal blocks of a symmetric block-banded matrix, regrouped.

    ``band[..., k, d]`` is the ``(s, s)`` block ``(k, k + d)``, ``d < w``; grouping ``g =
    w - 1`` consecutive block rows makes the matrix block-tridiagonal. Returns ``D``
    ``(..., G, g s, g s)`` and ``E`` ``(..., G, g s, g s)`` with ``E[j]`` the block
    ``(group j, group j - 1)`` (``E[0]`` unused).
    """
    *batch, n, w, s, _ = band.shape
    G = n // g
    a = torch.arange(g, device=band.device)
    j = torch.arange(G, device=band.device)[:, None, None]
    rows = j * g + a[:, None]  # (G, g, 1)
    cols = j * g + a[None, :]  # (G, 1, g)
    lo, d = torch.minimum(rows, cols), (rows - cols).abs()
    lo, d = torch.broadcast_tensors(lo, d)
    D = band[..., lo, d, :, :]  # (..., G, g, g, s, s)
    D = torch.where((rows > cols)[..., None, None], D.mT, D)
    # E[j][a, b] = block (j g + a, (j - 1) g + b) = band[(j - 1) g + b, g + a - b]^T
    prev = ((j - 1) * g + a[None, :]).clamp(min=0)  # (G, 1, g)
    dist = g + a[:, None] - a[None, :]  # (g, g)
    inside = (dist <= w - 1) & (j > 0)
    prev, dist = torch.broadcast_tensors(prev, dist.clamp(max=w - 1).expand(G, g, g))
    E = band[..., prev, dist, :, :].mT * inside[..., None, None]
    order = (*range(len(batch)), -5, -4, -2, -3, -1)  # (..., G, g, s, g, s)
    return (D.permute(order).reshape(*batch, G, g * s, g * s),
            E.permute(order).reshape(*batch, G, g * s, g * s))


def _solve_block_banded(band: Tensor, rhs: Tensor) -> Tensor | None:
    """Solve ``A x = rhs`` for a symmetric positive definite block-banded ``A``.

    ``band`` ``(..., n, w, s, s)`` as in :func:`_banded_to_block_tridiagonal`, ``rhs``
    ``(..., n, s)``. Block-tridiagonal Cholesky (Schur complements group by group): ``O(n)``
    time and memory. Returns None when ``A`` is not numerically positive definite.
    """
    *batch, n, w, s, _ = band.shape
    dev = band.device
    beyond = torch.arange(n, device=dev)[:, None] + torch.arange(w, device=dev) >= n
    band = band.masked_fill(beyond[:, :, None, None], 0.0)
    g = max(w - 1, 1)
    G = -(-n // g)
    pad = G * g - n
    if pad:
        eye = band.new_zeros(*batch, pad, w, s, s)
        eye[..., 0, :, :] = torch.eye(s, dtype=band.dtype, device=dev)
        band = torch.cat((band, eye), dim=-4)
        rhs = torch.cat((rhs, rhs.new_zeros(*batch, pad, s)), dim=-2)
    D, E = _banded_to_block_tridiagonal(band, g)
    b = rhs.reshape(*batch, G, g * s, 1)
    chol: list[Tensor] = []
    y: list[Tensor] = []
    for j in range(G):
        S, yj = D[..., j, :, :], b[..., j, :, :]
        if j:
            X = torch.cholesky_solve(E[..., j, :, :].mT, chol[-1])  # S_{j-1}^-1 E_j^T
            S = S - E[..., j, :, :] @ X
            yj = yj - X.mT @ y[-1]
        L, info = torch.linalg.cholesky_ex(S)
        if bool((info != 0).any()):
            return None
        chol.append(L)
        y.append(yj)
    x = {G - 1: torch.cholesky_solve(y[G - 1], chol[G - 1])}
    for j in range(G - 2, -1, -1):
        x[j] = torch.cholesky_solve(y[j] - E[..., j + 1, :, :].mT @ x[j + 1], chol[j])
    return torch.cat([x[j] for j in range(G)], dim=-2).reshape(*batch, G * g, s)[..., :n, :]


def _jacobian(residual: Callable[[Tensor], Tensor], ctrl: Tensor, first: Tensor, w: int,
              ) -> Tensor:
    """Jacobian ``(..., N, w, 6, 6)`` of the residuals ``(..., N, 6)`` with respect to
    body-frame steps ``ctrl_k exp(delta_k)`` of the ``w`` control points of each support.

    Colouring: the control points ``k = c mod w`` never share a support, so ``6 w``
    directional derivatives (one per colour and step component) give the whole band. They
    are central differences in float64 with step ``1e-5`` (relative error ~1e-9; the 12
    evaluations of a colour in one batched call of the fused curve kernel): this Jacobian
    only shapes the Gauss-Newton matrix, the gradient is exact (reverse mode).
    """
    eps = 1e-5
    columns = []
    for c in range(w):
        V = ctrl.new_zeros(6, *ctrl.shape[:-1], 6)
        for m in range(6):
            V[m, ..., c::w, m] = eps
        r = residual(dualquat.mul(ctrl, dualquat.exp(torch.cat((V, -V)))))
        columns.append((r[:6] - r[6:]) / (2.0 * eps))  # (6m, ..., N, 6r)
    D = torch.stack(columns).movedim((0, 1), (-2, -1))  # (..., N, 6r, w colours, 6m)
    colour = (first[:, None] + torch.arange(w, device=first.device)) % w  # (N, w) slots
    index = colour[:, None, :, None].expand(*D.shape)
    return D.gather(-2, index).transpose(-3, -2)  # (..., N, w slots, 6r, 6m)


def _gradient(objective: Callable[[Tensor], Tensor], ctrl: Tensor) -> tuple[float, Tensor]:
    """The objective (a sum of squares) and its exact gradient, halved, with respect to
    body-frame steps ``delta`` (reverse mode)."""
    with torch.enable_grad():
        delta = ctrl.new_zeros(*ctrl.shape[:-1], 6).requires_grad_()
        value = objective(dualquat.mul(ctrl, dualquat.exp(delta)))
        (grad,) = torch.autograd.grad(0.5 * value, delta)
    return float(value), grad


def _normal_matrix(J: Tensor, first: Tensor, n: int) -> Tensor:
    """Band ``(..., n, w, 6, 6)`` of ``J^T J`` (block ``(k, k + d)`` at ``[..., k, d]``)."""
    *batch, _, w, _, s = J.shape
    band = J.new_zeros(*batch, n, w, s, s)
    nd = len(batch)
    for a in range(w):
        for d in range(w - a):  # J_a^T J_{a+d} of every sample, into block (k, k + d)
            block = torch.einsum("...irm,...irq->...imq", J[..., a, :, :], J[..., a + d, :, :])
            band[..., d, :, :].index_add_(nd, first + a, block)
    return band


def _levenberg_marquardt(module, times: Tensor, target: Tensor, weights, prior: float,
                         steps: int, tol: float, history: FitHistory, bar) -> None:
    """Levenberg-Marquardt in local charts on a curve layer (see :func:`fit`), in float64
    whatever the module's dtype (its control points are rounded once at the end)."""
    start = module.control_points.detach().to(torch.float64)
    target = target.to(torch.float64)
    times = times.to(torch.promote_types(times.dtype, torch.float64))
    first, values = module.basis(times)
    first = first.to(start.device)
    n, w = module.n_ctrl, values.shape[-1]
    count = target.shape[:-1].numel()

    def residual(c):
        return _pose_residuals(module(times, ctrl=c), target, weights)

    band = _normal_matrix(_jacobian(residual, start, first, w), first, n)
    # prior weight: `prior` of the mean curvature of the data term per step component
    mu = prior * float(band[..., 0, :, :].diagonal(dim1=-2, dim2=-1).mean())

    def objective(c):
        r = residual(c)
        value = (r * r).sum()
        if mu > 0:
            p = dualquat.log(dualquat.mul(dualquat.conj(start), c))
            value = value + mu * (p * p).sum()
        return value

    ctrl = start
    cost, grad = _gradient(objective, ctrl)
    lam = 1e-4
    for k in range(steps):
        history.loss.append(cost / count)
        history.steps = k + 1
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{cost / count:.3e}")
        if not math.isfinite(cost) or cost == 0.0:
            history.converged = cost == 0.0
            break
        if k:
            band = _normal_matrix(_jacobian(residual, ctrl, first, w), first, n)
        diag = band[..., 0, :, :].diagonal(dim1=-2, dim2=-1) + mu  # (..., n, 6)
        floor = 1e-12 * float(diag.mean())
        for _ in range(_MAX_REJECTIONS):
            damped = band.clone()
            damped[..., 0, :, :] += torch.diag_embed(mu + lam * (diag + floor))
            delta = _solve_block_banded(damped, -grad)
            if delta is not None:
                trial = dualquat.mul(ctrl, dualquat.exp(delta))
                cost_trial = float(objective(trial))
                if cost_trial < cost:
                    break
            lam *= 10.0
        else:  # no damping lowers the cost: a (numerical) minimum
            history.converged = True
            break
        lam = max(lam / 10.0, 1e-12)
        decrease = cost - cost_trial
        ctrl = trial
        cost, grad = _gradient(objective, ctrl)
        if decrease <= tol * (cost + decrease):
            history.converged = True
            break
    module.control_points = ctrl.to(module.control_points.dtype)
    history.best_step = history.steps


# ----------------------------------------------------------------------------- fit

def fit(module: torch.nn.Module, times: Tensor, poses: Tensor,
        optimizer: str | torch.optim.Optimizer
        | Callable[[list[Tensor]], torch.optim.Optimizer] = "auto",
        steps: int = 500, lr: float | None = None, tol: float = 1e-9, window: int = 10,
        loss: Callable[[Tensor, Tensor], Tensor] = pose_loss, prior: float = 1e-3,
        verbose: bool = True) -> FitHistory:
    r"""Fit a curve module to timestamped poses; the module ends at the best iterate seen.

    Minimises ``loss(module(times), poses)`` (``times`` in the module's own time, the
    caller's units, exactly as for ``module(times)``) over the module's parameters.

    - ``optimizer="lm"``: Levenberg-Marquardt on a :class:`~torch_dq.nn.BSpline` or
      :class:`~torch_dq.nn.Bezier`, stepping in local charts ``ctrl_k exp(delta_k)``
      (body-frame twists: the fit does not depend on where the world origin is), with the
      Gauss-Newton matrix of the residuals (rotation vector and translation difference,
      whose squared norm is ``pose_loss``'s term) assembled from forward-mode products
      and solved block-tridiagonally in :math:`O(n)`; it only accepts steps that lower the
      loss. Needs ``loss`` to be :func:`~torch_dq.losses.pose_loss` or a
      ``functools.partial`` of it setting ``rot_weight`` / ``trans_weight``. One step is one
      Gauss-Newton iteration; stops when a step lowers the loss by at most ``tol``
      relatively, or when no damping gives a decrease. Regularised: the objective adds
      ``prior`` times the mean data curvature times :math:`\sum_k |\log(c_k^{0\,-1} c_k)|^2`
      (a pull towards the control points ``c^0`` the fit started from), which keeps the
      control points that the samples barely or do not determine (a time gap longer than a
      knot span) where the start put them (:meth:`~torch_dq.nn.BSpline.from_poses` bridges
      such gaps by screw motion), and changes a well-determined fit by about ``prior``
      times its distance from the start. ``prior=0`` gives the plain least-squares fit and
      raises ``ValueError`` when it is underdetermined (Schoenberg-Whitney).
    - ``"adam"``, ``"sgd"`` (momentum 0.9), ``"lbfgs"`` (strong Wolfe line search), a
      ``torch.optim.Optimizer`` instance over the module's parameters, or a callable
      ``params -> Optimizer``: each step calls ``optimizer.step(closure)`` on the raw
      control points (they stay unit through the parametrization). Early stopping: after
      ``window`` steps, stop when :math:`|L_{k-w} - L_k| \le tol \cdot |L_{k-w}|` or the
      loss is exactly 0; a non-finite loss stops the loop. The parameters of the lowest
      loss evaluated (including inside LBFGS's line search) are restored at the end.
    - ``"auto"`` (default): ``"lm"`` for a curve layer with a ``pose_loss`` loss and no
      ``lr``, else ``"adam"``.

    Args:
        module: a :class:`~torch_dq.nn.Bezier` / :class:`~torch_dq.nn.BSpline` (or, with
            a torch optimizer, any module mapping ``(N,)`` times to ``(..., N, 8)`` poses).
        times: ``(N,)`` strictly increasing times in the module's time. A curve layer
            takes them as they are (float64 UNIX seconds with a float32 module are fine);
            another module gets them cast to its parameters' dtype.
        poses: ``(..., N, 8)`` unit dual quaternions or ``(..., N, 4, 4)`` homogeneous
            matrices, cast to the module's dtype and device.
        optimizer: see above.
        steps: maximum number of optimizer steps (``>= 1``).
        lr: learning rate of a named torch optimizer (default 1e-2 for Adam and SGD, 1 for
            LBFGS); must be None with an instance or a factory, and with ``"lm"``.
        tol: relative loss change below which to stop (0: never, for torch optimizers).
        window: steps between the compared losses (``>= 1``; torch optimizers).
        loss: ``loss(pred, target) -> 0-d tensor``; default :func:`torch_dq.losses.pose_loss`
            (mean of rad² + length²; use ``functools.partial(pose_loss, trans_weight=...)``
            to balance the units).
        prior: weight of the pull towards the start for ``"lm"`` (see above), ``>= 0``.
        verbose: show a tqdm progress bar when stderr is a terminal and tqdm is installed.

    Returns:
        :class:`FitHistory` with the per-step losses; ``final_loss`` is the loss of the
        returned (best) parameters.

    Raises:
        ValueError: bad shapes, unknown optimizer name, bad ``steps``/``lr``/``tol``/
            ``window``, non-increasing times, times outside the module's domain,
            ``"lm"`` with another loss or module, more control points than samples (and,
            with ``prior=0``, a control point whose support holds no sample of its own).
        TypeError: non-module ``module``, non-floating tensors, a factory that does not
            return an optimizer.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> from torch_dq.nn import BSpline
        >>> t = torch.linspace(0.0, 2.0, 30)
        >>> target = dq.exp(t[:, None] * torch.tensor([0.0, 0.0, 1.0, 0.5, 0.0, 0.0]))
        >>> spline = BSpline(dq.identity((6,)), knots=torch.tensor(
        ...     [0.0, 0, 0, 0, 0.67, 1.33, 2, 2, 2, 2]))  # domain [0, 2] seconds
        >>> history = fit(spline, t, target, verbose=False)  # Levenberg-Marquardt
        >>> history.final_loss < 1e-6 * history.loss[0]
        True
    """
    fn = "nn.fit"
    if not isinstance(module, torch.nn.Module):
        _checks.fail(fn, f"expected a torch.nn.Module for module, got {type(module).__name__}",
                     TypeError)
    steps = _check_count(fn, "steps", steps)
    window = _check_count(fn, "window", window)
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not tol >= 0:
        _checks.fail(fn, f"tol must be a real number >= 0, got {tol!r}")
    if isinstance(prior, bool) or not isinstance(prior, numbers.Real) or not (
            math.isfinite(prior) and prior >= 0):
        _checks.fail(fn, f"prior must be a finite real number >= 0, got {prior!r}")
    if not callable(loss):
        _checks.fail(fn, f"expected a callable for loss, got {type(loss).__name__}", TypeError)
    if isinstance(optimizer, str) and optimizer.lower() not in ("auto", "lm", *_DEFAULT_LR):
        _checks.fail(fn, f"optimizer must be {_NAMES} -> optimizer, got {optimizer!r}")
    _checks.tensor(fn, "poses", poses)
    if poses.dim() >= 3 and tuple(poses.shape[-2:]) == (4, 4):
        poses = dualquat.from_matrix(poses)
    elif poses.dim() < 2 or poses.shape[-1] != 8:
        _checks.fail(fn, f"expected (..., N, 8) dual quaternions or (..., N, 4, 4) matrices "
                         f"for poses, got shape {_checks.shape_str(poses.shape)}")
    check_times(fn, times, poses.shape[-2])
    params = [p for p in module.parameters() if p.requires_grad]
    if not params:
        _checks.fail(fn, "module has no parameters that require grad")
    curve = callable(getattr(module, "basis", None)) and hasattr(module, "control_points")
    weights = _pose_loss_weights(loss)
    name = optimizer.lower() if isinstance(optimizer, str) else None
    if name == "auto":
        name = "lm" if curve and weights is not None and lr is None else "adam"
    if name == "lm":
        if not curve:
            _checks.fail(fn, f"optimizer='lm' fits a torch_dq.nn.BSpline or Bezier, got "
                             f"{type(module).__name__}")
        if weights is None:
            _checks.fail(fn, "optimizer='lm' minimises pose_loss: pass loss=pose_loss or "
                             "functools.partial(pose_loss, rot_weight=..., trans_weight=...)")
        if lr is not None:
            _checks.fail(fn, "lr applies to the torch optimizers, not to optimizer='lm'")
    like = module.control_points if curve else params[0]
    if curve:
        try:
            first, values = module.basis(times.detach())
        except ValueError as e:  # times outside the module's domain: say who was called
            raise ValueError(f"{fn}: {e}") from None
        if module.n_ctrl > values.shape[0] or (name == "lm" and prior == 0):
            check_determined(fn, first.cpu(), values.cpu(), module.n_ctrl,
                             getattr(module, "knots", None))
        t_in = times.detach().to(like.device)
    else:
        t_in = times.detach().to(dtype=like.dtype, device=like.device)
    target = poses.detach().to(dtype=like.dtype, device=like.device)
    history = FitHistory(optimizer=name or type(optimizer).__name__)
    bar = _progress(steps, verbose and sys.stderr.isatty())
    start = time.perf_counter()
    try:
        if name == "lm":
            if target.shape[:-2] != like.shape[:-2]:
                try:
                    target = target.expand(*like.shape[:-2], *target.shape[-2:])
                except RuntimeError:
                    _checks.fail(fn, f"optimizer='lm' needs poses with the module's batch "
                                     f"shape {_checks.shape_str(like.shape[:-2])}, got poses "
                                     f"{_checks.shape_str(poses.shape)}")
            with torch.no_grad():
                _levenberg_marquardt(module, t_in, target, weights, prior, steps, tol,
                                     history, bar)
                history.final_loss = float(loss(module(t_in), target))
        else:
            opt = _make_optimizer(fn, optimizer, params, lr)
            _torch_loop(module, t_in, target, opt, params, steps, tol, window, loss, history,
                        bar)
    finally:
        if bar is not None:
            bar.close()
    history.seconds = time.perf_counter() - start
    return history


def _check_count(fn: str, name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        _checks.fail(fn, f"{name} must be an int >= 1, got {value!r}")
    return int(value)


def _torch_loop(module, t: Tensor, target: Tensor, opt, params: list, steps: int, tol: float,
                window: int, loss, history: FitHistory, bar) -> None:
    """``optimizer.step(closure)`` loop with early stopping; restores the best iterate."""
    best: dict[str, Any] = {"loss": math.inf, "params": None, "step": 0}

    def closure():
        opt.zero_grad(set_to_none=True)
        value = loss(module(t), target)
        v = float(value.detach())
        if v < best["loss"]:  # the parameters that gave it, before the step changes them
            best.update(loss=v, params=[p.detach().clone() for p in params],
                        step=history.steps)
        value.backward()
        return value

    for k in range(steps):
        value = float(opt.step(closure).detach())
        history.loss.append(value)
        history.steps = k + 1
        if bar is not None:
            bar.update(1)
            if k % 10 == 0:
                bar.set_postfix(loss=f"{value:.3e}")
        if not math.isfinite(value):
            break
        if value == 0.0 or (k >= window and tol > 0 and
                            abs(history.loss[k - window] - value)
                            <= tol * abs(history.loss[k - window])):
            history.converged = True
            break
    with torch.no_grad():
        final = float(loss(module(t), target))
        if best["params"] is not None and not final <= best["loss"]:
            for p, saved in zip(params, best["params"], strict=True):
                p.copy_(saved)
            final = float(loss(module(t), target))
            history.best_step = best["step"]
        else:
            history.best_step = history.steps
    history.final_loss = final

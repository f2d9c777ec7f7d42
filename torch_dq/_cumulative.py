r"""The cumulative B-spline form of rigid motions (Kim, Kim & Shin 1995) (private).

For control points :math:`c_0, \dots, c_{n-1}` (unit dual quaternions, sign-aligned by
:func:`torch_dq._core.align_chain`) and non-decreasing knots :math:`u`,

.. math::
    X(t) = c_0 \prod_{j \ge 1} \big(c_{j-1}^{-1} c_j\big)^{\tilde B_j(t)},\qquad
    \tilde B_j = \sum_{l \ge j} B_{l,p},

with :math:`B_{l,p}` the B-spline basis of degree ``p`` and each power
:math:`x^w = \exp(w \log x)` the screw motion on the shortest path, i.e. eq. 11 from the
identity, :math:`x^w = \mathrm{sclerp}(1, x, w)`. For ``t`` in the span
:math:`u_r \le t < u_{r+1}` the cumulative weights are 1 for :math:`j \le r - p` and 0 for
:math:`j > r`. A whole power is the relative motion itself when its real part is
non-negative (the shortest path), which sign alignment guarantees, so the whole powers
telescope (:math:`c_0 \prod_{j \le r-p} c_{j-1}^{-1} c_j = c_{r-p}`) and only the span's
``p + 1`` control points matter:

.. math::
    X(t) = c_{r-p} \prod_{j=1}^{p}
        \big(c_{r-p+j-1}^{-1} c_{r-p+j}\big)^{\tilde B_{r-p+j}(t)}.

The weights are polynomials of degree ``p`` on each span, and the curve is
:math:`C^{p-1}` at a simple interior knot, :math:`C^{p-m}` at a knot of multiplicity ``m``
(as the cumulative basis, since each power is analytic in its weight): a cubic's
accelerations are continuous, unlike those of the De Boor form (:math:`C^1`).

- :func:`basis`: the cumulative weights of each time's span and their time derivatives.
- :func:`jets`: the curve and its exact time derivatives from the span's control points and
  the weights, in truncated Taylor arithmetic (:mod:`torch_dq._taylor`): the power's jets
  are eq. 11's (:func:`torch_dq._taylor.sclerp` from the identity; the derivative of
  :math:`x^{w(t)}` is :math:`x^w \log(x)\, \dot w`), their product a Leibniz product.
- :func:`poses`: the poses alone as one fused autograd op (eager reverse mode and
  ``torch.compile``): each power from the identity is :math:`\beta + \alpha x` with dual
  numbers :math:`\alpha, \beta` (eq. 11's weights), so the product expands into a sum of
  per-span products of control points (:func:`_span_tables`, computed once per span) with
  per-time dual weights, one weighted sum of table rows per time; analytic backward.
- :func:`derivatives`: the poses and their time derivatives the same way: the tables are
  constant on a span, so the derivatives fall on the scalar dual weights alone (jets of
  ``(L, 2, p, n)`` rows instead of dual-quaternion jets), each order one weighted sum of
  table rows with an analytic backward (:class:`_Rows`); :func:`jets` is its plain-op
  reference.

The readable reference is :func:`torch_dq.curves._kim_kim_shin`.
"""

from __future__ import annotations

import math
from typing import NamedTuple, cast

import torch
from torch import Tensor

from . import _taylor
from ._autograd import index_add, reference_vjp, save, saved
from ._dispatch import batched, opaque_scatter, written_backward
from ._kernels import products
from ._kernels.layout import chunks, rows_into, to_rows
from ._kernels.sclerp import Frame
from ._kernels.sclerp import weights as screw_weights
from ._kernels.weights import Angle, Weights, WeightSlopes, angle, angle_square
from ._numerics import even, safe_denominator

__all__ = ["basis", "derivatives", "jets", "poses"]

BASIS_CHUNK = 16384  # times per eager chunk of the basis (2x faster than 1e5 at once)
JET_CHUNK = 16384  # times per eager chunk of the jets (their temporaries stay in cache)
POSES_CHUNK = 16384  # times per eager chunk of the fused poses (fewer, larger ops than 8192)
TABLE_MIN_TIMES = 2  # times per span start below which the span tables do not pay
RUN_MIN_TIMES = 32  # times per span start from which sorted times run per span (_runs)


def _span_basis(knots: Tensor, r: Tensor, t: Tensor, degree: int,
                order: int) -> list[Tensor]:
    r"""Taylor coefficients in ``t`` (``0..order``) of :math:`B_{r-p+m,p}`, ``m = 0..p``,
    each ``(p + 1, ..., T)`` (``m`` leading): the polynomial pieces of span ``r``, evaluated
    at ``t``.

    Cox-de Boor on the span's knots :math:`u_{r-p+1}, \dots, u_{r+p}`: with
    :math:`V_0 = (1)` and, for ``k = 1..p``,
    :math:`\alpha_i = (t - u_i) / (u_{i+k} - u_i)`, ``i = r-k+1..r`` (0 where the
    denominator is 0: the 0/0 terms of repeated knots),

    .. math::
        B_{i,k} = \alpha_i B_{i,k-1} + (1 - \alpha_{i+1}) B_{i+1,k-1},

    i.e. :math:`V_k = (0, \alpha V_{k-1}) + ((1 - \alpha) V_{k-1}, 0)`. Every step is a
    polynomial in ``t``, so ``t`` outside the span gives the pieces' continuation.
    """
    p = degree
    # u_{r-p+1..r+p} as leading rows (2p, ..., T): every op below runs over contiguous rows
    # of times (a trailing dim of p + 1 is several times slower on CPU)
    offsets = torch.arange(1 - p, p + 1, device=r.device).view(-1, *[1] * r.dim())
    K = knots.index_select(0, (r + offsets).reshape(-1)).view(2 * p, *r.shape)
    V = [torch.ones_like(t)[None]] + [torch.zeros_like(t)[None] for _ in range(order)]
    zero = torch.zeros_like(t)[None]
    for k in range(1, p + 1):
        left, right = K[p - k:p], K[p:p + k]
        denom = right - left
        empty = denom <= 0  # never inside a non-empty span; 0 / 0 = 0 all the same
        safe = safe_denominator(denom, empty)
        keep = (~empty).to(t.dtype)  # a product, not torch.where (several times slower)
        alpha = (t - left) / safe * keep
        aV = [alpha * V[0]]
        if order:  # (alpha + slope h) V, truncated: the product by an affine function of t
            slope = keep / safe
            aV += [alpha * V[i] + slope * V[i - 1] for i in range(1, order + 1)]
        V = [torch.cat((zero, a)) + torch.cat((v - a, zero))
             for a, v in zip(aV, V, strict=True)]
    return V


def basis(knots: Tensor, r: Tensor, t: Tensor, degree: int, order: int) -> list[Tensor]:
    r"""The cumulative basis of each time's span and its time derivatives.

    :math:`\tilde B_{r-p+j}(t) = \sum_{m=j}^{p} B_{r-p+m,p}(t)`, ``j = 1..p``
    (:math:`\tilde B_{r-p} = 1` by the partition of unity, and :math:`\tilde B_l = 0` for
    ``l > r``, so neither is returned).

    Args:
        knots: ``(K,)`` non-decreasing knots (uniform or not, clamped or not, repeated
            interior knots allowed), in the time dtype.
        r: ``(..., T)`` int64 spans, ``knots[r] <= t < knots[r + 1]``, ``r`` in
            ``[p, n - 1]`` (``torch_dq._time.KnotDomain.span``).
        t: ``(..., T)`` times in ``knots``' dtype. Times outside their span give the
            polynomial continuation of the span's pieces (extrapolation).
        degree: ``p >= 1``.
        order: highest time derivative, ``>= 0``.

    Returns:
        ``order + 1`` tensors ``(..., T, p)``:
        :math:`[\tilde B, d\tilde B/dt, \dots, d^{order}\tilde B/dt^{order}]` with
        ``Bt[..., j - 1]`` :math:`= \tilde B_{r-p+j}(t)`; differentiable (any order) with
        respect to ``t`` and ``knots``. Each is a view of ``(p, ..., T)`` rows (its
        transpose, what the kernels read, is contiguous).
    """
    r, t = torch.broadcast_tensors(r, t)
    flat_r, flat_t = r.reshape(-1), t.reshape(-1)
    parts = [[math.factorial(k) * v[1:].flip(0).cumsum(0).flip(0)
              for k, v in enumerate(_span_basis(knots, flat_r[i], flat_t[i], degree, order))]
             for i in chunks(flat_r.shape[0], BASIS_CHUNK)]  # cache-sized temporaries
    return [(x[0] if len(x) == 1 else torch.cat(x, -1)).view(degree, *r.shape).movedim(0, -1)
            for x in zip(*parts, strict=True)]


def _identity_rows(like: Tensor) -> Tensor:
    """The identity as component rows ``(8, 1, 1)`` in ``like``'s dtype and device."""
    one = torch.zeros(8, 1, 1, dtype=like.dtype, device=like.device)
    one[0] = 1.0
    return one


def _conj_rows(x: Tensor) -> Tensor:
    """Quaternion conjugate of both halves of component rows ``(8, ...)``."""
    sign = x.new_tensor([1.0, -1.0, -1.0, -1.0] * 2).view(8, *[1] * (x.dim() - 1))
    return x * sign


def _chunk_jets(P: Tensor, w: _taylor.Jet) -> _taylor.Jet:
    """The product of powers on one chunk: ``P (8, p + 1, N)`` control-point rows, ``w``
    the normalised Taylor coefficients ``(p, N)`` of the weights -> the curve's jet
    ``(8, N)`` per coefficient."""
    order = len(w) - 1
    rel = _taylor.dq_rows(_conj_rows(P[:, :-1]), P[:, 1:])  # c_{j-1}^-1 c_j, (8, p, N)
    powers = _taylor.sclerp([_identity_rows(P), *[None] * order], [rel, *[None] * order], w)
    x: _taylor.Jet = [P[:, 0], *[None] * order]
    factors = [[None] * (P.shape[1] - 1) if e is None else e.unbind(1) for e in powers]
    for j in range(P.shape[1] - 1):
        x = _taylor.dq_mul(x, [f[j] for f in factors])
    return x


def jets(points: Tensor, weights: list[Tensor], order: int) -> list[Tensor]:
    r"""The cumulative form and its exact time derivatives at each time.

    :math:`X = c_{r-p} \prod_{j=1}^p (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}` (module
    docstring) in truncated Taylor arithmetic: each power is eq. 11 from the identity on
    jets (its derivative is :math:`x^w \log(x)\, \dot w`), the product a Leibniz product
    of dual-quaternion jets. Plain torch ops: differentiable (twice, reverse and forward
    mode, ``torch.func`` transforms) with respect to ``points`` and ``weights``,
    compilable with ``fullgraph=True``. Equal neighbours (a static segment) have finite
    derivatives; at a half turn between neighbours (orthogonal real parts) the sign of the
    zero dot picks the path, and the derivatives are that side's.

    Args:
        points: ``(..., T, p + 1, 8)`` the sign-aligned control points
            :math:`c_{r-p}, \dots, c_r` of each time's span.
        weights: ``order + 1`` tensors ``(..., T, p)`` as :func:`basis` returns them
            (rounded to ``points``' dtype): the weights :math:`w_j = \tilde B_{r-p+j}(t)`
            and their time derivatives.
        order: highest time derivative, ``0 <= order < len(weights)``; ``0`` gives the
            poses alone (the plain-op reference of :func:`poses`, which is faster in
            eager reverse mode: it computes each pair's relative motion once).

    Returns:
        ``order + 1`` tensors ``(..., T, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`.
    """
    *batch, T, m, _ = points.shape
    n = math.prod(batch) * T
    rows = points.reshape(n, m * 8).T.reshape(m, 8, n).transpose(0, 1)  # (8, m, n)
    w_rows = [w.expand(*batch, T, m - 1).reshape(n, m - 1).T / math.factorial(k)
              for k, w in enumerate(weights[:order + 1])]
    outs = []
    for part in chunks(n, JET_CHUNK):
        coefs: _taylor.Jet = [w[:, part].contiguous() for w in w_rows]
        x = _chunk_jets(rows[..., part].contiguous(), coefs)
        outs.append([v.T for v in _taylor.derivatives(x)])
    return [torch.cat(xs).view(*batch, T, 8) for xs in zip(*outs, strict=True)]


# ----------------------------------------------------------------------------- fused poses

def _span_tables(ctrl: Tensor, starts: Tensor, p: int,
                 used: Tensor | None = None) -> tuple[Tensor, Tensor]:
    r"""Per span start ``f`` in ``starts (U,)`` (indices into ``ctrl (M, 8)``, at most
    ``M - p``), the products of the expanded form and the relative motions' frames, as plain
    (differentiable) torch ops on ``U``-sized rows.

    With :math:`R_j = c_{f+j-1}^{-1} c_{f+j}` and its power
    :math:`R_j^{w} = \beta_j + \alpha_j R_j` (eq. 11 from the identity; the dual numbers
    :math:`\beta = F_0 - \epsilon\delta G_0`, :math:`\alpha = \sigma (F_1 - \epsilon\delta
    G_1)` commute with everything), the pose expands into
    :math:`c_f \prod_j (\beta_j + \alpha_j R_j) = \sum_S w_S\, T_S`,
    :math:`T_S = c_f \prod_{j \in S} R_j` (ascending ``j``) over the subsets ``S`` of
    ``1..p``, :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S} \beta_j`.

    Returns ``table (U * 2K, 8)``, ``K = 2^p``: rows ``u 2K + m`` the :math:`T_S` of
    ``starts[u]`` (bit ``j - 1`` of ``m`` set where ``j`` is in ``S``) and rows
    ``u 2K + K + m`` their real parts moved to the dual half (what a dual weight
    multiplies); and ``pairs (3, p, U)``: the frames ``c, delta, sigma`` of the
    :math:`R_j` from the identity. Where ``used (U,)`` (bool) is given, the starts it marks
    false (which no time reads) are computed from zeros: a NaN control point of one curve
    cannot reach the gradients of another through a span that straddles both.
    """
    idx = starts[:, None] + torch.arange(p + 1, device=ctrl.device)
    P = ctrl[idx]  # (U, p + 1, 8)
    if used is not None:
        P = torch.where(used[:, None, None], P, 0.0)
    conj = P.new_tensor([1.0, -1.0, -1.0, -1.0] * 2)
    rel = (products.right_matrix(P[:, 1:]) @ (P[:, :-1] * conj)[..., None]).squeeze(-1)
    right = products.right_matrix(rel).transpose(-1, -2)  # x R_j = x @ right[:, j]
    T = P[:, :1]
    for j in range(p):
        T = torch.cat((T, T @ right[:, j]), 1)  # (F, 2^(j+1), 8)
    shifted = torch.cat((torch.zeros_like(T[..., :4]), T[..., :4]), -1)
    table = torch.cat((T, shifted), 1).reshape(-1, 8)
    sigma = 1.0 - 2.0 * (rel[..., 0] < 0).to(rel.dtype)
    return table, torch.stack((sigma * rel[..., 0], sigma * rel[..., 4], sigma)).transpose(1, 2)


def _chunk_weights(full: Tensor, f: Tensor, w: Tensor, derivatives: bool = False,
                   need_w: bool = False,
                   h_slope: bool = False) -> tuple[Frame, Weights | WeightSlopes, Tensor]:
    """The powers' frames (gathered per time), weights and the real parts ``b_r (2, p, n)``
    of their dual factors of one chunk (``full (6 p, F)``: the pairs' frames and angles, or
    ``(7 p, F)`` with :math:`y = 1 - c` last, computed in a wider dtype; ``h_slope``: as in
    :func:`screw_weights`)."""
    p, n = w.shape
    g = full.index_select(1, f).view(-1, p, n)
    fr = Frame(*g[:3])
    ws = screw_weights(fr, w, derivatives, need_w, Angle(*g[3:6]),
                       g[6] if g.shape[0] == 7 else None, h_slope)
    return fr, ws, ws.F * _signs(fr.sigma)


def _dual_parts(sigma: Tensor, delta: Tensor, G: Tensor) -> Tensor:
    r"""The dual parts ``b_d (2, p, n)`` of :math:`\beta, \alpha`: :math:`-\delta (G_0,
    \sigma G_1)`."""
    return -delta * (G * _signs(sigma))


def _signs(sigma: Tensor, first: float = 1.0) -> Tensor:
    """``(first, sigma)`` stacked, to weigh the two rows of eq. 11's weights (products, not
    selected rows: their gradients are not zero-filled copies)."""
    return torch.stack((torch.full_like(sigma, first), sigma))


def _bags(f: Tensor, width: int, rows: int) -> Tensor:
    """``(n, width)`` row indices ``f width + k`` of each time's block of a table of ``rows``
    rows (int32 on CPU where they fit: several times faster to make than int64)."""
    k = torch.arange(width, device=f.device)
    if f.device.type == "cpu" and rows < 2**31:
        k = k.int()
    return torch.add(k, f[:, None].to(k.dtype), alpha=width)


def _weighted_rows(table: Tensor, f: Tensor, W: Tensor) -> Tensor:
    """``(n, 8)``: :math:`\\sum_k W_{nk}` ``table[f_n width + k]``, ``W (n, width)``. Under
    ``torch.compile`` a gather, product and sum that inductor fuses (``embedding_bag`` is an
    aten fallback there, several times slower)."""
    width = W.shape[1]
    if torch.compiler.is_compiling():
        return _gathered_rows(table, f, W)
    return torch.nn.functional.embedding_bag(_bags(f, width, table.shape[0]), table,
                                             mode="sum", per_sample_weights=W)


def _gathered_rows(table: Tensor, f: Tensor, W: Tensor) -> Tensor:
    """:func:`_weighted_rows` as a gather, products and sum of plain ops ``(n, 8)``. The sum
    over the ``width`` rows is written out term by term, an elementwise expression: as a
    reduction, inductor (CPU) parallelised it over its 16 terms, one OpenMP region per
    time, 10x slower than the eager op."""
    rows = table.view(-1, W.shape[1], 8)[f]
    out = rows[:, 0] * W[:, :1]
    for k in range(1, W.shape[1]):
        out = torch.addcmul(out, rows[:, k], W[:, k:k + 1])
    return out


def _row_dots(table: Tensor, f: Tensor, G: Tensor, F: int) -> Tensor:
    """``(width, n)`` rows: the dot products of each time's table rows ``table[f_n width +
    k]`` with ``G (n, 8)`` (the cotangent of :func:`_weighted_rows`' weights). Under
    ``torch.compile`` a fused gather and sum, otherwise ``embedding_bag`` over the
    transposed table's rows ``(f, component)``."""
    blocks = table.view(F, -1, 8)
    if torch.compiler.is_compiling():  # components leading: inductor reduces across rows
        return (blocks.permute(1, 2, 0)[..., f] * G.T).sum(1)
    columns = blocks.transpose(1, 2).reshape(F * 8, -1)
    return to_rows(torch.nn.functional.embedding_bag(
        _bags(f, 8, columns.shape[0]), columns, mode="sum", per_sample_weights=G))


def _kept(kept: Tensor, part: slice, shape: torch.Size) -> Tensor:
    """The chunk ``part`` of the forward's saved weights, a contiguous ``(3, 2, p, n)`` block
    of the flat buffer ``kept`` (chunks one after the other)."""
    p, N = shape
    start, stop, _ = part.indices(N)
    return kept[6 * p * start:6 * p * stop].view(3, 2, p, stop - start)


def _segment_outer(W: Tensor, G: Tensor, f: Tensor, F: int) -> Tensor:
    r""":math:`\sum_{n: f_n = s} W_n \otimes G_n` for every span start ``s``: ``W (n, k)``,
    ``G (n, 8)`` -> ``(F, k, 8)``, a scatter of the outer products (differentiable; sorted
    times run per span instead, :func:`_runs`); :func:`_segment_outer_op` where
    :func:`~torch_dq._dispatch.opaque_scatter`."""
    if opaque_scatter(W):
        return _segment_outer_op(W, G, f, F)
    return W.new_zeros(F, W.shape[1], 8).index_add(0, f, W[:, :, None] * G[:, None, :])


@torch.library.custom_op("torch_dq::segment_outer", mutates_args=())
def _segment_outer_op(W: Tensor, G: Tensor, f: Tensor, F: int) -> Tensor:
    """:func:`_segment_outer` as one matrix product per span start over the times sorted by
    start, an op that ``torch.compile`` calls as it is: inductor's scatter of the outer
    products (atomic adds of 8 lanes onto a few rows, from both threads) took 35 ms for 1e5
    times on 61 starts, 4x the rest of the compiled forward and backward (not
    differentiable)."""
    order = torch.argsort(f, stable=True)
    W, G = W[order], G[order]
    out = W.new_zeros(F, W.shape[1], 8)
    a = 0
    for start, count in enumerate(torch.bincount(f, minlength=F).tolist()):
        if count:
            torch.mm(W[a:a + count].T, G[a:a + count], out=out[start])
            a += count
    return out


@_segment_outer_op.register_fake
def _(W: Tensor, G: Tensor, f: Tensor, F: int) -> Tensor:
    return W.new_empty(F, W.shape[1], 8)


# chunks of the fused op, each with its runs (a, b, f) of times a <= i < b on span start f
Runs = list[tuple[slice, list[tuple[int, int, int]]]]


def _runs(first: Tensor) -> Runs | None:
    """The chunks of :data:`POSES_CHUNK` times, each with its runs ``(a, b, f)``: times
    ``a <= i < b`` (absolute indices) of one span start ``f``; ``None`` unless eager on CPU
    with non-decreasing ``first (N,)`` (sorted times) holding :data:`RUN_MIN_TIMES` times or
    more per span start on average. Per run, the weighted sum of table rows and its
    cotangents are then small matrix products on the weights' rows (no bag indices, no
    transposes). Host reads: the first and last starts, the order check and the starts'
    counts."""
    N = first.shape[0]
    if torch.compiler.is_compiling() or first.device.type != "cpu" or N < 2:
        return None
    lo = int(first[0])
    if (int(first[-1]) - lo) * RUN_MIN_TIMES >= N or not bool((first[1:] >= first[:-1]).all()):
        return None
    out: Runs = []
    runs: list[tuple[int, int, int]] = []
    a0 = a = 0
    for f, count in enumerate(torch.bincount(first - lo).tolist(), lo):
        b = a + count
        while a < b:
            stop = min(b, a0 + POSES_CHUNK)
            runs.append((a, stop, f))
            a = stop
            if stop in (a0 + POSES_CHUNK, N):
                out.append((slice(a0, stop), runs))
                runs, a0 = [], stop
    return out


def _run_rows(blocks: Tensor, W: Tensor, part: slice, runs: list[tuple[int, int, int]],
              out: Tensor) -> None:
    """:func:`_weighted_rows` per run, in place: ``out[a:b] = W[:, a:b]^T blocks[f]`` for the
    runs ``(a, b, f)`` of the chunk ``part``, ``W (width, n)`` its weights in rows, ``blocks
    (F, width, 8)`` the table. The products are taken in rows, ``blocks[f]^T W[:, a:b]``
    (about 3x faster than the transposed product on CPU), and copied into ``out`` once."""
    rows = W.new_empty(8, W.shape[1])
    for a, b, f in runs:
        torch.mm(blocks[f].T, W[:, a - part.start:b - part.start],
                 out=rows[:, a - part.start:b - part.start])
    rows_into(out[part], rows)


def _run_cotangents(blocks: Tensor, W: Tensor, grad: Tensor, part: slice,
                    runs: list[tuple[int, int, int]], g_table: Tensor) -> Tensor:
    """The cotangents of :func:`_run_rows`' weights, ``(width, n)`` rows (``blocks[f]
    grad[a:b]^T`` per run), and in place the table's: ``W[:, a:b] grad[a:b]`` added to
    ``g_table[f] (width, 8)`` (not differentiable: first-order backward only). ``grad``
    is the chunk's, in rows ``(8, n)``."""
    gW = W.new_empty(W.shape)
    for a, b, f in runs:
        cols = slice(a - part.start, b - part.start)
        torch.mm(blocks[f], grad[:, cols], out=gW[:, cols])
        g_table[f].addmm_(W[:, cols], grad[:, cols].T)
    return gW


def _run_sums(x: Tensor, runs: list[tuple[int, int, int]], total: Tensor) -> Tensor:
    """``total (..., F)`` plus the sums of ``x (..., n)`` over each run's times, at its span
    start (the chunk's runs in order, covering ``x``)."""
    sums = torch.stack([y.sum(-1) for y in x.split([b - a for a, b, _ in runs], -1)], -1)
    return total.index_add(-1, x.new_tensor([f for *_, f in runs], dtype=torch.long), sums)


class _Poses(torch.autograd.Function):
    r"""The cumulative form's poses from the span tables (:func:`_span_tables`):
    :math:`\sum_S w_S(t)\, T_S[f]`, one weighted bag of table rows per time
    (:func:`_weighted_rows`, or per run of sorted times :func:`_run_rows`), the weights from
    eq. 11's dual weights of each power.

    Inputs: ``table (F * 2K, 8)``, ``pairs (3, p, F)`` of ``F`` span starts, ``first (N,)``
    int64 (each time's start ``f``, an index into them), ``w (p, N)``, ``save``, ``runs``
    (:func:`_runs`, or ``None``). Outputs: the poses ``(N, 8)``, in the caller's layout,
    and with ``save`` what the backward reads (not differentiable): the bags' weights
    ``(N, 2K)`` (``(0, 2K)`` with ``runs``, whose backward recomputes them from the last
    subset level, and under ``torch.compile``, whose backward recomputes them in fused
    elementwise code) and ``(b_r, G, H) (3, 2, p, N)``, memory about 2x (4x without
    ``runs``) the poses'. The weights run over cache-sized chunks of component rows. The
    backward returns the cotangents of the table and of the frames' ``c`` and ``delta``;
    autograd carries them to the control points through the (small) tables.
    Where the backward is itself differentiated, or the gradient of ``w`` is asked for, it
    recomputes the weights from the inputs instead (plain torch ops: twice differentiable).
    """

    generate_vmap_rule = True

    @staticmethod
    def forward(table: Tensor, pairs: Tensor, first: Tensor, w: Tensor, save: bool,
                runs: Runs | None) -> tuple[Tensor, Tensor, Tensor]:
        full = _full_pairs(pairs)
        N, width = first.shape[0], table.shape[0] // pairs.shape[-1]
        out = table.new_empty(N, 8)
        # with runs or under torch.compile the backward recomputes the bags' weights
        keep = save and runs is None and not torch.compiler.is_compiling()
        bags = table.new_empty(N if keep else 0, width)
        kept = table.new_empty(6 * w.shape[0] * N if save else 0)
        for i, run in _parts(N, runs):
            fr, ws, b_r = _chunk_weights(full, first[i], w[:, i], save, False)
            W = _subset_jets(b_r[None], _dual_parts(fr.sigma, fr.delta, ws.G)[None])[0]
            if save:
                torch.stack((b_r, ws.G, cast(WeightSlopes, ws).H),
                            out=_kept(kept, i, w.shape))
            if run is not None:
                _run_rows(table.view(-1, width, 8), W, i, run, out)
                continue
            if bags.shape[0]:
                bags[i] = W.T
            out[i] = _weighted_rows(table, first[i], bags[i] if bags.shape[0] else W.T)
        return out, bags, kept

    @staticmethod
    def setup_context(ctx, inputs, output):
        table, pairs, first, w, _, ctx.runs = inputs
        ctx.mark_non_differentiable(*output[1:])
        ctx.set_materialize_grads(False)
        ctx.save_for_backward(table, pairs, first, w, *output[1:])

    @staticmethod
    def backward(ctx, grad, *_):
        if grad is None:  # only the (non-differentiable) saved weights were reached
            return None, None, None, None, None, None
        table, pairs, first, w, bags, kept = ctx.saved_tensors
        if batched(grad):  # under vmap (jacobian / hessian with vectorize=True)
            g_table, g_pairs, g_w = reference_vjp(
                lambda *x: _reference_poses(x[0], x[1], first, x[2]), (table, pairs, w), grad)
            return g_table, g_pairs, None, g_w, None, None
        need_w, plain = ctx.needs_input_grad[3], not torch.is_grad_enabled()
        reuse = kept.shape[0] > 0 and not need_w and plain
        runs = ctx.runs if plain else None  # the runs' products are not differentiable
        full = _full_pairs(pairs)
        p, F = pairs.shape[1:]
        width = table.shape[0] // F
        grad = grad.contiguous()
        g_pairs = torch.zeros_like(pairs[:2])
        g_table, grad_w = table.new_zeros(F, width, 8), []
        for i, run in _parts(first.shape[0], runs):
            f, G = first[i], grad[i]
            if reuse:
                sd = full.view(6, -1, F)[1:3].flatten(0, 1).index_select(1, f)
                (delta, sigma), (b_r, wG, wH) = sd.view(2, p, -1), _kept(kept, i, w.shape)
            else:
                fr, slopes, b_r = _chunk_weights(full, f, w[:, i], True, need_w)
                ws = cast(WeightSlopes, slopes)
                sigma, delta, wG, wH = fr.sigma, fr.delta, ws.G, ws.H
            b_d = _dual_parts(sigma, delta, wG)
            levels = _subset_levels(b_r[None], b_d[None])
            last = torch.cat(levels[-1], 1)[0]
            if run is not None:
                gW = _run_cotangents(table.view(F, width, 8), last, to_rows(G), i, run, g_table)
            else:
                W = bags[i] if reuse and bags.shape[0] else last.T
                g_table = g_table + _segment_outer(W, G, f, F)
                gW = _row_dots(table, f, G, F)
            g_r, g_d = (x[0] for x in _subset_vjp(levels, b_r[None], b_d[None], gW[None]))
            # b_r = (F0, sigma F1), b_d = -delta (G0, sigma G1): sensitivities to F and G
            sig = _signs(sigma)
            gF, gG = sig * g_r, -delta * sig * g_d
            g_delta = -(sig * wG * g_d).sum(0)
            g_c = -(wG * gF + wH * gG).sum(0)  # dF/dc = -G, dG/dc = -H
            g_cd = torch.stack((g_c, g_delta))
            g_pairs = (_run_sums(g_cd, run, g_pairs) if run is not None
                       else index_add(g_pairs, 2, f, g_cd))
            if need_w:  # s = (1 - w, w)
                Fs, Gs = cast(Tensor, ws.Fs), cast(Tensor, ws.Gs)
                grad_w.append((Fs[1] * gF[1] + Gs[1] * gG[1]) - (Fs[0] * gF[0] + Gs[0] * gG[0]))
        g_pairs = torch.cat((g_pairs, torch.zeros_like(pairs[2:])))
        return (g_table.view(-1, 8), g_pairs, None,
                torch.cat(grad_w, -1) if need_w else None, None, None)


def _reference_poses(table: Tensor, pairs: Tensor, first: Tensor, w: Tensor) -> Tensor:
    """:class:`_Poses`' poses ``(N, 8)`` in plain torch ops, unchunked (its backward's
    reference under ``vmap``)."""
    fr, ws, b_r = _chunk_weights(_full_pairs(pairs), first, w)
    W = _subset_jets(b_r[None], _dual_parts(fr.sigma, fr.delta, ws.G)[None])[0]
    return _gathered_rows(table, first, W.T)


def _parts(N: int, runs: Runs | None) -> Runs | list[tuple[slice, None]]:
    """The chunks of the fused op: ``runs`` (:func:`_runs`) if given, else
    :func:`~torch_dq._kernels.layout.chunks` of :data:`POSES_CHUNK` times, without runs."""
    return runs if runs is not None else [(i, None) for i in chunks(N, POSES_CHUNK)]


def _full_pairs(pairs: Tensor) -> Tensor:
    """``(6 p, F)``: the frames ``(3, p, F)`` and their :class:`Angle` rows."""
    return torch.cat((pairs, torch.stack(angle(pairs[0])))).flatten(0, 1)


def poses(ctrl: Tensor, first: Tensor, weights: Tensor) -> Tensor:
    r"""The cumulative form's poses through the fused op (pose only, eager reverse mode).

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened
            into one ``M``).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`; the time
            reads ``ctrl[first .. first + p]``.
        weights: ``(p, N)`` the cumulative basis :math:`\tilde B_{r-p+j}(t)`, ``j = 1..p``
            (:func:`basis`, transposed), in ``ctrl``'s dtype.

    Returns:
        ``(N, 8)``: :math:`c_{r-p} \prod_j (c_{r-p+j-1}^{-1} c_{r-p+j})^{w_j}`. Differentiable
        twice (reverse mode) with respect to ``ctrl`` and ``weights``. Under ``torch.func``
        transforms and forward AD (:func:`torch_dq._dispatch.fused_path` false) use
        :func:`jets` instead, which this does not check. With fewer than
        ``TABLE_MIN_TIMES`` times per span start (``M - p`` of them; e.g. the estimator's
        one-span copies of each sample, where every time has a span of its own) the span
        tables cost more than they save, and the product of powers runs per time
        (:func:`jets` at order 0). In eager mode the tables (:func:`_span_tables`,
        ``2^(p+1) x 8`` values each) are built for the span starts in use only (at most
        ``N``); under ``torch.compile`` (no data-dependent sizes) for every span start.
    """
    p = weights.shape[0]
    if first.shape[0] == 0:  # no times (an empty batch): an empty output tied to ctrl
        return ctrl[:0] * 1
    if _per_time(ctrl, first, p):
        points = ctrl[first[:, None] + torch.arange(p + 1, device=first.device)]
        return jets(points, [weights.T], 0)[0]
    table, pairs, first = _tables(ctrl, first, p)
    save = torch.is_grad_enabled() and (ctrl.requires_grad or weights.requires_grad)
    return _Poses.apply(table, pairs, first, weights, save, _runs(first))[0]


def _per_time(ctrl: Tensor, first: Tensor, p: int) -> bool:
    """Whether the product of powers runs per time (:func:`jets`): eager, with fewer than
    :data:`TABLE_MIN_TIMES` times per span start, where the span tables cost more than they
    save (e.g. the estimator's one-span copies of each sample)."""
    return (not torch.compiler.is_compiling()
            and first.shape[0] < TABLE_MIN_TIMES * (ctrl.shape[0] - p))


def _tables(ctrl: Tensor, first: Tensor, p: int) -> tuple[Tensor, Tensor, Tensor]:
    """:func:`_span_tables` of the span starts that ``first`` reads, and ``first`` as
    indices into them. Eager: the starts in use only (one host read); under
    ``torch.compile`` (no data-dependent sizes) a table per start, unused ones from zeros."""
    F = ctrl.shape[0] - p
    used = torch.zeros(F, dtype=torch.bool, device=ctrl.device).index_fill(0, first, True)
    if torch.compiler.is_compiling():
        table, pairs = _span_tables(ctrl, torch.arange(F, device=ctrl.device), p, used)
        return table, pairs, first
    starts = used.nonzero()[:, 0]  # one host read
    if starts.shape[0] < F:  # index the tables of the starts in use
        first = (used.cumsum(0) - 1)[first]
    table, pairs = _span_tables(ctrl, starts, p)
    return table, pairs, first


# ----------------------------------------------------------------------------- fused derivatives

def _compose(D: list[Tensor], h: _taylor.Jet) -> list[Tensor]:
    r"""Taylor coefficients of :math:`f(s(t))` from the derivatives ``D[m]`` :math:`=
    f^{(m)}(s_0)` and the normalised Taylor coefficients ``h = [None, s_1, s_2, ...]`` of
    :math:`s` (Faà di Bruno): :math:`\sum_m D_m (s - s_0)^m / m!`, truncated."""
    order = len(h) - 1
    terms: list[list[Tensor]] = [[] for _ in range(order + 1)]
    power = h
    for m in range(1, order + 1):
        scaled = D[m] / math.factorial(m) if m > 1 else D[m]
        for k in range(m, order + 1):
            terms[k].append(cast(Tensor, power[k]) * scaled)
        if m < order:
            power = _taylor.mul(power, h)
    return [D[0], *(sum(x[1:], x[0]) for x in terms[1:])]


def _s_derivatives(F: Tensor, Fs: Tensor, G: Tensor, Gs: Tensor, th2: Tensor, kappa: Tensor,
                   count: int) -> tuple[list[Tensor], list[Tensor]]:
    r"""The derivatives :math:`\partial_s^m F`, :math:`\partial_s^m G`, ``m < count`` (at
    least 2), of eq. 11's weights (or of sums of them) from their values and slopes by
    :math:`\partial_s^2 F = -\theta^2 F`, :math:`\partial_s^2 G = -\kappa F - \theta^2 G`
    (:func:`angle_square`)."""
    DF, DG = [F, Fs], [G, Gs]
    for m in range(2, count):
        DF.append(-th2 * DF[m - 2])
        DG.append(-(kappa * DF[m - 2] + th2 * DG[m - 2]))
    return DF, DG


def _h_derivatives(DF: list[Tensor], DG: list[Tensor], H: Tensor, Hs: Tensor, th2: Tensor,
                   kappa: Tensor, kappa_y: Tensor) -> list[Tensor]:
    r""":math:`\partial_s^m H = \partial_y \partial_s^m G` (as :func:`_s_derivatives`, for
    ``m < len(DF)``) by :math:`\partial_s^2 H = -\kappa' F - 2 \kappa G - \theta^2 H`: the
    derivative in :math:`y` of the second equation, as ``DG`` is that of ``DF``."""
    DH = [H, Hs]
    for m in range(2, len(DF)):
        DH.append(-(kappa_y * DF[m - 2] + 2.0 * kappa * DG[m - 2] + th2 * DH[m - 2]))
    return DH


class _BagParts(NamedTuple):
    r"""What :class:`_BagJets`' backward keeps: the real parts of the factors of the subsets
    (``b_r (L, 2, p, n)``) and of the total weight (``t_r (L, 1, p, n)``); the jets of
    their derivatives in :math:`y`, ``CG`` (of ``b_r``; also the dual parts per unit
    :math:`-\delta`), ``CH`` (of ``CG``), ``TG``, ``TH`` (the same for ``t``); ``delta (p,
    n)``; and the levels of both products (:func:`_subset_levels`)."""

    b_r: Tensor
    CG: Tensor
    CH: Tensor
    t_r: Tensor
    TG: Tensor
    TH: Tensor
    delta: Tensor
    levels_b: list[tuple[Tensor, Tensor]]
    levels_t: list[tuple[Tensor, Tensor]]

    def tensors(self) -> list[Tensor]:
        """Every tensor, flat (:meth:`rebuild` inverts it)."""
        return [*self[:7], *(x for lv in (self.levels_b, self.levels_t) for pair in lv
                             for x in pair)]

    @staticmethod
    def rebuild(items: list[Tensor]) -> _BagParts:
        """The parts from :meth:`tensors`."""
        b_r, CG, CH, t_r, TG, TH, delta = items[:7]
        pairs = list(zip(items[7::2], items[8::2], strict=True))
        half = len(pairs) // 2
        return _BagParts(b_r, CG, CH, t_r, TG, TH, delta, pairs[:half], pairs[half:])


def _weight_jets(full: Tensor, squares: Tensor, f: Tensor, w: list[Tensor]) -> Tensor:
    r"""The bags' weights of :func:`_span_tables`' expansion and their time derivatives,
    ``(L, 2K, n)`` (order first, real parts above dual parts; the empty subset's rows hold
    the total weight, :func:`_difference_table`), at times reading the span starts ``f
    (n,)``, from the ``L`` normalised Taylor coefficients ``w``, ``(p, n)`` each, of the
    cumulative basis (any ``L``); ``full``: :func:`_full_pairs`, ``squares (3, p, F)``:
    :func:`angle_square` of the pairs.

    The span's frames are constant in time, so only the powers' dual weights
    :math:`\beta_j = F(1 - w_j) - \epsilon\delta_j G(1 - w_j)`,
    :math:`\alpha_j = \sigma_j (F(w_j) - \epsilon\delta_j G(w_j))` move. Their derivatives
    in ``s`` follow from eq. 11's weights and slopes (:func:`screw_weights`) by
    :math:`\partial_s^2 F = -\theta^2 F`, :math:`\partial_s^2 G = -\kappa F - \theta^2 G`
    (:func:`angle_square`), their jets in time by composition with :math:`w_j(t)`
    (:func:`_compose`), and :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S}
    \beta_j` is a Cauchy product of dual-number jets (:class:`_SubsetJets`). Torch ops on
    ``(L, 2, p, n)`` rows; where reverse mode differentiates the pairs alone, eagerly, one op
    whose backward is written out (:class:`_BagJets`).
    """
    if _BagJets.applies(full, squares, w):
        return _BagJets.apply(full, squares, f, *w)
    return _bag_jets(full, squares, f, w)[0]


def _bag_jets(full: Tensor, squares: Tensor, f: Tensor, w: list[Tensor],
              keep: bool = False) -> tuple[Tensor, _BagParts | None]:
    """:func:`_weight_jets` and, with ``keep``, :class:`_BagParts`."""
    fr, slopes, _ = _chunk_weights(full, f, w[0], True, True, keep)
    ws = cast(WeightSlopes, slopes)
    th2, kappa, kappa_y = squares.flatten(0, 1).index_select(1, f).view(3, -1, f.shape[0])
    Fs, Gs = cast(Tensor, ws.Fs), cast(Tensor, ws.Gs)
    DF, DG = _s_derivatives(ws.F, Fs, ws.G, Gs, th2, kappa, len(w))
    h: _taylor.Jet = [None, *(torch.stack((-x, x)) for x in w[1:])]  # s = (1 - w, w)
    sig = _signs(fr.sigma)
    b_r, CG = (torch.stack(_compose(D, h)) * sig for D in (DF, DG))
    b_d = CG * -fr.delta
    levels: list[list[tuple[Tensor, Tensor]]] | None = [] if keep else None
    W = _products(b_r, b_d, levels)
    # The empty subset's rows 0 and K weigh c_f by the total sum_S w_S = prod_j (beta_j +
    # alpha_j), each factor F(1 - w) + sigma F(w) - eps delta (G(1 - w) + sigma G(w)) as a
    # function of w. Its slope -F_s(1 - w) + F_s(w) cancels on a slow span: for sigma = 1 it
    # is theta sin((1/2 - w) theta) / cos(theta / 2) (the sum is cos((1/2 - w) theta) /
    # cos(theta / 2)), from theta^2 and sinc((1/2 - w) theta), exact to the last bits.
    u = 0.5 - w[0]
    slope = th2 * u * even("sinc", u * u * th2) / torch.sqrt(0.5 * (1.0 + fr.c))
    neg = _signs(fr.sigma, -1.0)
    TF, TG = _s_derivatives((ws.F * sig).sum(0),
                            torch.where(fr.sigma > 0, slope, (Fs * neg).sum(0)),
                            (ws.G * sig).sum(0), (Gs * neg).sum(0), th2, kappa, len(w))
    hw: _taylor.Jet = [None, *w[1:]]
    t_r, t_G = (torch.stack(_compose(D, hw))[:, None] for D in (TF, TG))
    t_d = t_G * -fr.delta
    total = _products(t_r, t_d, levels)
    K = W.shape[1] // 2
    W = W.index_copy(1, torch.tensor([0, K], device=W.device), total)
    W = W * _factorials(W, len(w))
    if not keep:
        return W, None
    H, Hs = ws.H, cast(Tensor, ws.Hs)
    DH = _h_derivatives(DF, DG, H, Hs, th2, kappa, kappa_y)
    TH = _h_derivatives(TF, TG, (H * sig).sum(0), (Hs * neg).sum(0), th2, kappa, kappa_y)
    kept = cast(list, levels)
    return W, _BagParts(b_r, CG, torch.stack(_compose(DH, h)) * sig, t_r, t_G,
                        torch.stack(_compose(TH, hw))[:, None], fr.delta, *kept)


def _products(b_r: Tensor, b_d: Tensor, kept: list | None) -> Tensor:
    """:class:`_SubsetJets` of the factors; with ``kept`` (in :class:`_BagJets`' forward,
    where autograd records nothing), its levels appended there for the backward."""
    if kept is None:
        return _SubsetJets.apply(b_r, b_d)
    kept.append(_subset_levels(b_r, b_d))
    return torch.cat(kept[-1][-1], 1)


def _factorials(W: Tensor, count: int) -> Tensor:
    """``(count, 1, 1)``: ``k!``, the derivatives' scale of the normalised coefficients."""
    return W.new_tensor([float(math.factorial(k)) for k in range(count)])[:, None, None]


class _BagJets(torch.autograd.Function):
    r""":func:`_weight_jets` with its backward written out, for cotangents of the pairs alone
    (``full``: :math:`\delta` and :math:`y = 1 - c`).

    Every quantity of a factor is a function of its pair's :math:`y` (the weights, their
    slopes, :math:`\theta^2`, :math:`\kappa`) and, linearly, :math:`\delta`; and
    :math:`\partial_y \partial_s^m F = \partial_s^m G`, :math:`\partial_y \partial_s^m G =
    \partial_s^m H` (:func:`_h_derivatives`), so the derivative in :math:`y` of a factor's
    jets is the composition of the next weight's (``CG``, ``CH``). The subsets' cotangents
    come from :func:`_subset_vjp`; the total derivatives in :math:`y` go to the row of ``y``
    (the angle rows and ``squares`` get none: their part is in it). Where the backward is
    itself differentiated or batched, the plain ops' VJP."""

    @staticmethod
    def applies(full: Tensor, squares: Tensor, w: list[Tensor]) -> bool:
        """Whether :func:`_weight_jets` takes this op: eager reverse mode on the pairs alone
        (the basis' gradient, for ``t`` and the knots, through the plain ops), with ``y`` in
        ``full`` (``7 p`` rows: it carries the total derivative in ``y``, ``squares`` none)."""
        return full.shape[0] == 7 * w[0].shape[0] and written_backward([full], list(w))

    @staticmethod
    def forward(ctx, full: Tensor, squares: Tensor, f: Tensor, *w: Tensor) -> Tensor:
        W, parts = _bag_jets(full, squares, f, list(w), keep=True)
        save(ctx, [full, squares, f, *w, *cast(_BagParts, parts).tensors()])
        ctx.count = len(w)
        return W

    @staticmethod
    def backward(ctx, gW):
        items = cast(list[Tensor], saved(ctx))
        full, squares, f, w = items[0], items[1], items[2], items[3:3 + ctx.count]
        none = (None,) * (1 + len(w))  # f, w
        if batched(gW) or torch.is_grad_enabled():
            return (*reference_vjp(lambda a, b: _bag_jets(a, b, f, w)[0], (full, squares), gW),
                    *none)
        p = _BagParts.rebuild(items[3 + ctx.count:])
        gW = gW * _factorials(gW, len(w))
        at = torch.tensor([0, gW.shape[1] // 2], device=gW.device)
        gb_r, gb_d = _subset_vjp(p.levels_b, p.b_r, p.CG * -p.delta,
                                 gW.index_fill(1, at, 0.0))
        gt_r, gt_d = _subset_vjp(p.levels_t, p.t_r, p.TG * -p.delta, gW.index_select(1, at))
        gy = ((gb_r * p.CG - p.delta * gb_d * p.CH).sum((0, 1))
              + (gt_r * p.TG - p.delta * gt_d * p.TH).sum((0, 1)))
        gdelta = -((gb_d * p.CG).sum((0, 1)) + (gt_d * p.TG).sum((0, 1)))
        n_p = gy.shape[0]
        rows = full.new_zeros(2 * n_p, full.shape[1]).index_add(
            1, f, torch.cat((gdelta, gy)))
        grad = full.new_zeros(7, n_p, full.shape[1])
        grad[1], grad[6] = rows[:n_p], rows[n_p:]
        return grad.view(full.shape), None, *none


def _difference_table(table: Tensor, width: int) -> Tensor:
    r""":func:`_span_tables`' rows with the empty subset's :math:`T_\emptyset = c_f` kept and
    subtracted from the others (real and shifted rows alike): :math:`\sum_S w_S T_S =
    (\sum_S w_S)\, c_f + \sum_{S \ne \emptyset} w_S (T_S - c_f)`. For the time
    derivatives, whose weights sum to nearly nothing on a slow span: summed as they are, the
    rounding of the large weights times :math:`|c_f|` (a translation far from the origin)
    swamps the result (float32: 6e-3 m/s^2 for a robot standing still 17 m away)."""
    blocks = table.view(-1, 2, width // 2, 8)
    base = blocks[:, :, :1]
    return torch.cat((base, blocks[:, :, 1:] - base), 2).view(-1, 8)


def _cauchy(a: Tensor, b: Tensor) -> Tensor:
    r"""Cauchy products :math:`(ab)_k = \sum_{i \le k} a_i b_{k-i}` of jets stacked along the
    leading dim (``L`` coefficients; the other dims broadcast): one product per
    coefficient of ``a``, added into the shifted rows."""
    out = a[0] * b
    for i in range(1, a.shape[0]):
        out[i:] += a[i] * b[:-i]
    return out


def _cauchy_vjp(a: Tensor, g: Tensor) -> Tensor:
    r"""The cotangent of ``b`` in :func:`_cauchy` ``(a, b)`` (unreduced over broadcast
    dims): :math:`\sum_{k \ge i} g_k a_{k-i}`."""
    out = a[0] * g
    for i in range(1, a.shape[0]):
        out[:-i] += a[i] * g[i:]
    return out


def _subset_levels(b_r: Tensor, b_d: Tensor) -> list[tuple[Tensor, Tensor]]:
    r"""The dual weights :math:`w_S` level by level, on jets stacked coefficient first:
    ``b_r, b_d (L, 2, p, n)`` the Taylor coefficients of the real and dual parts of
    :math:`(\beta_j, \alpha_j)` (``L = 1``: their values); level ``j`` holds the products over
    ``1..j``, ``(L, 2^j, n)`` each (index ``m``: bit ``i - 1`` set for :math:`\alpha_i`),
    Cauchy products of dual numbers (:func:`_cauchy`)."""
    levels = [(b_r[:, :, 0], b_d[:, :, 0])]
    for j in range(1, b_r.shape[2]):
        w_r, w_d = (x[:, None] for x in levels[-1])  # (L, 1, 2^j, n) beside (L, 2, 1, n)
        r, d = b_r[:, :, j, None], b_d[:, :, j, None]
        levels.append((_cauchy(r, w_r).flatten(1, 2),
                       (_cauchy(r, w_d) + _cauchy(d, w_r)).flatten(1, 2)))
    return levels


def _subset_vjp(levels: list[tuple[Tensor, Tensor]], b_r: Tensor, b_d: Tensor,
                grad: Tensor) -> tuple[Tensor, Tensor]:
    """Cotangents of ``b_r, b_d (L, o, p, n)`` (``o`` options per factor) from ``grad (L,
    2 o^p, n)``, those of the last level's real and dual parts one above the other (as the
    bags' weights): the levels' products transposed (:func:`_cauchy_vjp`)."""
    g_r, g_d = grad.chunk(2, 1)
    gb_r, gb_d = [], []
    for j in range(b_r.shape[2] - 1, 0, -1):
        w_r, w_d = (x[:, None] for x in levels[j - 1])
        r, d = b_r[:, :, j, None], b_d[:, :, j, None]
        g_r, g_d = (x.unflatten(1, (b_r.shape[1], -1)) for x in (g_r, g_d))
        gb_r.append((_cauchy_vjp(w_r, g_r) + _cauchy_vjp(w_d, g_d)).sum(2))
        gb_d.append(_cauchy_vjp(w_r, g_d).sum(2))
        g_r, g_d = ((_cauchy_vjp(r, g_r) + _cauchy_vjp(d, g_d)).sum(1),
                    _cauchy_vjp(r, g_d).sum(1))
    gb_r.append(g_r)
    gb_d.append(g_d)
    return torch.stack(gb_r[::-1], 2), torch.stack(gb_d[::-1], 2)


def _subset_jets(b_r: Tensor, b_d: Tensor) -> Tensor:
    """:class:`_SubsetJets`' output in differentiable torch ops, ``(L, 2K, n)``."""
    return torch.cat(_subset_levels(b_r, b_d)[-1], 1)


class _SubsetJets(torch.autograd.Function):
    r"""The dual subset weights :math:`w_S = \prod_{j \in S} \alpha_j \prod_{j \notin S}
    \beta_j` on jets: ``b_r, b_d (L, 2, p, n)``, the Taylor coefficients of the real and
    dual parts of :math:`(\beta_j, \alpha_j)` -> ``(L, 2K, n)``, real parts above dual
    parts (:func:`_subset_levels`); with one option per factor, ``(L, 1, p, n)``, their
    product ``(L, 2, n)``. The backward is written out (:func:`_subset_vjp`) instead of
    autograd over hundreds of small products; where it is itself differentiated or batched,
    the plain-op VJP of :func:`_subset_jets`."""

    @staticmethod
    def forward(b_r: Tensor, b_d: Tensor) -> Tensor:
        return _subset_jets(b_r, b_d)

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.save_for_backward(*inputs)

    @staticmethod
    def backward(ctx, grad):
        b_r, b_d = ctx.saved_tensors
        if batched(grad) or torch.is_grad_enabled():
            return reference_vjp(_subset_jets, (b_r, b_d), grad)
        return _subset_vjp(_subset_levels(b_r, b_d), b_r, b_d, grad)


class _Rows(torch.autograd.Function):
    r"""Weighted sums of table rows, :math:`\sum_k W_{l k n}` ``table[first[n] width + k]``
    for each time ``n`` and each set ``l`` of weights: ``table (F * width, 8)``, ``first
    (N,)`` int64, ``W (L, width, N)``, ``runs`` (:func:`_runs`, or ``None``) -> ``L``
    tensors ``(N, 8)`` (each its own, so that a caller may modify one in place). Per run of
    sorted times one small matrix product (:func:`_run_rows`), otherwise one weighted bag
    per time (:func:`_weighted_rows`). Bilinear in ``table`` and ``W``: the backward is the
    transposed map (:func:`_run_cotangents`, or :func:`_segment_outer` and
    :func:`_row_dots`), and in plain torch ops where it is itself differentiated or batched
    (:func:`_plain_rows_vjp`)."""

    @staticmethod
    def forward(table: Tensor, first: Tensor, W: Tensor,
                runs: Runs | None) -> tuple[Tensor, ...]:
        L, width, N = W.shape
        outs = tuple(table.new_empty(N, 8) for _ in range(L))
        for W_l, out in zip(W, outs, strict=True):
            for i, run in _parts(N, runs):
                if run is not None:
                    _run_rows(table.view(-1, width, 8), W_l[:, i], i, run, out)
                else:
                    out[i] = _weighted_rows(table, first[i], W_l[:, i].T)
        return outs

    @staticmethod
    def setup_context(ctx, inputs, output):
        table, first, W, ctx.runs = inputs
        ctx.save_for_backward(table, first, W)
        ctx.set_materialize_grads(False)

    @staticmethod
    def backward(ctx, *grads):
        table, first, W = ctx.saved_tensors
        if batched(*grads) or torch.is_grad_enabled():
            grad = torch.stack([torch.zeros_like(W[0].T) if g is None else g for g in grads])
            return (*_plain_rows_vjp(table, first, W, grad), None)
        width, N = W.shape[1:]
        F = table.shape[0] // width
        blocks = table.view(F, width, 8)
        g_table, g_W = table.new_zeros(F, width, 8), torch.empty_like(W)  # each row written
        for l, grad in enumerate(grads):
            if grad is None:
                g_W[l].zero_()
                continue
            grad = grad.contiguous()
            for i, run in _parts(N, ctx.runs):
                if run is not None:
                    g_W[l, :, i] = _run_cotangents(blocks, W[l, :, i], to_rows(grad[i]), i, run,
                                                   g_table)
                else:
                    g_table += _segment_outer(W[l, :, i].T, grad[i], first[i], F)
                    g_W[l, :, i] = _row_dots(table, first[i], grad[i], F)
        return g_table.view(-1, 8), None, g_W, None


def _plain_rows_vjp(table: Tensor, first: Tensor, W: Tensor,
                    grad: Tensor) -> tuple[Tensor, None, Tensor]:
    """:class:`_Rows`' cotangents of ``table`` and ``W`` in plain torch ops (differentiable
    again; batched under ``vmap``)."""
    blocks = table.view(-1, W.shape[1], 8)
    rows = blocks[first]  # (N, width, 8)
    g_W = (rows * grad[..., None, :]).sum(-1).transpose(-1, -2)  # (L, width, N)
    outer = (W.transpose(-1, -2)[..., None] * grad[..., None, :]).sum(-4)  # (N, width, 8)
    g_table = blocks.new_zeros(blocks.shape).index_add(0, first, outer)
    return g_table.view(-1, 8), None, g_W


def derivatives(ctrl: Tensor, first: Tensor, weights: list[Tensor]) -> list[Tensor]:
    r"""The cumulative form and its time derivatives through the span tables (eager
    reverse mode and ``torch.compile``; :func:`poses` for the poses alone).

    With the expansion of :func:`_span_tables`, :math:`X^{(k)}(t) = \sum_S w_S^{(k)}(t)\,
    T_S`: the tables are constant on a span, so the time derivatives fall on the scalar dual
    weights alone (:func:`_weight_jets`: jets of ``(L, 2, p, n)`` rows, not dual-quaternion
    jets as in :func:`jets`; their backward written out, :class:`_BagJets`, or where the
    basis is differentiated too, the subset products' alone, :class:`_SubsetJets`),
    and each order is one weighted sum of table rows (:class:`_Rows`, analytic backward).
    The tables, the pairs' angles and ``y = 1 - c`` are computed in float64
    (:func:`_difference_table`). Differentiable twice (reverse mode) with
    respect to ``ctrl`` and ``weights``; under ``torch.func`` transforms and forward AD
    (:func:`torch_dq._dispatch.fused_path` false) use :func:`jets`.

    Args:
        ctrl: ``(M, 8)`` sign-aligned control points (several curves may be flattened).
        first: ``(N,)`` int64 index into ``ctrl`` of each time's :math:`c_{r-p}`.
        weights: ``order + 1`` tensors ``(p, N)``, the cumulative basis and its time
            derivatives (:func:`basis`, transposed), in ``ctrl``'s dtype.

    Returns:
        ``order + 1`` tensors ``(N, 8)``: :math:`[X, \dot X, \dots, X^{(order)}]`.
    """
    p, N = weights[0].shape
    order = len(weights) - 1
    if order == 0:
        return [poses(ctrl, first, weights[0])]
    if N == 0:
        return [ctrl[:0] * 1 for _ in weights]
    if _per_time(ctrl, first, p):
        points = ctrl[first[:, None] + torch.arange(p + 1, device=first.device)]
        return jets(points, [w.T for w in weights], order)
    # the tables' products and differences in float64: exact for nearly equal neighbours
    # and the pairs' angles with y = 1 - c (the series' variable: a small angle's y is below
    # float32's resolution at 1, and with it the weights' theta^2 terms)
    table, pairs, first = _tables(ctrl.to(torch.float64), first, p)
    table = _difference_table(table, 2 ** (p + 1)).to(ctrl.dtype)
    full = torch.cat((_full_pairs(pairs), 1.0 - pairs[0])).to(ctrl.dtype)
    squares = torch.stack(angle_square(pairs[0])).to(ctrl.dtype)
    coefs = [w / math.factorial(k) for k, w in enumerate(weights)]
    W = torch.cat([_weight_jets(full, squares, first[i], [w[:, i] for w in coefs])
                   for i in chunks(N, POSES_CHUNK)], -1)
    return list(_Rows.apply(table, first, W, _runs(first)))

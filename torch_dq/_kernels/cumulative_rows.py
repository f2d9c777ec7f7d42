"""The cumulative form's weighted sums of span-table rows (private): per time a weighted bag
of its span's rows (``embedding_bag``), or per run of sorted times one small matrix product,
with their cotangents; :class:`Rows` as one op with its backward written out."""

from __future__ import annotations

import torch
from torch import Tensor

from .._dispatch import batched, opaque_scatter
from .layout import chunks, rows_into, to_rows

__all__ = ["Rows", "Runs", "chunk_parts", "gathered_rows", "row_dots", "run_cotangents",
           "run_rows", "run_sums", "segment_outer", "sorted_runs", "weighted_rows"]

POSES_CHUNK = 16384  # times per eager chunk of the fused poses (fewer, larger ops than 8192)
RUN_MIN_TIMES = 32  # times per span start from which sorted times run per span (sorted_runs)


def _bags(f: Tensor, width: int, rows: int) -> Tensor:
    """``(n, width)`` row indices ``f width + k`` of each time's block of a table of ``rows``
    rows (int32 on CPU where they fit: several times faster to make than int64)."""
    k = torch.arange(width, device=f.device)
    if f.device.type == "cpu" and rows < 2**31:
        k = k.int()
    return torch.add(k, f[:, None].to(k.dtype), alpha=width)


def weighted_rows(table: Tensor, f: Tensor, W: Tensor) -> Tensor:
    """``(n, 8)``: :math:`\\sum_k W_{nk}` ``table[f_n width + k]``, ``W (n, width)``. Under
    ``torch.compile`` a gather, product and sum that inductor fuses (``embedding_bag`` is an
    aten fallback there, several times slower)."""
    width = W.shape[1]
    if torch.compiler.is_compiling():
        return gathered_rows(table, f, W)
    return torch.nn.functional.embedding_bag(_bags(f, width, table.shape[0]), table,
                                             mode="sum", per_sample_weights=W)


def gathered_rows(table: Tensor, f: Tensor, W: Tensor) -> Tensor:
    """:func:`weighted_rows` as a gather, products and sum of plain ops ``(n, 8)``. The sum
    over the ``width`` rows is written out term by term, an elementwise expression: as a
    reduction, inductor (CPU) parallelised it over its 16 terms, one OpenMP region per
    time, 10x slower than the eager op."""
    rows = table.view(-1, W.shape[1], 8)[f]
    out = rows[:, 0] * W[:, :1]
    for k in range(1, W.shape[1]):
        out = torch.addcmul(out, rows[:, k], W[:, k:k + 1])
    return out


def row_dots(table: Tensor, f: Tensor, G: Tensor, F: int) -> Tensor:
    """``(width, n)`` rows: the dot products of each time's table rows ``table[f_n width +
    k]`` with ``G (n, 8)`` (the cotangent of :func:`weighted_rows`' weights). Under
    ``torch.compile`` a fused gather and sum, otherwise ``embedding_bag`` over the
    transposed table's rows ``(f, component)``."""
    blocks = table.view(F, -1, 8)
    if torch.compiler.is_compiling():  # components leading: inductor reduces across rows
        return (blocks.permute(1, 2, 0)[..., f] * G.T).sum(1)
    columns = blocks.transpose(1, 2).reshape(F * 8, -1)
    return to_rows(torch.nn.functional.embedding_bag(
        _bags(f, 8, columns.shape[0]), columns, mode="sum", per_sample_weights=G))


def segment_outer(W: Tensor, G: Tensor, f: Tensor, F: int) -> Tensor:
    r""":math:`\sum_{n: f_n = s} W_n \otimes G_n` for every span start ``s``: ``W (n, k)``,
    ``G (n, 8)`` -> ``(F, k, 8)``, a scatter of the outer products (differentiable; sorted
    times run per span instead, :func:`sorted_runs`); :func:`_segment_outer_op` where
    :func:`~torch_dq._dispatch.opaque_scatter`."""
    if opaque_scatter(W):
        return _segment_outer_op(W, G, f, F)
    return W.new_zeros(F, W.shape[1], 8).index_add(0, f, W[:, :, None] * G[:, None, :])


@torch.library.custom_op("torch_dq::segment_outer", mutates_args=())
def _segment_outer_op(W: Tensor, G: Tensor, f: Tensor, F: int) -> Tensor:
    """:func:`segment_outer` as one matrix product per span start over the times sorted by
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


def sorted_runs(first: Tensor) -> Runs | None:
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


def run_rows(blocks: Tensor, W: Tensor, part: slice, runs: list[tuple[int, int, int]],
              out: Tensor) -> None:
    """:func:`weighted_rows` per run, in place: ``out[a:b] = W[:, a:b]^T blocks[f]`` for the
    runs ``(a, b, f)`` of the chunk ``part``, ``W (width, n)`` its weights in rows, ``blocks
    (F, width, 8)`` the table. The products are taken in rows, ``blocks[f]^T W[:, a:b]``
    (about 3x faster than the transposed product on CPU), and copied into ``out`` once."""
    rows = W.new_empty(8, W.shape[1])
    for a, b, f in runs:
        torch.mm(blocks[f].T, W[:, a - part.start:b - part.start],
                 out=rows[:, a - part.start:b - part.start])
    rows_into(out[part], rows)


def run_cotangents(blocks: Tensor, W: Tensor, grad: Tensor, part: slice,
                    runs: list[tuple[int, int, int]], g_table: Tensor) -> Tensor:
    """The cotangents of :func:`run_rows`' weights, ``(width, n)`` rows (``blocks[f]
    grad[a:b]^T`` per run), and in place the table's: ``W[:, a:b] grad[a:b]`` added to
    ``g_table[f] (width, 8)`` (not differentiable: first-order backward only). ``grad``
    is the chunk's, in rows ``(8, n)``."""
    gW = W.new_empty(W.shape)
    for a, b, f in runs:
        cols = slice(a - part.start, b - part.start)
        torch.mm(blocks[f], grad[:, cols], out=gW[:, cols])
        g_table[f].addmm_(W[:, cols], grad[:, cols].T)
    return gW


def run_sums(x: Tensor, runs: list[tuple[int, int, int]], total: Tensor) -> Tensor:
    """``total (..., F)`` plus the sums of ``x (..., n)`` over each run's times, at its span
    start (the chunk's runs in order, covering ``x``)."""
    sums = torch.stack([y.sum(-1) for y in x.split([b - a for a, b, _ in runs], -1)], -1)
    return total.index_add(-1, x.new_tensor([f for *_, f in runs], dtype=torch.long), sums)


def chunk_parts(N: int, runs: Runs | None, device: torch.device
                ) -> Runs | list[tuple[slice, None]]:
    """The chunks of the fused op: ``runs`` (:func:`sorted_runs`) if given, else
    :func:`~torch_dq._kernels.layout.chunks` of :data:`POSES_CHUNK` times on ``device``,
    without runs."""
    return runs if runs is not None else [(i, None) for i in chunks(N, POSES_CHUNK, device)]


class Rows(torch.autograd.Function):
    r"""Weighted sums of table rows, :math:`\sum_k W_{l k n}` ``table[first[n] width + k]``
    for each time ``n`` and each set ``l`` of weights: ``table (F * width, 8)``, ``first
    (N,)`` int64, ``W (L, width, N)``, ``runs`` (:func:`sorted_runs`, or ``None``) -> ``L``
    tensors ``(N, 8)`` (each its own, so that a caller may modify one in place). Per run of
    sorted times one small matrix product (:func:`run_rows`), otherwise one weighted bag
    per time (:func:`weighted_rows`). Bilinear in ``table`` and ``W``: the backward is the
    transposed map (:func:`run_cotangents`, or :func:`segment_outer` and
    :func:`row_dots`), and in plain torch ops where it is itself differentiated or batched
    (:func:`_plain_rows_vjp`)."""

    @staticmethod
    def forward(table: Tensor, first: Tensor, W: Tensor,
                runs: Runs | None) -> tuple[Tensor, ...]:
        L, width, N = W.shape
        outs = tuple(table.new_empty(N, 8) for _ in range(L))
        for W_l, out in zip(W, outs, strict=True):
            for i, run in chunk_parts(N, runs, table.device):
                if run is not None:
                    run_rows(table.view(-1, width, 8), W_l[:, i], i, run, out)
                else:
                    out[i] = weighted_rows(table, first[i], W_l[:, i].T)
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
            grad = torch.stack([table.new_zeros(W.shape[-1], 8) if g is None else g for g in grads])
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
            for i, run in chunk_parts(N, ctx.runs, table.device):
                if run is not None:
                    g_W[l, :, i] = run_cotangents(blocks, W[l, :, i], to_rows(grad[i]), i, run,
                                                   g_table)
                else:
                    g_table += segment_outer(W[l, :, i].T, grad[i], first[i], F)
                    g_W[l, :, i] = row_dots(table, first[i], grad[i], F)
        return g_table.view(-1, 8), None, g_W, None


def _plain_rows_vjp(table: Tensor, first: Tensor, W: Tensor,
                    grad: Tensor) -> tuple[Tensor, None, Tensor]:
    """:class:`Rows`' cotangents of ``table`` and ``W`` in plain torch ops (differentiable
    again; batched under ``vmap``)."""
    blocks = table.view(-1, W.shape[1], 8)
    rows = blocks[first]  # (N, width, 8)
    g_W = (rows * grad[..., None, :]).sum(-1).transpose(-1, -2)  # (L, width, N)
    outer = (W.transpose(-1, -2)[..., None] * grad[..., None, :]).sum(-4)  # (N, width, 8)
    g_table = blocks.new_zeros(blocks.shape).index_add(0, first, outer)
    return g_table.view(-1, 8), None, g_W

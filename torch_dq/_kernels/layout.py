"""Component-row layout and cache-sized chunks of the fused kernels (private)."""

from __future__ import annotations

import torch
from torch import Tensor

CHUNK = 65536  # pairs per eager chunk: temporaries stay in cache, ops still use 2 threads
# The fused curve scheme keeps ~m (m + 1) / 2 slabs of 8 rows alive per chunk: smaller chunks
# keep its forward+backward peak memory a small multiple of the output.
PYRAMID_CHUNK = 8192
# Off the CPU every op is a kernel launch of ~5-10 us and memory is ~100x faster than a CPU's
# cache: CPU-sized chunks leave a GPU launch-bound (1e8 float32 sclerp pairs, 1526 chunks of
# ~60 ops: 1.8 s on an H200 where the bytes take 2.4 ms to copy). There the chunks are
# DEVICE_SCALE times larger, still bounding the temporaries (2M pairs: 8 float64 rows of 134
# MB each).
DEVICE_SCALE = 32


def chunks(n: int, size: int | None = None, device: torch.device | None = None) -> list[slice]:
    """Slices of the flattened batch evaluated one after the other.

    In eager mode each op of the kernel allocates a fresh temporary; over cache-sized chunks
    those stay in cache and are recycled by the allocator (about 3x faster on CPU for 1e6
    pairs). On another ``device`` (a GPU) the chunks are :data:`DEVICE_SCALE` times larger.
    Under ``torch.compile`` the whole batch is one graph.
    """
    size = CHUNK if size is None else size
    if device is not None and device.type != "cpu":
        size *= DEVICE_SCALE
    if torch.compiler.is_compiling() or n <= size:
        return [slice(None)]
    return [slice(i, i + size) for i in range(0, n, size)]


def to_rows(x: Tensor) -> Tensor:
    """``(N, k)`` -> contiguous ``(k, N)`` component rows.

    The kernels below work on such rows, ``(..., 8, N)``: every elementwise op then runs over
    contiguous length-N rows and every dot product is a sum of rows, instead of broadcasting
    over a trailing dim of 4 or 8 (several times slower on CPU). The copy goes through a
    3-d permutation, which torch's CPU copy runs 2-3x faster than a 2-d transpose.
    """
    return x.unsqueeze(-1).permute(1, 2, 0).contiguous().squeeze(1)


def from_rows(x: Tensor) -> Tensor:
    """Inverse of :func:`to_rows`: ``(k, N)`` rows -> contiguous ``(N, k)``."""
    return x.unsqueeze(1).permute(2, 0, 1).contiguous().squeeze(-1)


def rows_into(out: Tensor, x: Tensor) -> None:
    """:func:`from_rows` written into ``out`` (``(N, k)``, e.g. a chunk's slice of the
    result): saves the concatenation of the chunks, a full extra pass over the output."""
    out.unsqueeze(1).copy_(x.unsqueeze(1).permute(2, 1, 0))


def coef(x: Tensor) -> Tensor:
    """An ``(..., N)`` coefficient broadcast over the component axis of ``(..., k, N)`` rows."""
    return x.unsqueeze(-2)

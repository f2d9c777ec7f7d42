"""The banded Cholesky factorisation, its solves and its selected inverse in compiled C
(private): ``csrc/banded.c``, a sequential scalar banded Cholesky (LAPACK ``dpbtf2``'s
order) and Takahashi's recursion on it, looping in C over the batch, behind
``torch_dq.fitting._banded.BandedCholesky`` (whose block cyclic reduction is the reference
and runs where ``torch_dq._kernels.native.enabled`` does not hold; the tests compare
both, ``tests/test_band18_banded.py``).

The factor of a matrix of ``n`` block rows of size ``s`` and band width ``w`` blocks is
its upper factor (:math:`A = U^T U`) by rows, ``U (*batch, N, p + 1)``: ``N = G g s`` rows
(the band's ``n s`` and identity rows up to whole groups of ``g = max(w - 1, 1)`` block
rows, as the PyTorch path's grouping), ``p = w s - 1`` its scalar bandwidth, row ``j``'s
entries ``U(j, j .. j + p)`` (LAPACK ``dpbtrf``'s upper band, a row per column).
"""

from __future__ import annotations

import ctypes

import torch
from torch import Tensor

from . import native

__all__ = ["band_inverse", "factor", "selected_inverse", "solve"]

_P, _I = ctypes.c_void_p, ctypes.c_int64


_FACTOR = ("tdq_band_factor", (_P, _P, _I, _I, _I, _I, _I, _P, _P))
_SOLVE = ("tdq_band_solve", (_P, _I, _I, _I, _I, _I, _P))
_INVERSE = ("tdq_band_selected_inverse", (_P, _I, _I, _I, _I, _P, _P, _I, _I, _I, _P),
            ctypes.c_int)


def factor(band: Tensor, shift: Tensor | None, rows: int) -> tuple[Tensor, Tensor]:
    """The factor ``U (*batch, rows, w s)`` of ``band (*batch, n, w, s, s)`` plus
    ``diag(shift)`` (``shift (..., n, s)`` broadcast to the batch, or None), ``rows`` its
    padded rows, and ``ok (*batch)`` bool (False: not positive definite, that element's
    ``U`` the identity)."""
    *batch, n, w, s, _ = band.shape
    band = band.contiguous()
    if shift is not None:
        shift = shift.expand(*batch, n, s).contiguous()
    U = band.new_empty(*batch, rows, w * s)
    ok = torch.empty(batch, dtype=torch.uint8)
    native.function(*_FACTOR)(
        native.address(band), None if shift is None else native.address(shift),
        int(torch.Size(batch).numel()), n, w, s, rows, native.address(U), native.address(ok))
    return U, ok.bool()


def solve(U: Tensor, rhs: Tensor) -> Tensor:
    """``A^-1 rhs`` for ``rhs (*batch, n, s, r)`` (batch broadcast with the factor's):
    a new tensor."""
    *rb, n, s, r = rhs.shape
    batch = torch.broadcast_shapes(U.shape[:-2], torch.Size(rb))
    Ub = U.expand(*batch, *U.shape[-2:]).contiguous()
    x = rhs.expand(*batch, n, s, r).clone(memory_format=torch.contiguous_format)
    native.function(*_SOLVE)(native.address(Ub), int(batch.numel()), U.shape[-2],
                             U.shape[-1] - 1, n * s, r, native.address(x))
    return x


def selected_inverse(U: Tensor, b: int) -> tuple[Tensor, Tensor]:
    """The blocks of :math:`A^{-1}` of the grouped matrix (groups of ``b = g s`` rows):
    ``diag (*batch, G, b, b)`` and ``sub (*batch, G, b, b)`` (``sub[j]`` groups
    ``(j + 1, j)``, the last one zero), as ``BandedCholesky.selected_inverse``'s."""
    *batch, N, _ = U.shape
    diag, sub = U.new_empty(*batch, N // b, b, b), U.new_empty(*batch, N // b, b, b)
    _inverse(U, b, diag, sub, (0, 0, 0), None)
    return diag, sub


def band_inverse(U: Tensor, n: int, w: int, s: int) -> Tensor:
    """The blocks of :math:`A^{-1}` inside the matrix's band, ``(*batch, n, w, s, s)`` as
    the band (block ``(k, k + d)`` at ``[..., k, d]``; zero past the last block row): the
    recursion to the band's width only."""
    out = U.new_empty(*U.shape[:-2], n, w, s, s)
    _inverse(U, 0, None, None, (n, w, s), out)
    return out


def _inverse(U: Tensor, b: int, diag: Tensor | None, sub: Tensor | None,
             nws: tuple[int, int, int], band: Tensor | None) -> None:
    """``tdq_band_selected_inverse`` into the given outputs (None: not wanted)."""
    *batch, N, q = U.shape
    if native.function(*_INVERSE)(native.address(U), int(torch.Size(batch).numel()), N, q - 1, b,
                       *(None if x is None else native.address(x) for x in (diag, sub)),
                       *nws, None if band is None else native.address(band)):
        raise MemoryError("torch_dq: no memory for the compiled selected inverse's buffer")

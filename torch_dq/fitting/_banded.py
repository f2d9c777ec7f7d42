r"""Symmetric positive definite block-banded matrices: Cholesky, solves, selected inverse.

A matrix of ``n`` block rows of size ``s`` whose block ``(k, k + d)`` vanishes for
``d >= w`` is stored as its upper band ``band (..., n, w, s, s)`` (block ``(k, k + d)`` at
``band[..., k, d]``). Grouping ``g = max(w - 1, 1)`` consecutive block rows makes it
block-tridiagonal with ``G`` diagonal blocks ``D_j`` and sub-diagonal blocks ``E_j`` (group
``j`` against group ``j - 1``, ``E_0 = 0``), of size ``b = g s``.

The factorisation is *block cyclic reduction* (odd-even reduction; Heller, "Some aspects of
the cyclic reduction algorithm for block tridiagonal linear systems", SIAM J. Numer. Anal.
13, 1976): the even groups do not touch each other, so all of them are eliminated at once
(batched Cholesky factors :math:`C_i C_i^T = D_i`, :math:`L_i = C_i^{-1} E_i`,
:math:`R_i = C_i^{-1} E_{i+1}^T`), which leaves a block-tridiagonal Schur complement on the
odd groups,

.. math::
    D'_k = D_k - R_{k-1}^T R_{k-1} - L_{k+1}^T L_{k+1}, \qquad
    E'_k = -R_{k-1}^T L_{k-1},

reduced in turn: :math:`\lceil \log_2 G \rceil` batched levels in place of ``G`` sequential
steps, :math:`O(n b^2)` flops. It is the Cholesky factorisation of the matrix with its
groups permuted (odd-even order), so it is as stable as Cholesky on a positive definite
matrix. The selected inverse (Takahashi's recursion, from the coarsest level back:
:math:`\Sigma_{i,i\pm1} = -D_i^{-1} (E_i \Sigma_{i-1,i\pm1} + E_{i+1}^T \Sigma_{i+1,i\pm1})`,
:math:`\Sigma_{ii} = D_i^{-1} - D_i^{-1} (E_i \Sigma_{i-1,i} + E_{i+1}^T \Sigma_{i+1,i})`)
gives the blocks of :math:`A^{-1}` inside the band of the grouped matrix (the covariance of
every ``g + 1`` consecutive block rows) without forming the dense inverse.

Where the compiled kernels may run (``torch_dq._kernels.native.enabled``: float64 on the
CPU, nothing needing a gradient) the matrix is factored instead by a sequential scalar
banded Cholesky in C (``torch_dq._kernels.banded_native``: LAPACK ``dpbtf2``'s
factorisation, :math:`O(n s (w s)^2)` flops in one pass, the batch looped over), solved by
substitution, and its selected inverse taken by Takahashi's recursion on that factor, in the
same grouped layout; the cyclic reduction is the reference the tests compare it with, runs
everywhere else, and is built on first need where a call on a compiled factor is not for the
C (a right-hand side needing a gradient).
"""

from __future__ import annotations

import torch
from torch import Tensor

from .._kernels import banded_native, native

__all__ = ["BandedCholesky"]

_CHUNK = 1 << 10  # groups of a selected inverse or low-rank update at once (bounds their
# temporaries: 2.7 MB each at 18 x 18 blocks)


def _grouped(band: Tensor, g: int, below: bool = False) -> Tensor:
    """``D (..., G, g s, g s)`` of the band, or where ``below`` ``E (..., G + 1, g s, g s)``
    (``E[0]`` and ``E[G]`` zero: ``_Level`` reads ``E_{i+1}`` of every even group),
    ``G = ceil(n / g)``: block ``(a, c)`` of ``D_j`` is block ``(j g + a, j g + c)`` of the
    matrix, of ``E_j`` block ``(j g + a, (j - 1) g + c)``, each a strided slice of the band
    written once into its place (no per-element index, no concatenation, no copy of the
    band); the rows past ``n`` (``G g > n``) are identity rows, and the band's blocks past
    the last row are never read into the rest. One at a time (memory: each is the size of
    the band's two thirds at ``w = 4``)."""
    *batch, n, w, s, _ = band.shape
    G = -(-n // g)
    out = band.new_zeros(*batch, G + below, g, s, g, s)
    for a in range(g):
        for c in range(g):
            # E_j (a, c) = band[(j - 1) g + c, g + a - c]^T, zero for j = 0 and past the band;
            # D_j (a, c) = band[j g + min(a, c), |a - c|], transposed below the diagonal
            d = g + a - c if below else abs(a - c)
            if d >= w:
                continue
            if below:
                blk = band[..., c::g, d, :, :][..., :G - 1, :, :]
                out[..., 1:1 + blk.shape[-3], a, :, c, :] = blk.mT
            else:
                blk = band[..., min(a, c)::g, d, :, :]
                out[..., :blk.shape[-3], a, :, c, :] = blk.mT if a > c else blk
    for a in range(n - (G - 1) * g, g):  # the last group's rows past n: identity rows
        out[..., G - 1, a, :, :, :] = 0.0
        if not below:
            out[..., -1, :, :, a, :] = 0.0
            out[..., -1, a, :, a, :] = torch.eye(s, dtype=band.dtype, device=band.device)
    return out.reshape(*batch, G + below, g * s, g * s)


def _pad(x: Tensor, count: int, front: bool = False) -> Tensor:
    """``x (..., G, p, q)`` with zero blocks added to reach ``count`` along ``G`` (at the
    end, or one in front when ``front``)."""
    extra = count - x.shape[-3] if not front else 1
    if extra <= 0:
        return x
    z = x.new_zeros(*x.shape[:-3], extra, *x.shape[-2:])
    return torch.cat((z, x) if front else (x, z), dim=-3)


def _interleave(even: Tensor, odd: Tensor) -> Tensor:
    """Blocks ``even[0], odd[0], even[1], odd[1], ...`` along ``-3`` (``len(even)`` is
    ``len(odd)`` or one more)."""
    G = even.shape[-3] + odd.shape[-3]
    both = torch.stack(torch.broadcast_tensors(even, _pad(odd, even.shape[-3])), dim=-3)
    return both.flatten(-4, -3)[..., :G, :, :]


class _Level:
    """One level of the reduction: the even groups' factors and couplings.

    Attributes:
        C: ``(..., ne, b, b)`` lower Cholesky factors of the even diagonal blocks.
        L, R: ``(..., ne, b, b)`` :math:`C^{-1} E_i` and :math:`C^{-1} E_{i+1}^T` (zero
            where there is no neighbour).
        ok: ``(...)`` every factor succeeded.
    """

    def __init__(self, pair: list[Tensor]) -> None:
        """From ``pair = [D, E]`` (``D (..., G, b, b)``, ``E (..., G or G + 1, b, b)``; the
        list emptied, so that each is freed once read: memory)."""
        D, E = pair
        pair.clear()
        G = D.shape[-3]
        ne, h = (G + 1) // 2, G // 2
        self.G = G
        C, info = torch.linalg.cholesky_ex(D[..., 0::2, :, :])
        odd = D[..., 1::2, :, :].clone()  # D of the next level, less its updates below
        del D
        bad = info != 0
        self.ok = ~bad.any(-1)
        # a failed element continues on the identity: its own results are flagged
        b = C.shape[-1]
        if bool(bad.any()):
            C[bad] = torch.eye(b, dtype=C.dtype, device=C.device)
        self.C = C
        # E_i and E_{i+1}^T (zero past the last group) solved apart: a column's bits are
        # those of one solve of [E_i | E_{i+1}^T], without that copy (memory)
        self.L = torch.linalg.solve_triangular(C, E[..., 0:2 * ne:2, :, :], upper=False)
        self.R = torch.linalg.solve_triangular(
            C, _pad(E[..., 1::2, :, :], ne)[..., :ne, :, :].mT, upper=False)
        del E
        Rprev = self.R[..., :h, :, :]
        self.D = odd.sub_(Rprev.mT @ Rprev)
        nxt = min(ne - 1, h)  # odd group i has an even neighbour i + 1 below it
        self.D[..., :nxt, :, :] -= self.L[..., 1:nxt + 1, :, :].mT @ self.L[..., 1:nxt + 1, :, :]
        self.E = (Rprev.mT @ self.L[..., :h, :, :]).neg_()

    def forward(self, b: Tensor) -> tuple[Tensor, Tensor]:
        """``y`` of the even groups and the right-hand side of the odd ones."""
        h = self.G // 2
        y = torch.linalg.solve_triangular(self.C, b[..., 0::2, :, :], upper=False)
        odd = (b[..., 1::2, :, :] - self.R[..., :h, :, :].mT @ y[..., :h, :, :]
               - _pad(self.L[..., 1:, :, :].mT @ y[..., 1:, :, :], h)[..., :h, :, :])
        return y, odd

    def back(self, y: Tensor, x_odd: Tensor) -> Tensor:
        """All groups' solution from ``y`` and the odd groups' solution."""
        ne = y.shape[-3]
        left = _pad(x_odd, 0, front=True)[..., :ne, :, :]  # x_{i-1}
        right = _pad(x_odd, ne)  # x_{i+1}
        x_even = torch.linalg.solve_triangular(
            self.C.mT, y - self.L @ left - self.R @ right, upper=True)
        return _interleave(x_even, x_odd)

    def inverse(self, diag: Tensor, sub: Tensor) -> tuple[Tensor, Tensor]:
        """The blocks of the inverse at this level, ``(..., G, b, b)`` each, from those of
        the odd groups (``diag``, ``sub``: ``(..., G // 2, b, b)``), ``_CHUNK`` even groups
        at a time, each written once into its place (memory: a chunk's temporaries, no
        padded copies of the odd groups' blocks, no interleaving copy); an end without a
        neighbour takes zero blocks."""
        G, ne = self.G, self.C.shape[-3]
        fine = diag.new_empty(*diag.shape[:-3], G, *diag.shape[-2:])
        fine[..., 1::2, :, :] = diag
        # sub[j] = Sigma_{j+1,j}: Sigma_{i+1,i} for even j = i, Sigma_{i,i-1} for odd j = i - 1
        fine_sub = torch.empty_like(fine)
        fine_sub[..., 2 * ne - 1:, :, :] = 0.0  # past the last group
        for a in range(0, ne, _CHUNK):
            c = slice(a, min(a + _CHUNK, ne))
            fine[..., 2 * c.start:2 * c.stop:2, :, :] = self._inverse_part(c, diag, sub,
                                                                            fine_sub)
        return fine, fine_sub

    def _inverse_part(self, c: slice, diag: Tensor, sub: Tensor, fine_sub: Tensor) -> Tensor:
        """``inverse`` of the even groups ``c``: their blocks to the neighbours written
        into ``fine_sub``, their diagonal blocks ``(..., len(c), b, b)`` returned."""
        h = diag.shape[-3]
        lo = max(c.start, 1)  # the even groups with an odd group k = i - 1 before them
        k, at = slice(lo - 1, c.stop - 1), slice(lo - c.start, None)
        eye = torch.eye(self.C.shape[-1], dtype=self.C.dtype, device=self.C.device)
        Ci = torch.linalg.solve_triangular(self.C[..., c, :, :], eye, upper=False)
        # D^-1 E_i, D^-1 E_{i+1}^T (P_0 = 0, Q_i = 0 past the last group)
        P, Q = Ci.mT @ self.L[..., c, :, :], Ci.mT @ self.R[..., c, :, :]
        # Sigma_{i,i-1} = -(P_i Sigma_{i-1,i-1} + Q_i Sigma_{i+1,i-1}), zero for i = 0
        to_left = torch.zeros_like(P)
        torch.matmul(P[..., at, :, :], diag[..., k, :, :], out=to_left[..., at, :, :])
        to_left[..., at, :, :] += Q[..., at, :, :] @ sub[..., k, :, :]
        to_left.neg_()
        # Sigma_{i,i+1} = -(P_i Sigma_{i-1,i+1} + Q_i Sigma_{i+1,i+1})
        to_right = torch.zeros_like(P)
        r = slice(c.start, min(c.stop, h))  # an odd group k = i after them
        torch.matmul(Q[..., :r.stop - r.start, :, :], diag[..., r, :, :],
                     out=to_right[..., :r.stop - r.start, :, :])
        to_right[..., at, :, :] += P[..., at, :, :] @ sub[..., k, :, :].mT
        to_right.neg_()
        own = Ci.mT @ Ci
        own -= P @ to_left.mT
        own -= Q @ to_right.mT
        fine_sub[..., 2 * c.start:2 * c.stop:2, :, :] = to_right.mT
        fine_sub[..., 2 * lo - 1:2 * c.stop - 1:2, :, :] = to_left[..., at, :, :]
        return (own + own.mT).mul_(0.5)


class BandedCholesky:
    """Cholesky factorisation of a symmetric positive definite block-banded matrix: block
    cyclic reduction, or the compiled sequential banded Cholesky (module doc).

    Args:
        band: ``(..., n, w, s, s)`` upper band (blocks past the last row are ignored).
        shift: ``(..., n, s)`` added to the diagonal, or None (a regularised or damped
            matrix factored without a copy of its band).

    Attributes:
        ok: ``(...)`` bool, False where the matrix is not numerically positive definite (the
            results of those batch elements are meaningless; the others are unaffected).
    """

    def __init__(self, band: Tensor, shift: Tensor | None = None) -> None:
        *batch, n, w, s, _ = band.shape
        g = max(w - 1, 1)
        G = -(-n // g)
        self.n, self.s, self.g, self.G, self.batch = n, s, g, G, tuple(batch)
        self.levels: list[_Level] = []
        self._factor: Tensor | None = None  # the compiled path's (banded_native)
        self._source: tuple[Tensor, Tensor | None] | None = None  # its matrix (the reduction
        # of it where the compiled factor cannot serve a call)
        if native.enabled(band, *(() if shift is None else (shift,))):
            self._factor, self.ok = banded_native.factor(band, shift, G * g * s)
            self._source = band, shift
        else:
            self.ok = self._reduce(band, shift)

    def _reduce(self, band: Tensor, shift: Tensor | None) -> Tensor:
        """The cyclic reduction's levels into ``levels``; returns their ``ok``."""
        g, G, s = self.g, self.G, self.s
        pad = G * g - self.n  # identity rows after the last block row (_grouped)
        # [D, E]: each level frees its input once read (memory)
        pair = [_grouped(band, g), _grouped(band, g, below=True)]
        if shift is not None:
            shift = torch.cat((shift, shift.new_zeros(*shift.shape[:-2], pad, s)), -2)
            pair[0].diagonal(dim1=-2, dim2=-1).add_(shift.reshape(*shift.shape[:-2], G, g * s))
        ok = torch.ones(self.batch, dtype=torch.bool, device=band.device)
        while pair[0].shape[-3]:
            level = _Level(pair)
            ok &= level.ok
            self.levels.append(level)
            pair = [level.D, level.E]
            if level.D.shape[-3]:  # the next level's input, not kept (memory; the last one is)
                del level.D, level.E
        return ok

    def _compiled(self, *tensors: Tensor) -> Tensor | None:
        """The compiled factor where it serves a call on ``tensors``, else None (the cyclic
        reduction's levels then built on first need where the matrix was factored by the
        compiled path: ``tensors`` of another dtype, or needing a gradient)."""
        if self._source is None or native.enabled(*tensors):
            return self._factor
        if not self.levels:
            self._reduce(*self._source)
        return None

    def solve(self, rhs: Tensor) -> Tensor:
        """``A^-1 rhs`` for ``rhs (..., n, s, r)`` (batch broadcast with the matrix's)."""
        n, s, r = rhs.shape[-3:]
        factor = self._compiled(rhs)
        if factor is not None:
            return banded_native.solve(factor, rhs)
        g, G = self.g, self.G
        b = self._groups(rhs)
        ys = []
        for level in self.levels:
            y, b = level.forward(b)
            ys.append(y)
        x = b  # no group left: (..., 0, g s, r)
        for level, y in zip(reversed(self.levels), reversed(ys), strict=True):
            x = level.back(y, x)
        return x.reshape(*x.shape[:-3], G * g, s, r)[..., :n, :, :]

    def selected_inverse(self) -> tuple[Tensor, Tensor]:
        """Blocks of :math:`A^{-1}` of the grouped matrix: ``diag (..., G, g s, g s)`` and
        ``sub (..., G, g s, g s)`` (``sub[j]`` the block of groups ``(j + 1, j)``, the last
        one zero)."""
        factor = self._compiled()
        if factor is not None:
            return banded_native.selected_inverse(factor, self.g * self.s)
        return self._inverse_from(0)

    def _inverse_from(self, first: int) -> tuple[Tensor, Tensor]:
        """``selected_inverse``'s blocks of the groups of level ``first`` (level 1: the
        odd groups of the matrix)."""
        last = self.levels[-1]
        diag = last.D  # (..., 0, b, b)
        sub = last.E
        for level in reversed(self.levels[first:]):
            diag, sub = level.inverse(diag, sub)
        return diag, sub

    def trace_products(self, bands: list[Tensor], U: Tensor | None = None,
                       V: Tensor | None = None) -> list[Tensor]:
        r""":math:`\mathrm{tr}(M (A^{-1} + U V^T))` ``(...)`` for each symmetric block-banded
        ``M`` given by its upper band ``(..., n, w', s, s)`` in ``bands`` (``w' <= g + 1``),
        ``U V^T`` symmetric (``U``, ``V``: ``(..., n, s, r)``; None: none): the elementwise
        products of its grouped blocks with those of the selected inverse plus the update's
        (computed once for all), :math:`\sum_j \langle M_{jj}, \Sigma_{jj} \rangle + 2
        \langle M_{j+1,j}, \Sigma_{j+1,j} \rangle`, the rows past ``n`` left out. The finest
        level's diagonal blocks are taken ``_CHUNK`` groups at a time, as its selected
        inverse makes them (their row sums kept, never the whole diagonal: memory; on the
        compiled path, ``_trace_compiled``, the inverse's blocks inside the band)."""
        factor = self._compiled(*bands, *(x for x in (U, V) if x is not None))
        if factor is not None:
            return self._trace_compiled(factor, bands, U, V)
        g, G, top = self.g, self.G, self.levels[0]
        ne = top.C.shape[-3]
        diag, sub = self._inverse_from(1)  # the odd groups' blocks
        rows = torch.arange(G * g, device=diag.device) < self.n
        real = rows.repeat_interleave(self.s).reshape(G, g * self.s).to(diag.dtype)
        fine_sub = diag.new_empty(*diag.shape[:-3], G, *diag.shape[-2:])
        fine_sub[..., 2 * ne - 1:, :, :] = 0.0  # past the last group
        Ug, Vg = (None, None) if U is None or V is None else (self._groups(x) for x in (U, V))
        sums = [diag.new_empty(*diag.shape[:-3], G, g * self.s) for _ in bands]
        for a in range(0, ne, _CHUNK):  # the diagonal blocks a chunk of groups at a time
            c = slice(a, min(a + _CHUNK, ne))
            own = top._inverse_part(c, diag, sub, fine_sub)
            grp = slice(2 * c.start, min(2 * c.stop, G))  # its even groups and the odd after
            X = own.new_empty(*own.shape[:-3], grp.stop - grp.start, *own.shape[-2:])
            X[..., 0::2, :, :] = own
            X[..., 1::2, :, :] = diag[..., c.start:c.start + X.shape[-3] // 2, :, :]
            if Ug is not None and Vg is not None:
                X += Ug[..., grp, :, :] @ Vg[..., grp, :, :].mT
            for rs, band in zip(sums, bands, strict=True):
                rs[..., grp, :] = _grouped(band[..., grp.start * g:grp.stop * g, :, :, :],
                                           g).mul_(X).sum(-1)
        del diag, sub
        if Ug is not None and Vg is not None:
            for a in range(0, G, _CHUNK):  # the update added in place, a chunk at a time
                p = slice(max(a, 1) - 1, min(a + _CHUNK, G) - 1)  # sub[j] = (j + 1, j)
                fine_sub[..., p, :, :] += Ug[..., p.start + 1:p.stop + 1, :, :] @ Vg[
                    ..., p, :, :].mT
        out = []
        for rs, band in zip(sums, bands, strict=True):  # products in place, one at a time
            below = _grouped(band, g, below=True)[..., 1:G, :, :].mul_(fine_sub[..., :-1, :, :])
            out.append((rs * real).sum((-1, -2)) + 2.0 * below.sum((-1, -2, -3)))
            del below  # before the next band's (memory)
        return out

    def _trace_compiled(self, factor: Tensor, bands: list[Tensor], U: Tensor | None,
                        V: Tensor | None) -> list[Tensor]:
        """``trace_products`` on the compiled path: the inverse's blocks inside the band
        (``banded_native.band_inverse``) plus the update's, times each band's blocks
        (those of ``d > 0`` twice: the lower band's too)."""
        n, s = self.n, self.s
        w = factor.shape[-1] // s
        Z = banded_native.band_inverse(factor, n, w, s)
        if U is not None and V is not None:
            for d in range(min(w, n)):
                Z[..., :n - d, d, :, :] += U[..., :n - d, :, :] @ V[..., d:, :, :].mT
        twice = torch.full((w,), 2.0, dtype=Z.dtype, device=Z.device)
        twice[0] = 1.0
        past = (torch.arange(n)[:, None] + torch.arange(w)) >= n  # blocks past the last row
        out = []
        for band in bands:
            wb = band.shape[-3]
            per = (band * Z[..., :wb, :, :]).sum((-1, -2)).masked_fill_(past[:, :wb], 0.0)
            out.append((per * twice[:wb]).sum((-1, -2)))
        return out

    def _groups(self, x: Tensor) -> Tensor:
        """``x (..., n, s, r)`` as ``(..., G, g s, r)``, zero rows past ``n``."""
        *rb, n, s, r = x.shape
        pad = self.G * self.g - n
        if pad:
            x = torch.cat((x, x.new_zeros(*rb, pad, s, r)), dim=-3)
        return x.reshape(*rb, self.G, self.g * s, r)

    def window_covariance(self, first: Tensor, width: int) -> Tensor:
        r"""Covariance blocks of the ``width`` consecutive block rows ``first .. first +
        width - 1`` (``width <= g + 1``; rows past ``n`` read as zero).

        Args:
            first: ``(..., T)`` int64 first block rows (batch as the matrix's).
            width: number of block rows.

        Returns:
            ``(..., T, width s, width s)``.
        """
        diag, sub = self.selected_inverse()
        g, s = self.g, self.s
        # M_j = [[S_jj, S_{j+1,j}^T], [S_{j+1,j}, S_{j+1,j+1}]], 2 g block rows from group j
        nxt = torch.cat((diag[..., 1:, :, :], torch.zeros_like(diag[..., :1, :, :])), dim=-3)
        M = torch.cat((torch.cat((diag, sub.mT), -1), torch.cat((sub, nxt), -1)), -2)
        j = (first // g).clamp(max=self.G - 1)
        o = first - j * g
        Mj = M.gather(-3, j[..., None, None].expand(*j.shape, *M.shape[-2:]))
        idx = (o[..., None] * s + torch.arange(width * s, device=first.device))
        rows = Mj.gather(-2, idx[..., :, None].expand(*idx.shape, Mj.shape[-1]))
        return rows.gather(-1, idx[..., None, :].expand(*idx.shape[:-1], width * s, width * s))

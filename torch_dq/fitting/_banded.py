r"""Symmetric positive definite block-banded matrices: Cholesky, solves, selected inverse.

A matrix of ``n`` block rows of size ``s`` whose block ``(k, k + d)`` vanishes for
``d >= w`` is stored as its upper band ``band (..., n, w, s, s)`` (block ``(k, k + d)`` at
``band[..., k, d]``). Grouping ``g`` consecutive block rows (a multiple of ``w - 1``, about
16: fewer sequential steps on larger dense blocks) makes it
block-tridiagonal with diagonal blocks ``D_j`` and sub-diagonal blocks ``E_j`` (group ``j``
against group ``j - 1``), whose block :math:`LDL^T` factorisation is

.. math::
    S_0 = D_0, \quad S_j = D_j - E_j S_{j-1}^{-1} E_j^T, \quad L_j = E_j S_{j-1}^{-1},

each :math:`S_j` held by its Cholesky factor: :math:`O(n)` time and memory. The selected
inverse (Takahashi's recursion, from :math:`\Sigma L = L^{-T} S^{-1}`)

.. math::
    \Sigma_{G-1,G-1} = S_{G-1}^{-1}, \quad \Sigma_{j+1,j} = -\Sigma_{j+1,j+1} L_{j+1}, \quad
    \Sigma_{j,j} = S_j^{-1} - \Sigma_{j+1,j}^T L_{j+1}

gives the blocks of :math:`A^{-1}` inside the band of the grouped matrix (the covariance of
every ``g + 1`` consecutive block rows) without forming the dense inverse.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["BandedCholesky"]

_GROUP_ROWS = 16  # block rows per group (a multiple of w - 1): Python steps vs dense work


def _grouped(band: Tensor, g: int) -> tuple[Tensor, Tensor]:
    """``D (..., G, g s, g s)`` and ``E (..., G, g s, g s)`` of the band (``E[0]`` zero)."""
    *batch, n, w, s, _ = band.shape
    G = n // g
    a = torch.arange(g, device=band.device)
    j = torch.arange(G, device=band.device)[:, None, None]
    rows = j * g + a[:, None]  # (G, g, 1)
    cols = j * g + a[None, :]  # (G, 1, g)
    lo, d = torch.broadcast_tensors(torch.minimum(rows, cols), (rows - cols).abs())
    D = band[..., lo, d.clamp(max=w - 1), :, :] * (d < w)[..., None, None]
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


class BandedCholesky:
    """Block :math:`LDL^T` factorisation of a symmetric block-banded matrix (module doc).

    Args:
        band: ``(..., n, w, s, s)`` upper band (blocks past the last row are ignored).

    Attributes:
        ok: ``(...)`` bool, False where the matrix is not numerically positive definite (the
            results of those batch elements are meaningless; the others are unaffected).
    """

    def __init__(self, band: Tensor) -> None:
        *batch, n, w, s, _ = band.shape
        dev = band.device
        beyond = torch.arange(n, device=dev)[:, None] + torch.arange(w, device=dev) >= n
        band = band.masked_fill(beyond[:, :, None, None], 0.0)
        g = max(w - 1, 1)
        g *= max(1, min(_GROUP_ROWS // g, -(-n // g)))  # fewer, larger groups: fewer steps
        G = -(-n // g)
        pad = G * g - n
        if pad:  # identity rows after the last block row
            eye = band.new_zeros(*batch, pad, w, s, s)
            eye[..., 0, :, :] = torch.eye(s, dtype=band.dtype, device=dev)
            band = torch.cat((band, eye), dim=-4)
        self.n, self.s, self.g, self.G, self.batch = n, s, g, G, tuple(batch)
        D, self.E = _grouped(band, g)
        self.chol: list[Tensor] = []
        self.L: list[Tensor] = []  # L_j = E_j S_{j-1}^-1 (L_0 unused)
        ok = torch.ones(batch, dtype=torch.bool, device=dev)
        for j in range(G):
            S = D[..., j, :, :]
            if j:
                Lj = torch.cholesky_solve(self.E[..., j, :, :].mT, self.chol[-1]).mT
                S = S - Lj @ self.E[..., j, :, :].mT
                self.L.append(Lj)
            else:
                self.L.append(torch.zeros_like(S))
            C, info = torch.linalg.cholesky_ex(S)
            bad = info != 0
            ok &= ~bad
            # a failed element continues on the identity: its own results are flagged
            eye = torch.eye(S.shape[-1], dtype=S.dtype, device=dev)
            self.chol.append(torch.where(bad[..., None, None], eye, C))
        self.ok = ok

    def solve(self, rhs: Tensor) -> Tensor:
        """``A^-1 rhs`` for ``rhs (..., n, s, r)`` (batch broadcast with the matrix's)."""
        *rb, n, s, r = rhs.shape
        g, G = self.g, self.G
        pad = G * g - n
        if pad:
            rhs = torch.cat((rhs, rhs.new_zeros(*rb, pad, s, r)), dim=-3)
        b = rhs.reshape(*rb, G, g * s, r)
        y = [b[..., 0, :, :]]
        for j in range(1, G):
            y.append(b[..., j, :, :] - self.L[j] @ y[-1])
        x = [torch.cholesky_solve(y[G - 1], self.chol[G - 1])]
        for j in range(G - 2, -1, -1):
            z = torch.cholesky_solve(y[j], self.chol[j])
            x.append(z - self.L[j + 1].mT @ x[-1])
        x.reverse()
        return torch.stack(x, dim=-3).reshape(*rb, G * g, s, r)[..., :n, :, :]

    def selected_inverse(self) -> tuple[Tensor, Tensor]:
        """Blocks of :math:`A^{-1}` of the grouped matrix: ``diag (..., G, g s, g s)`` and
        ``sub (..., G, g s, g s)`` (``sub[j]`` the block of groups ``(j + 1, j)``, the last
        one zero)."""
        G = self.G
        eye = torch.eye(self.g * self.s, dtype=self.chol[0].dtype, device=self.chol[0].device)
        diag = [torch.cholesky_solve(eye, self.chol[G - 1])]
        sub = [torch.zeros_like(diag[0])]
        for j in range(G - 2, -1, -1):
            low = -diag[-1] @ self.L[j + 1]  # Sigma_{j+1, j}
            diag.append(torch.cholesky_solve(eye, self.chol[j]) - low.mT @ self.L[j + 1])
            sub.append(low)
        diag.reverse()
        sub.reverse()
        return torch.stack(diag, dim=-3), torch.stack(sub, dim=-3)

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

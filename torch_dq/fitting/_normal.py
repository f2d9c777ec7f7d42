r"""The normal equations of :class:`~torch_dq.fitting._linearize.Linearization`, summed
window by window (private): each window's blocks :math:`\sum_i Y_i^T Y_i` of its samples'
whitened rows ``Y = [J_c | J_n | r]`` by batched matrix products (:func:`_window_normal`),
scattered into the control-point band, the coupling and the nuisance blocks
(:class:`_Normal`), the :class:`System` they make. Where the compiled kernels run
(``torch_dq._kernels.native``), ``_Normal.add_samples`` sums the samples' rows into the
same blocks in one pass over the samples instead (``csrc/normal.c``: no rows, pages or
window blocks in memory); the PyTorch path stays the reference it is tested against."""

from __future__ import annotations

import ctypes
from dataclasses import dataclass

import torch
from torch import Tensor

from .._kernels import native

__all__ = ["System"]


@dataclass
class System:
    """Gauss-Newton system (flattened batch ``Bf``): ``band (Bf, n, w, 6, 6)``, ``cn (Bf,
    n, 6, m)``, ``nn (Bf, m, m)``, gradients ``gc (Bf, n, 6)``, ``gn (Bf, m)``; per term
    whitened residuals and robust weights; ``own``: the blocks ``(band, cn, nn)`` of each
    term but the last alone (the last's are the rest: the per-term degrees of freedom of
    ``torch_dq.fitting._leverage``)."""

    band: Tensor
    cn: Tensor
    nn: Tensor
    gc: Tensor
    gn: Tensor
    residuals: list[Tensor]
    weights: list[Tensor]
    own: list[tuple[Tensor, Tensor, Tensor]]


class _Normal:
    """The normal equations summed from the blocks of the windows a chunk of samples uses,
    ``(U, 6 w + M + 1, ...)`` (``[J_c | J_n | r]``, the nuisance columns given per window):
    window ``f``'s block ``(a, a + d)`` added to the band at ``(f + a, d)`` and its rows
    ``a`` to control point ``f + a`` (``g_c``, the coupling), ``A_nn`` and ``g_n``
    scattered to their columns. Memory: the band and the coupling, whatever the samples,
    and those of each of the ``terms`` but the last alone (:attr:`System.own`; their blocks
    added to both, the sum's bits those of one accumulator)."""

    def __init__(self, like: Tensor, Bf: int, n: int, w: int, m: int, terms: int = 1) -> None:
        self.Bf, self.n, self.w, self.m = Bf, n, w, m
        self.own = [_Normal(like, Bf, n, w, m) for _ in range(terms - 1)]
        G = Bf * (n + w)  # window f of batch row b is b (n + w) + f
        self.band = like.new_zeros(G, w, 6, 6)
        self.gc = like.new_zeros(G, 6)
        self.cn = like.new_zeros(G * 6 * m)
        self.nn = like.new_zeros(Bf * m * m)
        self.gn = like.new_zeros(Bf * m)
        self.rows = torch.arange(6, device=like.device)
        self.offsets = torch.arange(w, device=like.device)
        self.pairs = [(a, d) for a in range(w) for d in range(w - a)]  # the band's blocks
        self.pair_a = torch.tensor([a for a, _ in self.pairs], device=like.device)
        self.pair_d = torch.tensor([d for _, d in self.pairs], device=like.device)

    def add(self, windows: Tensor, block: Tensor, gcols: Tensor, term: int = -1) -> None:
        """Add the blocks ``(U, q, q)`` of the ``windows (U,)``, columns ``[J_c (6 w) | J_n
        (M) | r]`` (window ``u``'s nuisance column ``j`` is the problem's ``gcols[u, j]``;
        padding columns are zero), rows of term ``term`` (to its own blocks too, where it
        has them): one scatter per destination (rows ``a`` of window ``f`` belong to control
        point ``f + a``, its block ``(a, a + d)`` to the band at ``(f + a, d)``)."""
        if 0 <= term < len(self.own):
            self.own[term].add(windows, block, gcols)
        w, m, M, U = self.w, self.m, gcols.shape[-1], windows.shape[0]
        nuis = slice(6 * w, 6 * w + M)
        at = windows[:, None] + self.offsets  # (U, w): the control points of the rows
        coupled = False
        if U and int(windows[-1] - windows[0]) == U - 1:
            coupled = self._add_consecutive(int(windows[0]), block, gcols)
        else:
            src = torch.stack([block[:, 6 * a:6 * a + 6, 6 * (a + d):6 * (a + d) + 6]
                               for a, d in self.pairs], 1)  # (U, P, 6, 6)
            band_at = at[:, self.pair_a] * w + self.pair_d  # (U, P): the band's (G w) blocks
            self.band.view(-1, 6, 6).index_add_(0, band_at.reshape(-1),
                                                src.reshape(-1, 6, 6))
            self.gc.index_add_(0, at.reshape(-1), block[:, :6 * w, -1].reshape(U * w, 6))
        if not M:
            return
        if not coupled:
            cols = (at[:, :, None, None] * 6 + self.rows[:, None]) * m + gcols[:, None, None, :]
            self.cn.index_add_(0, cols.reshape(-1), block[:, :6 * w, nuis].reshape(-1))
        row = torch.div(windows, self.n + w, rounding_mode="floor")[:, None] * m + gcols
        self.nn.index_add_(0, (row[:, :, None] * m + gcols[:, None, :]).reshape(-1),
                           block[:, nuis, nuis].reshape(-1))
        self.gn.index_add_(0, row.reshape(-1), block[:, nuis, -1].reshape(-1))

    def add_samples(self, rel: Tensor, lo: int, Jc: Tensor, Jn: Tensor, r: Tensor, wt: Tensor,
                    local: Tensor, gcols: Tensor, term: int = -1) -> None:
        r"""What ``add`` adds of ``_window_normal``'s blocks of the rows ``sqrt(wt) [J_c |
        J_n | r]``, summed sample by sample by the compiled kernel (``tdq_normal_add``;
        where ``native.enabled`` holds): sample ``s`` of window ``rel[s] + lo`` (``rel (S,)``),
        its rows ``Jc (S, k, w, 6)``, ``Jn (S, k, Mt)`` (the term's nuisance columns), ``r
        (S, k)``, robust weight ``wt (S,)`` (any strides: read as they lie); window ``u``'s
        nuisance columns are the term's ``local[u] (M,)``, the problem's ``gcols[u]`` (-1:
        none). The samples need not be sorted (a window's samples in a row are summed
        before they are added)."""
        S, k = r.shape
        if Jc.shape != (S, k, self.w, 6) or Jn.shape[:2] != (S, k) or wt.shape != (S,):
            raise ValueError(f"_Normal.add_samples: rows of {S} samples of {k} expected, got "
                             f"{tuple(Jc.shape)}, {tuple(Jn.shape)}, {tuple(wt.shape)}")
        if not S:
            return
        dims = torch.tensor([S, k, self.w, local.shape[-1], self.m, self.n + self.w, lo,
                             *Jc.stride(), *Jn.stride(), *r.stride(), *wt.stride()])
        index = [x.to(torch.int64).contiguous() for x in (rel, local, gcols)]
        sets = [self, *self.own[term:term + 1]] if term >= 0 else [self]
        out = [x.data_ptr() for acc in sets for x in (acc.band, acc.gc, acc.cn, acc.nn, acc.gn)]
        add = native.function("tdq_normal_add", (ctypes.c_void_p,) * 9, ctypes.c_int)
        if add(*(native.address(x) for x in (dims, *index)), (ctypes.c_void_p * 10)(*out),
               *(ctypes.c_void_p(x.data_ptr()) for x in (Jc, Jn, r, wt))):
            raise MemoryError("_Normal.add_samples: no memory for a window's accumulator")

    def _add_consecutive(self, f: int, block: Tensor, gcols: Tensor) -> bool:
        """``add`` of the consecutive windows ``f, f + 1, ...``: a row's blocks added to a
        slice of the band at once, ``g_c`` (and the coupling, where every window takes
        the same consecutive nuisance columns: then True), row ``a`` from the last to the
        first, so that every destination sums its windows in ``add``'s ``index_add_`` order
        (increasing window): the same bits, without the scatter."""
        w, U, M = self.w, block.shape[0], gcols.shape[-1]
        cn = None
        if M:
            c = int(gcols[0, 0])
            if bool((gcols == torch.arange(c, c + M, device=gcols.device)).all()):
                cn = self.cn.view(-1, 6, self.m)[:, :, c:c + M]
        for a in reversed(range(w)):
            rows = block[:, 6 * a:6 * a + 6]  # (U, 6, q): its blocks (a, a + d) in one add
            self.band[f + a:f + a + U, :w - a] += rows[:, :, 6 * a:6 * w].unflatten(
                2, (w - a, 6)).transpose(1, 2)
            self.gc[f + a:f + a + U] += rows[:, :, -1]
            if cn is not None:
                cn[f + a:f + a + U] += rows[:, :, 6 * w:6 * w + M]
        return cn is not None

    def blocks(self) -> tuple[Tensor, Tensor, Tensor]:
        """``band (Bf, n, w, 6, 6)``, ``cn (Bf, n, 6, m)`` and ``nn (Bf, m, m)``."""
        Bf, n, w, m = self.Bf, self.n, self.w, self.m
        return (self.band.reshape(Bf, n + w, w, 6, 6)[:, :n],
                self.cn.reshape(Bf, n + w, 6, m)[:, :n], self.nn.reshape(Bf, m, m))

    def system(self, rs: list[Tensor], weights: list[Tensor]) -> System:
        band, cn, nn = self.blocks()
        gc = self.gc.reshape(self.Bf, self.n + self.w, 6)[:, :self.n]
        return System(band, cn, nn, gc, self.gn.reshape(self.Bf, self.m), rs, weights,
                      [o.blocks() for o in self.own])


def _window_normal(keys: Tensor, Y: Tensor) -> tuple[Tensor, Tensor]:
    r"""The windows ``(U,)`` that samples' rows ``Y (S, k, q)`` with window ``keys (S,)``
    use, and per window :math:`\sum_i Y_i^T Y_i` ``(U, q, q)``, by batched matrix products.

    The samples of a window are laid out on pages of ``P`` samples (``P`` the mean count
    per used window: at most about twice as many pages as used windows, the padding at
    most ``S``), one product per page, the pages summed into their windows (where a window
    has several): each sample's rows copied once to their slot, the padding slots alone
    zeroed (by row index: a boolean mask's ``index_put`` cost a third of the call).
    """
    S, k, q = Y.shape
    windows, inverse, counts = torch.unique(keys, return_inverse=True, return_counts=True)
    U = windows.numel()
    if S == 0:
        return windows, Y.new_zeros(0, q, q)
    order = torch.argsort(inverse, stable=True)
    P = -(-S // U)
    pos = torch.arange(S, device=keys.device) - (torch.cumsum(counts, 0) - counts)[inverse[order]]
    pages = -(-counts // P)
    first_page = torch.cumsum(pages, 0) - pages
    # sample order[i] goes to page first_page + pos[i] // P, slot pos[i] % P
    slot = torch.empty_like(order).index_put_((order,), first_page[inverse[order]] * P + pos)
    n_pages = int(pages.sum())
    X = Y.new_empty(n_pages * P, k, q).index_copy_(0, slot, Y)
    if n_pages * P > S:
        pad = torch.ones(X.shape[0], dtype=torch.bool, device=keys.device).index_fill_(
            0, slot, False)
        X.index_fill_(0, pad.nonzero()[:, 0], 0.0)
    X = X.reshape(-1, P * k, q)
    if n_pages == U:  # a page per window
        return windows, X.mT @ X
    owner = torch.repeat_interleave(torch.arange(U, device=keys.device), pages)
    return windows, Y.new_zeros(U, q, q).index_add_(0, owner, X.mT @ X)

r"""The numerical prior of :func:`~torch_dq.fitting.estimate`: a pull towards the start on the
directions that the data do not determine, and on no other.

Control points: the data information of ``v = 4`` consecutive control points moved alone
is their principal submatrix ``A_w`` of the data Gauss-Newton matrix at the start (``v``
blocks, every window of the band). Scaled by the typical information per coordinate (``D``:
the median of the diagonal entries over the control points that some sample touches),
:math:`\hat A_w = D^{-1/2} A_w D^{-1/2} = V \Lambda V^T`; an eigen-direction with
:math:`\lambda <` ``SPARSE`` ``= 1e-6`` (a combination of neighbouring control points
with no information worth the name: a time gap, an end without samples) gets the pull
information ``p = prior`` (scaled; without estimated nuisance parameters the threshold is
``p`` itself, see :func:`control_pull`), :math:`D^{1/2} V \mathrm{diag}(p [\lambda < 10^{-6}])
V^T D^{1/2}`, summed over the windows into a band ``P``, and the cost
:math:`\delta^T P \delta`, :math:`\delta_k = \log(c^{0\,-1}_k c_k)`. A direction with
more information is not pulled at all. (A threshold of ``1e-3`` pulled combinations that an
accelerometer determines and moved an extrinsic by a standard deviation; the weak
combinations at the edges of TUM fr2_desk's long gaps, between ``1e-5`` and ``1e-3``, are
left to the data: they swing by 40 deg there, the data's least-squares answer, with large
standard deviations.) With estimated nuisance parameters a window's threshold is relative to
its own best-determined direction where that is below the typical information
(:func:`control_pull`), and :mod:`torch_dq.fitting._lm` re-anchors the pulls at every
linearisation point: they hold undetermined directions where the iteration has them, never
against the data. While the Levenberg-Marquardt damping is large, its diagonal is at
least ``WEAK`` times the typical information, so that weak points do not outrun the
others; it vanishes with the damping.

Nuisance parameters: the Schur complement ``S`` of the data information on the nuisance
(control points regularised by their pull and by ``1e-10`` of their diagonal, so that
combinations of control points that no sample determines drop out), scaled by its diagonal;
an eigen-direction below ``_NULL`` (numerically no information: a gyroscope's time offset
under constant rotation rate, gravity's direction against an accelerometer bias without
rotation) gets the pull ``p`` (scaled) towards the start, so that the iteration cannot
drift along it. Directions with information are never pulled: the estimate of a determined
parameter is the data's, whatever its start.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._banded import BandedCholesky

__all__ = ["NULL", "REGULARISE", "SPARSE", "WEAK", "Regularised", "band_apply", "control_null",
           "control_pull", "damping_floor", "nuisance_chart", "nuisance_pull", "scaled_eigh"]

NULL = 1e-9  # scaled eigenvalue of the nuisance information below which a direction is null
SPARSE = 1e-6  # scaled information of a window direction below which it is pulled
WEAK = 0.1  # least diagonal of the damping, relative to the typical information
REGULARISE = 1e-10  # fraction of the control points' diagonal added to factor a singular band
_WINDOW = 4  # consecutive control points whose joint information is tested for weak directions
_WINDOWS = 1 << 12  # windows decomposed at once (memory: 4.6 kB each, a few copies)
_NULL_RANK = 12  # columns of the subspace iteration for combinations without information


def _typical(blocks: Tensor) -> Tensor:
    """``(Bf, 6)`` median diagonal information over the control points with data."""
    d = blocks.diagonal(dim1=-2, dim2=-1)  # (Bf, n, 6)
    used = d.sum(-1, keepdim=True) > 0
    med = torch.where(used, d, torch.nan).nanmedian(dim=1).values
    top = med.nan_to_num(0.0).amax(-1, keepdim=True)
    floor = torch.where(top > 0, 1e-12 * top, torch.ones_like(top))
    return med.nan_to_num(0.0).clamp_min(0.0).maximum(floor)


def _windows(hat: Tensor, v: int, lo: int, hi: int) -> Tensor:
    """``(Bf, hi - lo, 6 v, 6 v)``: the principal submatrices of the ``v`` consecutive control
    points from each ``k`` in ``[lo, hi)`` of the padded band ``hat (Bf, >= hi + v - 1, w, 6,
    6)`` (each block written once into the windows' array)."""
    Bf, _, w = hat.shape[:3]
    m = hi - lo
    out = hat.new_empty(Bf, m, v, 6, v, 6)
    for a in range(v):
        for b in range(a, v):
            if b - a >= w:
                out[:, :, a, :, b].zero_()
                out[:, :, b, :, a].zero_()
                continue
            blk = hat[:, lo + a:hi + a, b - a]
            out[:, :, a, :, b] = blk
            if b > a:
                out[:, :, b, :, a] = blk.mT
    return out.reshape(Bf, m, 6 * v, 6 * v)


def _weak_windows(A: Tensor, threshold: float) -> Tensor:
    """``(Bf, n)`` bool: the windows ``A (Bf, n, k, k)`` (scaled, symmetric) that may have an
    eigenvalue below ``threshold``: those where the Cholesky factorisation of ``A - 2
    threshold I`` fails (a twelfth of an eigen-decomposition's cost; the eigen-decomposition
    then decides on these alone)."""
    eye = torch.eye(A.shape[-1], dtype=A.dtype, device=A.device)
    return torch.linalg.cholesky_ex(A - 2.0 * threshold * eye).info != 0


def control_pull(band: Tensor, prior: float, nuisance: bool) -> Tensor:
    """``(Bf, n, w, 6, 6)`` pull information of the control points, banded (module doc).

    Args:
        band: ``(Bf, n, w, 6, 6)`` data band at the start.
        prior: the pull's relative weight ``p >= 0``.
        nuisance: whether nuisance parameters are estimated. With them the threshold is
            ``min(p, SPARSE)`` (a pull on combinations that an IMU weakly determines would
            move an extrinsic) times the window's largest scaled eigenvalue where that is
            below 1 (at least ``NULL``): where only a less informative sensor sees the
            control points (poses at the ends of an IMU record, 1e-6 of the accelerometer's
            typical information but well determined: 1 mm), information is judged against
            what determines them there, not against the accelerometer; without them (a
            trajectory from poses or positions alone, where a pull can decide no other
            parameter) it is ``p`` itself, so that the
            weakly determined edges of long time gaps stay near the start instead of
            swinging to the few samples' least-squares answer (TUM fr2_desk: 40 deg).
    """
    threshold = min(prior, SPARSE) if nuisance else prior
    if prior == 0:
        return torch.zeros_like(band)
    Bf, n, w = band.shape[:3]
    v = min(w, _WINDOW)
    t = _typical(band[:, :, 0]).sqrt()
    s = t.repeat(1, v)[:, None, :]  # (Bf, 1, 6 v)
    outer = s[..., :, None] * s[..., None, :]
    # the band scaled, past the last control point the identity (scaled): blocks of the windows
    scale = (t[:, :, None] * t[:, None, :])[:, None, None]
    hat = band.new_zeros(Bf, n + v, w, 6, 6)
    hat[:, :n] = band / scale
    hat[:, n:, 0] = torch.eye(6, dtype=band.dtype, device=band.device) / scale[:, 0]
    screen = max(threshold, NULL) if nuisance else threshold
    pull = band.new_zeros(Bf, n + v, w, 6, 6)
    for lo in range(0, n, _WINDOWS):  # a chunk of windows at a time (memory)
        hi = min(lo + _WINDOWS, n)
        A = _windows(hat, v, lo, hi)
        weak = _weak_windows(A, screen)
        if not bool(weak.any()):
            continue
        lam, V = torch.linalg.eigh(A[weak])
        # with nuisance: relative to the window's best-determined direction, at most typical
        cut = ((threshold * lam[..., -1:].clamp(0.0, 1.0)).clamp_min(NULL) if nuisance
               else threshold)
        bi, ki = weak.nonzero().unbind(-1)
        W = (V * torch.where(lam < cut, prior, 0.0)[..., None, :]) @ V.mT * outer[bi, 0]
        for a in range(v):  # the weak windows' blocks alone (the others add nothing)
            for b in range(a, v):
                pull.index_put_((bi, lo + a + ki, torch.full_like(ki, b - a)),
                                W[:, 6 * a:6 * a + 6, 6 * b:6 * b + 6], accumulate=True)
    return pull[:, :n]


def damping_floor(band: Tensor) -> Tensor:
    """``(Bf, 1, 6)``: ``WEAK`` times the typical information per coordinate, the least
    diagonal of the Levenberg-Marquardt damping (weakly determined control points move
    no faster than typical ones while the damping is large; it vanishes with it)."""
    return WEAK * _typical(band[:, :, 0])[:, None, :]


def scaled_eigh(S: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r"""Eigen-decomposition of ``S (Bf, m, m)`` scaled by its diagonal.

    Returns:
        ``lam (Bf, m)`` and ``V (Bf, m, m)`` with :math:`D^{-1/2} S D^{-1/2} = V \Lambda
        V^T`, and ``d (Bf, m)`` the diagonal ``D`` (floored at ``1e-12`` of its largest
        entry; ones where ``S`` is zero).
    """
    d = S.diagonal(dim1=-2, dim2=-1).clamp_min(0.0)
    top = d.amax(-1, keepdim=True)
    d = torch.where(top > 0, d.maximum(1e-12 * top), torch.ones_like(d))
    r = d.rsqrt()
    lam, V = torch.linalg.eigh(0.5 * (S + S.mT) * r[:, :, None] * r[:, None, :])
    return lam, V, d


class Regularised:
    r"""The data band plus the pulls, ``A = band + pull``, and its factorisations, each on
    first use: regularised by ``REGULARISE`` times its floored diagonal ``D`` (``(Bf, n,
    6)``, plus ``1e-12`` of its largest entry), :math:`(A + \epsilon D)^{-1}`
    (:attr:`chol`, for :func:`nuisance_pull` and :func:`control_null`); shifted by ``-NULL
    D`` (:attr:`certified`); and ``A`` as it is (:attr:`exact`, where certified: the
    undamped Gauss-Newton solve, and :func:`nuisance_pull`'s test that no nuisance direction
    is null, which spares :attr:`chol` there).

    Args:
        band: ``(Bf, n, w, 6, 6)`` data band.
        pull: ``(Bf, n, w, 6, 6)`` the control points' pull information.

    Attributes:
        A, D: the band plus the pulls and its floored diagonal; pulled: whether ``pull``
            has a nonzero entry.
    """

    def __init__(self, band: Tensor, pull: Tensor) -> None:
        self.A, self.pulled = band + pull, bool(pull.any())
        D = self.A[:, :, 0].diagonal(dim1=-2, dim2=-1)
        self.D = D + 1e-12 * D.amax((-1, -2), keepdim=True).clamp_min(1e-300)
        self._chol: BandedCholesky | None = None
        self._exact: BandedCholesky | None = None
        self._certified: bool | None = None

    @property
    def chol(self) -> BandedCholesky:
        r"""The factorisation of :math:`A + \epsilon D`, ``epsilon = REGULARISE``."""
        if self._chol is None:
            self._chol = BandedCholesky(self.A, shift=REGULARISE * self.D)
        return self._chol

    @property
    def exact(self) -> BandedCholesky:
        """The factorisation of ``A`` itself (no shift)."""
        if self._exact is None:
            self._exact = BandedCholesky(self.A)
        return self._exact

    @property
    def certified(self) -> bool:
        r"""Whether a factorisation of :math:`A - \mathrm{NULL}\, D` succeeds (every batch
        element): no generalised eigenvalue at or below ``NULL``, every combination of
        control points informed."""
        if self._certified is None:
            self._certified = bool(BandedCholesky(self.A, shift=-NULL * self.D).ok.all())
        return self._certified


def _no_null(reg: Regularised, cn: Tensor, nn: Tensor) -> bool:
    r"""Whether :func:`nuisance_pull` finds no null direction, decided without
    ``reg.chol`` where nothing is pulled and ``A`` is certified (its factorisation as it is,
    ``reg.exact``, then serves the undamped solve): the Schur complement :math:`S_0 = N - C^T
    Z`, :math:`Z = A^{-1} C`, scaled by ``E`` (below) is positive definite with room,
    :math:`\lambda_{\min}(E^{-1/2} S_0 E^{-1/2}) > 10\, m\, \mathrm{NULL} + 2 r`.

    With :math:`\hat A = D^{-1/2} A D^{-1/2}` (eigenvalues :math:`\mu > 0`) and
    :math:`\epsilon` = ``REGULARISE``, :math:`\mu^{-1} - \epsilon \mu^{-2} \le (\mu +
    \epsilon)^{-1} \le \mu^{-1}`, so the regularised complement :math:`S_\epsilon = N - C^T
    (A + \epsilon D)^{-1} C` satisfies :math:`S_\epsilon \succeq S_0` and
    :math:`\mathrm{diag}(S_\epsilon) \le u = \mathrm{diag}(S_0 + \epsilon Z^T D Z)`: its
    diagonal floored as :func:`scaled_eigh` does is at most :math:`E = u + 10^{-12}
    \max u`. Its scaled smallest eigenvalue is then at least the test's, its largest at
    most its trace ``m``: none is at or below ``NULL`` times the largest, and the pull is
    zero, as from ``reg.chol``. ``r`` bounds either complement's roundoff: a backward
    error :math:`\|\delta \hat A\| \le 10^3\, \mathrm{eps}\, \|\hat
    A\|`, :math:`\|\hat A\| \le 6 (2 w - 1)`, moves :math:`C^T A^{-1} C` by at most
    :math:`\|\delta \hat A\|\, \mathrm{tr}(E^{-1} Z^T D Z)` in the scaled norm. (The 60 s
    job of ``benchmarks/bench_gtsam.py``: 0.51 against a room below ``1e-7``.)"""
    if reg.pulled or not reg.certified:
        return False
    chol, m, w = reg.exact, nn.shape[-1], reg.A.shape[2]
    Z = chol.solve(cn)
    S = nn - torch.einsum("bnim,bniq->bmq", cn, Z)
    zdz = torch.einsum("bnim,bni->bm", Z * Z, reg.D)  # diag(Z^T D Z)
    u = (S.diagonal(dim1=-2, dim2=-1) + REGULARISE * zdz).clamp_min(0.0)
    e = (u + 1e-12 * u.amax(-1, keepdim=True)).clamp_min(1e-300)
    r = 1e3 * torch.finfo(nn.dtype).eps * 6 * (2 * w - 1) * (zdz / e).sum(-1)
    room = 10 * m * NULL + 2.0 * r
    s = e.rsqrt()
    eye = torch.eye(m, dtype=nn.dtype, device=nn.device)
    hat = 0.5 * (S + S.mT) * s[:, :, None] * s[:, None, :] - room[:, None, None] * eye
    return bool(chol.ok.all()) and bool((torch.linalg.cholesky_ex(hat).info == 0).all())


def nuisance_pull(reg: Regularised, cn: Tensor, nn: Tensor, prior: float) -> Tensor:
    """``(Bf, m, m)`` pull information of the nuisance parameters (module doc); zero without
    ``reg.chol`` where ``_no_null`` decides it.

    Args:
        reg: the data band at the start plus the control points' pulls.
        cn: ``(Bf, n, 6, m)`` coupling.
        nn: ``(Bf, m, m)`` nuisance block (with the Free priors' information).
        prior: the pull's relative weight.
    """
    m = nn.shape[-1]
    if prior == 0 or m == 0 or _no_null(reg, cn, nn):
        return torch.zeros_like(nn)
    chol = reg.chol
    S = nn - torch.einsum("bnim,bniq->bmq", cn, chol.solve(cn))
    lam, V, d = scaled_eigh(S)
    null = (lam <= NULL * lam.amax(-1, keepdim=True).clamp_min(0.0)) & chol.ok[:, None]
    P = (V * torch.where(null, prior, 0.0)[..., None, :]) @ V.mT
    s = d.sqrt()
    return P * (s[:, :, None] * s[:, None, :])


def nuisance_chart(problem, anchor: list[Tensor], values: list[Tensor]) -> Tensor:
    """``(..., m)`` chart coordinates of the nuisance ``values`` around ``anchor``."""
    parts = [p.chart.local(a, v).expand(*problem.batch, p.dim)
             for p, a, v in zip(problem.params, anchor, values, strict=True)]
    if not parts:
        return torch.zeros(*problem.batch, 0, dtype=torch.float64, device=problem.spans.device)
    return torch.cat(parts, -1)


def band_apply(band: Tensor, x: Tensor) -> Tensor:
    """``A x`` for the symmetric band ``(Bf, n, w, 6, 6)`` and ``x (Bf, n, 6, r)``."""
    n, w = band.shape[1], band.shape[2]
    y = band[:, :, 0] @ x
    for d in range(1, min(w, n)):
        blk = band[:, :n - d, d]  # block (k, k + d)
        y[:, :n - d] += blk @ x[:, d:]
        y[:, d:] += blk.mT @ x[:, :n - d]
    return y


def control_null(reg: Regularised, rank: int = _NULL_RANK) -> tuple[Tensor, Tensor]:
    r"""``(Bf, n, 6, r)`` combinations of control points that no sample determines (the
    null space of the data band plus the pulls, ``reg``, when it is not made of whole
    blocks: knots closer than the samples), ``D``-orthonormal (:math:`U^T D U = I`, ``D``
    the band's diagonal): a few steps of inverse subspace iteration on :math:`(A +
    \epsilon D)^{-1} D` from ``rank`` fixed pseudo-random columns, then the Ritz vectors
    whose Ritz value is below ``NULL`` (scaled). ``r = 0`` (an empty last axis) where there
    are none, and without the iteration where a factorisation certifies it (:math:`A -
    \mathrm{NULL}\, D` positive definite: no generalised eigenvalue, so no Ritz value, at
    or below ``NULL``).

    Returns:
        ``U`` and ``D U``: a step ``x`` without those combinations is :math:`x - U (D U)^T
        x`."""
    A, D = reg.A, reg.D
    if reg.certified:
        none = A.new_zeros(*D.shape, 0)
        return none, none
    chol = reg.chol
    # drawn on the CPU whatever A's device: every device starts from the same columns (a
    # CUDA generator draws others), so that a GPU finds the CPU's combinations
    gen = torch.Generator().manual_seed(0)
    rank = min(rank, D.shape[1] * 6)
    X = torch.randn(*D.shape, rank, generator=gen, dtype=A.dtype).to(A.device)
    Bf, n = D.shape[:2]
    for _ in range(3):
        X = chol.solve(D[..., None] * X)
        Q = torch.linalg.qr((D.sqrt()[..., None] * X).reshape(Bf, n * 6, rank)).Q
        X = Q.reshape(Bf, n, 6, rank) / D.sqrt()[..., None]
    K = torch.einsum("bnir,bnis->brs", X, band_apply(A, X))
    lam, V = torch.linalg.eigh(0.5 * (K + K.mT))
    null = (lam <= NULL) & chol.ok[:, None]
    k = int(null.sum(-1).max())
    U = (X.reshape(Bf, n * 6, rank) @ V)[..., :k].reshape(Bf, n, 6, k)
    U = U * null[:, None, None, :k]
    return U, D[..., None] * U

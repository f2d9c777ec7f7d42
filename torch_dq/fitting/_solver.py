r"""The damped Gauss-Newton step of :func:`~torch_dq.fitting.estimate`: damping policy and
linear solver, apart from the loop (:mod:`torch_dq.fitting._lm`).

The system ``[[A, C], [C^T, N]] [dc; dn] = -[gc; gn]`` (``A`` the banded control-point
block, ``C`` the coupling, ``N`` the nuisance block; data, pulls and Free priors) is damped by
:class:`Marquardt` (``lam`` times its diagonal, floored) and solved by a linear solver:
:class:`SchurSolver` factors ``A`` (``BandedCholesky``) and solves the ``m x m`` Schur
complement :math:`S = N - C^T A^{-1} C`, :math:`O((N + n) m + m^3)`. Another solver (a
second Schur level for a large block such as landmarks, ``docs/architecture.md``) replaces it
with the same ``solve`` and leaves the loop alone.
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import _prior
from ._banded import BandedCholesky

__all__ = ["DampedStep", "Marquardt", "SchurSolver"]


class SchurSolver:
    """Banded Cholesky of ``A`` and dense Cholesky of the Schur complement on the nuisance."""

    def solve(self, band: Tensor, cn: Tensor, nn: Tensor, gc: Tensor, gn: Tensor,
              shift: Tensor | None = None, factor: BandedCholesky | None = None,
              ) -> tuple[Tensor, Tensor, Tensor]:
        """Steps ``dc (Bf, n, 6)``, ``dn (Bf, m)`` and ``ok (Bf,)`` (both factorisations
        succeeded) of the system ``band (Bf, n, w, 6, 6)`` (plus ``shift (Bf, n, 6)`` on its
        diagonal, or None), ``cn (Bf, n, 6, m)``, ``nn (Bf, m, m)`` with gradients ``gc``,
        ``gn``; ``factor``: that band's factorisation where one is at hand (None: factored
        here)."""
        chol = BandedCholesky(band, shift=shift) if factor is None else factor
        ok = chol.ok
        m = nn.shape[-1]
        if not m:
            return -chol.solve(gc[..., None])[..., 0], gc.new_zeros(gc.shape[0], 0), ok
        X = chol.solve(torch.cat((gc[..., None], cn), dim=-1))
        y, Z = X[..., 0], X[..., 1:]
        S = nn - torch.einsum("bnim,bniq->bmq", cn, Z)
        rhs = -gn + torch.einsum("bnim,bni->bm", cn, y)
        L, info = torch.linalg.cholesky_ex(0.5 * (S + S.mT))
        ok = ok & (info == 0)
        eye = torch.eye(m, dtype=S.dtype, device=S.device)
        L = torch.where((info == 0)[:, None, None], L, eye)
        dn = torch.cholesky_solve(rhs[..., None], L)[..., 0]
        dc = -y - torch.einsum("bnim,bm->bni", Z, dn)
        return dc, dn, ok


class Marquardt:
    r"""Damping policy: ``lam`` per batch element times the diagonal (Marquardt's scaling),
    the control points' floored at ``WEAK`` times the typical information
    (``torch_dq.fitting._prior.damping_floor``) and both at ``1e-12`` of its mean.

    ``lam`` starts at ``1e-4``. After an accepted step whose gain ratio :math:`\rho` (actual
    over predicted decrease of the objective, :meth:`DampedStep.predicted`) exceeds ``1/4`` it
    falls by the factor :math:`4 |1 - \rho|`, tenfold at least, to ``1e-12`` at least;
    otherwise it stays (Marquardt's and Nielsen's rules, tied to the model's error: its
    relative error grows about linearly with the step, and a smaller damping lengthens the
    steps along weakly determined directions about as much). A rejected step below the last
    accepted damping goes halfway back to it (geometric mean; tenfold at least); at or above
    it, tenfold (to ``1e-4`` at least). A rejected trial costs a cost evaluation, an
    iteration a Gauss-Newton system several times that: tenfold falls from ``1e-4`` took four
    systems where two reach the same optimum on the 60 s IMU + poses job of
    ``benchmarks/bench_gtsam.py`` (:math:`\rho = 1 - 5 \cdot 10^{-8}` at its first step);
    a return to ``1e-4`` after each too long step crept along a weak direction that the
    model holds only nearby (a rolling-shutter rig's intrinsics: 20 steps instead of 6).

    Args:
        Bf: flattened batch size.
        like: a float64 tensor on the device.
    """

    START, UP, DOWN, LEAST = 1e-4, 10.0, 10.0, 1e-12

    def __init__(self, Bf: int, like: Tensor) -> None:
        self.lam = torch.full((Bf,), self.START, dtype=torch.float64, device=like.device)
        self.good = self.lam.clone()  # the damping of the last accepted step

    @staticmethod
    def diagonals(data_band: Tensor, band: Tensor, nn: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The damped diagonals of ``band`` (floored by the data band's typical
        information) and of ``nn``, and the floor ``(Bf,)``."""
        diag = band[:, :, 0].diagonal(dim1=-2, dim2=-1).maximum(
            _prior.damping_floor(data_band))
        floor = 1e-12 * diag.mean((-1, -2)).clamp_min(1e-300)
        return diag, nn.diagonal(dim1=-2, dim2=-1), floor

    def reject(self, pending: Tensor) -> None:
        """Raise the damping where a step was rejected (``pending``)."""
        back = (self.lam * self.good).sqrt().maximum(self.lam * self.UP)
        up = torch.where(self.lam < self.good, back, (self.lam * self.UP).clamp_min(self.START))
        self.lam = torch.where(pending, up, self.lam)

    def accept(self, pending: Tensor, gain: Tensor) -> None:
        """Lower the damping where the iteration accepted a step (not ``pending``) by its
        gain ratio ``gain (Bf,)``."""
        shrink = torch.where(gain > 0.25, (4.0 * (1.0 - gain).abs()).clamp(max=1 / self.DOWN),
                             1.0)
        self.good = torch.where(pending, self.good, self.lam)
        self.lam = torch.where(pending, self.lam, (self.lam * shrink).clamp_min(self.LEAST))


class DampedStep:
    """The damped step of one iteration: the data system plus the pulls
    (``torch_dq.fitting._prior``) and the Free priors, damped by ``lam`` times the
    :class:`Marquardt` diagonals, solved by ``solver``, without the combinations of control
    points that no sample determines.

    Args:
        system: the data :class:`~torch_dq.fitting._normal.System`.
        pulls: ``(Bf, n, w, 6, 6)`` and ``(Bf, m, m)`` pull information.
        null: ``U`` and ``D U`` (``torch_dq.fitting._prior.control_null``).
        prior_information: ``(m,)`` the Free priors' diagonal information.
        solver: the linear solver (:class:`SchurSolver` by default).
        factor: the factorisation of the undamped band ``system.band + pulls[0]`` (bit
            for bit: no shift), reused by the steps at zero damping, or None.
        ends: ``(Bf, m)`` bool, the nuisance components at their natural end 0 (a line
            delay), or None: a step that would take one below is solved again with it held
            (its rows and columns out, its step zero), until none goes below (an active
            set). Clamped afterwards instead, the others' step was the one for a move that
            did not happen: a line delay at 0 on global-shutter pixels crept for 50 steps,
            unconverged. (A clock offset's bound is a search limit, clamped: held there, a
            far start's offset stayed on it while the rest fit around it.)
    """

    def __init__(self, system, pulls: tuple[Tensor, Tensor], null: tuple[Tensor, Tensor],
                 prior_information: Tensor, solver: SchurSolver | None = None,
                 ends: Tensor | None = None, factor: BandedCholesky | None = None) -> None:
        self.s, self.null, self.ends, self.factor = system, null, ends, factor
        self.solver = SchurSolver() if solver is None else solver
        self.band = system.band + pulls[0]
        self.nn = system.nn + torch.diag(prior_information.to(system.band)) + pulls[1]
        self.diag, self.ndiag, self.floor = Marquardt.diagonals(system.band, self.band, self.nn)

    def step(self, lam: Tensor, gc: Tensor, gn: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Steps ``dc (Bf, n, 6)``, ``dn (Bf, m)`` and ``ok (Bf,)`` at damping ``lam``."""
        shift = lam[:, None, None] * (self.diag + self.floor[:, None, None])
        nn = self.nn + torch.diag_embed(lam[:, None] * (self.ndiag + self.floor[:, None]))
        cn, held = self.s.cn, torch.zeros_like(gn, dtype=torch.bool)
        factor = None if self.factor is None or bool(lam.any()) else self.factor
        while True:
            dc, dn, ok = self.solver.solve(self.band, cn, nn, gc, gn, shift, factor=factor)
            if self.ends is None:
                break
            out = self.ends & (dn < 0)
            if not bool(out.any()):
                break
            held = held | out  # grows each pass: at most m passes
            keep = (~held).to(nn.dtype)
            cn, gn = self.s.cn * keep[:, None, None, :], gn * keep
            nn = nn * keep[:, :, None] * keep[:, None, :] + torch.diag_embed(1.0 - keep)
        return self._project(dc), dn, ok

    def predicted(self, gc: Tensor, gn: Tensor, dc: Tensor, dn: Tensor) -> Tensor:
        r"""``(Bf,)`` the decrease of the objective that the undamped quadratic model
        predicts for the step ``(dc, dn)``: :math:`-(2 g^T \delta + \delta^T H \delta)`
        (``g`` half the gradient, ``H`` half the Hessian: data, pulls, Free priors)."""
        cn = self.s.cn
        hc = _prior.band_apply(self.band, dc[..., None])[..., 0]
        hc = hc + torch.einsum("bnim,bm->bni", cn, dn)
        hn = torch.einsum("bnim,bni->bm", cn, dc) + (self.nn @ dn[..., None])[..., 0]
        quad = (dc * hc).sum((-1, -2)) + (dn * hn).sum(-1)
        return -(2.0 * ((gc * dc).sum((-1, -2)) + (gn * dn).sum(-1)) + quad)

    def _project(self, dc: Tensor) -> Tensor:
        """``dc`` without the combinations of control points that no sample determines (no
        drift along them: ``torch_dq.fitting._prior.control_null``)."""
        U, DU = self.null
        if not U.shape[-1]:
            return dc
        return dc - torch.einsum("bnik,bk->bni", U, torch.einsum("bnik,bni->bk", DU, dc))

r"""Uncertainties of an estimate from the data-only Gauss-Newton matrix at the optimum.

With the control-point block ``A`` (banded), the coupling ``C`` and the nuisance block
``N`` (robust weights as converged, :func:`~torch_dq.fitting.estimate`'s ``prior``
excluded, the Gaussian priors of :class:`~torch_dq.fitting.Free` included), the joint
covariance is the inverse of ``[[A, C], [C^T, N]]``:

.. math::
    \Sigma_{nn} = S^{-1},\ S = N - C^T Z,\ Z = A^{-1} C, \qquad
    \Sigma_{cc} = A^{-1} + Z \Sigma_{nn} Z^T, \qquad \Sigma_{cn} = -Z \Sigma_{nn}.

``A^{-1}`` is only needed on the band (the selected inverse of
``BandedCholesky``), ``Z`` by one banded solve with ``m`` columns: no dense inverse.

Rank deficiency: the quantities are those of the pseudo-inverse restricted to the determined
subspace, inf for what loads on a direction without information. ``A`` is factored
regularised, :math:`A + \epsilon\,\mathrm{diag}(A)` with :math:`\epsilon = 10^{-10}`
(``Z`` and ``S`` then tend to those of :math:`A^+`, since ``C`` vanishes on the null space
of ``A``), and once more with :math:`10^{-8}`: a trajectory quantity whose control-point
variance more than doubles between the two loads on combinations of control points that no
sample determines (knots closer than the samples) and is inf. ``S`` is scaled by its
diagonal and inverted through its eigen-decomposition: a direction with a scaled eigenvalue
below ``1e-9`` of the largest (or a parameter with no information at all) gets an infinite
variance and a warning, and only the quantities with a component along it (above ``1e-8`` of
their largest) are inf. Control points without any data information (a time gap, an end
without samples) have zero rows and columns in ``A`` and ``C``: they are left out (their
poses' uncertainties are inf, with a warning naming the gap), which leaves ``S`` exact.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import cast

import torch
from torch import Tensor

from .. import _checks, curves, dualquat, quat
from . import _chi2, _robust
from ._banded import BandedCholesky
from ._charts import Scalar
from ._leverage import decouple, taken
from ._local import sample_jacobians, tangent_step
from ._observed import honest_std, observed_ratio
from ._prior import NULL, REGULARISE, scaled_eigh
from ._score import directions, warn_omitted

__all__ = ["Estimate"]

_FLOOR = 1e-12  # information below this fraction of the largest diagonal entry: none
_UNEXCITED = 0.1  # a time offset's std above this fraction of its bound: barely excited
_NEAR = 1e-2  # a Newton decrement within which the estimate is at the optimum (0.1 std of any
# quantity): the observed information's check of a time offset's std is taken there only
_LOOSE = 100.0  # the second regularisation (times REGULARISE) that tells undetermined apart


def _warn_unexcited(term, bound: float, s: Tensor) -> None:
    """Warn where a time offset's finite std exceeds ``_UNEXCITED`` of its bound: the motion
    barely excites it (a nearly constant rotation rate for a gyroscope, nearly constant
    specific force for an accelerometer), the bound rather than the data limits it and the
    linearised std is unreliable (issue 31: 3-4x overconfident, 1-sigma coverage 3-30 %)."""
    weak = torch.isfinite(s) & (s > _UNEXCITED * bound)
    if bool(weak.any()):
        warnings.warn(f"fitting.Estimate: {type(term).__name__}.time_offset is barely excited "
                      f"by the motion: its standard deviation {float(s[weak].max()):.3g} s "
                      f"exceeds {_UNEXCITED:g} of max_time_offset={bound!r}, the data hardly "
                      f"determine it and the standard deviation is unreliable (more varied "
                      f"motion determines it)", RuntimeWarning, stacklevel=3)


def _unregularised(band: Tensor, informed: bool) -> BandedCholesky | None:
    """The band factored as it is where every direction carries information (``informed``:
    the iteration certified it positive definite with room, nothing pulled, the loop's
    ``History.informed``); None elsewhere or where that factorisation fails."""
    if not informed:
        return None
    chol = BandedCholesky(band)
    return chol if bool(chol.ok.all()) else None


def _schur(factor: Callable[[float], BandedCholesky], cn: Tensor,
           nn: Tensor) -> tuple[BandedCholesky, Tensor, Tensor]:
    r"""The band factored with ``REGULARISE D`` (``factor(eps)``: the band with ``eps D`` on
    its diagonal), ``Z = A^{-1} C (Bf, n, 6, m)`` and the nuisance information ``S = N - C^T
    Z (Bf, m, m)`` in the limit of no regularisation, from that factor and a second one with
    ``_LOOSE REGULARISE D`` (factored first and freed: one factor held at a time): both are
    linear in ``eps`` while ``eps D`` is small against the information (Richardson's
    extrapolation to ``eps = 0``). The regularisation alone adds ``eps`` times the diagonal
    summed over every control point that a nuisance direction moves (an extrinsic's
    translation moves them all): on a weakly determined direction (a lever arm against an
    accelerometer bias under a nearly constant rotation rate) that was comparable to the
    data's information and shrank the standard deviation by 1.25 (measured against a dense
    pseudo-inverse)."""
    z2 = factor(_LOOSE * REGULARISE).solve(cn)
    s2 = torch.einsum("bnim,bniq->bmq", cn, z2)
    chol = factor(REGULARISE)
    z1 = chol.solve(cn)
    k = 1.0 / (_LOOSE - 1.0)
    s1 = torch.einsum("bnim,bniq->bmq", cn, z1)
    return chol, z1 + k * (z1 - z2), nn - (s1 + k * (s1 - s2))


def _drop_undetermined(band: Tensor, cn: Tensor,
                       scale: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Decouple the control points without data information (a time gap, an end without
    samples): their rows and columns of the band and of the coupling are (numerically)
    zero, so replacing their diagonal blocks by the identity and zeroing the rest leaves the
    Schur complement over the others exact.

    Args:
        band: ``(Bf, n, w, 6, 6)`` upper band of the control-point block.
        cn: ``(Bf, n, 6, m)`` coupling with the nuisance parameters.
        scale: ``(Bf, 1)`` the largest diagonal entry of the band.

    Returns:
        The band and coupling with those points decoupled, and ``free (Bf, n)`` bool, True
        at the undetermined control points.
    """
    free = (band[:, :, 0].abs().amax((-1, -2)) <= _FLOOR * scale) & (scale > 0)  # none: inf
    if not bool(free.any()):
        return band, cn, free
    band, cn = decouple(band, cn, free)
    eye = torch.eye(band.shape[-1], dtype=band.dtype, device=band.device)
    band[:, :, 0] = torch.where(free[..., None, None], eye, band[:, :, 0])
    return band, cn, free


def _count(x: Tensor) -> str:
    """A 0-d count's value, or a batch's largest."""
    return f"{int(x.max())}" if x.dim() == 0 else f"up to {int(x.max())}"


def _number(x: Tensor) -> str:
    """A 0-d tensor's value, or a batch's range and shape."""
    return f"{float(x):.6g}" if x.dim() == 0 else f"{x.min():.6g} to {x.max():.6g} {tuple(x.shape)}"


class Estimate:
    """What :func:`~torch_dq.fitting.estimate` found, and its uncertainties.

    Attributes:
        loss: ``(steps + 1, ...)`` data-only robust cost at the start and after each step
            (priors excluded).
        final_loss: ``(...)`` the last entry of ``loss``.
        objective: ``(steps + 1, ...)`` the minimised objective (``loss`` plus the priors),
            decreasing.
        steps: Levenberg-Marquardt iterations run.
        converged: ``(...)`` bool, True where the scaled gradient test of
            :func:`~torch_dq.fitting.estimate` passed (or the cost is zero); a stop for
            lack of progress, at ``steps`` or without a lowering step is False.
        reason: what stopped it (one string per batch element, joined by ``"; "``).
        chi2, dof, weights: per term (dicts keyed by the term), see the properties; the
            first uncertainty asked for warns where a term's chi2/dof is far above or below
            1 (:meth:`summary` lists them) and where the pixels ask for a line delay or
            distortion their camera model leaves out (score tests, ``fitting._score``). With
            a robust kernel the sigmas describe the inliers and ``chi2`` and ``dof`` count
            only them (a 99.9 % chi-square quantile cutoff scaled by the term's chi2/dof,
            the sum over the truncated mean: :attr:`chi2`); the summary and the warning say
            how many were left out, per term :attr:`outliers`.
        parameters: the estimated nuisance parameters in the order of :meth:`cov`'s rows.
    """

    def __init__(self, summary, ctrl: Tensor, values: list[Tensor], history) -> None:
        """Built by :func:`~torch_dq.fitting.estimate` from the solved problem's
        ``Summary`` (``torch_dq.fitting._problem``), the solution and the loop's
        ``History`` (``torch_dq.fitting._lm``)."""
        self._problem, self._ctrl, self._values = summary, ctrl, values
        self._dtype = summary.trajectory.control_points.dtype  # the uncertainties' (Conventions)
        self.loss: Tensor = history.loss
        self.final_loss: Tensor = self.loss[-1]
        self.objective: Tensor = history.objective
        self.steps: int = history.steps
        self.converged: Tensor = history.converged
        self.reason: str = history.reason
        self._system = summary.system
        self._informed = history.informed
        self._near = history.decrement <= _NEAR  # (Bf,) at the optimum (_observed)
        self._factored = self._checked = False
        self._weak: list[str] = []  # nuisance parameters with a direction without information
        self._inliers: dict | None = None
        self._taken: list[Tensor] | None = None
        self._ratios: dict[int, Tensor] = {}  # the observed information's std ratios, by column
        self._omitted = directions(summary.terms, summary.trajectory)  # at the solution

    def __repr__(self) -> str:
        ratios = ", ".join(f"{type(t).__name__}: {r:.3g}" + (f" (far {far} 1)" if far else "")
                           for t, (r, far) in self._far().items())
        return (f"Estimate(steps={self.steps}, reason={self.reason!r}, "
                f"final_loss={_number(self.final_loss)}, chi2/dof={{{ratios}}})")

    @property
    def parameters(self) -> list[tuple]:
        """The estimated nuisance parameters in the order of :meth:`cov`'s rows: a list of
        ``(term, name, size)``, ``size`` the chart's dimension (bias, lever arm 3, time
        offset 1, extrinsic 6, gravity 2); a shared :class:`~torch_dq.fitting.Free` appears
        once, under the first term that holds it."""
        return [(*q.uses[0], q.dim) for q in self._problem.params]

    def _per_term(self, what: str) -> dict:
        batch, s = self._problem.batch, self._system
        kept = self._kept() if what != "weights" else {}
        out = {}
        for term, r, w, c in zip(self._problem.terms, s.residuals, s.weights,
                                 self._problem.counted, strict=True):
            if what == "chi2":
                keep, kappa = kept[term]
                out[term] = torch.where(keep[..., None], r * r, 0.0).sum((-1, -2)).expand(
                    batch) / kappa
            elif what == "count":
                out[term] = (kept[term][0].sum(-1) * term.dim).expand(batch).to(torch.float64)
            else:
                out[term] = torch.where(c, w, 0.0).expand(*batch, w.shape[-1])
        return out

    def _leverages(self) -> list[Tensor]:
        r"""Per term ``(...)``: :math:`\mathrm{tr}(H_t \Sigma)`, the parameters its residuals
        take (``torch_dq.fitting._leverage``), NaN where the factorisation failed; once,
        on first use (it factors the Gauss-Newton matrix)."""
        if self._taken is None:
            self._factorise()
            bad = torch.isinf(self._inv)
            inv = torch.where(bad, 0.0, self._inv)
            r = self._r
            cov = ((self._U * inv[:, None, :]) @ self._U.mT) * r[:, :, None] * r[:, None, :]
            b = self._problem.batch
            self._taken = [torch.where(self._ok, x, torch.nan).reshape(b) for x in taken(
                self._chol, self._Z, cov, self._free, self._system)]
        return self._taken

    def _kept(self) -> dict:
        """Per term: the samples its :attr:`chi2` counts ``(..., N)`` bool and the divisor of
        their sum: the unmasked samples and 1 without a robust kernel, the inliers and the
        truncated mean ``kappa`` with one (``torch_dq.fitting._robust.inliers``); once."""
        if self._inliers is None:
            batch, out = self._problem.batch, {}
            for i, (term, r, mask) in enumerate(zip(self._problem.terms,
                                                    self._system.residuals,
                                                    self._problem.counted, strict=True)):
                if term.robust is None:
                    out[term] = (mask, 1.0)
                    continue
                s2 = (r * r).sum(-1)
                s2 = s2.expand(*batch, s2.shape[-1])
                out[term] = _robust.inliers(s2, mask.expand_as(s2), term.dim,
                                            self._leverages()[i])
            self._inliers = out
        return self._inliers

    def _left_out(self) -> dict:
        """Per robust term: ``(...)`` int, the unmasked samples beyond its inlier cutoff."""
        return {t: (c.expand_as(keep) & ~keep).sum(-1) for (t, (keep, _)), c in
                zip(self._kept().items(), self._problem.counted, strict=True)
                if t.robust is not None}

    @property
    def outliers(self) -> dict:
        """Per term ``(...)`` int64: its unmasked samples beyond its robust kernel's inlier
        cutoff, left out of :attr:`chi2` and :attr:`dof` (zero for a term without one)."""
        left = self._left_out()
        none = torch.zeros(self._problem.batch, dtype=torch.int64,
                           device=self._problem.spans.device)
        return {t: left.get(t, none) for t in self._problem.terms}

    @property
    def chi2(self) -> dict:
        r"""Per term ``(...)``: sum of squared whitened residuals of the unmasked samples.

        With a robust kernel the sigmas describe the inliers, and only they count: the
        samples whose squared whitened norm is at most :math:`q f` (``q`` the 99.9 %
        quantile of the chi-square distribution with the residual's dimension ``d``
        degrees of freedom, 16.27 for 3, 22.46 for 6; ``f`` the term's chi2/dof itself, a
        fixed point), their sum divided by :math:`\kappa = P(\chi^2_{d+2} \le q) /
        P(\chi^2_d \le q)`, the mean of the truncated distribution over ``d`` (0.994 for
        3): chi2/dof is about 1 when the sigmas are right whatever the gross outliers, 4 for
        sigmas 2x too small, 0.25 for 2x too large; :attr:`dof` counts the inliers, and
        :meth:`summary` how many samples were left out
        (``torch_dq.fitting._robust.inliers``)."""
        return self._per_term("chi2")

    @property
    def dof(self) -> dict:
        r"""Per term ``(...)`` float: the term's residual components ``N_t`` (unmasked
        samples; with a robust kernel its inliers, see :attr:`chi2`) less the parameters its
        residuals take, :math:`\nu_t = N_t - \mathrm{tr}(H_t \Sigma)` (at least 0): ``H_t``
        the term's Gauss-Newton matrix at the optimum (robust weights as converged),
        ``Sigma`` the covariance of :meth:`cov` and :meth:`pose_std` (the inverse of the
        data-only matrix with the :class:`~torch_dq.fitting.Free` priors, on the directions
        the data determine), so that :math:`\chi^2_t / \nu_t` is about 1 when the term's
        sigmas describe its data, whatever the other terms (``torch_dq.fitting._leverage``:
        the term's samples' leverages summed; 20 Hz poses beside a 200 Hz IMU take far fewer
        than their share of the residual count). Summed over the terms, the residual
        components less the parameters the data determine (the directions kept by
        ``estimate``'s ``prior``, or without information, count for no term). NaN where the
        Gauss-Newton matrix could not be factored. Computed on first use (it factors the
        matrix, as the first uncertainty does)."""
        return {t: (c - x).clamp_min(0.0) for (t, c), x in zip(
            self._per_term("count").items(), self._leverages(), strict=True)}

    def _factor_scale(self) -> Tensor:
        r"""``(Bf,)`` :math:`\sqrt{\sum_t \chi^2_t / \sum_t \nu_t}`, pooled over every term
        (``scaled=True``; see :meth:`cov`); inf below 0.5 dof (scipy's ``curve_fit``'s)."""
        chi2 = sum(self.chi2.values())
        dof = cast(Tensor, sum(self.dof.values()))
        return torch.where(dof < 0.5, torch.inf, chi2 / dof.clamp_min(1.0)).sqrt().reshape(-1)

    def _far(self) -> dict:
        """Per term: ``(ratio, "above" | "below" | None)`` (``fitting._chi2.far``)."""
        return _chi2.far(self.chi2, self.dof)

    def summary(self) -> str:
        r"""A few lines: the steps and why they stopped, the final loss, and per term its
        :math:`\chi^2`, :attr:`dof` and their ratio, marked where far above or below 1
        (the tests of the warning that the first uncertainty asked for gives), and for a
        robust term the samples beyond its inlier cutoff, left out (:attr:`chi2`)."""
        loss = self.final_loss
        lines = [f"estimate: {self.steps} step{'s' * (self.steps != 1)} ({self.reason}), "
                 f"final loss {_number(loss)}"]
        note = {"above": "  far above 1: sigmas too small, standard deviations too small",
                "below": "  far below 1: sigmas too large, standard deviations too large",
                None: ""}
        left = self._left_out()
        for (term, (ratio, far)), c, d in zip(self._far().items(), self.chi2.values(),
                                              self.dof.values(), strict=True):
            out = (f"  ({_count(left[term])} beyond the {term.robust} kernel's inlier cutoff "
                   f"left out)" if term in left else "")
            lines.append(f"  {type(term).__name__:<14} chi2 {_number(c)}  dof "
                         f"{_number(d)}  chi2/dof {ratio:.3g}{note[far]}{out}")
        return "\n".join(lines)

    def _check_chi2(self) -> None:
        """Warn where a term's chi2/dof is far above or far below 1 (:meth:`_far`)."""
        left = self._left_out()
        far = [(type(t).__name__, f"{r:.3g}" + (f" ({_count(left[t])} outliers left out)"
                                                if t in left else ""), t.order, how)
               for t, (r, how) in self._far().items() if how]
        above = [(n, r, o) for n, r, o, how in far if how == "above"]
        below = [(n, r) for n, r, _, how in far if how == "below"]
        if above:
            imu = [name for name, _, order in above if order >= 1]
            hint = (f"; for {', '.join(imu)}: or the trajectory's knots are too far apart for "
                    f"its readings (BSpline.from_poses(..., knot_spacing=...) finer)"
                    if imu else "")
            warnings.warn(f"fitting.Estimate: chi2/dof far above 1 "
                          f"({', '.join(f'{n} {r}' for n, r, _ in above)}): the sigmas do not "
                          f"describe the residuals, the standard deviations are too small "
                          f"(std(..., scaled=True) scales them by sqrt(chi2/dof) pooled over "
                          f"the terms){hint}",
                          RuntimeWarning, stacklevel=4)
        if below:
            warnings.warn(f"fitting.Estimate: chi2/dof far below 1 "
                          f"({', '.join(f'{n} {r}' for n, r in below)}): the sigmas are larger "
                          f"than the residuals' scatter, the standard deviations too large "
                          f"(pass the sensors' noise levels, or std(..., scaled=True))",
                          RuntimeWarning, stacklevel=4)

    @property
    def weights(self) -> dict:
        """Per term ``(..., N)``: robust weights at the optimum (0 where masked, and for a
        reprojection without an image at the solution)."""
        return self._per_term("weights")

    def _ensure(self) -> None:
        """The first uncertainty's factor and warnings (``_check_chi2``, ``_score``, null)."""
        if not self._checked:
            self._checked = True
            self._check_chi2()
            self._factorise()
            warn_omitted(self, self._omitted)
            if self._weak:
                warnings.warn(f"fitting.Estimate: the data carry no information on a "
                              f"direction of {', '.join(self._weak)}: its standard deviation "
                              f"is inf", RuntimeWarning, stacklevel=3)

    def _factorise(self) -> None:
        """Factor the Gauss-Newton matrix, once (the uncertainties, :attr:`dof`)."""
        if not self._factored:
            self._factor(self._system)
            self._factored = True

    # -- factorisation
    def _factor(self, system) -> None:
        p = self._problem
        Bf = max(p.batch.numel(), 1)
        scale = system.band[:, :, 0].diagonal(dim1=-2, dim2=-1).amax((-1, -2))[:, None]
        band, cn, self._free = _drop_undetermined(system.band, system.cn, scale)
        diag = band[:, :, 0].diagonal(dim1=-2, dim2=-1) + 1e-12 * scale[:, :, None]

        def regularised(eps: float) -> BandedCholesky:
            return BandedCholesky(band, shift=eps * diag)

        self._regularised = regularised
        self._loose_factor: BandedCholesky | None = None  # on first use: _loose()
        exact = _unregularised(band, self._informed)
        self._exact = exact is not None  # no direction without information: no loose test
        m = p.m
        if not m:
            self._chol = exact if exact is not None else regularised(REGULARISE)
            self._ok = self._chol.ok
            self._Z = system.cn
            self._U = system.nn
            self._r = system.nn.new_ones(Bf, 0)
            self._inv = system.nn.new_zeros(Bf, 0)
            return
        S = system.nn + torch.diag(p.prior_information).to(system.nn)
        # the nuisance information before the trajectory's share is taken out: S's
        # diagonal below _FLOOR of it is cancellation, none; below _FLOOR**2 of the band's
        # scale (a std ratio of 1e12) it is roundoff itself (a gyroscope's clock on a
        # constant rate); _FLOOR of the band's scale alone is units (1e-7 m poses put it
        # 1e13 above a camera's intrinsics)
        own = S.diagonal(dim1=-2, dim2=-1).amax(-1, keepdim=True)
        if exact is not None:  # S exactly, from the one factor
            self._chol, self._Z = exact, exact.solve(cn)
            S = S - torch.einsum("bnim,bniq->bmq", cn, self._Z)
        else:
            self._chol, self._Z, S = _schur(regularised, cn, S)
        ok = self._ok = self._chol.ok
        lam, U, d = scaled_eigh(S)
        bad = ((lam <= NULL * lam.amax(-1, keepdim=True).clamp_min(0.0))
               | (S.diagonal(dim1=-2, dim2=-1).amax(-1, keepdim=True) <= _FLOOR * own)
               | (own <= _FLOOR * _FLOOR * scale) | ~ok[:, None])
        self._U, self._r = U, d.rsqrt()
        self._inv = torch.where(bad, torch.inf, 1.0 / lam.clamp_min(1e-300))
        if bool(bad.any()):
            self._weak = sorted({f"{type(t).__name__}.{name}" for q in p.params
                                 for t, name in q.uses
                                 if bool((U[:, q.offset:q.offset + q.dim, :].abs() > 1e-6)
                                         .any(-2)[bad].any())})

    def _loads_free(self, J: Tensor, idx: Tensor) -> Tensor:
        """``(Bf, T, k)`` bool: the outputs with a component on a control point without data
        information (``J (Bf, T, k, sup 6)`` on the window ``idx (Bf, T, sup)``) above
        roundoff of the row's largest: a knot at a query time leaves the point whose support
        starts there with an exactly zero weight, and the pose there does not depend on it."""
        Bf, T, sup = idx.shape
        free = self._free.gather(1, idx.reshape(Bf, T * sup)).reshape(Bf, T, 1, sup, 1)
        a = J.reshape(Bf, T, J.shape[2], sup, 6).abs()
        return (a * free).amax((-1, -2)) > 1e-12 * a.amax((-1, -2))

    def _undetermined(self, J: Tensor, f: Tensor, sup: int, cvar: Tensor) -> Tensor:
        """``(Bf, T, k)`` bool: the kinematic outputs whose control-point variance ``cvar``
        halves with ``_LOOSE`` times the regularisation (a combination of control points
        that no sample resolves); none where the band was factored exactly (every direction
        informed)."""
        if self._exact:
            return torch.zeros_like(cvar, dtype=torch.bool)
        loose = torch.einsum("btij,btjl,btil->bti", J, self._loose().window_covariance(f, sup),
                             J)
        return cvar > 2.0 * loose.clamp_min(0.0)

    def _loose(self) -> BandedCholesky:
        """The band factored with ``_LOOSE REGULARISE D`` (the kinematic uncertainties' test
        of directions without information), on first use (the factorisation held one factor
        at a time)."""
        if self._loose_factor is None:
            self._loose_factor = self._regularised(_LOOSE * REGULARISE)
        return self._loose_factor

    def _quadratic(self, A: Tensor) -> Tensor:
        """``diag(A Sigma_nn A^T)`` for ``A (Bf, ..., k, m)``, inf-safe (a component along
        a direction without information below ``1e-8`` of the row's largest is roundoff)."""
        shape = (A.shape[0],) + (1,) * (A.dim() - 3) + self._U.shape[1:]
        a = (A * self._r.reshape((*shape[:-2], 1, -1))) @ self._U.reshape(shape)
        inv = self._inv.reshape((*shape[:-2], 1, -1))
        big = a.abs() > 1e-8 * a.abs().amax(-1, keepdim=True)
        return torch.where(big, a * a * inv, 0.0).sum(-1)

    def _param(self, term, name: str, fn: str = "fitting.Estimate.std"):
        p = self._problem
        if not any(t is term for t in p.terms):
            _checks.fail(fn, "term is not one of the estimated terms")
        for q in p.params:
            if any(t is term and n == name for t, n in q.uses):
                return q
        _checks.fail(fn, f"{type(term).__name__}.{name} was not estimated")

    def _chart_map(self, q) -> Tensor | None:
        """Map from the chart to the reported coordinates (gravity: world ``(3, 2)``)."""
        v = self._values[self._problem.params.index(q)]
        return q.chart.report(v.reshape(-1, *q.chart.shape))

    def cov(self, *items: tuple, scaled: bool = False) -> Tensor:
        r"""Joint covariance ``(..., k, k)`` of ``(term, name)`` pairs in their charts.

        Args:
            items: ``(term, name)`` pairs, their rows in that order; none: every estimated
                parameter, in the order of :attr:`parameters` (``(term, name, size)``,
                ``size`` rows each).
            scaled: multiply by the pooled :math:`\sum_t \chi^2_t / \sum_t \nu_t` over
                every term (:attr:`chi2`, :attr:`dof`; :math:`\sum_t \nu_t = N - p`, ``N``
                every residual component, ``p`` the parameters the data determine): the
                a-posteriori reference variance of least squares (``scipy.optimize.
                curve_fit``'s ``absolute_sigma=False``, MATLAB's ``lscov``), the covariance as
                the residuals' own scatter suggests when every term's sigmas are off by one
                common factor (no term's own: a parameter is determined by several terms
                together, each term's :math:`\chi^2_t / \nu_t` says how far its own sigmas
                are off; GTSAM's ``Marginals``, Ceres' ``Covariance`` and pypose scale by
                nothing, as ``scaled=False`` does).

        Returns:
            ``(..., k, k)``, ``k`` the sum of the sizes, in the trajectory's dtype.
        """
        return self._cov(items, scaled).to(self._dtype)

    def _cov(self, items: tuple, scaled: bool) -> Tensor:  # cov in float64
        for item in items:
            if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[1], str)):
                _checks.fail("fitting.Estimate.cov", f"items must be (term, name) pairs, got "
                                                     f"{item!r}", TypeError)
        self._ensure()
        p = self._problem
        qs = [self._param(t, n, "fitting.Estimate.cov") for t, n in items] if items else p.params
        dev = self._U.device
        if not qs:  # nothing estimated: the (0, 0) covariance
            return self._U.new_zeros(*p.batch, 0, 0)
        cols = torch.cat([torch.arange(q.offset, q.offset + q.dim, device=dev) for q in qs])
        Bf = self._U.shape[0]
        E = torch.eye(p.m, dtype=self._U.dtype, device=dev)[cols].expand(Bf, -1, -1)
        a = (E * self._r[:, None, :]) @ self._U
        big = a.abs() > 1e-8 * a.abs().amax(-1, keepdim=True)
        prod = a[:, :, None, :] * a[:, None, :, :]
        both = big[:, :, None, :] & big[:, None, :, :]
        C = torch.where(both, prod * self._inv[:, None, None, :], 0.0).sum(-1)
        if _checks.flag("fitting.Estimate.cov", "scaled", scaled):
            C = C * self._factor_scale()[:, None, None] ** 2
        return C.reshape(*p.batch, len(cols), len(cols))

    def std(self, term, name: str, scaled: bool = False, observed: bool = False) -> Tensor:
        r"""Marginal standard deviation of ``term``'s estimated ``name`` in its chart: bias,
        lever arm ``(..., 3)``; time offset ``(...)``; gravity ``(..., 3)`` world axes;
        extrinsic ``(..., 6)`` (``e exp(delta)``), from the data-only Gauss-Newton matrix.
        ``scaled``: times :math:`\sqrt{\chi^2 / \nu}` pooled over every term (see
        :meth:`cov`). A time offset that ended on its ``max_time_offset`` bound (a
        constrained optimum, where the curvature says nothing of its uncertainty) gets inf and
        a warning; one whose std exceeds a tenth of that bound (without a ``Free``
        ``prior_std``) warns that the motion barely excites it (its linearised std is then
        unreliable). A time offset's Gauss-Newton std is also checked against the observed
        information's (the Hessian with the offset's row exact, ``torch_dq.fitting._observed``:
        its Jacobian, read on the estimated trajectory, carries the fitted noise, which can
        inflate the Gauss-Newton information): more than 1.4 times smaller, or the estimate
        no minimum along it, is warned of. ``observed`` (a time offset's only): the larger of
        the Gauss-Newton and the observed information's std (inf where the estimate is no
        minimum along it)."""
        fn = "fitting.Estimate.std"
        if _checks.flag(fn, "observed", observed) and name != "time_offset":
            _checks.fail(fn, f"observed=True is for a time_offset (the observed information of "
                             f"a sensor's clock), got name={name!r}")
        q = self._param(term, name)
        C = self._cov(((term, name),), scaled).reshape(-1, q.dim, q.dim)
        M = self._chart_map(q)
        if M is not None:  # gravity: from its 2-d chart to world axes
            finite = torch.isfinite(C).all(-1).all(-1)[:, None, None]
            C = torch.where(finite, M @ torch.where(finite, C, 0.0) @ M.mT, torch.inf)
        s = C.diagonal(dim1=-2, dim2=-1).clamp_min(0.0).sqrt()
        b = self._problem.batch
        if isinstance(q.chart, Scalar):
            v = self._values[self._problem.params.index(q)].reshape(-1, 1)
            pinned = q.chart.pinned(v)
            if bool(pinned.any()):
                warnings.warn(f"fitting.Estimate: {type(term).__name__}.time_offset ended on "
                              f"its bound max_time_offset={q.chart.high!r}: its standard "
                              f"deviation is inf (raise max_time_offset)", RuntimeWarning,
                              stacklevel=2)
            s = torch.where(pinned, torch.inf, s)
            if name == "time_offset":  # a line delay's exact rows: 0.65 to 1.36 and inf there
                s = self._observed(term, name, q, s, observed)
            if q.free.prior_std is None:  # with a prior, the std is the user's statement
                _warn_unexcited(term, q.chart.high, torch.where(pinned, torch.nan, s))
            return s.reshape(b).to(self._dtype)
        return s.reshape(*b, s.shape[-1]).to(self._dtype)

    def _observed(self, term, name: str, q, s: Tensor, observed: bool) -> Tensor:
        """A time offset's Gauss-Newton std ``s (Bf, 1)``, checked against the observed
        information's, or with ``observed`` the latter (``torch_dq.fitting._observed``: the
        ratio computed once per parameter, where ``s`` is finite and the estimate within
        ``_NEAR`` of the optimum: elsewhere the second-order terms are a point's that is no
        optimum)."""
        if not bool((torch.isfinite(s[:, 0]) & self._near).any()):
            return s
        if q.offset not in self._ratios:
            self._ratios[q.offset] = observed_ratio(
                self._problem.problem, self._ctrl, self._values, self._system, self._chol,
                self._free, q.offset).where(self._near, 1.0)
        return honest_std(f"{type(term).__name__}.{name}", s, self._ratios[q.offset], observed)

    # -- trajectory uncertainties
    def _along(self, fn: str, t: Tensor, k: int, output, scaled: bool) -> Tensor:
        """Standard deviations ``(..., T, k)`` of ``output(derivs, ref)`` at ``t`` (errors
        named by ``fn``); computed on the estimate's device, returned on ``t``'s."""
        self._ensure()
        p = self._problem
        spans, ctrl = p.spans, self._ctrl
        home = _checks.tensor(fn, "t", t).device
        t = t.to(ctrl.device)
        sup, n = spans.support, spans.n
        # the layer's checks: type, shape, domain (no extrapolation of the uncertainty)
        p.trajectory._times(fn, t, ctrl, False, "as the standard deviations are not extrapolated")
        lead = t.shape[:-1]
        if not p.batch:  # one trajectory: any leading shape of times, flattened
            t = t.reshape(-1)
        elif torch.broadcast_shapes(p.batch, lead) != p.batch:
            _checks.fail(fn, f"times {_checks.shape_str(t.shape)} do not broadcast to the "
                             f"batch {_checks.shape_str(p.batch)}")
        shape = p.batch
        T = t.shape[-1]
        t = spans.since_origin(t.to(torch.float64).expand(*shape, T))
        first = spans.first(t)
        window = first[..., None] + torch.arange(sup, device=t.device)
        pts = ctrl.expand(*shape, n, 8).gather(-2, window.reshape(*shape, T * sup, 1).expand(
            *shape, T * sup, 8)).reshape(*shape, T, sup, 8)
        ref = [d.detach() for d in spans.derivatives(pts, t, first, 2)]

        def out(lv):
            d = spans.derivatives(tangent_step(pts, lv[0]), t, first, 2)
            return output(d, ref)

        _, (J,) = sample_jacobians(out, [ctrl.new_zeros(*shape, T, sup, 6)], k)
        Bf = max(p.batch.numel(), 1)
        J = J.expand(*p.batch, T, k, sup, 6).reshape(Bf, T, k, sup * 6)
        f = first.expand(*p.batch, T).reshape(Bf, T)
        var = cvar = torch.einsum("btij,btjl,btil->bti", J,
                                  self._chol.window_covariance(f, sup), J)
        idx = (f[..., None] + torch.arange(sup, device=f.device)).clamp(max=n - 1)
        if p.m:
            Zw = self._Z.gather(1, idx.reshape(Bf, T * sup, 1, 1).expand(
                Bf, T * sup, 6, p.m)).reshape(Bf, T, sup * 6, p.m)
            var = var + self._quadratic(J @ Zw)
        std = var.clamp_min(0.0).sqrt()
        gap = self._loads_free(J, idx)
        null = self._undetermined(J, f, sup, cvar) & ~gap
        std = torch.where(self._ok[:, None, None] & ~gap & ~null, std, torch.inf)
        if bool(gap.any()) or bool(null.any()) or not bool(self._ok.all()):
            why = ("a time gap or an end without samples" if bool(gap.any()) else
                   "combinations of control points that no sample resolves: more control "
                   "points than the samples determine (knots closer than the samples)")
            warnings.warn(f"fitting.Estimate: the data do not determine every control point "
                          f"({why}); the uncertainties that depend on them are inf",
                          RuntimeWarning, stacklevel=4)
        if _checks.flag("fitting.Estimate", "scaled", scaled):
            std = std * self._factor_scale()[:, None, None]
        # a NaN time passes the domain check; its std is NaN, never a finite number
        std = torch.where(torch.isnan(t).reshape(Bf, T, 1), torch.nan, std)
        return std.reshape(*(p.batch or lead), -1, k).to(home, self._dtype)

    def pose_std(self, t: Tensor, scaled: bool = False) -> Tensor:
        """``(..., T, 6)``: standard deviations of the pose at ``t``: the rotation ``delta``
        with ``R = R_hat exp(delta)`` (body axes, radians), then the translation (world).
        ``t``: ``(T,)``, or ``(..., T)`` broadcasting to the batch (any leading shape for
        one trajectory), on any device (the result on ``t``'s: an estimate computed on the
        CPU, as ``calibration.camera_imu``'s, answers CUDA times); ``scaled`` as for
        :meth:`std`. Inf (with a warning) where the pose depends on control points or
        combinations of them that the data do not determine."""
        def output(d, ref):
            q, pos = dualquat.to_rt(d[0])
            q0, p0 = dualquat.to_rt(ref[0])
            return torch.cat((quat.to_rotvec(quat.mul(quat.conj(q0), q)), pos - p0), -1)

        return self._along("fitting.Estimate.pose_std", t, 6, output, scaled)

    def kinematics_std(self, t: Tensor, scaled: bool = False) -> Tensor:
        """``(..., T, 12)``: standard deviations of the angular velocity, linear velocity,
        angular acceleration and linear acceleration at ``t`` (world axes); ``t`` and
        ``scaled`` as for :meth:`pose_std`."""
        def output(d, ref):
            k = curves.kinematics(d[0], d[1], d[2])
            parts = [k.angular_velocity, k.linear_velocity, k.angular_acceleration,
                     k.linear_acceleration]
            return torch.cat([cast(Tensor, v) for v in parts], -1)

        return self._along("fitting.Estimate.kinematics_std", t, 12, output, scaled)

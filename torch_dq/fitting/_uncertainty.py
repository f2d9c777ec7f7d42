r"""Uncertainties of an estimate from the data-only Gauss-Newton matrix at the optimum.

With the control-point block ``A`` (banded), the coupling ``C`` and the nuisance block
``N`` (robust weights as converged, :func:`~torch_dq.fitting.estimate`'s ``prior``
excluded, the Gaussian priors of :class:`~torch_dq.fitting.Free` included), the joint
covariance is the inverse of ``[[A, C], [C^T, N]]``:

.. math::
    \Sigma_{nn} = S^{-1},\ S = N - C^T Z,\ Z = A^{-1} C, \qquad
    \Sigma_{cc} = A^{-1} + Z \Sigma_{nn} Z^T, \qquad \Sigma_{cn} = -Z \Sigma_{nn}.

``A^{-1}`` is only needed on the band (the selected inverse of
``BandedCholesky``), ``Z`` by one banded solve with ``m``
columns: no dense inverse. ``S`` is inverted through its eigen-decomposition: a direction
with an eigenvalue below ``1e-9`` of the largest, or below ``1e-12`` of the largest diagonal
entry of ``A`` (no information at float64 precision), gets an infinite variance and a
warning, never a value chosen by the numerical prior. Control points without data
information (a time gap, an end without samples) have zero rows and columns in ``A`` and
``C``: they are left out (their poses' uncertainties are inf), which leaves ``S`` exact.
"""

from __future__ import annotations

import warnings
from typing import cast

import torch
from torch import Tensor

from .. import _checks, curves, dualquat, quat
from ._banded import BandedCholesky
from ._local import sample_jacobians, tangent_step
from ._nuisance import gravity_basis

__all__ = ["Estimate"]

_NULL = 1e-9  # relative eigenvalue of the Schur complement below which a direction is unknown
_FLOOR = 1e-12  # ... or below this fraction of the largest control-point information


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
    n, w = band.shape[1], band.shape[2]
    free = (band[:, :, 0].abs().amax((-1, -2)) <= _FLOOR * scale) & (scale > 0)  # none: inf
    if not bool(free.any()):
        return band, cn, free
    col = torch.arange(n, device=band.device)[:, None] + torch.arange(w, device=band.device)
    hit = free[:, :, None] | free.gather(1, col.clamp(max=n - 1).reshape(1, -1).expand(
        free.shape[0], -1)).reshape(-1, n, w)
    band = band.masked_fill(hit[..., None, None], 0.0)
    eye = torch.eye(band.shape[-1], dtype=band.dtype, device=band.device)
    band[:, :, 0] = torch.where(free[..., None, None], eye, band[:, :, 0])
    return band, cn.masked_fill(free[..., None, None], 0.0), free


class Estimate:
    """What :func:`~torch_dq.fitting.estimate` found, and its uncertainties.

    Attributes:
        loss: ``(steps + 1, ...)`` data-only robust cost at the start and after each step
            (priors excluded).
        final_loss: ``(...)`` the last entry of ``loss``.
        objective: ``(steps + 1, ...)`` the minimised objective (``loss`` plus the priors),
            decreasing.
        steps: Levenberg-Marquardt iterations run.
        converged: ``(...)`` bool, True where a stopping test held.
        reason: what stopped it (one string per batch element, joined by ``"; "``).
        chi2, dof, weights: per term (dicts keyed by the term), see the properties.
        parameters: the estimated nuisance parameters in the order of :meth:`cov`'s rows.
    """

    def __init__(self, problem, ctrl: Tensor, values: list[Tensor], history: dict) -> None:
        self._problem, self._ctrl, self._values = problem, ctrl, values
        self.loss: Tensor = history["loss"]
        self.final_loss: Tensor = self.loss[-1]
        self.objective: Tensor = history["objective"]
        self.steps: int = history["steps"]
        self.converged: Tensor = history["converged"]
        self.reason: str = history["reason"]
        self._sys = history.get("system")  # built at the optimum by the loop, or None
        self._factored = False

    def __repr__(self) -> str:
        loss = self.final_loss
        loss_s = f"{float(loss):.6g}" if loss.dim() == 0 else f"<{tuple(loss.shape)} tensor>"
        ratios = ", ".join(f"{type(t).__name__}: {float(c.sum()) / max(float(d.sum()), 1):.3g}"
                           for (t, c), d in zip(self.chi2.items(), self.dof.values(),
                                                strict=True))
        return (f"Estimate(steps={self.steps}, reason={self.reason!r}, final_loss={loss_s}, "
                f"chi2/dof={{{ratios}}})")

    @property
    def parameters(self) -> list[tuple]:
        """The estimated nuisance parameters in the order of :meth:`cov`'s rows: a list of
        ``(term, name, size)``, ``size`` the chart's dimension (bias, lever arm 3, time
        offset 1, extrinsic 6, gravity 2); a shared :class:`~torch_dq.fitting.Free` appears
        once, under the first term that holds it."""
        p = self._problem
        first: dict[int, tuple] = {}
        for (i, name), q in p.index.items():
            first.setdefault(id(q), (p.terms[i], name, q.dim))
        return [first[id(q)] for q in p.params]

    @property
    def _system(self):
        """The data-only Gauss-Newton system at the optimum (built on first use)."""
        if self._sys is None:
            p = self._problem
            self._sys = p.system(self._ctrl, self._values, p.width(self._values))
        return self._sys

    def _per_term(self, what: str) -> dict:
        batch, s = self._problem.batch, self._system
        out = {}
        for term, r, w in zip(self._problem.terms, s.residuals, s.weights, strict=True):
            if what == "chi2":
                out[term] = (r * r).sum((-1, -2)).expand(batch)
            elif what == "dof":
                out[term] = (term.mask.sum(-1) * term.dim).expand(batch)
            else:
                out[term] = w.expand(*batch, w.shape[-1])
        return out

    @property
    def chi2(self) -> dict:
        """Per term ``(...)``: sum of squared whitened residuals of the unmasked samples."""
        return self._per_term("chi2")

    @property
    def dof(self) -> dict:
        """Per term ``(...)``: the number of residual components of the unmasked samples."""
        return self._per_term("dof")

    @property
    def weights(self) -> dict:
        """Per term ``(..., N)``: robust weights at the optimum (0 where masked)."""
        return self._per_term("weights")

    def _ensure(self) -> None:
        """Factor the Gauss-Newton matrix on the first uncertainty asked for."""
        if not self._factored:
            self._factor(self._system)
            self._factored = True

    # -- factorisation
    def _factor(self, system) -> None:
        p = self._problem
        Bf = max(p.batch.numel(), 1)
        scale = system.band[:, :, 0].diagonal(dim1=-2, dim2=-1).amax((-1, -2))[:, None]
        band, cn, self._free = _drop_undetermined(system.band, system.cn, scale)
        self._chol = BandedCholesky(band)
        ok = self._chol.ok
        if not bool(ok.all()) or bool(self._free.any()):
            warnings.warn("fitting.Estimate: the data do not determine every control point "
                          "(a time gap or an end without samples); the uncertainties that depend "
                          "on them are inf", RuntimeWarning, stacklevel=4)
        self._ok = ok
        m = p.m
        if not m:
            self._Z = system.cn
            self._V = system.nn
            self._inv = system.nn.new_zeros(Bf, 0)
            return
        self._Z = self._chol.solve(cn)  # (Bf, n, 6, m)
        S = system.nn + torch.diag(p.prior_information()).to(system.nn)
        S = S - torch.einsum("bnim,bniq->bmq", cn, self._Z)
        S = 0.5 * (S + S.mT)
        lam, V = torch.linalg.eigh(S)
        top = lam.amax(-1, keepdim=True).clamp_min(0.0)
        bad = (lam <= _NULL * top) | (lam <= _FLOOR * scale) | ~ok[:, None]
        self._V = V
        self._inv = torch.where(bad, torch.inf, 1.0 / lam.clamp_min(1e-300))
        if bool(bad.any()):
            weak = [f"{type(p.terms[i]).__name__}.{name}" for (i, name), q in p.index.items()
                    if bool((V[:, q.offset:q.offset + q.dim, :].abs() > 1e-6)
                            .any(-2)[bad].any())]
            warnings.warn(f"fitting.Estimate: the data carry no information on a direction of "
                          f"{', '.join(sorted(set(weak)))}: its standard deviation is inf",
                          RuntimeWarning, stacklevel=4)

    def _quadratic(self, A: Tensor) -> Tensor:
        """``diag(A Sigma_nn A^T)`` for ``A (Bf, ..., k, m)``, inf-safe."""
        shape = (A.shape[0],) + (1,) * (A.dim() - 3) + self._V.shape[1:]
        a = A @ self._V.reshape(shape)
        inv = self._inv.reshape(shape[:-2] + (1, -1))
        scale = a.abs().amax(-1, keepdim=True)
        return torch.where(a.abs() > 1e-8 * scale, a * a * inv, 0.0).sum(-1)

    def _param(self, term, name: str):
        fn = "fitting.Estimate.std"
        p = self._problem
        for i, t in enumerate(p.terms):
            if t is term:
                q = p.index.get((i, name))
                if q is None:
                    _checks.fail(fn, f"{type(term).__name__}.{name} was not estimated")
                return q
        _checks.fail(fn, "term is not one of the estimated terms")

    def _chart_map(self, q) -> Tensor | None:
        """Map from the chart to the reported coordinates (gravity: world ``(3, 2)``)."""
        if q.kind != "gravity":
            return None
        g = self._values[self._problem.params.index(q)].reshape(-1, 3)
        cross = torch.linalg.cross(g[:, :, None].expand(-1, 3, 3),
                                   torch.eye(3, dtype=g.dtype, device=g.device).expand(
                                       g.shape[0], 3, 3),
                                   dim=1)  # [g]x columns: g x e_j
        return -cross @ gravity_basis(g)  # d(Exp(B d) g)/dd = -[g]x B

    def cov(self, *items: tuple) -> Tensor:
        """Joint covariance ``(..., k, k)`` of ``(term, name)`` pairs in their charts.

        Args:
            items: ``(term, name)`` pairs, their rows in that order; none: every estimated
                parameter, in the order of :attr:`parameters` (``(term, name, size)``,
                ``size`` rows each).

        Returns:
            ``(..., k, k)``, ``k`` the sum of the sizes.
        """
        self._ensure()
        p = self._problem
        qs = [self._param(t, n) for t, n in items] if items else p.params
        dev = self._V.device
        cols = torch.cat([torch.arange(q.offset, q.offset + q.dim, device=dev) for q in qs])
        Bf = self._V.shape[0]
        E = torch.eye(p.m, dtype=self._V.dtype, device=dev)[cols].expand(Bf, -1, -1)
        a = E @ self._V
        prod = a[:, :, None, :] * a[:, None, :, :]
        big = (a.abs() > 1e-8)[:, :, None, :] & (a.abs() > 1e-8)[:, None, :, :]
        C = torch.where(big, prod * self._inv[:, None, None, :], 0.0).sum(-1)
        return C.reshape(*p.batch, len(cols), len(cols))

    def std(self, term, name: str) -> Tensor:
        """Marginal standard deviation of ``term``'s estimated ``name`` in its chart: bias,
        lever arm ``(..., 3)``; time offset ``(...)``; gravity ``(..., 3)`` world axes;
        extrinsic ``(..., 6)`` (``e exp(delta)``)."""
        q = self._param(term, name)
        C = self.cov((term, name)).reshape(-1, q.dim, q.dim)
        M = self._chart_map(q)
        if M is not None:  # gravity: from its 2-d chart to world axes
            finite = torch.isfinite(C).all(-1).all(-1)[:, None, None]
            C = torch.where(finite, M @ torch.where(finite, C, 0.0) @ M.mT, torch.inf)
        s = C.diagonal(dim1=-2, dim2=-1).clamp_min(0.0).sqrt()
        b = self._problem.batch
        return s.reshape(b) if q.kind == "offset" else s.reshape(*b, s.shape[-1])

    # -- trajectory uncertainties
    def _along(self, t: Tensor, k: int, output) -> Tensor:
        """Standard deviations ``(..., T, k)`` of ``output(derivs, ref)`` at ``t``."""
        self._ensure()
        p = self._problem
        spans, ctrl = p.spans, self._ctrl
        sup, n = spans.support, spans.n
        _checks.tensor("fitting.Estimate", "t", t)
        if t.dim() < 1:
            _checks.fail("fitting.Estimate", "expected (T,) or (..., T) times for t")
        p.trajectory.derivatives(t, 0, ctrl=ctrl)  # the layer's domain check
        shape = torch.broadcast_shapes(p.batch, t.shape[:-1])
        T = t.shape[-1]
        t = t.to(torch.float64).expand(*shape, T)
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
        Sw = self._chol.window_covariance(f, sup)
        var = torch.einsum("btij,btjl,btil->bti", J, Sw, J)
        idx = (f[..., None] + torch.arange(sup, device=f.device)).clamp(max=n - 1)
        if p.m:
            Zw = self._Z.gather(1, idx.reshape(Bf, T * sup, 1, 1).expand(
                Bf, T * sup, 6, p.m)).reshape(Bf, T, sup * 6, p.m)
            var = var + self._quadratic(J @ Zw)
        std = var.clamp_min(0.0).sqrt()
        known = self._ok[:, None] & ~self._free.gather(1, idx.reshape(Bf, T * sup)).reshape(
            Bf, T, sup).any(-1)
        std = torch.where(known[..., None], std, torch.inf)
        return std.reshape(*p.batch, T, k)

    def pose_std(self, t: Tensor) -> Tensor:
        """``(..., T, 6)``: standard deviations of the pose at ``t``: the rotation ``delta``
        with ``R = R_hat exp(delta)`` (body axes, radians), then the translation (world)."""
        def output(d, ref):
            q, pos = dualquat.to_rt(d[0])
            q0, p0 = dualquat.to_rt(ref[0])
            return torch.cat((quat.to_rotvec(quat.mul(quat.conj(q0), q)), pos - p0), -1)

        return self._along(t, 6, output)

    def kinematics_std(self, t: Tensor) -> Tensor:
        """``(..., T, 12)``: standard deviations of the angular velocity, linear velocity,
        angular acceleration and linear acceleration at ``t`` (world axes)."""
        def output(d, ref):
            k = curves.kinematics(d[0], d[1], d[2])
            parts = [k.angular_velocity, k.linear_velocity, k.angular_acceleration,
                     k.linear_acceleration]
            return torch.cat([cast(Tensor, v) for v in parts], -1)

        return self._along(t, 12, output)

"""The factorisations the pulls and the scaled gradient test share (``fitting._prior``,
``fitting._solver``): the nuisance pull decided from the band's own factorisation where
nothing is pulled and every direction carries information, the regularised one only where
that test cannot decide, and the undamped step on the factorisation at hand; against
numpy's dense solves and eigen-decompositions of the same matrices."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from test_prior_null import N, W, _band  # the dense matrix's upper band

from torch_dq.fitting import _banded, _prior, _solver

M = 3  # nuisance parameters (N control points, W blocks wide: test_prior_null's)


def _normal(seed: int, null: bool) -> np.ndarray:
    """``J^T J`` of random rows on windows of ``W`` control points and the ``M`` nuisance
    columns; with ``null`` the first nuisance column is the second's plus a combination of
    the control points' columns (their difference a direction the trajectory absorbs: a
    null of the Schur complement)."""
    rng = np.random.default_rng(seed)
    rows = []
    for f in range(N - W + 1):
        J = np.zeros((40, 6 * N + M))
        J[:, 6 * f:6 * (f + W)] = rng.standard_normal((40, 6 * W))
        J[:, 6 * N:] = rng.standard_normal((40, M))
        rows.append(J)
    J = np.concatenate(rows)
    if null:
        J[:, 6 * N] = J[:, 6 * N + 1] + J[:, :6 * N] @ (0.1 * rng.standard_normal(6 * N))
    return J.T @ J


def _parts(H: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The band, the coupling ``(1, N, 6, M)`` and the nuisance block ``(1, M, M)``."""
    return (_band(H[:6 * N, :6 * N]), torch.from_numpy(H[:6 * N, 6 * N:].reshape(1, N, 6, M)),
            torch.from_numpy(H[None, 6 * N:, 6 * N:]))


def _reference_pull(H: np.ndarray, prior: float) -> np.ndarray:
    """The nuisance pull as the module documents it, dense: the Schur complement with the
    control points regularised by ``REGULARISE`` of their floored diagonal, scaled by its
    diagonal, ``prior`` on its eigen-directions at or below ``NULL`` of the largest."""
    A, C, Nn = H[:6 * N, :6 * N], H[:6 * N, 6 * N:], H[6 * N:, 6 * N:]
    d = np.diag(A) + 1e-12 * np.diag(A).max()
    S = Nn - C.T @ np.linalg.solve(A + _prior.REGULARISE * np.diag(d), C)
    e = np.maximum(np.diag(S), 1e-12 * np.diag(S).max())
    lam, V = np.linalg.eigh((S + S.T) / 2 / np.sqrt(np.outer(e, e)))
    P = (V * np.where(lam <= _prior.NULL * lam.max(), prior, 0.0)) @ V.T
    return P * np.sqrt(np.outer(e, e))


def test_informed_nuisance_has_no_pull_without_the_regularised_factorisation():
    H = _normal(0, null=False)
    band, cn, nn = _parts(H)
    assert np.abs(_reference_pull(H, 1e-6)).max() == 0.0  # the reference: nothing null
    reg = _prior.Regularised(band, torch.zeros_like(band))
    P = _prior.nuisance_pull(reg, cn, nn, 1e-6)
    assert P.shape == (1, M, M) and not bool(P.any())
    assert reg._chol is None  # decided from the band's own factorisation
    Z = reg.exact.solve(cn).reshape(6 * N, M).numpy()
    np.testing.assert_allclose(Z, np.linalg.solve(H[:6 * N, :6 * N], H[:6 * N, 6 * N:]),
                               rtol=1e-9, atol=1e-12 * np.abs(Z).max())


def test_null_nuisance_direction_is_pulled_as_the_dense_reference():
    H = _normal(1, null=True)
    band, cn, nn = _parts(H)
    ref = _reference_pull(H, 1e-6)
    assert np.abs(ref).max() > 0  # the reference pulls the absorbed direction
    reg = _prior.Regularised(band, torch.zeros_like(band))
    P = _prior.nuisance_pull(reg, cn, nn, 1e-6)[0].numpy()
    assert reg._chol is not None  # the test could not decide: the regularised path
    np.testing.assert_allclose(P, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())


def test_pulled_band_takes_the_regularised_path_alone():
    H = _normal(2, null=False)
    band, cn, nn = _parts(H)
    pull = torch.zeros_like(band)
    pull[0, 0, 0] = 1e-3 * torch.eye(6, dtype=torch.float64)  # one control point pulled
    reg = _prior.Regularised(band, pull)
    H2 = H.copy()
    H2[:6, :6] += 1e-3 * np.eye(6)
    P = _prior.nuisance_pull(reg, cn, nn, 1e-6)
    assert reg._exact is None and reg._chol is not None
    np.testing.assert_array_equal(P[0].numpy(), _reference_pull(H2, 1e-6))  # zeros


@pytest.mark.parametrize("lam", [0.0, 1e-3])
def test_step_on_the_given_factorisation_is_the_dense_solve(lam, monkeypatch):
    """At zero damping the step solves on the factorisation given (none made); damped, it
    factors its own: both the dense Newton step of the damped system."""
    H = _normal(3, null=False)
    band, cn, nn = _parts(H)
    rng = np.random.default_rng(3)
    g = rng.standard_normal(6 * N + M)
    gc, gn = torch.from_numpy(g[None, :6 * N].reshape(1, N, 6)), torch.from_numpy(g[None, 6 * N:])
    factor = _banded.BandedCholesky(band)
    system = SimpleNamespace(band=band, cn=cn, nn=nn)
    none = torch.zeros(1, N, 6, 0, dtype=torch.float64)
    step = _solver.DampedStep(system, (torch.zeros_like(band), torch.zeros_like(nn)),
                              (none, none), torch.zeros(M, dtype=torch.float64), factor=factor)
    made = []
    init = _banded.BandedCholesky.__init__

    def counted(self, *a, **k):
        made.append(1)
        init(self, *a, **k)

    monkeypatch.setattr(_banded.BandedCholesky, "__init__", counted)
    dc, dn, ok = step.step(torch.tensor([lam], dtype=torch.float64), gc, gn)
    assert bool(ok.all()) and len(made) == (0 if lam == 0 else 1)
    diag = np.concatenate((step.diag.reshape(-1).numpy(), step.ndiag.reshape(-1).numpy()))
    floor = float(step.floor)
    x = -np.linalg.solve(H + lam * np.diag(diag + floor), g)
    got = np.concatenate((dc.reshape(-1).numpy(), dn.reshape(-1).numpy()))
    np.testing.assert_allclose(got, x, rtol=1e-9, atol=1e-12 * np.abs(x).max())

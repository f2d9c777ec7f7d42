r"""Score tests of what a camera model leaves out (private; the first uncertainty asked of an
:class:`~torch_dq.fitting.Estimate` runs them and warns).

Why. A rolling shutter fitted as a global one, or a pinhole model on a lens that distorts,
leaves a systematic pattern in the pixel errors that the other parameters partly absorb (the
time offset takes up half the readout, the focal length part of the distortion): the
estimate ends converged, far from the truth by tens of its standard deviations, with a
reprojection :math:`\chi^2 / \nu` (1.44 on 1e4 dof for a 4.8 ms readout) that says little
of the cause. The score (Rao, Lagrange multiplier) test of the omitted parameter ``k`` at
the estimate asks whether the data pull ``k`` away from the value the model fixes, with no
second estimate: the gradient of half the data cost along ``k``, :math:`g = j^T W r`, over
its standard deviation under the model, :math:`\sqrt{I}`, with
:math:`I = j^T W j - b^T M^{-1} b` the information of ``k`` left once every estimated
parameter (control points and nuisance parameters: ``M`` the Gauss-Newton matrix of the
uncertainties, ``b = J^T W j`` the coupling) is eliminated (the Schur complement). Under the
model the residuals are :math:`(I - H) e` and :math:`g` has the variance :math:`I`
(Gauss-Newton): :math:`z = -g / \sqrt{I}` is standard normal, its sign the step's below. It
is divided by :math:`\sqrt{\max(\chi^2/\nu, 1)}` of the term as well (sigmas stated too
small would scale every :math:`z` up; so scaled, the test is one of the residuals'
correlation with :math:`j`, which an omitted parameter's pattern has and noise has not).
The Gauss-Newton step :math:`-g / I` is the value of ``k`` that the data suggest.

What. Per :class:`~torch_dq.fitting.Reprojections` term (its ``_omitted``): the line delay
where it is fixed at 0 or absent (column :math:`v_i \dot u_i / \sigma`), and for a
``"pinhole"`` camera the first radial coefficient ``k1`` of ``"pinhole-radtan"`` (column
:math:`(u - c)\, r^2 / \sigma`). ``|z| > THRESHOLD = 5`` warns (a standard normal exceeds it
with probability 5.7e-7; ``calibration.camera_imu`` on ``tests/_rig16_sim``'s 4 s rigs,
global shutter: the line delay's |z| 0.1 to 2.1 over 12 seeds and lenses, k1's of a pinhole
on an undistorted lens at most 1.0 over 3; a 4.8 ms readout reads 74, k1 = -0.21 reads 128).

At the optimum only (a Newton decrement within ``_NEAR`` of ``torch_dq.fitting.
_uncertainty``, as the observed information's check): elsewhere ``g`` carries the gradient
that the other parameters have left (a start, ``steps=0``), and no test is made.

How. ``j`` from the predicted pixels at the solution (``Reprojections._omitted``), ``g`` and
:math:`j^T W j` from the system's residuals and robust weights; ``b`` without a Jacobian of
its own: the Gauss-Newton gradient :math:`J^T W r` is linear in the residuals, so moving the
term's measured pixels by :math:`-h\, \sigma j` (at most ``_SHIFT`` of a sigma) moves it by
:math:`h b` (one more linearisation per test, the pixels restored after it); ``M^{-1}`` from
the uncertainties' factors (the control-point block's, ``Z = A^{-1} C`` and the nuisance
Schur complement's eigen-decomposition).
"""

from __future__ import annotations

import warnings

import torch
from torch import Tensor

from ._camera import Reprojections

__all__ = ["THRESHOLD", "asking", "directions", "warn_omitted"]

THRESHOLD = 5.0  # |z| beyond which a score test warns (module docstring)
_SHIFT = 0.1  # the measured pixels' move for the coupling b, at most this many sigmas
_ADVICE = {
    "line_delay": ("a rolling shutter", " s/row", "model it: Reprojections(..., line_delay="
                   "Free(...)), calibration.camera_imu(..., rolling_shutter=True), the CLI's "
                   "--rolling-shutter"),
    "k1": ("radial distortion", "", "the lens distorts: use a model with distortion "
           "('pinhole-radtan', 'pinhole-equidistant', 'double-sphere')"),
}


def directions(terms: list, trajectory) -> list[tuple[int, str, Tensor]]:
    """``(term index, parameter, d (..., N, 2))`` for every parameter that a
    :class:`~torch_dq.fitting.Reprojections` term's model leaves out (its ``_omitted``), read
    on ``trajectory`` at the solution."""
    out: list[tuple[int, str, Tensor]] = []
    for i, term in enumerate(terms):
        if isinstance(term, Reprojections):
            with torch.no_grad():
                out.extend((i, name, d) for name, d in term._omitted(trajectory).items())
    return out


def _coupling(problem, ctrl: Tensor, values: list[Tensor], system, term, d: Tensor,
              ) -> tuple[Tensor, Tensor]:
    """``b = J^T W j`` as ``(bc (Bf, n, 6), bn (Bf, m))``: the system's gradient with the
    term's measured pixels moved by ``-h d`` (``j = d / sigma``), its change over ``h``."""
    pixels = term.pixels
    h = _SHIFT / float((d / term.sigma).abs().amax().clamp_min(1e-300))
    try:
        term.pixels = pixels - h * d.to(pixels.dtype)
        moved = problem.system(ctrl, values, problem.width(values))
    finally:
        term.pixels = pixels
    return (moved.gc - system.gc) / h, (moved.gn - system.gn) / h


def _score(est, i: int, d: Tensor) -> tuple[Tensor, Tensor]:
    """``(z (Bf,), step (Bf,))`` of the omitted parameter with pixel derivatives ``d`` of
    term ``i`` (module docstring); nan where the others leave it no information or the
    estimate is not at its optimum (``Estimate._near``: elsewhere the gradient ``g`` is not
    the score, e.g. ``steps=0`` at the truth reads the parameter-alone information)."""
    summary, system = est._problem, est._system
    term = summary.terms[i]
    Bf = max(summary.batch.numel(), 1)
    if not bool(est._near.any()):  # no test anywhere: no linearisation
        nan = system.gn.new_full((Bf,), torch.nan)
        return nan, nan
    r, w = system.residuals[i], torch.where(summary.counted[i], system.weights[i], 0.0)
    j = d / term.sigma
    g = (w * (j * r).sum(-1)).sum(-1).expand(summary.batch).reshape(Bf)
    own = (w * j.square().sum(-1)).sum(-1).expand(summary.batch).reshape(Bf)
    bc, bn = _coupling(summary.problem, est._ctrl, est._values, system, term, d)
    bc = torch.where(est._free[..., None], 0.0, bc)
    info = own - (bc * est._chol.solve(bc[..., None])[..., 0]).sum((-1, -2))
    if summary.m:
        u = bn - torch.einsum("bni,bnim->bm", bc, est._Z)
        info = info - est._quadratic(u[:, None, :])[:, 0]
    c, nu = est.chi2[term], est.dof[term]
    scale = (c / nu.clamp_min(1.0)).clamp_min(1.0).reshape(Bf)
    info = torch.where(est._near & (info > 1e-9 * own), info, torch.nan)
    return -g / (info * scale).sqrt(), -g / info


def warn_omitted(est, found: list[tuple[int, str, Tensor]]) -> None:
    """Run the score tests of ``found`` (``directions``) on the estimate ``est`` (an
    :class:`~torch_dq.fitting.Estimate`, factored) and warn (``RuntimeWarning``) where
    ``|z| > THRESHOLD``, naming the term, the parameter, ``z`` and the value suggested;
    where several parameters of one term fire, each warning says so (a test assumes the
    rest of the model right: a pinhole model on a distorted lens also pulls the line delay,
    ``z`` 10 against k1's 128 on ``tests/test_trust17_score.py``'s rig)."""
    fired: dict[int, list[tuple[str, float, float]]] = {}
    for i, name, d in found:
        zs, steps = _score(est, i, d)
        bad = zs.abs() > THRESHOLD
        if bool(bad.any()):
            k = int(torch.where(bad, zs.abs(), -1.0).argmax())
            fired.setdefault(i, []).append((name, float(zs[k]), float(steps[k])))
    for i, tests in fired.items():
        largest = max(tests, key=lambda x: abs(x[1]))[0]
        for name, z, step in tests:
            both = (f" ({', '.join(n for n, _, _ in tests)} fire together; each test assumes "
                    f"the rest of the model right: model {largest}, the largest |z|, first)"
                    if len(tests) > 1 else "")
            warnings.warn(f"fitting.Estimate: the pixel errors of Reprojections (terms[{i}], "
                          f"camera {est._problem.terms[i].model!r}) {asking(name, z, step)}"
                          f"{both}", RuntimeWarning, stacklevel=4)


def asking(name: str, z: float, step: float) -> str:
    """The warnings' text of a score test of ``name`` (``"line_delay"``, ``"k1"``) that read
    ``z`` with the one-step value ``step``: what the pixels ask for and how to model it."""
    what, unit, advice = _ADVICE[name]
    return (f"ask for {what}: the score test of {name} at the estimate reads z = {z:.3g} "
            f"(|z| > {THRESHOLD:g}: the data pull it from 0 by {abs(z):.3g} of its standard "
            f"deviations), one Gauss-Newton step suggests {name} = {step:.3g}{unit}; "
            f"{advice}. The estimates and their standard deviations do not account for it")

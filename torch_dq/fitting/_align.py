r"""A start for the rotations that only an IMU sees (positions + gyroscope + accelerometer,
GNSS/INS alignment), for :func:`~torch_dq.fitting.estimate`.

Positions fix where the body is, not how it is turned. From a start with arbitrary
rotations (the identity everywhere: what a GNSS + IMU user has), Gauss-Newton crawls along
the heading and gravity's direction for hundreds of steps (``benchmarks/
positions_imu_identity_start.py``). The data give a start in closed form:

1. the gyroscope's body rates, less the bias's start, integrated by the midpoint rule (a
   parallel prefix product of the steps' rotations): :math:`R(t) = R_0\, \Delta R(t)`, the
   rotation up to the unknown :math:`R_0`;
2. the positions fit by the trajectory's own curve without rotation: accelerations
   :math:`a(t)` in world axes;
3. the accelerometer's specific force :math:`f = R^T (a - g) + b` gives
   :math:`a(t_j) - g = R_0\, u_j` with :math:`u_j = \Delta R(t_j) (f_j - b)`: :math:`R_0` by
   Kabsch's SVD (Wahba's problem) on these pairs with a fixed gravity, on the pairs centred
   with an estimated gravity direction (:math:`g` drops out; the readings must vary);
4. with a fixed gravity, :math:`R_0` and corrections of the biases (gyroscope, accelerometer)
   together by a few Gauss-Newton steps on the same pairs, :math:`\Delta R` integrated
   again, from Kabsch's answer: a gyroscope bias left in the rates tilts :math:`\Delta R`
   by its integral, and :math:`|g|` times the tilt swamps the motion's accelerations that
   fix the heading (a 0.02 rad/s bias over 8 s of slow motion: 5 deg of tilt, the heading
   20 to 27 deg off; refined 4 to 11 deg).

The curve fit to the poses :math:`(R_0 \Delta R(t_k),\ p(t_k))` (refined where 4. applies)
at the gyroscope's times (``p`` the caller's translations: only the rotations change) is the
start where its cost, every term at its start values, is below the caller's start's cost: a
caller's better start (a previous estimate) is kept. Not tried: batches of trajectories,
other terms (poses, odometry or cameras see the rotations themselves), a lever arm's effect
on the accelerations (left to the iteration).
"""

from __future__ import annotations

import warnings
from typing import cast

import torch
from torch import Tensor
from torch.nn.utils.parametrize import type_before_parametrizations

from .. import dualquat, quat
from .._core import qmul
from .._curve import Curve
from ._imu import Accel, Gyro
from ._terms import Positions, Term

__all__ = ["imu_aligned"]


def imu_aligned(fn: str, trajectory, terms: list[Term], ctrl: Tensor) -> Tensor:
    """``ctrl (n, 8)``, or the IMU-aligned start (module docstring) where it applies (one
    trajectory, Positions, Gyro and Accel terms only, on shared times) and costs less."""
    kinds: set[type] = {type(t) for t in terms}
    ours: set[type] = {Positions, Gyro, Accel}
    if ctrl.dim() != 2 or kinds != ours \
            or any(t.times.dim() != 1 or t.mask.dim() != 1 for t in terms):
        return ctrl
    pos = next(t for t in terms if isinstance(t, Positions))
    gyro = next(t for t in terms if isinstance(t, Gyro))
    acc = next(t for t in terms if isinstance(t, Accel))
    if int(pos.mask.sum()) < 8 or min(int(t.mask.sum()) for t in (gyro, acc)) < 3:
        return ctrl
    with warnings.catch_warnings():  # an attempt: its fits' warnings are not the caller's
        warnings.simplefilter("ignore")
        try:
            aligned = _aligned(fn, trajectory, pos, gyro, acc, ctrl)
        except ValueError:  # a fit that the samples do not determine
            return ctrl
    if aligned is None:
        return ctrl
    theirs = _cost(trajectory, terms, ctrl)  # first: the terms' one-time checks see it
    return aligned if bool(_cost(trajectory, terms, aligned) < theirs) else ctrl


def _aligned(fn: str, trajectory, pos: Positions, gyro: Gyro, acc: Accel, ctrl: Tensor,
             ) -> Tensor | None:
    """The aligned control points ``(n, 8)``, or None where the data do not align them (too
    few positions, pairs that fix no rotation, a fit that the samples do not determine)."""
    tg = gyro.times[gyro.mask].to(torch.float64)
    rates = gyro.readings[gyro.mask].to(torch.float64) - _start(gyro, "bias")
    rel = _integrate(tg, rates)
    through = _translation_curve(trajectory, pos)
    lo, hi = (float(e) for e in through.domain)
    ta = acc.times[acc.mask].to(torch.float64)
    keep = (ta >= lo) & (ta <= hi)
    ta = ta[keep]
    with torch.no_grad():
        a = through.kinematics(ta, frame="world").linear_acceleration.to(torch.float64)
    f = acc.readings[acc.mask][keep].to(torch.float64) - _start(acc, "bias")
    u = quat.rotate(_at(tg, rel, ta), f)
    gravity = acc._value("gravity")
    if acc._slots["gravity"].free is None and gravity is not None:  # fixed: the pairs as such
        v = a - gravity.to(torch.float64)
        R0 = _kabsch(u, v)  # refined with the biases (module docstring, 4.)
        q = None if R0 is None else _refined(tg, rates, ta, f, v, R0)
    else:  # its direction estimated: the pairs centred
        R0 = _kabsch(u - u.mean(0), a - a.mean(0))
        q = None if R0 is None else qmul(R0.expand_as(rel), rel)
    if q is None:
        return None
    with torch.no_grad():  # the caller's translations, kept
        t = dualquat.to_rt(trajectory(tg, ctrl=ctrl.to(trajectory.control_points.dtype)))[1]
    return trajectory._fitted(fn, dualquat.from_rt(q, t.to(torch.float64)), tg)


def _refined(tg: Tensor, rates: Tensor, ta: Tensor, f: Tensor, v: Tensor, R0: Tensor,
             steps: int = 5) -> Tensor:
    r"""``(N, 4)`` the rotations :math:`R_0\, \Delta R_b(t_g)` at the gyroscope's times
    ``tg (N,)``, :math:`\Delta R_b` integrated from ``rates (N, 3)`` less a bias correction
    :math:`b_g`: :math:`R_0`, :math:`b_g` and an accelerometer bias correction :math:`b_a`
    minimise :math:`\sum_j |R_0 \Delta R_b(t_j) (f_j - b_a) - v_j|^2` (``f (M, 3)`` the
    specific forces at ``ta (M,)``, ``v (M, 3)`` the accelerations less a fixed gravity), by
    Gauss-Newton steps from ``R0 (4,)`` and zero corrections (forward differences in the
    biases; the rotation's columns in closed form), each kept only where it lowers the sum."""
    eye = torch.eye(6, dtype=torch.float64, device=rates.device)

    def residuals(R: Tensor, b: Tensor) -> tuple[Tensor, Tensor]:
        rel = _integrate(tg, rates - b[:3])
        Ru = quat.rotate(qmul(R.expand(ta.shape[0], 4), _at(tg, rel, ta)), f - b[3:])
        return Ru - v, rel

    b = torch.zeros(6, dtype=torch.float64, device=rates.device)
    r, rel = residuals(R0, b)
    for _ in range(steps):
        Ru = r + v
        cols = [torch.linalg.cross(e.expand_as(Ru), Ru).reshape(-1) for e in eye[:3, :3]]
        cols += [(residuals(R0, b + 1e-6 * e)[0] - r).reshape(-1) / 1e-6 for e in eye]
        x = torch.linalg.lstsq(torch.stack(cols, 1), -r.reshape(-1, 1)).solution[:, 0]
        R1 = quat.normalize(qmul(quat.from_rotvec(x[:3]), R0))
        r1, rel1 = residuals(R1, b + x[3:])
        if not bool(r1.square().sum() < r.square().sum()):
            break
        R0, b, rel, r = R1, b + x[3:], rel1, r1
    return qmul(R0.expand_as(rel), rel)


def _start(term: Term, name: str) -> Tensor:
    """``(3,)`` float64: a bias's value or start (zero without one)."""
    v = term._value(name)
    like = term.sigma.device
    return torch.zeros(3, dtype=torch.float64, device=like) if v is None else v.to(torch.float64)


def _integrate(t: Tensor, rates: Tensor) -> Tensor:
    r"""``(N, 4)`` rotations :math:`\Delta R(t_k)` from body rates ``rates (N, 3)`` at times
    ``t (N,)``, :math:`\Delta R(t_0) = I`: the midpoint rule's steps
    :math:`\exp(\tfrac12 (\omega_k + \omega_{k+1}) (t_{k+1} - t_k))`, multiplied on the right,
    by a parallel prefix product (Hillis and Steele: ``log2 N`` passes)."""
    steps = quat.from_rotvec(0.5 * (rates[1:] + rates[:-1]) * (t[1:] - t[:-1])[:, None])
    q = torch.cat((quat.identity(dtype=rates.dtype, device=rates.device).expand(1, 4), steps))
    d = 1
    while d < q.shape[0]:
        q = torch.cat((q[:d], qmul(q[:-d], q[d:])))
        d *= 2
    return quat.normalize(q)


def _at(t: Tensor, q: Tensor, s: Tensor) -> Tensor:
    """``(M, 4)`` the rotations ``q (N, 4)`` at times ``t (N,)`` slerped to the times ``s
    (M,)`` (clamped to ``t``'s range)."""
    s = s.clamp(t[0], t[-1])
    j = torch.searchsorted(t, s, right=True).clamp(1, t.shape[0] - 1)
    lo, hi = t[j - 1], t[j]
    w = ((s - lo) / (hi - lo).clamp_min(1e-300)).clamp(0.0, 1.0)
    return quat.slerp(q[j - 1], q[j], w)


def _kabsch(u: Tensor, v: Tensor) -> Tensor | None:
    r"""``(4,)`` the rotation :math:`R` minimising :math:`\sum_j |R u_j - v_j|^2` (Kabsch /
    Wahba, by the SVD of :math:`\sum_j v_j u_j^T`, the determinant's sign corrected), or
    None where the pairs fix no rotation (their second singular value below ``1e-9`` of the
    first, or not finite)."""
    H = v.T @ u
    if not bool(torch.isfinite(H).all()):
        return None
    U, S, Vh = torch.linalg.svd(H)
    if not bool(S[1] > 1e-9 * S[0]):
        return None
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.diag(torch.stack((torch.ones_like(d), torch.ones_like(d), d)))
    return quat.from_matrix(U @ D @ Vh)


def _translation_curve(trajectory, pos: Positions):
    """A curve of ``trajectory``'s class through the positions without rotation, on at most
    half as many control points as positions (smoothing) and at most the trajectory's."""
    m = pos.mask
    p = pos.positions[m].to(torch.float64)
    q = quat.identity(dtype=torch.float64, device=p.device)
    x = dualquat.from_rt(q.expand(p.shape[0], 4), p)
    cls = cast("type[Curve]", type_before_parametrizations(trajectory))
    return cls.from_dualquats(x, pos.times[m].to(torch.float64),
                              n_ctrl=min(trajectory.n_ctrl, p.shape[0] // 2))


def _cost(trajectory, terms: list[Term], ctrl: Tensor) -> Tensor:
    """The sum of squared whitened residuals of ``terms`` at ``ctrl``, each term's nuisance
    at its start values there."""
    total = ctrl.new_zeros(())
    with torch.no_grad():
        for term in terms:
            r = term.evaluate(trajectory, ctrl, term.values(trajectory, ctrl))
            total = total + (r.to(torch.float64) * term.mask[..., None]).square().sum()
    return total

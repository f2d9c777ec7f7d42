"""Peer implementations for ``benchmarks/run.py``, each on work matched to torch_dq's.

Every ``make_*`` function takes inputs already converted from torch_dq's conventions
(outside the timing) and returns ``(fn, check)``: ``fn()`` runs the peer once (the timed
work); ``check()`` returns the peer's result on the same inputs as a torch tensor in
torch_dq's layout, for the agreement note. A peer that is not installed raises
``PeerMissing`` from ``make_*``.
"""

from __future__ import annotations

import importlib

import numpy as np
import torch

import torch_dq.dualquat as dq


class PeerMissing(Exception):
    """The peer package is not installed."""


def _need(name: str):
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise PeerMissing(f"{name} not installed") from exc


def version(name: str) -> str | None:
    try:
        mod = importlib.import_module(name)
    except ImportError:
        return None
    return getattr(mod, "__version__", "?")


# ----------------------------------------------------------------------------- sclerp

def pytransform3d_sclerp(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor):
    """``pytransform3d.trajectories.dual_quaternions_sclerp`` (numpy, float64).

    Same ``(rw, rx, ry, rz, dw, dx, dy, dz)`` layout as torch_dq. pytransform3d takes the
    path from ``a`` to ``b`` as given (no shortest-path sign choice), so ``b`` is
    sign-aligned with ``a`` beforehand, outside the timing: both then compute the same motion.
    """
    ptr = _need("pytransform3d.trajectories")
    a64 = a.detach().cpu().double().numpy()
    b64 = b.detach().cpu().double().numpy()
    flip = (a64[:, :4] * b64[:, :4]).sum(-1) < 0
    b64 = np.where(flip[:, None], -b64, b64)
    t64 = t.detach().cpu().double().numpy()

    def fn():
        return ptr.dual_quaternions_sclerp(a64, b64, t64)

    def check():
        return torch.from_numpy(fn())

    return fn, check


def _pp_se3(x: torch.Tensor, grad: bool):
    pp = _need("pypose")
    X = pp.SE3(dq.to_pose7(x.detach()).contiguous())
    return X.requires_grad_() if grad else X


def pypose_sclerp(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor, backward: bool):
    """pypose's geodesic SE3 interpolation ``X0 * Exp(t * Log(X0^-1 X1))``.

    ``X = pp.SE3(dualquat.to_pose7(x))`` (``[t, qx, qy, qz, qw]``), built outside the timing.
    With ``backward``: gradients of the sum of the output's 7 components with respect to
    both SE3 tensors and ``t`` (pypose's SE3 gradients are tangent-space, 7 slots with the
    last one zero; the work is what pypose does for a user calling ``.backward()``).
    """
    _need("pypose")
    X0, X1 = _pp_se3(a, backward), _pp_se3(b, backward)
    tt = t.detach().clone().requires_grad_(backward)

    def forward():
        return X0 * (X0.Inv() * X1).Log().mul(tt[:, None]).Exp()

    def fn():
        Y = forward()
        if backward:
            torch.autograd.grad(Y.tensor().sum(), (X0, X1, tt))

    def check():
        with torch.no_grad():
            return dq.from_pose7(forward().tensor())

    return fn, check


# ----------------------------------------------------------------------------- slerp

def roma_slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor, backward: bool):
    """``roma.unitquat_slerp(q0, q1, steps, shortest_arc=True)`` (xyzw order).

    roma's ``steps`` of shape ``(B,)`` gives ``(B, N, 4)``: an outer product of the steps
    with the batch, never one step per pair (``(N,)`` steps for ``N`` pairs would be an
    ``N x N`` output). The matched call passes a 0-d ``steps`` (one ``t`` shared by all
    pairs), for which roma's coefficients are still computed per pair: same elementwise
    work, one fewer input stream (``N`` values of ``t``) than torch_dq's per-pair ``t``.
    Inputs are reordered to xyzw outside the timing; ``t`` is ``t[0]`` of torch_dq's.
    """
    roma = _need("roma")
    a = q0.detach()[..., [1, 2, 3, 0]].contiguous().requires_grad_(backward)
    b = q1.detach()[..., [1, 2, 3, 0]].contiguous().requires_grad_(backward)
    s = t.detach()[0].clone().requires_grad_(backward)

    def fn():
        q = roma.unitquat_slerp(a, b, s, shortest_arc=True)
        if backward:
            torch.autograd.grad(q.sum(), (a, b, s))

    def check():
        with torch.no_grad():
            return roma.unitquat_slerp(a, b, s, shortest_arc=True)[..., [3, 0, 1, 2]]

    return fn, check, s.detach()


def scipy_slerp(q0: torch.Tensor, q1: torch.Tensor, t: torch.Tensor):
    """Per-pair slerp with scipy rotations, ``r0 * Rotation.from_rotvec(t (r0^-1 r1).as_rotvec())``.

    ``scipy.spatial.transform.Slerp`` interpolates one key sequence at given times; for
    independent pairs this composition is its formula. ``r0``, ``r1`` are built outside the
    timing (``Rotation.from_quat`` of the xyzw quaternions, float64); the timed work ends
    with ``as_quat()``. ``as_rotvec`` takes the angle in [0, pi]: shortest path.
    """
    tr = _need("scipy.spatial.transform")
    R = tr.Rotation
    r0 = R.from_quat(q0.detach().cpu().double()[..., [1, 2, 3, 0]].numpy())
    r1 = R.from_quat(q1.detach().cpu().double()[..., [1, 2, 3, 0]].numpy())
    tt = t.detach().cpu().double().numpy()

    def fn():
        return (r0 * R.from_rotvec(tt[:, None] * (r0.inv() * r1).as_rotvec())).as_quat()

    def check():
        return torch.from_numpy(fn())[..., [3, 0, 1, 2]]

    return fn, check


# ----------------------------------------------------------------------------- B-spline

def pypose_bspline(ctrl: torch.Tensor, n_out: int, backward: bool):
    """``pp.bspline(data, interval, extrapolate=False)`` on the same 64 control poses.

    pypose's cubic B-spline is the cumulative uniform SE3 spline (Hug et al. 2020): for
    ``N`` control poses it has ``N - 3`` segments and returns ``(N - 3) / interval + 1``
    poses on a uniform grid. ``interval = 1 / ceil((n_out - 1) / (N - 3))`` gives the
    closest count ``>= n_out``; the caller scales by the count actually returned.
    Returns ``(fn, None, count)`` (its curve is not torch_dq's clamped De Boor curve, so
    there is no value check).
    """
    pp = _need("pypose")
    N = ctrl.shape[-2]
    k = -(-(n_out - 1) // (N - 3))
    data = _pp_se3(ctrl, backward)
    interval = 1.0 / k

    def fn():
        P = pp.bspline(data, interval=interval, extrapolate=False)
        if backward:
            torch.autograd.grad(P.tensor().sum(), data)
        return P.shape[-2]

    with torch.no_grad():
        count = pp.bspline(data.detach(), interval=interval, extrapolate=False).shape[-2]
    return fn, None, count


def pypose_train_step(init: torch.Tensor, target_at, interval: float):
    """One Adam step fitting ``pp.bspline`` control poses to target poses on its grid.

    The control poses are a ``pp.Parameter(pp.SE3(...))`` started at ``init``; the loss is
    pypose's geodesic error, the mean of ``|Log(target^-1 P)|^2`` over the poses ``P`` of
    ``pp.bspline(X, interval)``; Adam (lr 1e-3) updates the 7 stored numbers per pose, as a
    pypose user's ``optimizer.step()`` does. ``target_at(count)`` returns the ``(count, 8)``
    target poses on pypose's uniform grid of ``count`` poses (outside the timing).
    Returns ``(step, count)``.
    """
    pp = _need("pypose")
    X = pp.Parameter(pp.SE3(dq.to_pose7(init.detach()).contiguous()))
    with torch.no_grad():
        count = pp.bspline(X.detach(), interval=interval, extrapolate=False).shape[-2]
    tgt_inv = pp.SE3(dq.to_pose7(target_at(count).detach()).contiguous()).Inv()
    opt = torch.optim.Adam([X], lr=1e-3)

    def step():
        opt.zero_grad(set_to_none=True)
        P = pp.bspline(X, interval=interval, extrapolate=False)
        loss = (tgt_inv * P).Log().tensor().pow(2).sum(-1).mean()
        loss.backward()
        opt.step()

    return step, count


def pypose_bspline_curve(ctrl: torch.Tensor, interval: float):
    """pypose's cumulative cubic B-spline of ``ctrl`` ``(N, 8)`` on its own uniform grid:
    ``(s, poses)``, the times ``s`` in ``[0, N - 3]`` and the poses ``(len(s), 8)`` in
    torch_dq's layout (for the agreement note of the cumulative rows)."""
    pp = _need("pypose")
    with torch.no_grad():
        P = pp.bspline(_pp_se3(ctrl, False), interval=interval, extrapolate=False)
    s = torch.arange(P.shape[-2], dtype=ctrl.dtype, device=ctrl.device) * interval
    return s, dq.from_pose7(P.tensor())

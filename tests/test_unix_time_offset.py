"""A clock offset estimated on UNIX-time stamps (~1.4e9 s, float64 spacing 2.4e-7 s).

``t + dt`` rounded there makes every cost a staircase in ``dt`` (steps of 2.4e-7 s): the
estimation reads its samples at times since the trajectory's origin, ``(t - origin) + dt``,
exact at any epoch (found by calib13 on EuRoC-like stamps: "not converged" on every real
recording). The same data on stamps from 0 s and from 1403709395 s (grids of powers of two,
exact at both) must give the same estimate, and the truth within its standard deviation.
The motion is written out here: ``R = Rz(theta) Rx(phi)``, body rates
``(phi', theta' sin phi, theta' cos phi)``.
"""

import numpy as np
import torch

import torch_dq.dualquat as dq
from torch_dq import quat
from torch_dq.fitting import Free, Gyro, Poses, estimate
from torch_dq.nn import BSpline

F64 = torch.float64
DT = 0.0037  # the gyroscope's true clock offset (s)


def _angles(t):
    theta = 1.5 * np.sin(0.9 * t) + 0.4 * t
    phi = 0.3 * np.sin(1.7 * t + 0.2)
    dtheta = 1.35 * np.cos(0.9 * t) + 0.4
    dphi = 0.51 * np.cos(1.7 * t + 0.2)
    return theta, phi, dtheta, dphi


def _rotation(t):
    theta, phi, _, _ = _angles(t)
    z = quat.from_rotvec(torch.as_tensor(np.outer(theta, [0.0, 0.0, 1.0])))
    x = quat.from_rotvec(torch.as_tensor(np.outer(phi, [1.0, 0.0, 0.0])))
    return quat.mul(z, x)


def _problem(t0):
    """Poses at 32 Hz and a gyroscope at 256 Hz over 8 s from ``t0`` (stamps exact)."""
    rng = np.random.default_rng(3)
    tp = np.arange(0, 8 * 32 + 1) / 32.0
    tg = np.arange(16, 8 * 256 - 15) / 256.0
    pos = np.stack([np.sin(tp), np.cos(0.5 * tp), 0.1 * tp], -1)
    noise = quat.from_rotvec(torch.as_tensor(1e-3 * rng.standard_normal(pos.shape)))
    poses = dq.from_rt(quat.mul(_rotation(tp), noise),
                       torch.as_tensor(pos + 1e-3 * rng.standard_normal(pos.shape)))
    _, phi, dtheta, dphi = _angles(tg + DT)  # the sample stamped t is the motion at t + dt
    rates = np.stack([dphi, dtheta * np.sin(phi), dtheta * np.cos(phi)], -1)
    rates += 1e-3 * rng.standard_normal(rates.shape)
    spline = BSpline.from_poses(_rotation(tp), torch.as_tensor(pos), torch.as_tensor(t0 + tp),
                                knot_spacing=0.125, margin=0.1)
    gyro = Gyro(torch.as_tensor(t0 + tg), torch.as_tensor(rates), sigma=1e-3,
                time_offset=Free(0.0))
    return spline, [Poses(torch.as_tensor(t0 + tp), poses, rot_sigma=1e-3, trans_sigma=1e-3),
                    gyro]


def test_offset_on_unix_stamps_as_on_small_ones():
    out = []
    for t0 in (0.0, 1403709395.0):
        spline, terms = _problem(t0)
        est = estimate(spline, terms, verbose=False)
        assert bool(est.converged), (t0, est.reason)
        out.append((float(terms[1].time_offset), float(est.std(terms[1], "time_offset")),
                    est.steps, spline.control_points.detach().clone()))
    (a, sa, na, ca), (b, sb, nb, cb) = out
    assert abs(a - DT) < 3 * sa and sa < 2e-4, (a, sa)
    assert na == nb
    assert abs(a - b) < 1e-6 * sa, (a, b, sa)
    assert abs(sa - sb) < 1e-6 * sa
    # the starts differ by 1e-7 (from_poses), the stops by the convergence test's tolerance
    assert (ca - cb).abs().max() < 1e-6, (ca - cb).abs().max()  # the noise: 1e-3

"""Synthetic IMU residuals of the three cubic B-spline forms (issue 35, ``docs/bspline_forms.md``).

Two closed-form smooth motions, both turning as ``R(t) = Rz(a t) Ry(b sin(f t))``:
``sines`` moves by sums of sines independent of the rotation, ``orbit`` along a helix whose
tangent is the yaw heading (the body moves forward, as a vehicle or a walking camera: a
motion close to a screw motion). Each is sampled as poses at 20 Hz over ``--duration``
seconds; each form (``de_boor``, ``cumulative``, ``split``; cubic, the same clamped uniform
knots, ``--spacing`` seconds apart) is started by :meth:`torch_dq.nn.BSpline.from_poses`
and fitted to the poses by :func:`torch_dq.fitting.fit` (Levenberg-Marquardt). The fitted
curve's ideal IMU readings (``module.imu(t)``: gyroscope ``R^T w``, accelerometer
``R^T (a - g)``) at 200 Hz are then compared with the truth's, written here by
differentiating the motion by hand; the first and last ``--trim`` seconds are left out
(the clamped ends). float64 throughout, so the figures are the forms' approximation errors,
not rounding.

Run::

    PYTHONPATH=$PWD python benchmarks/forms_imu.py [--spacing 0.1 0.2] [--duration 6]

Prints one row per motion, knot spacing and form: RMS gyro error (rad/s), RMS accel error (m/s^2),
RMS position (mm) and rotation (mrad) errors at the same 200 Hz times, and the largest jump
of the acceleration across an interior knot (m/s^2; 0 for a C^2 form).
"""

from __future__ import annotations

import argparse
import itertools
import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.nn import BSpline

F64 = torch.float64
A, B, F = 0.9, 0.6, 1.7          # yaw rate (rad/s), pitch amplitude (rad), its frequency (rad/s)
P_AMP = np.array([0.8, 0.5, 0.3])  # position amplitudes (m)
P_FRQ = np.array([1.1, 2.3, 1.6])  # and frequencies (rad/s)
P_PHS = np.array([0.0, 0.7, 1.3])
G = np.array([0.0, 0.0, -9.81])


RADIUS, CLIMB = 1.5, 0.2           # the orbit of motion "orbit" (m, m/s)


def truth(t: np.ndarray, motion: str = "sines"):
    """Rotation, position, world angular velocity and linear acceleration at times ``t``."""
    phi, dphi = B * np.sin(F * t), B * F * np.cos(F * t)
    R = Rotation.from_euler("z", (A * t)[:, None]) * Rotation.from_euler("y", phi[:, None])
    if motion == "sines":
        arg = P_FRQ * t[:, None] + P_PHS
        p = P_AMP * np.sin(arg)
        acc = -P_AMP * P_FRQ**2 * np.sin(arg)
    else:  # a helix whose heading is the yaw: the body moves forward (coupled motion)
        c, s = np.cos(A * t), np.sin(A * t)
        p = np.stack((RADIUS * s, RADIUS * (1 - c), CLIMB * t), -1)
        acc = np.stack((-RADIUS * A**2 * s, RADIUS * A**2 * c, 0 * t), -1)
    # w = A e_z + dphi Rz(A t) e_y  (the pitch axis turned by the yaw)
    w = np.stack((-dphi * np.sin(A * t), dphi * np.cos(A * t), A + 0 * t), -1)
    return R, p, w, acc


def imu_truth(t: np.ndarray, motion: str):
    R, _, w, acc = truth(t, motion)
    return R.inv().apply(w), R.inv().apply(acc - G)


def fitted(form: str, t_pose: torch.Tensor, q: torch.Tensor, p: torch.Tensor,
           spacing: float) -> BSpline:
    duration = float(t_pose[-1] - t_pose[0])
    n_ctrl = math.ceil(duration / spacing - 1e-9) + 3
    spline = BSpline.from_poses(q, p, t_pose, n_ctrl=n_ctrl, degree=3, form=form)
    fitting.fit(spline, t_pose, dq.from_rt(q, p), steps=50, verbose=False)
    return spline


def knot_jump(spline: BSpline) -> float:
    """Largest jump of the linear acceleration across an interior knot."""
    knots = spline.knots[3:-3][1:-1]
    eps = 1e-7
    t = torch.stack((knots - eps, knots + eps), -1).reshape(-1)
    a = spline.kinematics(t).linear_acceleration.detach().reshape(-1, 2, 3)
    return float((a[:, 1] - a[:, 0]).norm(dim=-1).max())


def row(spline: BSpline, t_imu: torch.Tensor, motion: str) -> tuple[float, ...]:
    gyro, accel = spline.imu(t_imu, gravity=torch.tensor(G, dtype=F64))
    g_true, a_true = (torch.from_numpy(v) for v in imu_truth(t_imu.numpy(), motion))
    rms = lambda e: float(e.norm(dim=-1).pow(2).mean().sqrt())  # noqa: E731
    R, p_true = truth(t_imu.numpy(), motion)[:2]
    q_est, p_est = dq.to_rt(spline(t_imu).detach())
    q_true = torch.from_numpy(R.as_quat(scalar_first=True))
    rot = quat.to_rotvec(quat.mul(quat.conj(q_true), q_est))  # (T, 3) rotation vectors
    return (rms(gyro.detach() - g_true), rms(accel.detach() - a_true),
            1e3 * rms(p_est - torch.from_numpy(p_true)), 1e3 * rms(rot), knot_jump(spline))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing", type=float, nargs="+", default=[0.1, 0.2])
    parser.add_argument("--duration", type=float, default=6.0)
    parser.add_argument("--trim", type=float, default=0.3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    t_pose = torch.linspace(0.0, args.duration, round(20 * args.duration) + 1, dtype=F64)
    n_imu = round(200 * (args.duration - 2 * args.trim)) + 1
    t_imu = torch.linspace(args.trim, args.duration - args.trim, n_imu, dtype=F64)
    print("poses at 20 Hz, IMU at 200 Hz; RMS errors of the fitted curve against the truth")
    print(f"{'motion':>6s} {'spacing':>8s} {'form':>10s} {'gyro rad/s':>11s} {'accel m/s2':>11s} "
          f"{'pos mm':>9s} {'rot mrad':>9s} {'acc jump':>9s}")
    for motion, spacing in itertools.product(("sines", "orbit"), args.spacing):
        R, p = truth(t_pose.numpy(), motion)[:2]
        q, p = torch.from_numpy(R.as_quat(scalar_first=True)), torch.from_numpy(p)
        for form in ("de_boor", "cumulative", "split"):
            g, a, pos, rot, jump = row(fitted(form, t_pose, q, p, spacing), t_imu, motion)
            print(f"{motion:>6s} {spacing:8.3f} {form:>10s} {g:11.2e} {a:11.2e} {pos:9.2e} "
                  f"{rot:9.2e} {jump:9.2e}")


if __name__ == "__main__":
    main()

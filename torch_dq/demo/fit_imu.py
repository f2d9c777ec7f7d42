r"""``python -m torch_dq fit FILE --imu IMUFILE``: poses and an IMU fitted together.

After the pose-only fit of :mod:`torch_dq.demo.fit_file`, :func:`fit_with_imu` refines the
same B-spline with :func:`torch_dq.fitting.estimate` on three terms: the fitted poses
(:class:`~torch_dq.fitting.Poses`, which define the clock), the gyroscope
(:class:`~torch_dq.fitting.Gyro`) and the accelerometer (:class:`~torch_dq.fitting.Accel`),
each IMU term with its bias estimated, gravity's direction estimated (magnitude
:data:`GRAVITY`: the file's world frame need not have z up) and, with
``time_offset="estimate"``, one clock offset shared by the gyroscope and the accelerometer.

The noise levels are taken from the data, since the terms require them: the poses' from the
pose-only fit's residuals at the fitted poses (per kind, their sum of squares over the degrees
of freedom the fit leaves), the IMU's from its readings' high-frequency scatter (the RMS of
second differences over :math:`\sqrt 6`, per axis: white noise of standard deviation
:math:`\sigma` gives :math:`6\sigma^2`). They are printed and written to ``summary.json``
with the estimates and their standard deviations.
"""

from __future__ import annotations

import math
import os

import torch
from torch import Tensor

from .. import dualquat, fitting, io
from .fit_file import OptionError

__all__ = ["GRAVITY", "fit_with_imu"]

#: Gravity's magnitude (m/s²); its direction in the file's world frame is estimated.
GRAVITY = 9.81

#: The bound on an estimated clock offset (s), as :mod:`torch_dq.fitting`'s default.
MAX_OFFSET = 0.1


def _imu_sigma(readings: Tensor) -> Tensor:
    """Per-axis white-noise level of ``(N, 3)`` readings from their second differences."""
    d2 = readings[2:] - 2 * readings[1:-1] + readings[:-2]
    return (d2.square().mean(0) / 6.0).sqrt().clamp_min(1e-9)


def _pose_sigmas(spline, times: Tensor, poses: Tensor) -> tuple[float, float]:
    """Per-axis rotation (rad) and translation noise from the pose fit's residuals at its
    poses: the residuals' sum of squares over their degrees of freedom (3 per pose and kind,
    less 3 per control point: a fit with n control points through N poses leaves residuals
    smaller than the noise by sqrt(1 - n / N))."""
    with torch.no_grad():
        q, p = dualquat.to_rt(spline(times).double())
    q_m, p_m = dualquat.to_rt(poses.double())
    dot = (q * q_m).sum(-1).abs().clamp(max=1.0)
    rot = 2 * torch.acos(dot)
    n_poses, n_ctrl = rot.shape[-1], spline.control_points.shape[-2]
    dof = 3.0 * max(n_poses - n_ctrl, 1)
    rot_axis = math.sqrt(float(rot.square().sum()) / dof)
    trans_axis = math.sqrt(float((p - p_m).square().sum()) / dof)
    return max(rot_axis, 1e-6), max(trans_axis, 1e-6)


def _inside(times: Tensor, t0: float, t1: float, margin: float) -> Tensor:
    return (times >= t0 + margin) & (times <= t1 - margin)


def _read(path: str, t0: float, t1: float, margin: float) -> tuple[Tensor, Tensor, Tensor,
                                                                     int]:
    """The IMU samples inside the curve's domain (less ``margin``): times, gyro, accel and
    how many were left out."""
    times, gyro, accel = io.read_imu(path)
    keep = _inside(times, t0, t1, margin)
    if int(keep.sum()) < 10:
        raise OptionError(f"{path}: {int(keep.sum())} IMU samples lie within the poses' time "
                          f"span [{t0:.6f}, {t1:.6f}] s (less {margin:g} s at each end for the "
                          f"clock offset), the IMU file spans [{float(times[0]):.6f}, "
                          f"{float(times[-1]):.6f}] s: pass an IMU file of the same recording "
                          f"(same clock)")
    return times[keep], gyro[keep], accel[keep], int((~keep).sum())


def _stats(est, term, name: str) -> dict:
    value = getattr(term, name).detach().double()
    std = est.std(term, name).detach().double()
    return {"value": value.tolist(), "std": std.tolist()}


def fit_with_imu(spline, times: Tensor, poses: Tensor, imu: str | os.PathLike[str],
                 time_offset: str | None, steps: int, say) -> dict:
    """Refine ``spline`` on the fitted poses and the IMU file together; report the estimates.

    Args:
        spline: the pose-only fit (:class:`torch_dq.nn.BSpline`), refined in place.
        times, poses: the fitted poses (``(N,)`` float64 s, ``(N, 8)``).
        imu: the IMU file (:func:`torch_dq.io.read_imu`), on the poses' clock up to an
            offset.
        time_offset: ``None`` (the clocks agree) or ``"estimate"``.
        steps: maximum Levenberg-Marquardt steps.
        say: ``print`` or a silent stand-in.

    Returns:
        The ``"imu"`` entry of ``summary.json``: the file, samples used, noise levels, gyro
        and accelerometer biases, gravity, the time offset (each ``{"value", "std"}``) and
        the estimate's steps and reason.

    Raises:
        torch_dq.io.TrajectoryFileError: a malformed IMU file.
        OptionError: too few IMU samples within the poses' time span.
    """
    path = os.fspath(imu)
    t0, t1 = float(times[0]), float(times[-1])
    margin = MAX_OFFSET if time_offset == "estimate" else 0.0
    t, gyro, accel, dropped = _read(path, t0, t1, margin)
    rot_s, trans_s = _pose_sigmas(spline, times, poses)
    gyro_s, accel_s = _imu_sigma(gyro), _imu_sigma(accel)
    clock = fitting.Free() if time_offset == "estimate" else None
    terms = [fitting.Poses(times, poses.double(), rot_sigma=rot_s, trans_sigma=trans_s),
             fitting.Gyro(t, gyro, sigma=gyro_s, bias=True, time_offset=clock),
             fitting.Accel(t, accel, sigma=accel_s, bias=True, gravity=GRAVITY,
                           time_offset=clock)]
    say(f"IMU: {path}: {len(t)} samples ({dropped} outside the poses' time span left out); "
        f"noise from the data: poses {math.degrees(rot_s):.3g} deg, {1e3 * trans_s:.3g} mm "
        f"per axis; gyro {float(gyro_s.mean()):.3g} rad/s, accel {float(accel_s.mean()):.3g} "
        f"m/s^2")
    est = fitting.estimate(spline, terms, steps=steps, verbose=False)
    result = {"file": path, "samples": len(t), "left_out": dropped,
              "sigmas": {"rot_rad": rot_s, "trans_m": trans_s, "gyro_rad_s": gyro_s.tolist(),
                         "accel_m_s2": accel_s.tolist()},
              "gyro_bias_rad_s": _stats(est, terms[1], "bias"),
              "accel_bias_m_s2": _stats(est, terms[2], "bias"),
              "gravity_m_s2": _stats(est, terms[2], "gravity"),
              "steps": est.steps, "reason": est.reason}
    if clock is not None:
        result["time_offset_s"] = _stats(est, terms[1], "time_offset")
    _print(say, result)
    return result


def _print(say, r: dict) -> None:
    def vec(entry: dict, scale: float = 1.0) -> str:
        v, s = entry["value"], entry["std"]
        if not isinstance(v, list):
            return f"{scale * v:.4g} ± {scale * s:.2g}"
        return "(" + ", ".join(f"{scale * a:.4g} ± {scale * b:.2g}"
                               for a, b in zip(v, s, strict=True)) + ")"

    say(f"IMU fit: {r['steps']} steps ({r['reason']}); estimates ± one standard deviation:")
    say(f"  gyro bias [rad/s]       {vec(r['gyro_bias_rad_s'])}")
    say(f"  accel bias [m/s^2]      {vec(r['accel_bias_m_s2'])}")
    say(f"  gravity [m/s^2, world]  {vec(r['gravity_m_s2'])}")
    if "time_offset_s" in r:
        say(f"  time offset [ms]        {vec(r['time_offset_s'], 1e3)} (IMU stamp + offset = "
            f"pose clock)")

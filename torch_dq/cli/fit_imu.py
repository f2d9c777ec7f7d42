r"""``python -m torch_dq fit FILE --imu IMUFILE``: poses and an IMU fitted together.

After the pose-only fit of :mod:`torch_dq.cli.fit_file`, :func:`fit_with_imu` refines the
same B-spline with :func:`torch_dq.fitting.estimate` on three terms: the fitted poses
(:class:`~torch_dq.fitting.Poses`, which define the clock), the gyroscope
(:class:`~torch_dq.fitting.Gyro`) and the accelerometer (:class:`~torch_dq.fitting.Accel`),
each IMU term with its bias estimated, gravity's direction estimated (magnitude
:data:`GRAVITY`: the file's world frame need not have z up) and, with
``time_offset="estimate"``, one clock offset shared by the gyroscope and the accelerometer.

The knots are chosen for the IMU: a knot every :data:`IMU_SAMPLES_PER_SPAN` IMU samples
(finer than the pose-only fit's spacing, never coarser), the curve started anew on the
fitted poses at that spacing (``BSpline.from_poses(..., knot_spacing=)``, smoothing between
the poses), so that the curve can follow the motion that the IMU sees between the poses.
With ``time_offset="estimate"`` the B-spline is a quartic unless a degree is given
(:func:`default_degree`: its accelerations are C1 in time, so the accelerometer's cost is
smooth in the offset), and the curve's domain reaches :data:`MAX_OFFSET` beyond the
first and the last pose (``from_poses(..., margin=)``), so that every IMU sample within the
poses' time span stays inside it whatever the offset (the estimate's domain check, widened
by :meth:`~torch_dq.fitting.Term.time_reach`): none is cut at the ends.
Each term's ``chi2 / dof`` goes to the summary: far from 1, the noise levels do not describe
the data.

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
import warnings

import torch
from torch import Tensor

from .. import dualquat, fitting, io, quat
from ..fitting._imu import degrees_message
from ..nn import BSpline
from ._errors import OptionError

__all__ = ["GRAVITY", "IMU_SAMPLES_PER_SPAN", "MAX_OFFSET", "OFFSET_DEGREE", "default_degree",
           "fit_with_imu"]

#: Gravity's magnitude (m/s²); its direction in the file's world frame is estimated.
GRAVITY = 9.81

#: The bound on an estimated clock offset (s), as :mod:`torch_dq.fitting`'s default.
MAX_OFFSET = 0.1

#: The IMU fit's knot spacing, in IMU sampling periods.
IMU_SAMPLES_PER_SPAN = 5

#: The B-spline degree when an IMU clock offset is estimated and ``--degree`` is not given:
#: a quartic's accelerations are C1 in time, so the accelerometer's cost is smooth in the
#: offset (a cubic's are only C0: the cost kinks as samples cross knots, and the solve can
#: stall short of the optimum). Kalibr and basalt likewise fit on splines of degree 4-5.
OFFSET_DEGREE = 4


def default_degree(imu, time_offset: str | None) -> int:
    """The ``fit`` command's B-spline degree when none is given: :data:`OFFSET_DEGREE` with
    an IMU file and ``time_offset="estimate"``, else 3 (an explicit degree is always kept:
    :func:`torch_dq.fitting.estimate` then warns where it is below 4)."""
    return OFFSET_DEGREE if imu is not None and time_offset == "estimate" else 3


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


def _read(path: str) -> tuple[Tensor, Tensor, Tensor, str]:
    """The IMU file's times, gyroscope and accelerometer readings, and its reader's warnings
    (passed on to the caller's record, and as a hint for an error message)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        times, gyro, accel = io.read_imu(path)
    for w in caught:  # to the caller's record (summary.json)
        warnings.warn(w.message, w.category, stacklevel=2)
    return times, gyro, accel, "".join(f" ({w.message})" for w in caught)


def _reachable(path: str, spline, times: Tensor, clock, hint: str) -> Tensor:
    r"""``(N,)`` bool: the IMU samples that :func:`torch_dq.fitting.estimate`'s domain check
    accepts on ``spline``: their times moved by all that the parameters moving them can reach
    (:meth:`~torch_dq.fitting.Term.time_reach`: :math:`\pm` :data:`MAX_OFFSET` for an
    estimated clock offset) inside the curve's domain, which :func:`_imu_spline` widened by
    that much. So no sample within the poses' time span is cut for the offset.

    Raises:
        OptionError: fewer than 10 such samples (an IMU file of another clock).
    """
    probe = fitting.Gyro(times, torch.zeros((*times.shape, 3), dtype=torch.float64),
                         sigma=1.0, time_offset=clock, max_time_offset=MAX_OFFSET)
    low, high = probe.time_reach()
    t0, t1 = spline.domain
    keep = (times + low >= t0) & (times + high <= t1)
    if int(keep.sum()) < 10:
        span = f"[{t0 + float(high.max()):.6f}, {t1 + float(low.min()):.6f}]"
        raise OptionError(f"{path}: {int(keep.sum())} IMU samples lie within the poses' time "
                          f"span {span} s, the IMU file spans [{float(times[0]):.6f}, "
                          f"{float(times[-1]):.6f}] s: pass an IMU file of the same recording "
                          f"(same clock){hint}")
    return keep


def _imu_spline(spline, times: Tensor, poses: Tensor, imu_times: Tensor, margin: float):
    """The curve of the IMU fit and its knots' summary: the pose-only fit where its knots
    are as fine as :data:`IMU_SAMPLES_PER_SPAN` IMU periods and no ``margin`` is asked, else
    a new start on the fitted poses at the finer of the two spacings (smoothing between
    them), its domain widened by ``margin`` (s) at each end for an estimated clock offset."""
    knots = spline.knots
    pose_spacing = float(knots[spline.degree + 1] - knots[spline.degree])
    spacing = IMU_SAMPLES_PER_SPAN * float((imu_times[1:] - imu_times[:-1]).median())
    if spacing >= pose_spacing:
        reason = "the pose-only fit's (as fine as the IMU's)"
        if not margin:
            return spline, {"spacing_s": pose_spacing, "n_ctrl": spline.n_ctrl,
                            "reason": reason}
    else:
        reason = (f"{IMU_SAMPLES_PER_SPAN} IMU sampling periods (the poses' fit had "
                  f"{pose_spacing:.4g} s)")
    if margin:
        reason += f"; the domain widened by {margin:g} s at each end for the clock offset"
    q, p = dualquat.to_rt(poses)
    fine = BSpline.from_poses(q.to(spline.control_points.dtype),
                              p.to(spline.control_points.dtype), times,
                              knot_spacing=min(spacing, pose_spacing), degree=spline.degree,
                              form=spline.form, margin=margin)
    fine_knots = fine.knots
    return fine, {"spacing_s": float(fine_knots[fine.degree + 1] - fine_knots[fine.degree]),
                  "n_ctrl": fine.n_ctrl, "reason": reason}


#: Other orders of the four quaternion columns that files get wrong: the rotation ``(w, x,
#: y, z)`` as read, re-indexed (``x y z w`` read as ``w x y z`` and the converse).
_ORDERS = {"qw qx qy qz (w first)": [1, 2, 3, 0], "qx qy qz qw (w last)": [3, 0, 1, 2]}


def _rate_pairs(times: Tensor, q: Tensor, t_imu: Tensor, gyro: Tensor
                ) -> tuple[Tensor, Tensor, Tensor]:
    """The poses' body angular rates (finite differences of consecutive rotations) and the
    gyroscope's readings interpolated at their midpoints, both centred (free of a bias),
    ``(M, 3)`` each, and the rotation ``R`` (Kabsch) that best maps the first to the second."""
    rel = quat.to_rotvec(quat.mul(quat.conj(q[:-1]), q[1:]))
    dt = (times[1:] - times[:-1])[:, None]
    mid = 0.5 * (times[1:] + times[:-1])
    j = torch.searchsorted(t_imu.contiguous(), mid).clamp(1, len(t_imu) - 1)
    u = ((mid - t_imu[j - 1]) / (t_imu[j] - t_imu[j - 1])).clamp(0.0, 1.0)[:, None]
    inside = (mid >= t_imu[0]) & (mid <= t_imu[-1])
    a = (rel / dt)[inside]
    b = (gyro[j - 1] * (1 - u) + gyro[j] * u)[inside]
    a, b = a - a.mean(0), b - b.mean(0)
    U, _, Vh = torch.linalg.svd(b.mT @ a)
    d = torch.sign(torch.linalg.det(U @ Vh))
    return a, b, U @ torch.diag(torch.stack((d.new_ones(()), d.new_ones(()), d))) @ Vh


def _misfit(times: Tensor, q: Tensor, t_imu: Tensor, gyro: Tensor) -> float:
    """How badly the poses' body angular rates explain the gyroscope's up to one rotation
    between their axes (:func:`_rate_pairs`): the residual's share of the readings' scatter,
    in [0, 1]."""
    a, b, R = _rate_pairs(times, q, t_imu, gyro)
    return float((b - a @ R.mT).square().sum() / b.square().sum().clamp_min(1e-300))


def _warn_quaternion_order(times: Tensor, poses: Tensor, t_imu: Tensor, gyro: Tensor) -> None:
    """Warn when the gyroscope fits the poses' rotations far better with their quaternion
    columns in another order (the poses alone cannot tell: a permutation of the components
    keeps every angle between two rotations, not their axes)."""
    q = dualquat.to_rt(poses.double())[0]
    if len(times) < 10:
        return
    now = _misfit(times, q, t_imu, gyro)
    others = {name: _misfit(times, q[:, order], t_imu, gyro) for name, order in _ORDERS.items()}
    best = min(others.values())
    if now > 0.3 and best < 0.25 * now:  # one warning, naming every order that fits as well
        names = " or ".join(n for n, o in others.items() if o <= 1.1 * best + 1e-12)
        warnings.warn(f"the poses' quaternion columns look like {names}: the gyroscope "
                      f"explains their angular rates up to {100 * best:.2g} % in that order "
                      f"and {100 * now:.2g} % as read; reorder the columns if so",
                      UserWarning, stacklevel=3)

def _variance_step(est, terms) -> list[float] | None:
    """``sqrt(chi2/dof)`` per term where a term's chi2/dof is outside ``[0.5, 2]`` (the
    noise levels taken from the data before the joint fit misdescribe its residuals: the
    pose-only fit's residuals hold its model error), else None."""
    ratios = [float(est.chi2[term].sum()) / max(float(est.dof[term].sum()), 1.0)
              for term in terms]
    if all(0.5 <= r <= 2.0 for r in ratios):
        return None
    return [math.sqrt(max(r, 1e-12)) for r in ratios]


def _chi2(est, terms) -> dict:
    """Per term (by class name): chi2, degrees of freedom and their ratio."""
    out = {}
    for term in terms:
        c, d = float(est.chi2[term].sum()), float(est.dof[term].sum())
        out[type(term).__name__] = {"chi2": c, "dof": d, "chi2_per_dof": c / max(d, 1.0)}
    return out


def _stats(est, term, name: str) -> dict:
    value = getattr(term, name).detach().double()
    std = est.std(term, name).detach().double()
    return {"value": value.tolist(), "std": std.tolist()}


def fit_with_imu(spline, times: Tensor, poses: Tensor, imu: str | os.PathLike[str],
                 time_offset: str | None, steps: int, say) -> tuple[object, dict]:
    """Fit a curve on knots chosen for the IMU to the fitted poses and the IMU file
    together; report the estimates.

    Args:
        spline: the pose-only fit (:class:`torch_dq.nn.BSpline`): the noise levels of the
            poses come from its residuals; refined in place where its knots are as fine
            as the IMU's and no clock offset is estimated.
        times, poses: the fitted poses (``(N,)`` float64 s, ``(N, 8)``).
        imu: the IMU file (:func:`torch_dq.io.read_imu`), on the poses' clock up to an
            offset.
        time_offset: ``None`` (the clocks agree) or ``"estimate"``.
        steps: maximum Levenberg-Marquardt steps.
        say: ``print`` or a silent stand-in.

    Returns:
        The fitted curve, and the ``"imu"`` entry of ``summary.json``: the file, samples
        used, the knots (spacing, count, why), noise levels (taken from the data; where a
        first joint fit's chi2/dof of a term falls outside ``[0.5, 2]``, all rescaled once by
        ``sqrt(chi2/dof)`` and fitted again: ``rescaled_by``), gyro and accelerometer biases,
        gravity, the time offset (each ``{"value", "std"}``), each term's ``chi2``, ``dof``
        and ``chi2_per_dof``, and the estimate's steps and reason.

    Raises:
        torch_dq.io.TrajectoryFileError: a malformed IMU file.
        OptionError: too few IMU samples within the poses' time span (all of them are
            kept there, also when an offset is estimated).
    """
    path = os.fspath(imu)
    margin = MAX_OFFSET if time_offset == "estimate" else 0.0
    t, gyro, accel, hint = _read(path)
    rot_s, trans_s = _pose_sigmas(spline, times, poses)  # the pose-only fit's residuals
    spline, knots = _imu_spline(spline, times, poses, t, margin)
    clock = fitting.Free() if time_offset == "estimate" else None
    keep = _reachable(path, spline, t, clock, hint)
    t, gyro, accel, dropped = t[keep], gyro[keep], accel[keep], int((~keep).sum())
    gyro_s, accel_s = _imu_sigma(gyro), _imu_sigma(accel)
    _warn_quaternion_order(times, poses, t, gyro)
    sig: list = [rot_s, trans_s, gyro_s, accel_s]  # rad, m, (3,) rad/s, (3,) m/s^2

    def terms_at(s: list) -> list:
        return [fitting.Poses(times, poses.double(), rot_sigma=s[0], trans_sigma=s[1]),
                fitting.Gyro(t, gyro, sigma=s[2], bias=True, time_offset=clock),
                fitting.Accel(t, accel, sigma=s[3], bias=True, gravity=GRAVITY,
                              time_offset=clock)]

    terms = terms_at(sig)
    degrees = degrees_message(terms[1], spline)  # the Gyro term's own check, refused here
    if degrees:
        raise OptionError(f"{path}: {degrees}")
    say(f"IMU fit knots: every {knots['spacing_s']:.4g} s, {knots['n_ctrl']} control points "
        f"({knots['reason']})")
    say(f"IMU: {path}: {len(t)} samples ({dropped} outside the poses' time span left out); "
        f"noise from the data: poses {math.degrees(rot_s):.3g} deg, {1e3 * trans_s:.3g} mm "
        f"per axis; gyro {float(gyro_s.mean()):.3g} rad/s, accel {float(accel_s.mean()):.3g} "
        f"m/s^2")
    with warnings.catch_warnings(record=True) as first:  # kept if no second fit runs
        warnings.simplefilter("always")
        est = fitting.estimate(spline, terms, steps=steps, verbose=False)
    scale = _variance_step(est, terms)
    for w in first if scale is None else ():
        warnings.warn(w.message, stacklevel=2)
    if scale is not None:  # one variance-component step: the sigmas the residuals show
        say("noise levels rescaled by sqrt(chi2/dof) of a first fit: poses, gyro, accel x "
            + ", ".join(f"{f:.3g}" for f in scale))
        sig = [sig[0] * scale[0], sig[1] * scale[0], sig[2] * scale[1], sig[3] * scale[2]]
        terms = terms_at(sig)
        est = fitting.estimate(spline, terms, steps=steps, verbose=False)
    result = {"file": path, "samples": len(t), "left_out": dropped, "knots": knots,
              "sigmas": {"rot_rad": float(sig[0]), "trans_m": float(sig[1]),
                         "gyro_rad_s": sig[2].tolist(), "accel_m_s2": sig[3].tolist(),
                         "rescaled_by": scale},
              "gyro_bias_rad_s": _stats(est, terms[1], "bias"),
              "accel_bias_m_s2": _stats(est, terms[2], "bias"),
              "gravity_m_s2": _stats(est, terms[2], "gravity"),
              "chi2": _chi2(est, terms), "steps": est.steps, "reason": est.reason}
    if clock is not None:
        result["time_offset_s"] = _stats(est, terms[1], "time_offset")
    _print(say, result)
    return spline, result


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
    say("  chi2/dof                " + ", ".join(f"{name} {v['chi2_per_dof']:.3g}"
                                                  for name, v in r["chi2"].items()))

r"""Camera-IMU calibration (Kalibr's ``calibrate_imu_camera``) from target corners and IMU
readings, started without user guesses (private; public name :func:`camera_imu`).

Start, in this order (Furgale, Rehder, Siegwart, "Unified temporal and spatial calibration
for multi-sensor systems", IROS 2013, sec. IV, for the overall scheme):

1. The target's pose in each camera per frame from the frame's corners: the homography of
   the unprojected (undistorted) corners, decomposed (Zhang 2000, app. C; the private
   :mod:`torch_dq.calibration._start`).
2. Each camera's mean angular velocity between consecutive frames (camera axes).
3. The time offset maximising the correlation of the angular speeds (rotation-invariant:
   no extrinsic needed), the gyroscope's rates averaged over the same intervals.
4. The camera's orientation on the body: the rotation best aligning the centred camera
   rates with the centred gyroscope rates (Kabsch, "A discussion of the solution for the
   best rotation...", Acta Cryst. A34, 1978); the difference of the means starts the
   gyroscope bias. Translations start at zero for camera 0, other cameras at their pose
   relative to camera 0 from the shared frames.
5. The body trajectory: the target poses of the cameras moved to the body by the
   extrinsics' starts, on the IMU clock, fit by a coarse spline (knots every 0.1 s), sampled
   densely and refit with knots every ``knot_spacing`` (cumulative cubic B-spline; by
   default chosen from the IMU readings' spectra, the private
   ``calibration._knot_spacing``).

Then one :func:`torch_dq.fitting.estimate` over the trajectory, one
:class:`~torch_dq.fitting.Reprojections` term per camera (the target is the world frame),
:class:`~torch_dq.fitting.Gyro` and :class:`~torch_dq.fitting.Accel` with constant
biases and gravity of a known magnitude (``gravity_magnitude``, 9.81 by default) with its
direction estimated (started from the mean
accelerometer reading rotated into the target frame by the start trajectory).

Clock convention: the trajectory is on the IMU's clock, a frame stamped ``t`` by its camera
is the body at ``t + dt`` (``Reprojections``' ``time_offset``), which is Kalibr's
``timeshift_cam_imu`` (``t_imu = t_cam + shift``).
"""

from __future__ import annotations

import itertools
import math
import numbers
import sys
import time
import warnings

import torch
from torch import Tensor

from .. import _checks, dualquat, quat
from .._camera_values import normalised_hint
from ..camera import Camera
from ..fitting import Accel, Free, Gyro, Reprojections, estimate
from ..nn import BSpline
from . import _knot_spacing, _start
from ._cameras import _cameras_data, _distinct, _inside, _planar
from ._imu_result import _FN, CameraImuCalibration, result
from ._walk import WalkAccel, WalkGyro, segments

__all__ = ["CameraImuCalibration", "camera_imu"]

_MIN_RATE = 0.05  # rad/s RMS of the centred rate about an axis: less counts as no rotation
_MIN_ACCEL = 0.2  # m/s^2 RMS of the specific force's change: less leaves the accel bias
# pixels may stray this fraction of the image's size outside it (a corner refined at the
# border, the noise of a simulation); a camera of another resolution reaches far beyond
_SLACK = 0.01
_SAME_TIME = 1e-3  # seconds: body-pose samples closer than this are one in the start spline


def _sigma(name: str, density, times: Tensor) -> float:
    """Per-sample sigma of a noise density: ``density * sqrt(rate)``, the rate from the
    median sample spacing."""
    if isinstance(density, bool) or not isinstance(density, numbers.Real) or not (
            math.isfinite(density) and float(density) > 0):
        _checks.fail(_FN, f"expected {name} to be a positive finite noise density, got "
                          f"{density!r}")
    return float(density) * math.sqrt(sample_rate(times))


def sample_rate(times: Tensor) -> float:
    """The rate (Hz) of sorted sample ``times (N,)``, ``N >= 2``: one over the median
    spacing (robust to dropped samples)."""
    return 1.0 / float(times.diff().median())


def _arguments(cameras, observations, imu):
    """Validated cameras, observations (float64 CPU) and IMU data."""
    if not isinstance(cameras, (list, tuple)) or not cameras or not all(
            isinstance(c, Camera) for c in cameras):
        _checks.fail(_FN, "expected cameras to be a non-empty list of torch_dq.camera.Camera",
                     TypeError)
    if not isinstance(observations, (list, tuple)) or len(observations) != len(cameras):
        got = (f"{len(observations)}" if isinstance(observations, (list, tuple))
               else type(observations).__name__)
        _checks.fail(_FN, f"expected one (times, points, pixels) observation tuple per camera "
                          f"({len(cameras)}), got {got}")
    if not isinstance(imu, (list, tuple)) or len(imu) != 3:
        _checks.fail(_FN, "expected imu to be a (times (N,), gyro (N, 3), accel (N, 3)) tuple")
    t, g, a = _samples("imu", ("times", "gyro", "accel"), imu, (None, 3, 3))
    if t.numel() < 10:
        _checks.fail(_FN, f"expected at least 10 IMU samples, got {t.numel()}")
    _seconds("imu times", t, 0.5)
    obs = []
    for i, o in enumerate(observations):
        if not isinstance(o, (list, tuple)) or len(o) != 3:
            _checks.fail(_FN, f"expected observations[{i}] to be (times, points, pixels)")
        ot, op, ou = _samples(f"observations[{i}]", ("times", "points", "pixels"), o,
                              (None, 3, 2), increasing=False)
        _units(i, cameras[i], ot, op, ou)
        obs.append((ot, op, ou))
    _distinct(obs, _FN)
    return list(cameras), obs, (t, g, a)


def _units(i: int, cam: Camera, times: Tensor, points: Tensor, pixels: Tensor) -> None:
    """Camera ``i``'s observations in seconds, metres and pixels of its image: a
    ``ValueError`` for times in nanoseconds (or us, ms), pixels outside the resolution or
    that look like normalised coordinates, target points off the plane ``Z = 0`` or spread
    over more than 20 m (``_cameras._planar``)."""
    _seconds(f"observations[{i}] times", times.unique(), 10.0)
    _inside(i, pixels, cam.resolution, _FN, "cameras[{i}].resolution", _SLACK)
    _planar(i, points, _FN)
    hint = normalised_hint(pixels, cam.params)
    if hint is not None:
        _checks.fail(_FN, f"observations[{i}]: {hint}")


def _samples(label: str, fields: tuple[str, ...], xs, widths: tuple,
             increasing: bool = True) -> list[Tensor]:
    """``label``'s ``(times (N,), values (N, w)...)`` checked (float64 times, matching
    shapes, finite, times strictly increasing where ``increasing``), as float64 CPU copies."""
    names = [f"{label} {f}" for f in fields]
    out = []
    for n, x, w in zip(names, xs, widths, strict=True):
        x = _checks.tensor(_FN, n, x).detach()
        if w is None and x.dtype != torch.float64:
            _checks.fail(_FN, f"expected float64 seconds for {n}, got {x.dtype} (float32 "
                              f"holds UNIX seconds to 128 s)", TypeError)
        out.append(x.to("cpu", torch.float64))
    t = out[0]
    shapes = [(t.numel(),) if w is None else (t.numel(), w) for w in widths]
    if t.dim() != 1 or [tuple(x.shape) for x in out] != shapes:
        want = ", ".join(f"{f} {'(N,)' if w is None else f'(N, {w})'}"
                         for f, w in zip(fields, widths, strict=True))
        _checks.fail(_FN, f"expected {label} as {want}, got "
                          f"{', '.join(_checks.shape_str(x.shape) for x in out)}")
    for n, x in zip(names, out, strict=True):
        bad = ~torch.isfinite(x)
        if bool(bad.any()):
            _checks.fail(_FN, f"{n} holds a non-finite value at sample "
                              f"{_checks.first_index(bad)[0]}")
    back = (t.diff() <= 0).nonzero()
    if increasing and back.numel():
        k = int(back[0]) + 1
        _checks.fail(_FN, f"{names[0]} must be strictly increasing: sample {k} "
                          f"({float(t[k])!r}) is not after sample {k - 1} "
                          f"({float(t[k - 1])!r})")
    return out


def _seconds(name: str, t: Tensor, longest: float) -> None:
    """A ``ValueError`` where the median step of the sorted times ``t`` exceeds ``longest``
    seconds while as nanoseconds it would be a sensor's (an IMU at 0.5 s: 2 Hz; frames at
    10 s): times in nanoseconds (or microseconds, milliseconds), not seconds."""
    step = float(t.diff().median()) if t.numel() > 2 else 0.0
    if step <= longest:
        return
    # the coarsest unit that gives a sensor's spacing: milliseconds before nanoseconds
    for unit, scale in (("milliseconds", 1e-3), ("microseconds", 1e-6), ("nanoseconds", 1e-9)):
        if step * scale <= longest:
            _checks.fail(_FN, f"{name} look like {unit}, not seconds: read as seconds they "
                              f"lie {step:.4g} s apart (median), as {unit} {step * scale:.4g}"
                              f" s; divide them by {1 / scale:.0e} (io.read_imu and "
                              f"calibration.read_corners return seconds)")
    _checks.fail(_FN, f"{name} lie {step:.4g} s apart (median): expected seconds")


def _frame_poses(cam: Camera, obs, min_points: int) -> tuple[Tensor, Tensor]:
    """Per-frame camera poses in the target frame (``p_target = T p_cam``, ``(V, 8)``) and
    the frames' times ``(V,)``, from the homographies of the unprojected corners."""
    data, times = _cameras_data([obs], [cam.model], [cam.resolution], min_points)
    d = data[0]
    params = cam.params.detach().to("cpu", torch.float64)
    T, rms, ok = _start.view_poses(cam.model, params, *d.views)
    ok = ok & (rms < 10.0)
    return times[d.view_frames[ok]], dualquat.inv(T[ok])


def _camera_rates(times: Tensor, poses: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Mean angular velocities ``(M, 3)`` (camera axes) between consecutive frames at most
    twice the median spacing apart, with the intervals' starts and ends ``(M,)``."""
    dt = times.diff()
    keep = dt < 2.0 * dt.median()
    q = dualquat.to_rt(poses)[0]
    rel = quat.mul(quat.conj(q[:-1]), q[1:])
    w = quat.to_rotvec(rel) / dt[:, None]
    return w[keep], times[:-1][keep], times[1:][keep]


def _within(w: Tensor, a: Tensor, b: Tensor, t_imu: Tensor, max_offset: float, camera: int
            ) -> tuple[Tensor, Tensor, Tensor]:
    """The rates ``w`` over ``[a, b]`` inside the IMU log at any offset within ``max_offset``
    (a log covering part of the frames read as uncorrelated); fewer than 10: ValueError."""
    keep = (a - max_offset >= t_imu[0]) & (b + max_offset <= t_imu[-1])
    if int(keep.sum()) < 10:
        _checks.fail(_FN, f"camera {camera}: only {int(keep.sum())} pairs of consecutive frames "
                          f"lie inside the IMU log (at least 10 are needed to start the clock "
                          f"offset and orientation)")
    return w[keep], a[keep], b[keep]


def _mean_gyro(t: Tensor, gyro: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Gyroscope readings averaged over ``[a, b]`` (trapezoid integral, linear between
    samples, clamped at the ends): ``(M, 3)``."""
    cum = torch.cat((gyro.new_zeros(1, 3),
                     torch.cumsum(0.5 * (gyro[1:] + gyro[:-1]) * t.diff()[:, None], 0)))

    def integral(s: Tensor) -> Tensor:
        s = s.clamp(float(t[0]), float(t[-1]))
        j = torch.searchsorted(t, s, right=True).clamp(1, t.numel() - 1) - 1
        h = (s - t[j])[:, None]
        slope = (gyro[j + 1] - gyro[j]) / (t[j + 1] - t[j])[:, None]
        return cum[j] + gyro[j] * h + 0.5 * slope * h ** 2

    return (integral(b) - integral(a)) / (b - a)[:, None]


_MIN_CORRELATION = 0.3  # of the angular speeds at the best offset: below, unrelated logs


def _offset(imu_t, gyro, w_cam, a, b, max_offset: float, camera: int) -> float:
    """Time offset maximising the correlation of the angular speeds over ``[-max, max]``
    (0.5 ms grid, refined by a parabola through the best three); a ``ValueError`` when even
    the best correlation is below ``_MIN_CORRELATION`` (the IMU log is not this motion's,
    or its clock is further off than ``max_offset``) or lies at the grid's end (the offset
    likely beyond ``max_offset``)."""
    offsets = torch.arange(-max_offset, max_offset + 1e-12, 5e-4, dtype=torch.float64)
    speed = w_cam.norm(dim=-1)
    speed = speed - speed.mean()
    o = offsets[:, None]
    s = _mean_gyro(imu_t, gyro, (a + o).flatten(), (b + o).flatten()).norm(dim=-1)
    s = s.reshape(offsets.numel(), -1)
    s = s - s.mean(-1, keepdim=True)
    c = (s * speed).sum(-1) / (s.norm(dim=-1) * speed.norm()).clamp_min(1e-300)
    if not float(c.max()) >= _MIN_CORRELATION:
        _checks.fail(_FN, f"camera {camera}: the gyroscope's angular speeds do not follow the "
                          f"camera's (best correlation {float(c.max()):.2f} over offsets "
                          f"within +-{max_offset:g} s): the IMU log is not this recording's, or"
                          f" its clock further off (max_time_offset; --max-time-offset)")
    best = int(c.argmax())
    if best in (0, c.numel() - 1):
        _checks.fail(_FN, f"camera {camera}: the angular speeds correlate best at the bound of "
                          f"the offsets searched ({float(offsets[best]):+g} s; correlation "
                          f"{float(c[best]):.2f}): the clock offset is beyond {max_offset:g} s:"
                          f" raise max_time_offset (calibrate: --max-time-offset)")
    c0, c1, c2 = (float(c[best + d]) for d in (-1, 0, 1))
    denom = c0 - 2 * c1 + c2
    frac = 0.5 * (c0 - c2) / denom if denom < 0 else 0.0
    return float(offsets[best]) + max(-1.0, min(1.0, frac)) * 5e-4


def _check_scale(w_cam: Tensor, w_imu: Tensor, camera: int) -> None:
    """A ``ValueError`` where the gyroscope's centred angular speeds are more than 3 times
    the camera's or less than a third of them (the correlation of :func:`_offset` is blind
    to a scale): readings in deg/s (57.3 times) or another unit than rad/s."""
    spread = [float((w - w.mean(0)).norm(dim=-1).square().mean().sqrt()) for w in
              (w_cam, w_imu)]
    ratio = spread[1] / max(spread[0], 1e-300)
    if 1.0 / 3.0 <= ratio <= 3.0:
        return
    hint = ("deg/s, not rad/s: convert them with torch.deg2rad" if 40.0 <= ratio <= 80.0
            else "another unit than rad/s")
    _checks.fail(_FN, f"camera {camera}: the gyroscope's angular speeds are {ratio:.3g} times "
                      f"the camera's (RMS about their means, {spread[1]:.3g} against "
                      f"{spread[0]:.3g} rad/s): the readings look like {hint}")


def _kabsch(w_cam: Tensor, w_body: Tensor, camera: int) -> tuple[Tensor, Tensor]:
    r"""Rotation ``R`` (quaternion) and bias ``b`` minimising
    :math:`\sum |w_b - (R w_c + b)|^2` (centred Kabsch); a ``ValueError`` where a reflection
    explains the gyroscope's rates and no rotation does (left-handed IMU axes)."""
    mc, mb = w_cam.mean(0), w_body.mean(0)
    H = (w_cam - mc).T @ (w_body - mb)
    U, S, Vh = torch.linalg.svd(H)
    d = torch.sign(torch.linalg.det(Vh.T @ U.T))
    if float(d) < 0:
        _handedness(S, w_cam - mc, w_body - mb, camera)
    R = Vh.T @ torch.diag(torch.stack((d.new_ones(()), d.new_ones(()), d))) @ U.T
    return quat.from_matrix(R), mb - R @ mc


def _handedness(S: Tensor, c: Tensor, b: Tensor, camera: int) -> None:
    """Kabsch's best orthogonal map is a reflection (singular values ``S`` of the centred
    rates' cross-covariance, ``c`` camera, ``b`` gyroscope): a ``ValueError`` where the best
    rotation leaves over a tenth of the gyroscope's rates unexplained and the reflection
    under a quarter of that (with weak rotation about one axis both fit alike)."""
    total = float(c.square().sum() + b.square().sum())
    rotation = (total - 2.0 * float(S[0] + S[1] - S[2])) / float(b.square().sum())
    reflection = (total - 2.0 * float(S.sum())) / float(b.square().sum())
    if rotation > 0.1 and reflection < 0.25 * rotation:
        _checks.fail(_FN, f"camera {camera}: the gyroscope's rates follow the camera's through "
                          f"a reflection, not a rotation (misfit {reflection:.1%} of the "
                          f"rates against {rotation:.1%}): the IMU's axes are left-handed (two "
                          f"gyroscope columns swapped or one sign flipped in the log), or the "
                          f"target's points are mirrored (Kalibr's: Y up, Z = 0)")


def _relative(times0: Tensor, poses0: Tensor, times: Tensor, poses: Tensor) -> Tensor | None:
    """Camera ``i``'s pose in camera 0's frame from their shared frames (equal stamps; the
    median translation, the normalised mean quaternion); None without shared frames."""
    i0, i1 = torch.isin(times0, times).nonzero()[:, 0], torch.isin(times, times0).nonzero()[:, 0]
    if i0.numel() == 0:
        return None
    rel = dualquat.mul(dualquat.inv(poses0[i0]), poses[i1])
    q, t = dualquat.to_rt(rel)
    q = q * torch.where((q * q[:1]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    return dualquat.from_rt(quat.normalize(q.mean(0)), t.median(0).values)


def _coarse_trajectory(samples: list[tuple[Tensor, Tensor]]
                       ) -> tuple[BSpline, tuple[float, float]]:
    """A cubic B-spline with knots every 0.1 s fit to body poses ``(times, poses)`` (of
    several cameras: one per 1 ms), and the poses' time span."""
    t = torch.cat([s[0] for s in samples])
    order = torch.argsort(t, stable=True)
    t, x = t[order], torch.cat([s[1] for s in samples])[order]
    first = torch.ones_like(t, dtype=torch.bool)
    # stamps of several cameras within _SAME_TIME of each other (synchronised cameras whose
    # offsets' starts differ by microseconds): the first camera's pose, not a turn of the
    # poses' noise over microseconds
    first[1:] = t.diff() > _SAME_TIME
    t, x = t[first], x[first]
    n = max(4, math.ceil(float(t[-1] - t[0]) / 0.1) + 3)
    q, p = dualquat.to_rt(x)
    coarse = BSpline.from_poses(q, p, t, n_ctrl=min(n, t.numel()))
    return coarse, (float(t[0]), float(t[-1]))


def _start_trajectory(coarse: BSpline, span: tuple[float, float], lo: float, hi: float,
                      knot_spacing: float) -> BSpline:
    """Cumulative cubic B-spline with knots every ``knot_spacing`` over ``[lo, hi]``: the
    coarse spline (``_coarse_trajectory``, over ``span``) sampled four times per knot span
    (constant beyond ``span``) and refit."""
    grid = torch.linspace(lo, hi, max(8, math.ceil((hi - lo) / knot_spacing * 4) + 1),
                          dtype=torch.float64)
    with torch.no_grad():
        y = coarse(grid.clamp(*span))
    q, p = dualquat.to_rt(y)
    n = math.ceil((hi - lo) / knot_spacing) + 3
    return BSpline.from_poses(q, p, grid, n_ctrl=n, form="cumulative")


def _starts(cameras, obs, imu, max_offset: float, min_points: int):
    """Extrinsics ``(C, 8)``, time offsets ``(C,)`` and gyroscope bias starts, and the
    body-pose samples of every camera on the IMU clock."""
    t_imu, gyro, _ = imu
    frames = [_frame_poses(c, o, min_points) for c, o in zip(cameras, obs, strict=True)]
    rot, offs, biases = [], [], []
    for i, (t, T) in enumerate(frames):
        if t.numel() < 10:
            _checks.fail(_FN, f"camera {i}: only {t.numel()} frames give the target a pose "
                              f"(at least 10 with >= {min_points} corners are needed)")
        w, a, b = _within(*_camera_rates(t, T), t_imu, max_offset, i)
        dt = _offset(t_imu, gyro, w, a, b, max_offset, i)
        w_imu = _mean_gyro(t_imu, gyro, a + dt, b + dt)
        _check_scale(w, w_imu, i)
        q, bias = _kabsch(w, w_imu, i)
        rot.append(q)
        offs.append(dt)
        biases.append(bias)
    ext = [dualquat.from_rt(rot[0], torch.zeros(3, dtype=torch.float64))]
    for i in range(1, len(cameras)):
        rel = _relative(frames[0][0], frames[0][1], frames[i][0], frames[i][1])
        ext.append(dualquat.from_rt(rot[i], torch.zeros(3, dtype=torch.float64))
                   if rel is None else dualquat.mul(ext[0], rel))
    e = torch.stack(ext)
    samples = [(t + dt, dualquat.mul(T, dualquat.inv(e[i])))
               for i, ((t, T), dt) in enumerate(zip(frames, offs, strict=True))]
    return e, torch.tensor(offs, dtype=torch.float64), biases[0], samples


def _positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (
            math.isfinite(value) and float(value) > 0):
        _checks.fail(_FN, f"expected {name} to be a positive finite number, got {value!r}")
    return float(value)


def _check_accel_units(accel: Tensor, gravity_magnitude: float) -> None:
    """A ``ValueError`` where the accelerometer's mean reading magnitude is within a factor
    1.5 of ``gravity_magnitude`` in g or in milli-g (a rig held for calibration reads about
    g in m/s^2; fast motions may read several g, so other ratios pass)."""
    meas = float(accel.norm(dim=-1).mean())
    ratio = gravity_magnitude / max(meas, 1e-300)
    for unit, factor in (("g", 9.80665), ("milli-g", 9.80665e-3)):
        if factor / 1.5 < ratio < 1.5 * factor:
            _checks.fail(_FN, f"the accelerometer's readings average {meas:.4g} in magnitude "
                              f"against gravity_magnitude {gravity_magnitude:.4g} m/s^2 "
                              f"({1 / ratio:.3g} times): they look like {unit}, not m/s^2: "
                              f"multiply them by {factor:.6g}")


def _motion_warnings(gyro: Tensor, accel: Tensor) -> list[str]:
    """Warnings for motion that leaves parameters undetermined: rotation (the centred rate's
    RMS above 0.05 rad/s) about one IMU axis or none (the cameras' rates then fix their
    orientations only up to a rotation about that axis, and the accelerometer sees no
    lever arm along it), a specific force whose RMS change is below 0.2 m/s^2 (its bias and
    gravity not separated)."""
    out = []
    w = gyro - gyro.mean(0)
    ev, vec = torch.linalg.eigh(w.T @ w / w.shape[0])
    rms = ev.clamp_min(0).sqrt()
    strong = int((rms >= _MIN_RATE).sum())
    if strong == 0:
        out.append(f"{_FN}: no rotation (gyroscope RMS {float(rms.max()):.3f} rad/s): the "
                   f"extrinsics' rotations and translations and the time_offsets are "
                   f"undetermined")
    elif strong == 1:
        axis = ", ".join(f"{v:.2f}" for v in vec[:, 2].tolist())
        out.append(f"{_FN}: rotation about one IMU axis only ({axis}); too little rotation "
                   f"about the others ({float(rms[1]):.3f} rad/s RMS): the extrinsics' "
                   f"rotation about that axis and their translation along it are "
                   f"undetermined")
    f = accel - accel.mean(0)
    change = float((f ** 2).sum(-1).mean().sqrt())
    if change < _MIN_ACCEL:
        out.append(f"{_FN}: no change of the specific force (accelerometer RMS change "
                   f"{change:.3f} m/s^2): the accel_bias is undetermined (not separated "
                   f"from gravity)")
    return out


def _domain(obs, imu_t: Tensor, pad_lo: float, pad_hi: float) -> tuple[float, float]:
    f_lo = min(float(o[0].min()) for o in obs)
    f_hi = max(float(o[0].max()) for o in obs)
    lo, hi = max(float(imu_t[0]), f_lo - pad_lo), min(float(imu_t[-1]), f_hi + pad_hi)
    if hi - lo < 1.0:
        _checks.fail(_FN, f"the IMU readings ({float(imu_t[0]):.3f} to {float(imu_t[-1]):.3f} "
                          f"s) and the frames ({f_lo:.3f} to {f_hi:.3f} s) overlap for less "
                          f"than 1 s: are they on one clock, in seconds?")
    return lo, hi


def camera_imu(cameras, observations, imu, *, gyro_noise: float, accel_noise: float,
               pixel_sigma: float = 1.0, rolling_shutter: bool = False,
               shared_time_offset: bool = False, knot_spacing: float | None = None,
               max_time_offset: float = 0.1, max_line_delay: float = 1e-4,
               robust: str | None = None, steps: int = 30, prior: float = 0.0,
               min_points: int = 6, bias_walk: tuple[float, float] | None = None,
               bias_interval: float = 1.0, gravity_magnitude: float = 9.81,
               verbose: bool = False) -> CameraImuCalibration:
    r"""Cameras' poses on an IMU, clock offsets, line delays, IMU biases and gravity from
    target observations and IMU readings (Kalibr's ``calibrate_imu_camera``).

    Started without guesses (module docstring: target poses per frame, offsets by
    correlation of angular speeds, orientations by Kabsch on angular rates, trajectory from
    the poses), then one joint :func:`torch_dq.fitting.estimate`. The cameras' intrinsics
    stay fixed (calibrate them first with :func:`cameras`).

    Args:
        cameras: one :class:`torch_dq.camera.Camera` per camera.
        observations: one ``(times (N,), points (N, 3), pixels (N, 2))`` per camera, as
            :func:`read_corners` returns (seconds on the IMU file's clock up to the offsets;
            a planar target, ``Z = 0``).
        imu: ``(times (M,), gyro (M, 3), accel (M, 3))`` as :func:`torch_dq.io.read_imu`
            returns (seconds, rad/s, m/s^2; IMU axes).
        gyro_noise, accel_noise: noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz): Kalibr's
            ``imu.yaml``); per-sample sigma = density * sqrt(rate), the rate from the median
            sample spacing.
        pixel_sigma: corner noise (pixels, per axis).
        rolling_shutter: estimate one line delay per camera (seconds per row, in
            ``[0, max_line_delay]``); without it, a camera whose pixels ask for one is
            warned of (the score test of :class:`~torch_dq.fitting.Reprojections`).
        shared_time_offset: one clock offset for all cameras (hardware-synchronised
            cameras); else one per camera.
        knot_spacing: the trajectory's knot spacing (seconds), or None (default): chosen
            from the IMU readings before the estimate, the largest spacing up to 0.05 s
            (down to 0.01 s, and two IMU periods) whose cubic spline follows the motion
            seen in the readings' spectra (Welch) to within their noise: the model error
            adds at most 0.05 to the gyroscope's and accelerometer's chi2/dof, predicted
            from the least-squares approximation error of a uniform cubic B-spline's first
            and second derivatives at each frequency, the accelerometer's from the body
            velocity's rate that the cumulative spline models (the rule and its
            derivation: private module ``calibration._knot_spacing``). Slow motions keep
            0.05 s (their time); a faster one gets finer knots (EuRoC's calibration dance
            about 0.027 s, its accelerometer's chi2/dof about 1.05 where 0.05 s read 1.26
            on the gentle simulated rig); a motion too fast for 0.01 s is warned of (on a
            dance 2.5 times faster than the simulated ones the accelerometer reads 2.8). With
            densities too small, the spectrum's own floor (its median over the upper half
            of the band) replaces theirs. The result's ``knot_spacing`` holds it.
        max_time_offset: bound on the offsets (seconds); the frames within it of the IMU
            log's ends are left out.
        max_line_delay: bound on the line delays (seconds per row).
        robust: None, ``"huber"`` or ``"cauchy"`` on the reprojection errors.
        steps, prior, verbose: :func:`torch_dq.fitting.estimate`'s (``prior`` 0 by default:
            the IMU readings cover every control point, and a pull towards the start
            trajectory biases the extrinsics' translations).
        min_points: frames with fewer corners are left out.
        bias_walk: None (default: constant biases) or the random walks
            ``(gyroscope_random_walk, accelerometer_random_walk)`` of Kalibr's ``imu.yaml``
            (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)): each bias is then piecewise constant over
            segments of about ``bias_interval`` seconds, consecutive segments tied by the
            walk's prior (the difference of adjacent segment means of a Wiener process has
            the variance ``2/3 walk^2 interval`` per axis; private module
            ``calibration._walk``); the biases come out ``(K, 3)``.
        bias_interval: the segments' length ``h`` (seconds) with ``bias_walk``. The drift
            *within* a segment is not modelled: the walk strays from its segment mean by
            ``walk sqrt(h / 6)`` RMS, up to ``walk sqrt(h / 3)`` at the segment's ends,
            while the readings fix that mean to ``noise / sqrt(h)`` (``noise`` the noise
            density). The unmodelled part stays below the mean's own uncertainty when
            ``h <= sqrt(3) noise / walk``: choose ``bias_interval`` at most
            ``sqrt(3) min(gyro_noise / bias_walk[0], accel_noise / bias_walk[1])``
            (EuRoC's ADIS16448: 15 s for the gyroscope, 1.15 s for the accelerometer, so
            the default 1 s). The same rule with ``h`` the recording's length says when
            constant biases (``bias_walk=None``) suffice: for recordings shorter than that
            bound (on EuRoC's IMU about a second; a 72 s recording needs the walk). Finer
            segments resolve the walk no better than the readings allow and cost time (six
            parameters each: 72 s of EuRoC-like data at 1 s segments took 1.3 times the
            constant biases' time); coarser ones let the unmodelled
            drift leak into the other values beyond their standard deviations (a 3 s
            simulated rig with walks ``(1e-3, 0.02)``, bound 0.17 s: errors within 3.5
            standard deviations at the bound and at half of it, up to 4.8 at eight times
            it; constant biases: 3.6 on the extrinsics).
        gravity_magnitude: the local gravity's magnitude (m/s^2), fixed (its direction is
            estimated). The accelerometer bias along gravity takes up its error: 9.81 against
            9.80665 moved it by 6 of its standard deviations on a simulated 8 s rig
            (estimating the magnitude made that deviation 20 times larger). Give the place's
            value (9.780 at the equator to 9.832 at the poles, 9.807 in Zurich).

    Returns:
        :class:`CameraImuCalibration`.

    Raises:
        ValueError: mismatched lists or shapes, non-positive noises, pixels outside a
            camera's resolution (by over 1 % of its size) or that look like normalised
            coordinates (all within 4 px of ``(0, 0)``), target points off the plane
            ``Z = 0`` or spread over more than 20 m (millimetres, not metres), a
            ``max_line_delay`` or ``gravity_magnitude`` that is not positive, accelerometer
            readings whose mean magnitude is within a factor 1.5 of ``gravity_magnitude`` in
            g or milli-g (not m/s^2), fewer than 10
            frames of a camera with a target pose, IMU and frames that do not overlap by 1 s, a
            gyroscope whose angular speeds do not follow a camera's at any offset within
            ``max_time_offset`` (correlation below 0.3: another recording's log), a
            gyroscope whose rates follow a camera's through a reflection and not a rotation
            (left-handed axes: two columns swapped or one sign flipped).
        TypeError: cameras that are not :class:`~torch_dq.camera.Camera`.

    Warns:
        UserWarning: motion too weak to determine a parameter (named), too fast for the
            finest knots (``knot_spacing=None``: the predicted model error named), and
        :func:`~torch_dq.fitting.estimate`'s own warnings.
    """
    cams, obs, (t_imu, gyro, accel) = _arguments(cameras, observations, imu)
    sg = _sigma("gyro_noise", gyro_noise, t_imu)
    sa = _sigma("accel_noise", accel_noise, t_imu)
    pixel_sigma = _positive("pixel_sigma", pixel_sigma)
    if knot_spacing is not None:
        knot_spacing = _positive("knot_spacing", knot_spacing)
    max_time_offset = _positive("max_time_offset", max_time_offset)
    max_line_delay = _positive("max_line_delay", max_line_delay)
    _positive("bias_interval", bias_interval)
    gravity_magnitude = _positive("gravity_magnitude", gravity_magnitude)
    min_points = _checks.integer(_FN, "min_points", min_points, 4)
    for name, value in (("rolling_shutter", rolling_shutter),
                        ("shared_time_offset", shared_time_offset), ("verbose", verbose)):
        _checks.flag(_FN, name, value)
    _check_accel_units(accel, gravity_magnitude)
    notes = _motion_warnings(gyro, accel)
    for n in notes:
        warnings.warn(n, UserWarning, stacklevel=2)
    clock = [time.perf_counter()]
    reach = max_line_delay * max(c.resolution[1] for c in cams) if rolling_shutter else 0.0
    lo, hi = _domain(obs, t_imu, max_time_offset + 1e-6, max_time_offset + reach + 1e-6)
    e0, dt0, bg0, samples = _starts(cams, obs, (t_imu, gyro, accel), max_time_offset,
                                    min_points)
    clock.append(time.perf_counter())
    keep = (t_imu >= lo) & (t_imu <= hi)
    coarse, span = _coarse_trajectory(samples)
    if knot_spacing is None:
        knot_spacing = _automatic(t_imu[keep], gyro[keep], accel[keep],
                                  (float(gyro_noise), float(accel_noise)), (coarse, span),
                                  verbose)
    spline = _start_trajectory(coarse, span, lo, hi, knot_spacing)
    clock.append(time.perf_counter())
    terms: list = _camera_terms(cams, obs, e0, dt0, pixel_sigma, rolling_shutter,
                          shared_time_offset, max_time_offset, max_line_delay, robust,
                          (lo, hi, reach))
    terms = [*terms, *_imu_terms(t_imu[keep], gyro[keep], accel[keep], (sg, sa), bg0,
                                 bias_walk, bias_interval, gravity_magnitude)]
    est = estimate(spline, terms, steps=steps, prior=prior, verbose=verbose)
    clock.append(time.perf_counter())
    res = result(cams, terms, spline, est, rolling_shutter, notes).to(imu[0].device)
    res.knot_spacing = knot_spacing
    clock.append(time.perf_counter())
    res.timings = dict(zip(("start", "trajectory", "estimate", "uncertainties"),
                           (b - a for a, b in itertools.pairwise(clock)), strict=True))
    return res


def _automatic(t: Tensor, gyro: Tensor, accel: Tensor, densities: tuple[float, float],
               coarse: tuple[BSpline, tuple[float, float]], verbose: bool) -> float:
    """``knot_spacing=None``: the spacing chosen from the spectra of the gyroscope's
    readings and of the body velocity's rate (``_velocity_rate``) that the trajectory's
    accelerometer model follows (``calibration._knot_spacing``), told on stderr with
    ``verbose``."""
    rate = _velocity_rate(t, gyro, accel, *coarse)
    h, seen = _knot_spacing.choose(t.numpy(), (gyro.numpy(), rate.numpy()), densities)
    if max(seen["gyro"], seen["accel"]) > _knot_spacing.EXCESS:
        warnings.warn(f"{_FN}: the motion is too fast for the finest knots chosen (every "
                      f"{h:.3g} s): the spline's model error adds about {seen['gyro']:.2g} "
                      f"to the gyroscope's chi2/dof and {seen['accel']:.2g} to the "
                      f"accelerometer's (predicted from the readings' spectra), and the "
                      f"standard deviations come out too small: record a slower motion, or "
                      f"pass a finer knot_spacing (at least two IMU periods)", UserWarning,
                      stacklevel=3)
    if verbose:
        print(f"{_FN}: knots every {h:.4g} s, chosen from the IMU readings (signal above the "
              f"noise up to {seen['gyro_hz']:.3g} Hz in the gyroscope, {seen['accel_hz']:.3g} "
              f"Hz in the accelerometer; predicted excess chi2/dof from the spline: gyro "
              f"{seen['gyro']:.2g}, accel {seen['accel']:.2g})", file=sys.stderr)
    return h


def _velocity_rate(t: Tensor, gyro: Tensor, accel: Tensor, coarse: BSpline,
                   span: tuple[float, float]) -> Tensor:
    r"""The rate of the body-axes velocity :math:`u = R^T v` at the IMU times ``t (N,)``:
    :math:`\dot u = f + R^T g - \omega \times u` (``f`` the accelerometer's readings,
    ``omega`` the gyroscope's), ``(N, 3)``; ``R`` and ``u`` from the coarse start
    spline (``_coarse_trajectory``, clamped to ``span``), gravity ``g`` (world axes) minus
    the mean of ``R f``. The cumulative (SE(3)) spline's body twist is the derivative of
    its local cubic, so its model of the accelerometer follows :math:`\dot u` as a cubic's
    second derivative, not the readings: the product :math:`\omega \times u` adds the
    power at the higher frequencies that the knots must follow (``_knot_spacing``)."""
    with torch.no_grad():
        tc = t.clamp(*span)
        q, _ = dualquat.to_rt(coarse(tc))
        u = coarse.kinematics(tc, frame="body").linear_velocity
        g = -quat.rotate(q, accel).mean(0)
        return accel + quat.rotate(quat.conj(q), g.expand_as(accel)) - torch.linalg.cross(
            gyro, u)


def _imu_terms(t: Tensor, gyro: Tensor, accel: Tensor, sigmas: tuple[float, float],
               bg0: Tensor, walk, interval, gravity: float) -> list:
    """The Gyro and Accel terms (``sigmas`` theirs, ``gravity`` the magnitude): constant
    biases, or piecewise constant tied by the random walks ``walk`` over segments of about
    ``interval`` seconds."""
    sg, sa = sigmas
    if walk is None:
        return [Gyro(t, gyro, sigma=sg, bias=Free(start=bg0)),
                Accel(t, accel, sigma=sa, bias=True, gravity=gravity)]
    if not isinstance(walk, (tuple, list)) or len(walk) != 2:
        _checks.fail(_FN, f"expected bias_walk to be None or (gyroscope_random_walk, "
                          f"accelerometer_random_walk), got {walk!r}")
    wg, wa = (_positive(f"bias_walk[{i}]", w) for i, w in enumerate(walk))
    edges = segments(float(t[0]), float(t[-1]), _positive("bias_interval", interval))
    k = edges.numel() - 1
    return [WalkGyro(t, gyro, sigma=sg, edges=edges, walk=wg, starts=bg0.expand(k, 3)),
            WalkAccel(t, accel, sigma=sa, edges=edges, walk=wa,
                      starts=torch.zeros(k, 3, dtype=torch.float64), gravity=gravity)]


def _camera_terms(cams, obs, e0, dt0, sigma, rolling, shared, max_offset, max_delay, robust,
                  window) -> list[Reprojections]:
    """One Reprojections term per camera, frames sorted by time and kept where the bounds
    on the offset and line delay keep them inside the trajectory's domain."""
    lo, hi, reach = window
    one = Free(start=float(dt0.mean())) if shared else None
    out = []
    for i, (cam, (t, p, u)) in enumerate(zip(cams, obs, strict=True)):
        order = torch.argsort(t, stable=True)
        t, p, u = t[order], p[order], u[order]
        keep = (t - max_offset >= lo) & (t + max_offset + reach <= hi)
        if int(keep.sum()) == 0:
            _checks.fail(_FN, f"camera {i}: no frame inside the IMU log")
        out.append(Reprojections(
            t[keep], p[keep], u[keep], camera=cam, sigma=sigma,
            extrinsic=Free(start=e0[i]),
            time_offset=one if shared else Free(start=float(dt0[i])),
            line_delay=True if rolling else None, max_time_offset=max_offset,
            max_line_delay=max_delay, robust=robust))
    return out

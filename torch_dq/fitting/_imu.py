r"""The inertial terms: gyroscope and accelerometer readings (body axes) with their biases.

With ``x(t) = (R(t), p(t))`` the trajectory (body to world) and ``t' = t + dt``:
:class:`Gyro` predicts :math:`R^T \omega + b_g` (``omega`` the world angular velocity),
:class:`Accel` the specific force :math:`R^T (a - g) + b_a`. A gyroscope's estimated time
offset without a start comes from cross-correlating angular rates; an estimated gravity
direction without a start from the mean reading.
"""

from __future__ import annotations

import math
import numbers
import warnings

import torch
from torch import Tensor

from .. import _checks, curves, dualquat, quat
from .._kinematics import body_field
from ._charts import Direction, Vector
from ._imu_jacobians import accel_rows, gyro_rows, imu_residuals
from ._nuisance import Slot
from ._terms import (
    Options,
    Poses,
    Term,
    _first_bad,
    _masked,
    _nuisance,
    _sigma,
    _valid_at,
    _vector_data,
)

__all__ = ["Accel", "Gyro", "check_repeated", "degrees_message"]


def check_repeated(fn: str, times: Tensor, mask: Tensor) -> None:
    """Fail where a valid sample repeats the time of the valid one before it (``times`` as
    filled by the term: masked ones carry the largest valid time before them): an inertial
    sensor samples each instant once, and a logger's repeated stamp would count a reading
    twice or put two at one instant, silently."""
    m = _valid_at(mask, times)
    before = (m.cumsum(-1) - m.long()) > 0  # a valid sample earlier in the row
    bad = m[..., 1:] & before[..., 1:] & (times[..., 1:] == times[..., :-1])
    _first_bad(fn, "times must be strictly increasing (an IMU samples each instant once)",
               torch.cat((torch.zeros_like(bad[..., :1]), bad), -1),
               " (its time repeats the sample before: drop the repeated samples, or mask them)")


class _Imu(Term):
    """Shared construction of the inertial terms: readings ``(..., N, 3)``, bias."""

    dim = 3
    _unique_times = True  # False where a subclass adds samples of its own (checked before)
    _bias_kind = "bias"  # a gyroscope's (rad/s) or an accelerometer's (m/s^2): one Free each

    def __init__(self, times, readings, sigma, bias, options: Options) -> None:
        fn = self._fn
        readings = _vector_data(fn, "readings", readings)
        super().__init__([times], ["times"], readings, 1, _sigma(fn, "sigma", sigma, 3),
                         options)
        if self._unique_times:
            check_repeated(fn, self.times, self.mask)
        self._buffer("readings", _masked(readings, options.mask, 0.0), 1)
        self._slots["bias"] = Slot(fn, "bias", Vector(3), bias, kind=self._bias_kind)
        self._units_checked = False  # the readings' units, checked once (first values())
        self._units_pending = False  # a Gyro's check left to the poses (start at rest)

    bias = _nuisance("bias", "The bias ``(..., 3)`` (body axes), added to the ideal reading.")

    _rows_into = True  # residual_jacobians writes its rows into out (Term._rows_into)

    def _inverse_sigmas(self, dtype: torch.dtype) -> Tensor:
        """The whitening ``(..., N, 3)``: the mask over the sigmas (masked rows zero)."""
        return self.mask[..., None].to(dtype) / self.sigma.to(dtype)

    def _whitened(self, rows: Tensor, event: int) -> Tensor:
        """Jacobian ``rows (..., N, 3, *event)`` divided by the sigmas, masked rows zero."""
        scale = self._inverse_sigmas(rows.dtype)
        return rows * scale.reshape(*scale.shape, *[1] * event)

    def _scale(self, x: Tensor) -> Tensor | None:
        """:meth:`_inverse_sigmas` for the closed-form row builders, which multiply as they
        write (no second pass over the rows), where it broadcasts into the samples' shape
        ``x.shape[:-1]``; None where the masks' batch is wider (:meth:`_whitened` after)."""
        scale = self._inverse_sigmas(x.dtype)
        lead = x.shape[:-1]
        return scale if _checks.broadcast_shapes(lead, scale.shape[:-1]) == lead else None

    def _steps(self, names: list[str], p: dict[str, Tensor], toward: dict[str, Tensor],
               ) -> list[Tensor] | None:
        """The nuisance Jacobians ``(..., N, 3, dim)`` from the rows ``toward`` each
        parameter's value ``(..., N, 3, 3)``, times its chart's derivative (a bias's the
        identity, gravity's :meth:`~torch_dq.fitting._charts.Direction.report`); None where
        another parameter or chart is read."""
        out = []
        for name in names:
            chart = self._slots[name].chart
            if name not in toward or not isinstance(chart, (Vector, Direction)):
                return None
            rows = toward[name]
            if isinstance(chart, Direction):
                rows = rows @ chart.report(p[name])  # p: (..., 1, 3), a sample dim
            out.append(self._whitened(rows, 1))
        return out


class Gyro(_Imu):
    r"""Gyroscope readings :math:`R^T \omega + b_g` (body axes, rad/s).

    Args:
        times: ``(N,)`` or ``(B, N)`` times, strictly increasing over the valid samples (a
            repeated stamp is a ValueError).
        readings: ``(..., N, 3)`` angular rates (rad/s, body axes).
        sigma: noise (rad/s), a float or 3.
        bias: ``(3,)`` bias, fixed or estimated (start zero).
        time_offset: estimated without a start: from cross-correlating the measured and the
            trajectory's angular rates over ``[-max_time_offset, max_time_offset]``.
        max_time_offset, robust, robust_k, mask: as :class:`Poses`.

    Warns:
        UserWarning: readings whose mean magnitude is about ``180 / pi`` times the
            trajectory's angular rates (deg/s for rad/s), once, when
            :func:`~torch_dq.fitting.estimate` starts (the first :meth:`values`); where
            the start barely turns (an identity or constant start), against the rotation
            rates of the measured poses of a :class:`~torch_dq.fitting.Poses` term
            (:meth:`check_units_against`).
    """

    order = 1
    _fn = "fitting.Gyro"
    _bias_kind = "gyroscope bias"

    def __init__(self, times: Tensor, readings: Tensor, *, sigma, bias=None,
                 time_offset=None, max_time_offset: float = 0.1, robust: str | None = None,
                 robust_k: float | None = None, mask: Tensor | None = None) -> None:
        super().__init__(times, readings, sigma, bias,
                         Options(time_offset, max_time_offset, robust, robust_k, mask))

    def _residual(self, ev, p):
        x, dx = ev[0][:2]
        compiled = imu_residuals(x, dx, None, None, p["bias"], self.readings)
        if compiled is not None:
            return compiled
        w = body_field(x, dx, None, 0)  # kinematics(x, dx, frame="body").angular_velocity
        return w + p["bias"] - self.readings.to(w.dtype)

    def residual_jacobians(self, derivs: list[tuple[Tensor, ...]], p: dict[str, Tensor],
                           nuisance: list[str], r: Tensor | None = None,
                           out: Tensor | None = None) -> tuple[Tensor, list[Tensor]] | None:
        """Closed form (``torch_dq.fitting._imu_jacobians.gyro_rows``; the rows written into
        ``out`` where given, as there)."""
        x, dx = derivs[0][:2]
        eye = torch.eye(3, dtype=x.dtype, device=x.device)
        steps = self._steps(nuisance, p, {"bias": eye.expand(*x.shape[:-1], 3, 3)})
        if steps is None:
            return None
        scale = self._scale(x)
        rows = gyro_rows(x, dx, scale, out)
        rows = rows if scale is not None else self._whitened(rows, 2)
        return self.residuals(derivs, p) if r is None else r, [rows, *steps]

    def values(self, trajectory, ctrl: Tensor | None = None) -> dict[str, Tensor]:
        """As :meth:`Term.values`; the first call (``estimate`` makes it at its start) also
        warns when the readings look like deg/s (``_warn_degrees``)."""
        if not self._units_checked:
            self._units_checked = True
            self._units_pending = not _warn_degrees(self, trajectory, ctrl)
        return super().values(trajectory, ctrl)

    def check_units_against(self, terms: list[Term]) -> None:
        """Where the start barely turned (an identity or constant start tells nothing of the
        readings' units), the deg/s check of :meth:`values` against the rotation rates of
        the measured poses instead (``_poses_rate``; the first
        :class:`~torch_dq.fitting.Poses` term of ``terms`` that has them), if any."""
        if not self._units_pending:
            return
        self._units_pending = False
        rates = [r for r in (_poses_rate(t) for t in terms if isinstance(t, Poses)) if r]
        if rates:
            message = degrees_message(self, None, rates=(rates[0], _mean_reading(self)),
                                      source="the measured poses'")
            if message:
                warnings.warn(message, UserWarning, stacklevel=3)

    def default_start(self, name, trajectory, ctrl, values):
        if name != "time_offset":
            return super().default_start(name, trajectory, ctrl, values)
        return _correlate_offset(self, trajectory, ctrl)


_DEGREES = 180.0 / math.pi  # readings in deg/s are this many times those in rad/s
_UNITS_SAMPLES = 1 << 12  # samples the units check reads at most (a mean: 4096 do)


def _warn_degrees(term: Gyro, trajectory, ctrl) -> bool:
    """Warn with :func:`degrees_message`'s message, if any; False where the trajectory
    barely turns (the check could not tell)."""
    rates = (_trajectory_rate(term, trajectory, ctrl), _mean_reading(term))
    message = degrees_message(term, trajectory, ctrl, rates)
    if message:
        warnings.warn(message, UserWarning, stacklevel=4)
    return rates[0] > _TURNING


_TURNING = 1e-3  # rad/s: a trajectory turning slower than this tells nothing of deg/s


def degrees_message(term: Gyro, trajectory, ctrl=None, rates: tuple[float, float] | None = None,
                    source: str = "the trajectory's") -> str | None:
    """The message saying that ``term``'s readings look like deg/s, or None: where their
    mean magnitude is within a factor 1.5 of ``180 / pi`` times the trajectory's (its
    angular rates at the samples' times, clamped into its domain; None where it barely
    turns, below 1e-3 rad/s). The one deg/s check of the library's terms and of ``python
    -m torch_dq fit --imu``. ``rates``: the reference and the readings' mean magnitudes
    where already known (``source`` names the reference), else computed."""
    if rates is None:
        rates = (_trajectory_rate(term, trajectory, ctrl), _mean_reading(term))
    pred, meas = rates
    if pred > _TURNING and _DEGREES / 1.5 < meas / pred < 1.5 * _DEGREES:
        return (f"{term._fn}: the readings look like deg/s, not rad/s: their mean magnitude "
                f"{meas:.4g} is {meas / pred:.3g} times {source} angular rate "
                f"{pred:.4g} rad/s (180/pi = 57.3); convert them with torch.deg2rad")
    return None


def _strided(term: Gyro) -> tuple[Tensor, Tensor, Tensor]:
    """Times, mask and readings at ``_UNITS_SAMPLES`` evenly strided samples at most: the
    units checks need mean magnitudes, not every sample (their memory stays that of a short
    record)."""
    stride = -(-term.N // _UNITS_SAMPLES)
    return (term.times[..., ::stride], term.mask[..., ::stride],
            term.readings[..., ::stride, :])


def _mean_reading(term: Gyro) -> float:
    """The readings' mean magnitude over the unmasked (strided) samples."""
    _, mask, readings = _strided(term)
    w = mask.to(torch.float64)
    return float((readings.norm(dim=-1).to(torch.float64) * w).sum() / w.sum())


def _trajectory_rate(term: Gyro, trajectory, ctrl) -> float:
    """The mean magnitude of the trajectory's angular rate at the term's (strided,
    unmasked) samples' times, clamped into its domain."""
    t, mask, _ = _strided(term)
    lo, hi = (torch.as_tensor(e, dtype=torch.float64, device=t.device)
              for e in trajectory.domain)
    t = torch.minimum(torch.maximum(t, lo[..., None] if lo.dim() else lo),
                      hi[..., None] if hi.dim() else hi)
    with torch.no_grad():
        x, dx = trajectory.derivatives(t, 1, ctrl=None if ctrl is None else ctrl.detach())
        rate = curves.kinematics(x, dx, frame="body").angular_velocity.to(torch.float64)
    w = mask.to(torch.float64)
    return float((rate.norm(dim=-1) * w).sum() / w.expand(rate.shape[:-1]).sum())


def _poses_rate(term: Poses) -> float | None:
    """The mean angular rate (rad/s) of ``term``'s measured rotations between consecutive
    unmasked samples at distinct times (``|Log(R_i^T R_(i+1))| / (t_(i+1) - t_i)``; a
    sensor mount does not change it), or None where there are no such pairs."""
    keep = term.mask.reshape(-1, term.N)[0] if term.times.dim() == 1 else term.mask[0]
    t = (term.times if term.times.dim() == 1 else term.times[0])[keep].to(torch.float64)
    q = term.rotations.reshape(-1, term.N, 4)[0][keep].to(torch.float64)
    dt = t[1:] - t[:-1]
    ok = dt > 0
    if not bool(ok.any()):
        return None
    angle = quat.to_rotvec(quat.mul(quat.conj(q[:-1]), q[1:])).norm(dim=-1)
    return float((angle[ok] / dt[ok]).mean())


def _correlate_offset(term: Gyro, trajectory, ctrl) -> Tensor:
    """Time offset maximising the correlation of the measured and predicted body angular
    rates (each axis centred: free of the bias): the prediction on a grid of ``max / 20``
    spacing, interpolated at the shifted sample times for 81 offsets, the best refined by a
    parabola."""
    m = term.max_time_offset
    like = torch.empty((), dtype=torch.float64, device=term.sigma.device)
    if m == 0.0:
        return like.new_zeros(())
    t, meas, valid = term.times, term.readings, term.mask.to(torch.float64)
    lo, hi = (torch.as_tensor(e, dtype=torch.float64, device=t.device)
              for e in trajectory.domain)  # per trajectory for per-trajectory knots
    a, b = torch.maximum(lo, t.amin(-1) - m), torch.minimum(hi, t.amax(-1) + m)
    size = max(2, int(float(((b - a) / (m / 20.0)).max())) + 2)
    g = a[..., None] + (b - a)[..., None] * torch.linspace(0.0, 1.0, size, dtype=torch.float64,
                                                          device=t.device)
    a, b = a[..., None, None], b[..., None, None]
    with torch.no_grad():
        x, dx = trajectory.derivatives(g, 1, ctrl=None if ctrl is None else ctrl.detach())
        rate = curves.kinematics(x, dx, frame="body").angular_velocity.to(torch.float64)
    offsets = torch.linspace(-m, m, 81, dtype=torch.float64, device=t.device)
    step = g[..., 1:2, None] - g[..., :1, None]
    w = valid[..., None, None, :]
    v = _centred(meas.transpose(-1, -2)[..., None, :, :], w)

    def shifted(o: Tensor) -> Tensor:  # grid positions (..., O, N) of the shifted samples
        return (torch.minimum(torch.maximum(t[..., None, :] + o[:, None], a), b) - a) / step

    # offsets in chunks of 9: the (..., 9, 3, N) temporaries stay small for long IMU logs
    corr = torch.cat([_correlation(_interpolate(rate, shifted(o)), v, w)
                      for o in offsets.split(9)], -1)
    k = corr.argmax(-1).clamp(1, 79)
    c0, c1, c2 = (corr.gather(-1, (k + d)[..., None])[..., 0] for d in (-1, 0, 1))
    denom = c0 - 2 * c1 + c2
    frac = torch.where(denom < 0, 0.5 * (c0 - c2) / denom.clamp(max=-1e-300), 0.0)
    return (offsets[k] + frac.clamp(-1, 1) * (offsets[1] - offsets[0])).clamp(-m, m)


def _interpolate(rate: Tensor, s: Tensor) -> Tensor:
    """``rate (..., G, 3)`` linearly interpolated at grid positions ``s (..., O, N)``:
    ``(..., O, 3, N)``."""
    lead = _checks.broadcast_shapes(rate.shape[:-2], s.shape[:-2])  # shared times: s (O, N)
    s = s.expand(*lead, *s.shape[-2:])
    j = s.floor().clamp(0, rate.shape[-2] - 2)
    fr = (s - j)[..., None]
    j = j.long()[..., None]  # (..., O, N, 1): rate gathered per sample
    r = rate[..., None, :, :].expand(*s.shape[:-1], rate.shape[-2], 3)
    pred = torch.take_along_dim(r, j, -2) * (1 - fr) + torch.take_along_dim(r, j + 1, -2) * fr
    return pred.transpose(-1, -2)


def _centred(v: Tensor, w: Tensor) -> Tensor:
    """``v`` minus its ``w``-weighted mean over the last dim, times ``w``."""
    return (v - (v * w).sum(-1, keepdim=True) / w.sum(-1, keepdim=True)) * w


def _correlation(pred: Tensor, v: Tensor, w: Tensor) -> Tensor:
    """Correlation ``(..., O)`` of the centred predictions ``pred (..., O, 3, N)`` with the
    centred measurements ``v``."""
    u = _centred(pred, w)
    return (u * v).sum((-1, -2)) / ((u * u).sum((-1, -2)) * (v * v).sum((-1, -2))).sqrt(
    ).clamp_min(1e-300)


class Accel(_Imu):
    r"""Accelerometer readings (specific force) :math:`R^T (a - g) + b_a` (body axes).

    Args:
        times: ``(N,)`` or ``(B, N)`` times, strictly increasing over the valid samples (a
            repeated stamp is a ValueError).
        readings: ``(..., N, 3)`` specific forces (body axes, e.g. m/s²).
        sigma: noise, a float or 3.
        bias: ``(3,)`` bias, fixed or estimated (start zero).
        gravity: a fixed ``(3,)`` world vector (default ``(0, 0, -9.81)``); a float
            magnitude (or a 0-d tensor): its direction is estimated, started from the mean
            reading rotated to world axes by the trajectory (:math:`g \approx
            -\overline{R f}`); or a
            :class:`~torch_dq.fitting.Free` with a ``(3,)`` start (its norm is kept; the
            mean-reading direction replaces it where that explains the readings better,
            the bias absorbed: from a start far off, e.g. 90 deg, Gauss-Newton can end in
            the flipped-gravity local minimum).
        time_offset, max_time_offset, robust, robust_k, mask: as :class:`Poses`.

    Warns:
        UserWarning: readings whose mean magnitude is about ``|gravity| / 9.80665`` (g for
            m/s²) or ``1000 |gravity| / 9.80665`` (milli-g), once, when
            :func:`~torch_dq.fitting.estimate` starts.
    """

    order = 2
    _fn = "fitting.Accel"
    _bias_kind = "accelerometer bias"

    def __init__(self, times: Tensor, readings: Tensor, *, sigma, bias=None,
                 gravity=(0.0, 0.0, -9.81), time_offset=None, max_time_offset: float = 0.1,
                 robust: str | None = None, robust_k: float | None = None,
                 mask: Tensor | None = None) -> None:
        fn = self._fn
        super().__init__(times, readings, sigma, bias,
                         Options(time_offset, max_time_offset, robust, robust_k, mask))
        self._magnitude: float | None = None
        if isinstance(gravity, Tensor) and gravity.dim() == 0:  # a magnitude, as a float is
            gravity = float(gravity)
        if isinstance(gravity, numbers.Real) and not isinstance(gravity, bool):
            if not (math.isfinite(gravity) and float(gravity) > 0):
                _checks.fail(fn, f"a gravity magnitude must be positive and finite, got "
                                 f"{gravity!r}")
            self._magnitude = float(gravity)
            gravity = True
        elif isinstance(gravity, (tuple, list)):
            gravity = torch.tensor(gravity, dtype=torch.float64)
        if gravity is None or gravity is False:
            _checks.fail(fn, "gravity is required: a (3,) vector, a float magnitude or "
                             "fitting.Free")
        self._slots["gravity"] = Slot(fn, "gravity", Direction(), gravity)

    gravity = _nuisance("gravity", "Gravity ``(..., 3)`` in world axes (fixed or estimated).")

    def values(self, trajectory, ctrl: Tensor | None = None) -> dict[str, Tensor]:
        """As :meth:`Term.values`; an estimated gravity with the caller's start (before any
        estimate) starts instead from the mean reading where that explains the readings
        better (``_better_gravity``)."""
        out = super().values(trajectory, ctrl)
        free = self._slots["gravity"].free
        if free is not None and free.start is not None and free.value is None:
            out["gravity"] = _better_gravity(self, trajectory, ctrl, out)
        if not self._units_checked:
            self._units_checked = True
            _warn_g_units(self, out["gravity"])
        return out

    def default_start(self, name, trajectory, ctrl, values):
        if name != "gravity":
            return super().default_start(name, trajectory, ctrl, values)
        with torch.no_grad():
            c = ctrl if ctrl is None else ctrl.detach()
            x = trajectory(self.times + values["time_offset"][..., None], ctrl=c)
            q = dualquat.to_rt(x)[0].to(torch.float64)
            f = quat.rotate(q, self.readings - values["bias"][..., None, :])
            w = self.mask[..., None].to(f.dtype)
            mean = (f * w).sum(-2) / w.sum(-2)
        magnitude = 9.81 if self._magnitude is None else self._magnitude
        return -magnitude * mean / mean.norm(dim=-1, keepdim=True)

    def _residual(self, ev, p):
        x, dx, ddx = ev[0][:3]
        compiled = imu_residuals(x, dx, ddx, p["gravity"], p["bias"], self.readings)
        if compiled is not None:
            return compiled
        a = body_field(x, dx, ddx, 3)  # kinematics(..., frame="body").linear_acceleration
        q = x[..., :4]  # the rotation (dualquat.to_rt's, without its translation)
        g = quat.rotate(quat.conj(q), p["gravity"].expand(*q.shape[:-1], 3))
        return a - g + p["bias"] - self.readings.to(g.dtype)

    def residual_jacobians(self, derivs: list[tuple[Tensor, ...]], p: dict[str, Tensor],
                           nuisance: list[str], r: Tensor | None = None,
                           out: Tensor | None = None) -> tuple[Tensor, list[Tensor]] | None:
        """Closed form (``torch_dq.fitting._imu_jacobians.accel_rows``; ``out`` as
        :meth:`Gyro.residual_jacobians`)."""
        x, dx, ddx = derivs[0][:3]
        gravity = p["gravity"].to(x.dtype)
        scale = self._scale(x)
        rows, toward_g = accel_rows(x, dx, ddx, gravity, scale, out)
        eye = torch.eye(3, dtype=x.dtype, device=x.device)
        steps = self._steps(nuisance, p, {"bias": eye.expand(*x.shape[:-1], 3, 3),
                                          "gravity": toward_g})
        if steps is None:
            return None
        rows = rows if scale is not None else self._whitened(rows, 2)
        return self.residuals(derivs, p) if r is None else r, [rows, *steps]


_STANDARD_GRAVITY = 9.80665  # m/s^2 per g


def _warn_g_units(term: Accel, gravity: Tensor) -> None:
    """Warn when the readings look like g or milli-g, not m/s^2: their mean magnitude
    within a factor 1.5 of ``|gravity| / 9.80665`` (g) or of ``1000 |gravity| / 9.80665``
    (milli-g; a body at rest reads ``|gravity|`` in m/s^2)."""
    w = term.mask.to(torch.float64)
    meas = float((term.readings.norm(dim=-1).to(torch.float64) * w).sum() / w.sum())
    g = float(gravity.detach().to(torch.float64).norm(dim=-1).mean())
    ratio = g / meas if meas > 0 else math.inf
    for unit, per_g in (("g", 1.0), ("milli-g", 1e3)):
        factor = _STANDARD_GRAVITY / per_g  # m/s^2 per unit
        if factor / 1.5 < ratio < 1.5 * factor:
            warnings.warn(f"{term._fn}: the readings look like {unit}, not m/s^2: their mean "
                          f"magnitude {meas:.4g} is {1 / ratio:.4g} times gravity's {g:.4g} "
                          f"m/s^2; multiply them by {factor:.6g}", UserWarning, stacklevel=4)


def _better_gravity(term: Accel, trajectory, ctrl, values: dict[str, Tensor]) -> Tensor:
    """Per trajectory, the caller's gravity start or the mean-reading one
    (:meth:`Accel.default_start`, the caller's norm), whichever leaves the smaller sum of
    squared whitened residuals with the bias absorbed (each axis centred). Gauss-Newton on
    the sphere started far from the readings' direction (90 deg) can step past the horizon
    into the flipped-gravity local minimum when the bias is estimated: the bias absorbs the
    mean of the readings, and what is left to tell gravity's sign is the tilt's variation."""
    given = values["gravity"].to(torch.float64)
    alt = term.default_start("gravity", trajectory, ctrl, values)
    alt = alt * (given.norm(dim=-1, keepdim=True) / alt.norm(dim=-1, keepdim=True))
    c = None if ctrl is None else ctrl.detach()
    w = term.mask[..., None].to(torch.float64)
    costs = []
    with torch.no_grad():
        for g in (given, alt):
            r = term.evaluate(trajectory, c, {**values, "gravity": g}).to(torch.float64)
            mean = (r * w).sum(-2, keepdim=True) / w.sum(-2, keepdim=True).clamp_min(1.0)
            costs.append(((r - mean) * w).square().sum((-1, -2)))
    return torch.where((costs[1] < costs[0])[..., None], alt, given)


for _cls in (Gyro, Accel):  # help(Gyro.__init__): the args
    _cls.__init__.__doc__ = _cls.__doc__
del _cls

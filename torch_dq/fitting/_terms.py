r"""Measurement terms: timestamped data of one sensor, its noise and nuisance parameters.

Each term is a :class:`torch.nn.Module`; ``term(trajectory, ctrl=None)`` returns the
whitened residuals ``(..., N, k)`` (predicted minus measured, divided by the sigmas; zero
for masked samples) and ``term.cost(trajectory, ctrl=None)`` the robust cost
:math:`\sum_i \rho(|r_i|)` per batch element (:mod:`torch_dq.fitting`), both
differentiable with respect to the control points, for a torch optimizer loop. With
``x(t) = (R(t), p(t))`` the trajectory (body to world) and ``t' = t + dt`` the sample's
time in the trajectory's clock:

============== ==================================================== =======================
term           prediction                                           residual frame
============== ==================================================== =======================
Poses          ``x(t') e`` (sensor mount ``e``)                     rotation vector of
                                                                    ``R_m^T R R_e`` (sensor
                                                                    axes), translation
                                                                    (world)
Positions      ``R(t') l + p(t')`` (lever arm ``l``)                world
RelativePoses  ``x(t'_from)^-1 x(t'_to)``                           rotation: to-frame,
                                                                    translation: from-frame
Gyro           ``R^T w + b_g``                                      body
Accel          ``R^T (a - g) + b_a``                                body
============== ==================================================== =======================

(the inertial terms :class:`~torch_dq.fitting.Gyro` and :class:`~torch_dq.fitting.Accel` are
in ``torch_dq.fitting._imu``, :class:`~torch_dq.fitting.Reprojections` in
``torch_dq.fitting._camera``).

Times are the trajectory's (float64 absolute timestamps welcome), ``(N,)`` shared by the
batch or ``(B, N)`` of their own; data carry the same leading batch. ``mask`` (bool, the
samples' shape) excludes samples (their data may be NaN, their times are replaced by a
valid one of the row).
"""

from __future__ import annotations

import copy
import functools
import math
import numbers
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from .. import _checks, dualquat, quat
from .._time import MIN_RESOLUTION, time_step, unresolved
from . import _robust
from ._charts import Pose, Scalar, Vector
from ._local import SpanEvaluator
from ._nuisance import Slot

__all__ = ["Options", "Poses", "Positions", "RelativePoses", "Term"]


def _sigma(fn: str, name: str, value, k: int) -> Tensor:
    """``(k,)`` float64 positive standard deviations from a float or ``k`` values."""
    if isinstance(value, bool) or value is None:
        _checks.fail(fn, f"{name} is required: a positive float or {k} of them, got {value!r}")
    try:
        s = torch.as_tensor(value, dtype=torch.float64).detach().cpu()
    except (TypeError, ValueError, RuntimeError):
        _checks.fail(fn, f"{name} must be a positive float or {k} of them, got {value!r}",
                     TypeError)
    if s.dim() > 1 or (s.dim() == 1 and s.shape[0] != k):
        _checks.fail(fn, f"{name} must be a float or a ({k},) tensor, got shape "
                         f"{_checks.shape_str(s.shape)}")
    if not bool(((s > 0) & torch.isfinite(s)).all()):
        _checks.fail(fn, f"{name} must be positive and finite, got {value!r}")
    return s.expand(k).clone()


def _first_index(bad: Tensor) -> tuple[int, ...]:
    """Index of the first True entry of ``bad`` (row-major)."""
    return tuple(int(v) for v in torch.nonzero(bad)[0].tolist())


def _at(i: tuple[int, ...]) -> str:
    return "[" + ", ".join(str(v) for v in i) + "]"


def _first_bad(fn: str, message: str, bad: Tensor, hint: str = "") -> None:
    """Fail with ``message`` naming the first sample where ``bad (..., N)`` holds."""
    if bool(bad.any()):
        i = _first_index(bad)
        where = f"sample {i[-1]}" + (f" of batch element {_at(i[:-1])}" if len(i) > 1 else "")
        _checks.fail(fn, f"{message}: {where} is not{hint}")


def _valid_at(mask: Tensor, t: Tensor) -> Tensor:
    """The samples' ``mask`` at their times ``t (..., N)``, expanded to ``t``'s shape: the
    mask itself where it has ``t``'s dims, else (times shared by a batch of data) whether
    any element of the batch holds the sample."""
    return (mask if t.dim() == mask.dim() else mask.flatten(0, -2).any(0)).expand(t.shape)


def _check_resolution(fn: str, name: str, t: Tensor, valid: Tensor) -> None:
    """Fail when the times' dtype cannot resolve them (:func:`torch_dq._time.unresolved` at
    the largest time and the span: float32 UNIX timestamps round to steps of 128 s)."""
    if valid.sum() < 2:
        return
    v = t[valid].to(torch.float64)
    end, span = float(v.abs().max()), float(v.max() - v.min())
    if bool(unresolved(t.dtype, end, span)):
        _checks.fail(fn, f"{t.dtype} cannot resolve these {name}: its spacing at "
                         f"{end:.6g} is {float(time_step(t.dtype, end)):.3g} (the times' "
                         f"units), more than {MIN_RESOLUTION:g} of their span ({span:.3g} as "
                         f"rounded); pass times as torch.float64")


def _finer_unit(last: float, step: float, imu: bool) -> tuple[str, float] | None:
    """The finer unit that makes the times plausible: the last one a UNIX time (1e8 to 1e10
    s), else the median step an IMU's sampling period (0.2 ms to 0.05 s) or a pose
    sensor's (0.2 ms to 5 s); None where none does."""
    unit = _checks.unix_unit(last)
    if unit:
        return unit
    for name, scale in _checks.TIME_UNITS:
        if 2e-4 <= step * scale <= (0.05 if imu else 5.0):
            return name, scale
    return None


def _check_time_unit(fn: str, name: str, t: Tensor, valid: Tensor, imu: bool) -> None:
    r"""Times that cannot be seconds. A time beyond ``_checks.LATEST`` (1e11 s: UNIX nanoseconds,
    microseconds, milliseconds are 1.8e18, 1.8e15, 1.8e12) fails, naming the likely unit
    (:func:`_finer_unit`); samples a median step of 0.5 s or more apart for an IMU term (IMUs
    sample at 20 Hz to a few kHz), of 1e4 s or more for the others, warn where a finer unit
    gives a sensor's rate (relative nanoseconds: the velocities and the IMU's sigmas would
    be per nanosecond)."""
    v = t[valid].to(torch.float64)
    if v.numel() == 0:
        return
    last = float(v.abs().max())
    step = float(v.sort().values.diff().median()) if v.numel() > 2 else 0.0
    unit = _finer_unit(last, step, imu)
    what = (f"{name} look like {unit[0]}, not seconds" if unit else
            f"{name} cannot be seconds")
    fix = f": pass seconds ({name} * {unit[1]:g})" if unit else ": pass seconds"
    if last >= _checks.LATEST:
        _checks.fail(fn, f"{what}: the latest is {last:.6g} s, {last / 3.156e7:.3g} years"
                         f"{fix}")
    if unit and step >= (0.5 if imu else 1e4):
        warnings.warn(f"{fn}: {what}: the samples lie {step:.3g} s apart (median), "
                      f"{1.0 / (step * unit[1]):.4g} Hz as {unit[0]}{fix}", UserWarning,
                      stacklevel=5)


def _nuisance(name: str, doc: str) -> property:
    """A read-only property: the current value of the term's nuisance parameter ``name``
    (detached; None where the term has none)."""
    return property(lambda self: self._value(name), doc=doc)


@dataclass(frozen=True)
class Options:
    """The keywords every term takes (one object, checked once by :meth:`check`).

    Attributes:
        time_offset: the sensor's clock offset (seconds): None, a float, ``True`` or a
            :class:`~torch_dq.fitting.Free` (see :mod:`torch_dq.fitting`).
        max_time_offset: bound on an estimated offset (seconds, ``>= 0``).
        robust: None, ``"huber"`` or ``"cauchy"`` (case-insensitive).
        robust_k: the kernel's scale (None: the 95 % chi quantile of the residual's size).
        mask: ``(..., N)`` bool, False excludes a sample (None: every sample).
    """

    time_offset: object = None
    max_time_offset: float = 0.1
    robust: str | None = None
    robust_k: float | None = None
    mask: Tensor | None = None

    def check(self, fn: str, dim: int) -> tuple[str | None, float, float]:
        """The kernel, its scale and ``max_time_offset``, checked (errors name ``fn``)."""
        robust, robust_k, max_time_offset = self.robust, self.robust_k, self.max_time_offset
        kernel = robust.lower() if isinstance(robust, str) else robust
        if kernel not in _robust.KERNELS:
            _checks.fail(fn, f"robust must be None, 'huber' or 'cauchy', got {robust!r}")
        if robust_k is None:
            robust_k = _robust.chi_quantile(dim)
        if isinstance(robust_k, bool) or not isinstance(robust_k, numbers.Real) or not (
                math.isfinite(robust_k) and float(robust_k) > 0):
            _checks.fail(fn, f"robust_k must be a positive finite float, got {robust_k!r}")
        if isinstance(max_time_offset, bool) or not isinstance(
                max_time_offset, numbers.Real) or not (math.isfinite(max_time_offset)
                                                       and float(max_time_offset) >= 0):
            _checks.fail(fn, f"max_time_offset must be a finite float >= 0, got "
                             f"{max_time_offset!r}")
        return kernel, float(robust_k), float(max_time_offset)


class Term(torch.nn.Module):
    """Shared machinery of the measurement terms (see the module docstring).

    Subclasses set ``dim`` (residual size), ``order`` (time derivatives they read),
    ``_slots`` (their nuisance parameters) and implement ``_residual``.
    """

    dim = 0
    order = 0
    _fn = "fitting.Term"
    #: whether :meth:`residual_jacobians` takes ``out=``: an ``(..., N, k, O, 8)`` view of a
    #: group's stacked rows (``torch_dq.fitting._linearize``) its rows may be written into
    _rows_into = False

    if TYPE_CHECKING:  # buffers (registered in __init__ and the subclasses)
        mask: Tensor
        sigma: Tensor
        times: Tensor
        rotations: Tensor
        translations: Tensor
        positions: Tensor
        readings: Tensor

    def __init__(self, times: list[Tensor], names: list[str], data: Tensor, event: int,
                 sigma: Tensor, options: Options) -> None:
        """Check and store the samples' times, data, sigmas and the common keywords
        (``options``; called by the subclasses, whose class docstrings describe the
        arguments)."""
        super().__init__()
        self._sample_events: dict[str, int | None] = {}
        fn = self._fn
        self.robust, self.robust_k, self.max_time_offset = options.check(fn, self.dim)
        time_offset, mask = options.time_offset, options.mask
        self._slots: dict[str, Slot] = {"time_offset": Slot(
            fn, "time_offset", Scalar(-self.max_time_offset, self.max_time_offset), time_offset)}
        _checks.tensor(fn, "data", data)
        if data.dim() < 1 + event:
            _checks.fail(fn, f"expected (..., N, ...) data, got {_checks.shape_str(data.shape)}")
        n = data.shape[data.dim() - 1 - event]
        batch = data.shape[:data.dim() - 1 - event]
        for name, t in zip(names, times, strict=True):
            _checks.tensor(fn, name, t)
            if t.dim() not in (1, 2) or t.shape[-1] != n or (t.dim() == 2 and (
                    len(batch) != 1 or t.shape[0] != batch[0])):
                _checks.fail(fn, f"expected {name} of shape ({n},) or (B, {n}) matching the "
                                 f"data {_checks.shape_str(data.shape)}, got "
                                 f"{_checks.shape_str(t.shape)}")
        if mask is None:
            mask = torch.ones(data.shape[:data.dim() - event], dtype=torch.bool,
                              device=data.device)
        elif not isinstance(mask, Tensor) or mask.dtype != torch.bool:
            _checks.fail(fn, f"mask must be a bool tensor, got {mask!r}", TypeError)
        elif mask.shape != data.shape[:data.dim() - event] and mask.shape != (n,):
            _checks.fail(fn, f"mask must have the samples' shape "
                             f"{_checks.shape_str(data.shape[:data.dim() - event])}, got "
                             f"{_checks.shape_str(mask.shape)}")
        mask = mask.expand(data.shape[:data.dim() - event])
        if not bool(mask.any(-1).all()):
            _checks.fail(fn, "mask leaves no sample (in some batch element)")
        finite = torch.isfinite(data.detach()).reshape(*mask.shape, -1).all(-1)
        _first_bad(fn, "the measurements must be finite", mask & ~finite,
                   " (mask the samples that are not)")
        self._buffer("mask", mask.clone(), 0)
        self._buffer("sigma", sigma.to(data.device))
        self._names = list(names)
        for name, t in zip(names, times, strict=True):
            self._buffer(name, self._fill_times(fn, name, t.detach(), mask), 0)
        self.N = n

    def _buffer(self, name: str, value: Tensor, event: int | None = None) -> None:
        """Register buffer ``name``: per sample (``(..., N, *event dims)``, ``event`` the
        number of event dims) or, with ``event=None``, the whole term's. A term whose
        buffers are all registered so can be cut into parts (:meth:`parts`)."""
        self.register_buffer(name, value)
        self._sample_events[name] = event

    def parts(self, size: int) -> list[Term]:
        """The term cut into consecutive parts of at most ``size`` samples: shallow copies
        whose per-sample buffers are views of this term's (the linearisation streams a long
        term a part at a time, its memory bounded by the part). ``[self]`` when the term is
        no longer, or holds a buffer registered without ``_buffer`` (a term defined
        outside the library: its buffers' sample dims are unknown)."""
        if self.N <= size or set(self._buffers) - set(self._sample_events):
            return [self]
        out = []
        for a in range(0, self.N, size):
            part = copy.copy(self)
            part._buffers = dict(self._buffers)
            part.N = min(size, self.N - a)
            for name, event in self._sample_events.items():
                b = self._buffers[name]
                if event is not None and b is not None:
                    part._buffers[name] = b.narrow(b.dim() - 1 - event, a, part.N)
            out.append(part)
        return out

    def _fill_times(self, fn: str, name: str, t: Tensor, mask: Tensor) -> Tensor:
        """Valid times as given; masked ones replaced by the largest valid one before them
        (the first valid one before any), so that sorted times stay sorted. Checks finite
        valid times, non-decreasing for a term with one time argument (pairs of times,
        listed by keyframe or loop closure, may come in any order)."""
        mm = _valid_at(mask, t)
        _first_bad(fn, f"{name} must be finite", mm & ~torch.isfinite(t))
        _check_resolution(fn, name, t, mm)
        _check_time_unit(fn, name, t, mm, self.order >= 1)
        first = torch.where(mm, t, torch.inf).min(-1, keepdim=True).values
        filled = torch.where(mm, t, -torch.inf).cummax(-1).values
        filled = torch.where(mm, t, torch.where(torch.isinf(filled), first, filled))
        if len(self._names) == 1:
            bad = torch.cat((torch.zeros_like(mm[..., :1]),
                             mm[..., 1:] & (t[..., 1:] < filled[..., :-1])), -1)
            if bool(bad.any()):
                i = _first_index(bad)
                row = t[i[:-1]][:i[-1]]
                prev = int(torch.where(mm[i[:-1]][:i[-1]], row, -torch.inf).argmax())
                _checks.fail(fn, f"{name} must be non-decreasing: {name}{_at(i)} = "
                                 f"{t[i].item()!r} is before an earlier one ({row[prev].item()!r}"
                                 f", sample {prev}); sort the samples (torch.argsort of the "
                                 f"times)")
        return filled

    # -- nuisance values
    def _value(self, name: str) -> Tensor | None:
        slot = self._slots.get(name)
        if slot is None:
            return None
        v = slot.value(torch.empty((), dtype=torch.float64, device=self.sigma.device))
        return None if v is None else v.detach()

    time_offset = _nuisance(
        "time_offset",
        "The time offset ``dt`` (seconds; the sample stamped ``t`` is compared with the "
        "trajectory at ``t + dt``): fixed, estimated, its start, or None (default start not yet "
        "computed).")

    def times_list(self) -> list[Tensor]:
        """The samples' times, one ``(N,)`` or ``(B, N)`` tensor per time argument."""
        return [getattr(self, name) for name in self._names]

    def slots(self) -> dict:
        """The nuisance parameters by name (absent, fixed or estimated), a dict of
        ``str -> Slot`` (the resolved argument: ``fixed`` tensor or ``free`` parameter)."""
        return dict(self._slots)

    def default_start(self, name: str, trajectory, ctrl: Tensor | None,
                      values: dict[str, Tensor]) -> Tensor:
        """Start of an estimated parameter without one (zero / identity by default)."""
        like = torch.empty((), dtype=torch.float64, device=self.sigma.device)
        return self._slots[name].identity(like)

    def values(self, trajectory, ctrl: Tensor | None = None) -> dict[str, Tensor]:
        """Current nuisance values by name, default starts computed on ``trajectory``."""
        out: dict[str, Tensor] = {}
        for name in sorted(self._slots, key=lambda s: s != "time_offset"):
            v = self._value(name)
            out[name] = self.default_start(name, trajectory, ctrl, out) if v is None else v
        return out

    # -- parameters that move the samples' times
    def time_rates(self) -> dict[str, Tensor | float]:
        r"""The parameters that move the samples' times, and how: ``dt'_i / d\theta`` per
        present parameter name (a float or ``(..., N)``), ``t'_i = t_i + \sum_\theta \theta
        \, dt'_i/d\theta`` (affine; the same for every time argument). Such a parameter must
        be a ``Scalar`` (``torch_dq.fitting._charts``) that the residual does not read
        otherwise: the solver chains it through the curve's time derivative and widens the
        domain check by what its bounds reach (:meth:`time_reach`). Default: the time offset,
        rate 1."""
        return {"time_offset": 1.0}

    def time_shift(self, p: dict[str, Tensor]) -> Tensor:
        """Shift of the samples' times ``t' - t`` (``(..., N)`` or broadcastable) from the
        per-sample values ``p`` (:meth:`per_sample`) and :meth:`time_rates`."""
        return functools.reduce(torch.add, [p[name] * rate
                                            for name, rate in self.time_rates().items()])

    def time_reach(self) -> tuple[Tensor, Tensor]:
        """Lowest and highest :meth:`time_shift` ``(..., N)`` (float64) over the estimated
        time parameters' bounds (their charts'), the others at their values (exact: the
        shift is affine in them)."""
        like = torch.empty((), dtype=torch.float64, device=self.sigma.device)
        lo = hi = like.new_zeros(())
        for name, rate in self.time_rates().items():
            slot = self._slots[name]
            chart = slot.chart
            if not isinstance(chart, Scalar):
                _checks.fail(self._fn, f"{name} moves the samples' times (time_rates): its "
                                       f"chart must be a Scalar, got {chart.describe()}",
                             TypeError)
            if slot.estimated:
                r = torch.as_tensor(rate, dtype=torch.float64, device=like.device)
                a, b = chart.low * r, chart.high * r
                lo, hi = lo + torch.minimum(a, b), hi + torch.maximum(a, b)
            else:
                v = slot.value(like)
                part = (slot.identity(like) if v is None else v)[..., None] * rate
                lo, hi = lo + part, hi + part
        return lo, hi

    def solved(self, trajectory) -> Tensor:
        """Called by :func:`~torch_dq.fitting.estimate` at the solution (the terms' values
        set): the samples that :attr:`~torch_dq.fitting.Estimate.chi2` and ``dof`` count
        ``(..., N)`` bool, the unmasked ones by default
        (:class:`~torch_dq.fitting.Reprojections` leaves out, counts and warns of its
        observations without an image)."""
        return self.mask

    # -- residuals
    def _residual(self, ev: list[tuple[Tensor, ...]], p: dict[str, Tensor]) -> Tensor:
        raise NotImplementedError

    def seen(self, derivs: list[tuple[Tensor, ...]], p: dict[str, Tensor]) -> Tensor | None:
        """``(..., N)`` bool: the unmasked samples with a prediction at these derivatives
        and values (as ``residuals``), for a term whose residual is zero where there is
        none; None (the default): every sample has one. Levenberg-Marquardt rejects a step
        that loses one (it would lower the cost by the residual it hides)."""
        return None

    def residual_jacobians(self, derivs: list[tuple[Tensor, ...]], p: dict[str, Tensor],
                           nuisance: list[str], r: Tensor | None = None,
                           ) -> tuple[Tensor, list[Tensor]] | None:
        """Whitened residuals and their Jacobians in closed form, or None (the default: the
        linearisation differentiates :meth:`residuals` by a reverse pass).

        Args:
            derivs: as :meth:`residuals` (the derivatives ``0 .. order``, ``(..., N, 8)``).
            p: per-sample values (:meth:`per_sample`).
            nuisance: the estimated parameters the residual reads, in order.
            r: the whitened residuals at ``(derivs, p)`` where known (a trial's cost
                evaluated them at this point), returned as they are; None: evaluated.

        Returns:
            ``r (..., N, k)`` and the Jacobians with respect to each time argument's
            derivatives ``(..., N, k, order + 1, 8)``, then to each ``nuisance`` parameter's
            chart step ``(..., N, k, dim)`` (masked samples' rows zero).
        """
        return None

    def residuals(self, derivs: list[tuple[Tensor, ...]], p: dict[str, Tensor]) -> Tensor:
        """Whitened residuals ``(..., N, k)`` from the trajectory's derivatives at the
        samples' times (one tuple per time argument) and per-sample nuisance values."""
        r = self._residual(derivs, p)
        r = r / self.sigma.to(r.dtype)
        return torch.where(self.mask[..., None], r, 0.0)

    def per_sample(self, values: dict[str, Tensor]) -> dict[str, Tensor]:
        """Values by name with a sample dim inserted before their charts' event dims."""
        return {k: self._slots[k].chart.per_sample(v) for k, v in values.items()}

    def forward(self, trajectory, ctrl: Tensor | None = None) -> Tensor:
        """Whitened residuals ``(..., N, k)`` of the trajectory (or of ``ctrl`` predicted
        control points used with it, as ``trajectory(t, ctrl=...)``)."""
        return self.evaluate(trajectory, ctrl, self.values(trajectory, ctrl))

    def evaluate(self, trajectory, ctrl: Tensor | None, values: dict[str, Tensor]) -> Tensor:
        """Whitened residuals with the nuisance ``values`` (by name, batch first), the
        trajectory read at ``(t - origin) + shift`` (as the estimation reads it)."""
        like = trajectory.control_points if ctrl is None else ctrl
        p = self.per_sample({k: v.to(like.dtype) for k, v in values.items()})
        since = SpanEvaluator(trajectory).since_origin  # exact at UNIX stamps
        derivs = [trajectory.derivatives(since(t, self.time_shift(p)), self.order, ctrl=ctrl,
                                         since_origin=True) for t in self.times_list()]
        return self.residuals(derivs, p)

    def cost(self, trajectory, ctrl: Tensor | None = None) -> Tensor:
        """Robust cost :math:`\\sum_i \\rho(|r_i|)` per batch element ``(...)``."""
        r = self(trajectory, ctrl)
        return _robust.rho(self.robust, r.norm(dim=-1), self.robust_k).sum(-1)


def _pose_data(fn: str, name: str, poses: Tensor) -> tuple[Tensor, Tensor | None]:
    """``(..., N, 8)`` dual quaternions from dual quaternions or matrices, and the matrices
    (None for dual quaternions), detached."""
    _checks.tensor(fn, name, poses)
    if poses.dim() >= 3 and tuple(poses.shape[-2:]) == (4, 4):
        return dualquat.from_matrix(poses.detach()), poses.detach()
    if poses.dim() < 2 or poses.shape[-1] != 8:
        _checks.fail(fn, f"expected (..., N, 8) dual quaternions or (..., N, 4, 4) matrices "
                         f"for {name}, got shape {_checks.shape_str(poses.shape)}")
    return poses.detach(), None


# Defect of a rigid 4x4 matrix accepted (max |R^T R - I|, |det R - 1| and the last row's
# distance from (0, 0, 0, 1)): poses written with 6 significant digits (KITTI's format)
# are off by ~1e-6, a matrix that is not a pose (scaled, reflected, transposed) by far more.
_RIGID_ATOL = 1e-4


def check_pose_data(fn: str, name: str, x: Tensor, T: Tensor | None, mask: Tensor) -> None:
    """Fail naming the first valid sample whose pose is not one: a matrix that is not rigid
    (rotation block not orthonormal or with determinant -1, last row not ``(0, 0, 0, 1)``:
    a transposed matrix), a zero rotation quaternion (a dropped frame written as zeros)."""
    if T is not None:
        M = T.to(torch.float64)
        R = M[..., :3, :3]
        eye = torch.eye(3, dtype=torch.float64, device=M.device)
        last = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64, device=M.device)
        checks = (((R.mT @ R - eye).abs().amax((-1, -2)), "a rotation block R with R^T R = I"),
                  ((torch.linalg.det(R) - 1.0).abs(), "a rotation block of det +1 (a "
                                                      "reflection)"),
                  ((M[..., 3, :] - last).abs().amax(-1), "a last row (0, 0, 0, 1) (a "
                                                         "transposed matrix?)"))
        for defect, what in checks:
            _first_bad(fn, f"{name} must be rigid 4x4 matrices [[R, t], [0, 1]]",
                       mask & ~(defect <= _RIGID_ATOL), f" ({what}, to {_RIGID_ATOL:g})")
    norm = x[..., :4].norm(dim=-1)
    _first_bad(fn, f"{name} must have non-zero rotation quaternions", mask & ~(norm > 0),
               " (a dropped frame written as zeros? mask it)")


def _vector_data(fn: str, name: str, x: Tensor) -> Tensor:
    """``x`` checked as ``(..., N, 3)`` samples (detached)."""
    _checks.tensor(fn, name, x, 3)
    if x.dim() < 2:
        _checks.fail(fn, f"expected (..., N, 3) {name}, got {_checks.shape_str(x.shape)}")
    return x.detach()


def _masked(x: Tensor, mask: Tensor | None, fill: Tensor | float) -> Tensor:
    """``x (..., N, k)`` with the masked-out samples replaced by ``fill`` (harmless values)."""
    return x if mask is None else torch.where(mask[..., None], x, fill)


def _rotation_residual(q_meas: Tensor, q: Tensor) -> Tensor:
    """Rotation vector of ``R_m^T R`` (in ``q``'s frame)."""
    return quat.to_rotvec(quat.mul(quat.conj(q_meas.to(q.dtype)), q))


class _PoseTerm(Term):
    """A term measuring poses: rotation residual (radians) then translation difference."""

    dim = 6

    def _store_poses(self, times: list[Tensor], names: list[str], poses: Tensor, rot_sigma,
                     trans_sigma, options: Options) -> None:
        """Validate ``poses`` and the two sigmas, set up the term, keep the measured poses
        (normalized; masked samples replaced by the identity) as ``rotations`` and
        ``translations``."""
        fn = self._fn
        x, T = _pose_data(fn, "poses", poses)
        sigma = torch.cat((_sigma(fn, "rot_sigma", rot_sigma, 3),
                           _sigma(fn, "trans_sigma", trans_sigma, 3)))
        Term.__init__(self, times, names, x, 1, sigma, options)
        check_pose_data(fn, "poses", x, T, self.mask)
        safe = _masked(x, options.mask, dualquat.identity(dtype=x.dtype, device=x.device))
        q, t = dualquat.to_rt(dualquat.normalize(safe))
        self._buffer("rotations", q, 1)
        self._buffer("translations", t, 1)

    def _pose_residual(self, x: Tensor) -> Tensor:
        q, t = dualquat.to_rt(x)
        return torch.cat((_rotation_residual(self.rotations, q),
                          t - self.translations.to(t.dtype)), dim=-1)


class Poses(_PoseTerm):
    r"""Poses of a sensor mounted on the body at ``extrinsic`` ``e``: :math:`x(t) e`.

    Args:
        times: ``(N,)`` or ``(B, N)`` times (the trajectory's).
        poses: ``(..., N, 8)`` dual quaternions or ``(..., N, 4, 4)`` matrices (sensor to
            world); normalized on construction (:func:`~torch_dq.dualquat.normalize`).
        rot_sigma: rotation noise (radians), a float or 3 (sensor axes).
        trans_sigma: translation noise (length), a float or 3 (world axes).
        extrinsic: ``(8,)`` sensor mount (None: identity), fixed or estimated.
        time_offset: the sensor's clock offset (seconds), see :mod:`torch_dq.fitting`.
        max_time_offset: bound on an estimated offset (seconds).
        robust: None, ``"huber"`` or ``"cauchy"``; robust_k: its scale (default 3.5485).
        mask: ``(..., N)`` bool, False excludes a sample.

    Residual ``(..., N, 6)``: the rotation vector of :math:`R_m^T R(t) R_e` (sensor axes,
    radians) over ``rot_sigma``, then the translation of :math:`x(t) e` minus the measured
    one (world axes) over ``trans_sigma``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> t = torch.linspace(0.0, 1.0, 5, dtype=torch.float64)
        >>> term = Poses(t, dq.identity((5,), dtype=torch.float64), rot_sigma=0.01,
        ...              trans_sigma=0.001)
    """

    _fn = "fitting.Poses"

    def __init__(self, times: Tensor, poses: Tensor, *, rot_sigma, trans_sigma,
                 extrinsic=None, time_offset=None, max_time_offset: float = 0.1,
                 robust: str | None = None, robust_k: float | None = None,
                 mask: Tensor | None = None) -> None:
        self._store_poses([times], ["times"], poses, rot_sigma, trans_sigma,
                          Options(time_offset, max_time_offset, robust, robust_k, mask))
        self._slots["extrinsic"] = Slot(self._fn, "extrinsic", Pose(), extrinsic)

    extrinsic = _nuisance(
        "extrinsic",
        "The sensor mount ``e`` ``(..., 8)`` (body to sensor pose on the body).")

    def _residual(self, ev, p):
        x = ev[0][0]
        if self._slots["extrinsic"].present:
            x = dualquat.mul(x, p["extrinsic"])
        return self._pose_residual(x)


class Positions(Term):
    r"""Positions of a point fixed on the body at ``lever_arm`` ``l`` (body axes), seen in
    world axes (GNSS antenna, mocap marker): :math:`R(t) l + p(t)`.

    Args:
        times: ``(N,)`` or ``(B, N)`` times.
        positions: ``(..., N, 3)`` measured positions (world axes).
        sigma: noise (length), a float or 3 (world axes).
        lever_arm: ``(3,)`` (None: the body origin), fixed or estimated.
        time_offset, max_time_offset, robust, robust_k, mask: as :class:`Poses`.

    Residual ``(..., N, 3)``: predicted minus measured position over ``sigma``.
    """

    dim = 3
    _fn = "fitting.Positions"

    def __init__(self, times: Tensor, positions: Tensor, *, sigma, lever_arm=None,
                 time_offset=None, max_time_offset: float = 0.1, robust: str | None = None,
                 robust_k: float | None = None, mask: Tensor | None = None) -> None:
        fn = self._fn
        positions = _vector_data(fn, "positions", positions)
        super().__init__([times], ["times"], positions, 1, _sigma(fn, "sigma", sigma, 3),
                         Options(time_offset, max_time_offset, robust, robust_k, mask))
        self._buffer("positions", _masked(positions, mask, 0.0), 1)
        self._slots["lever_arm"] = Slot(fn, "lever_arm", Vector(3), lever_arm)

    lever_arm = _nuisance("lever_arm", "The lever arm ``l`` ``(..., 3)`` in body axes.")

    def _residual(self, ev, p):
        q, t = dualquat.to_rt(ev[0][0])
        pred = t + quat.rotate(q, p["lever_arm"].expand(*q.shape[:-1], 3)) \
            if self._slots["lever_arm"].present else t
        return pred - self.positions.to(t.dtype)


class RelativePoses(_PoseTerm):
    r"""Relative poses (odometry) :math:`x(t_{from})^{-1} x(t_{to})`.

    Args:
        times_from, times_to: ``(N,)`` or ``(B, N)`` times of each pair (in any order;
            the two times of a valid pair differ).
        poses: ``(..., N, 8)`` or ``(..., N, 4, 4)`` measured relative poses (to-frame in
            from-frame); normalized on construction.
        rot_sigma: rotation noise (radians; to-frame axes); trans_sigma: translation noise
            (from-frame axes).
        time_offset, max_time_offset, robust, robust_k, mask: as :class:`Poses`.

    Residual ``(..., N, 6)``: rotation vector of :math:`R_m^T R_{rel}` (to-frame) over
    ``rot_sigma``, translation difference in from-frame axes over ``trans_sigma``.
    """

    _fn = "fitting.RelativePoses"

    def __init__(self, times_from: Tensor, times_to: Tensor, poses: Tensor, *, rot_sigma,
                 trans_sigma, time_offset=None, max_time_offset: float = 0.1,
                 robust: str | None = None, robust_k: float | None = None,
                 mask: Tensor | None = None) -> None:
        self._store_poses([times_from, times_to], ["times_from", "times_to"], poses, rot_sigma,
                          trans_sigma, Options(time_offset, max_time_offset, robust, robust_k,
                                               mask))
        a, b = self.times_list()
        _first_bad(self._fn, "times_from and times_to must differ (a pair at one instant "
                             "predicts the identity whatever the trajectory)",
                   _valid_at(self.mask, a) & (a == b),
                   " (mask it, or check the time columns)")

    def _residual(self, ev, p):
        return self._pose_residual(dualquat.mul(dualquat.conj(ev[0][0]), ev[1][0]))


for _cls in (Poses, Positions, RelativePoses):  # help(Poses.__init__): the args
    _cls.__init__.__doc__ = _cls.__doc__
del _cls

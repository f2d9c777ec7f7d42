r"""Nuisance parameters of the measurement terms: absent, fixed or estimated (:class:`Free`).

Every nuisance argument of a term (``extrinsic``, ``lever_arm``, ``bias``, ``gravity``,
``time_offset``; a camera's ``target``, ``intrinsics``, ``line_delay``) is resolved into a
:class:`Slot`: ``None`` / ``False`` absent (identity or zero), a tensor or float fixed,
``True`` / ``"estimate"`` estimated from a default start, a :class:`Free` estimated from its
``start`` with an optional Gaussian prior. One :class:`Free` given to several terms is one
parameter. Each slot holds its chart (:mod:`torch_dq.fitting._charts`): the value's shape,
the local coordinates in which :func:`~torch_dq.fitting.estimate` steps it and reports its
uncertainty.
"""

from __future__ import annotations

import numbers
import weakref

import torch
from torch import Tensor

from .. import _checks
from ._charts import Chart

__all__ = ["Free", "Slot"]


class Free:
    """An estimated nuisance parameter: start value and optional Gaussian prior.

    Args:
        start: start value (the parameter's shape: ``(3,)`` bias or lever arm, a float time
            offset in seconds, an ``(8,)`` extrinsic, a ``(3,)`` gravity vector whose norm is
            kept); None: the kind's default start (zero, identity; gravity's direction from
            the mean accelerometer reading; a gyroscope's time offset from cross-correlating
            angular rates).
        prior_std: None (no prior) or the standard deviation of a Gaussian prior around
            ``start`` in the parameter's chart (a positive float, or one per chart axis). It
            is part of the estimate and of its uncertainties (it is information the caller
            gave, unlike :func:`~torch_dq.fitting.estimate`'s numerical ``prior``).

    Attributes:
        value: the current value, set by :func:`~torch_dq.fitting.estimate` (None before);
            a second estimate continues from it.

    Example:
        >>> clock = Free(start=0.0, prior_std=0.05)  # one IMU clock for Gyro and Accel
    """

    def __init__(self, start=None, prior_std=None) -> None:
        fn = "fitting.Free"
        if (start is not None and not isinstance(start, (Tensor, numbers.Real))) or isinstance(
                start, bool):
            _checks.fail(fn, f"start must be None, a float or a tensor, got {start!r}",
                         TypeError)
        if isinstance(start, Tensor):
            _checks.tensor(fn, "start", start)
            if not bool(torch.isfinite(start).all()):
                _checks.fail(fn, "start must be finite")
        if prior_std is not None:
            p = torch.as_tensor(prior_std, dtype=torch.float64)
            if p.dim() > 1 or not bool((p > 0).all()) or not bool(torch.isfinite(p).all()):
                _checks.fail(fn, f"prior_std must be None or positive finite float(s), got "
                                 f"{prior_std!r}")
        self.start = start
        self.prior_std = prior_std
        self.value: Tensor | None = None
        self._slots: weakref.WeakSet[Slot] = weakref.WeakSet()  # the live terms' uses

    def __repr__(self) -> str:
        return f"Free(start={self.start!r}, prior_std={self.prior_std!r})"

    def __getstate__(self) -> dict:
        """Picklable (and deep-copyable): the uses as a plain list."""
        return {**self.__dict__, "_slots": list(self._slots)}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update({**state, "_slots": weakref.WeakSet(state.get("_slots", ()))})


class Slot:
    """A term's nuisance argument resolved: absent, fixed, or estimated (``free``).

    Args:
        fn: public name of the term, for messages.
        name: argument name (``"bias"``, ...).
        chart: the parameter's :class:`~torch_dq.fitting._charts.Chart`.
        arg: the user's argument.
        kind: what the parameter is (None: ``name``; a gyroscope's and an accelerometer's
            bias are two kinds): one :class:`Free` is one parameter of one kind, so a lever
            arm and a bias, or a time offset and a line delay, never share one.
    """

    def __init__(self, fn: str, name: str, chart: Chart, arg, kind: str | None = None) -> None:
        self.fn, self.name, self.chart = fn, name, chart
        self.kind = name if kind is None else kind
        self.free: Free | None = None
        self.fixed: Tensor | None = None
        if arg is None or arg is False:
            return
        if arg is True or (isinstance(arg, str) and arg == "estimate"):
            self.free = Free()
        elif isinstance(arg, Free):
            self._adopt(arg)
        elif isinstance(arg, str) or isinstance(arg, bool):
            _checks.fail(fn, f"{name} must be None, False, a tensor or float, True, "
                             f"'estimate' or fitting.Free, got {arg!r}")
        else:
            self.fixed = self._check_value(fn, name, arg)

    def _adopt(self, free: Free) -> None:
        """Take ``free`` as this parameter: its start checked, and of this slot's kind
        (and shape) wherever else a live term uses it (one Free is one parameter)."""
        for other in list(free._slots):
            if other.kind != self.kind or not other.chart.same_kind(self.chart):
                _checks.fail(self.fn, f"{self.name} is given a fitting.Free that is also "
                                      f"{other.fn}'s {other.name}, a parameter of another kind "
                                      f"({self.kind}: {self.chart.describe()} vs {other.kind}: "
                                      f"{other.chart.describe()}): one Free is one parameter; "
                                      f"pass separate Free objects")
        if free.start is not None:
            self._check_value(self.fn, f"{self.name} start", free.start)
        if free.prior_std is not None:
            k = torch.as_tensor(free.prior_std).numel()
            if k not in (1, self.dim):
                _checks.fail(self.fn, f"{self.name}'s fitting.Free has {k} prior_std values: "
                                      f"expected a float or {self.dim}, one per axis of its "
                                      f"chart ({self.chart.describe()}: {self.dim}-d)")
        self.free = free
        free._slots.add(self)

    def _check_value(self, fn: str, name: str, value) -> Tensor:
        if isinstance(value, numbers.Real) and not isinstance(value, bool):
            value = torch.tensor(float(value), dtype=torch.float64)
        if not isinstance(value, Tensor):
            _checks.fail(fn, f"{name} must be a tensor or a float, got "
                             f"{type(value).__name__}", TypeError)
        _checks.tensor(fn, name, value)
        shape = self.shape
        if tuple(value.shape[value.dim() - len(shape):]) != shape or value.dim() < len(shape):
            matrix = shape == (8,) and tuple(value.shape[-2:]) == (4, 4)
            hint = ": a 4 x 4 matrix? convert it with torch_dq.dualquat.from_matrix" * matrix
            _checks.fail(fn, f"expected {name} of shape (..., {', '.join(map(str, shape))}) "
                             f"(batch first), got {_checks.shape_str(value.shape)}{hint}"
                         if shape else f"expected a float or a tensor for {name}")
        if not bool(torch.isfinite(value).all()):
            _checks.fail(fn, f"{name} must be finite")
        self.chart.check(fn, name, value)
        return value

    @property
    def estimated(self) -> bool:
        return self.free is not None

    @property
    def present(self) -> bool:
        return self.free is not None or self.fixed is not None

    @property
    def shape(self) -> tuple[int, ...]:
        """The value's shape (the chart's)."""
        return self.chart.shape

    @property
    def dim(self) -> int:
        """Dimension of the chart."""
        return self.chart.dim

    def identity(self, like: Tensor) -> Tensor:
        """The absent value (zero, identity) in ``like``'s dtype and device."""
        return self.chart.identity(like)

    def value(self, like: Tensor) -> Tensor | None:
        """Current value (fixed, estimated, or start if given), None if a default start is
        still to be computed; in ``like``'s dtype and device."""
        if self.fixed is not None:
            return self.fixed.to(dtype=like.dtype, device=like.device)
        if self.free is None:
            return self.identity(like)
        v = self.free.value if self.free.value is not None else self.free.start
        if v is None:
            return None
        return torch.as_tensor(v).to(dtype=like.dtype, device=like.device)

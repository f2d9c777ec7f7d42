r"""Curve layers with learnable unit-dual-quaternion control points, in the caller's time.

- :class:`UnitDualQuaternion`: a parametrization in PyTorch's sense
  (:func:`torch.nn.utils.parametrize.register_parametrization`): the stored raw ``(..., 8)``
  tensor is unconstrained and ``forward`` projects it with
  :func:`torch_dq.dualquat.normalize`, so the parameter seen by the module is a unit dual
  quaternion whatever an optimizer does to the raw tensor.
- :class:`Curve`: the contract of a curve layer (an abstract base class): learnable control
  points, a time model (:attr:`Curve.time_model`: knots relative to a float64 origin),
  evaluation with exact time derivatives, kinematics and IMU readings, the Euclidean basis
  of its least-squares problems (:meth:`Curve.basis`), construction from poses and from a
  saved ``state_dict``. :mod:`torch_dq.fitting` recognises a layer by
  ``isinstance(module, Curve)``.
- :class:`Bezier` and :class:`BSpline`: the two curves, wrapping
  :func:`torch_dq.curves.bezier` and :func:`torch_dq.curves.bspline` (any B-spline form,
  ``form="de_boor"``, ``"cumulative"`` or ``"split"``); ``forward(t, ctrl=...)`` (and
  :meth:`~Curve.derivatives`, :meth:`~Curve.kinematics`, :meth:`~Curve.imu`) use control
  points predicted by another network instead. ``from_poses`` / ``from_matrices`` /
  ``from_dualquats`` build a curve by local least squares on timestamped poses.
- :func:`fit` and :class:`FitHistory` (lazy re-exports of :mod:`torch_dq.fitting`, which
  imports this module): refine a curve on timestamped poses.

Time is the caller's (seconds, frames, ...): a :class:`Bezier` lives on its ``domain``
``(t0, t1)`` and a :class:`BSpline` on ``[knots[degree], knots[n]]``, and ``module(t)``
takes ``t`` in those units. ``from_poses`` places the curve over ``[times[0], times[-1]]``,
so ``module(times)`` is the fit at those very times. Absolute timestamps (UNIX seconds,
~1.7e9) are welcome in float64 even for a float32 module: the module keeps its time origin
(the start of its domain) as a Python float (float64, saved in the ``state_dict`` as extra
state and untouched by ``.to(dtype)``) and its knots relative to it, and evaluates
``t - origin`` in the wider of the two dtypes, so nothing is lost beyond the rounding of the
time since the origin in the module's dtype. A batch of trajectories with times of their
own (``from_poses`` with ``(B, N)`` times, or ``BSpline`` with ``(B, K)`` knots) holds a row
of knots and a float64 origin per trajectory (a ``(B, 1)`` tensor that follows the module's
device but keeps float64 under ``.to(dtype)``): ``module(t)`` with ``t (B, T)`` evaluates
each trajectory at its own times, and ``.domain`` / ``.knots`` report per row. All of this is
the time model
(:class:`torch_dq._time.KnotDomain`), the one place where an origin is subtracted, a span
searched or a domain checked.

Domain rules: times outside the domain ``[t0, t1]`` by at most
``tol = max(1e-9 (t1 - t0), 4 eps(t.dtype) max(|t0|, |t1|))`` (a rounding of ``t0 + k dt``)
are evaluated at the nearest end; further out they raise ``ValueError`` naming the domain,
unless ``extrapolate=True`` (on the constructor, or per call), which continues the end
spans. The check reads ``t`` on the host (one synchronisation); it is skipped with
``check=False``, under ``torch.compile`` (so that ``torch.compile(module, fullgraph=True)``
works with the default arguments) and on meta tensors, and then such times give NaN poses,
never a silent extrapolation.

Saving: ``state_dict`` holds the raw control points, the relative knots (a buffer) and, as
extra state, the origin, the degree and the form (or a Bézier's length);
:meth:`BSpline.from_state_dict` / :meth:`Bezier.from_state_dict` rebuild a module from it,
and ``torch.save(module)`` / ``torch.load(path, weights_only=False)`` pickle whole modules
through the same route.

Control polygons: every interpolation takes the shortest path, so the curve jumps where two
neighbouring control points come to differ by a half turn of rotation. Keep neighbours
closer than that: ``from_poses`` with enough control points does; an optimizer started far
from the data (e.g. LBFGS from identity control points) can stall at such a jump.

Example (a small network predicting trajectories, trained end to end):
    >>> import torch_dq.dualquat as dq
    >>> from torch_dq.losses import pose_loss
    >>> spline = BSpline(dq.identity((6,)))
    >>> net = torch.nn.Sequential(torch.nn.Linear(3, 32), torch.nn.Tanh(),
    ...                           torch.nn.Linear(32, 6 * 8))
    >>> cond, t = torch.randn(5, 3), torch.linspace(0, 1, 20)
    >>> raw = net(cond).view(5, 6, 8) + dq.identity()  # raw outputs, projected by the layer
    >>> x = spline(t, ctrl=raw)  # (5, 20, 8) unit dual quaternions
    >>> pose_loss(x, dq.identity()).backward()  # gradients reach net's weights
"""

from __future__ import annotations

import abc
import math
import numbers
import warnings
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor
from torch.nn.utils import parametrize

from . import _checks, _start, curves, dualquat, quat
from ._time import KnotDomain, time_pair

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Protocol

    from typing_extensions import Self

    class _CtrlParametrization(Protocol):
        """``parametrizations.ctrl`` as the curve layers use it (``nn.Module.__getattr__``
        types it ``Tensor | Module``)."""

        original: Tensor

        def __getitem__(self, index: int) -> Callable[[Tensor], Tensor]: ...

    class _Parametrizations(Protocol):
        ctrl: _CtrlParametrization

__all__ = ["BSpline", "Bezier", "Curve", "FitHistory", "UnitDualQuaternion", "fit"]

_RAW = "parametrizations.ctrl.original"  # state_dict key of the raw control points


def __getattr__(name: str) -> Any:
    # fit and FitHistory live in torch_dq.fitting, which imports this module: re-exported
    # lazily so that imports run one way (fitting -> nn -> curves).
    if name in ("fit", "FitHistory"):
        from . import fitting
        return getattr(fitting, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ----------------------------------------------------------------------------- parametrization

class UnitDualQuaternion(torch.nn.Module):
    r"""Parametrization onto unit dual quaternions (PyTorch's parametrization contract).

    ``forward(X)`` maps a raw ``(..., 8)`` tensor onto unit dual quaternions with
    :func:`torch_dq.dualquat.normalize` (real part divided by its norm, dual part made
    orthogonal to it; the translation is kept). ``right_inverse(X)`` returns the projection
    of ``X`` (so ``forward(right_inverse(X)) == X`` for unit ``X``): it is used when the
    parametrization is registered (the current value is projected) and on assignment
    ``module.weight = value``. A raw real part of zero gives NaN in that element.

    Example:
        >>> from torch.nn.utils import parametrize
        >>> layer = torch.nn.Linear(8, 4)  # weight (4, 8): four dual quaternions
        >>> _ = parametrize.register_parametrization(layer, "weight", UnitDualQuaternion())
        >>> bool(dualquat.is_unit(layer.weight).all())
        True
    """

    def forward(self, X: Tensor) -> Tensor:
        _checks.tensor("nn.UnitDualQuaternion", "X", X, 8)
        return dualquat.normalize(X)

    def right_inverse(self, X: Tensor) -> Tensor:
        _checks.tensor("nn.UnitDualQuaternion.right_inverse", "X", X, 8)
        return dualquat.normalize(X)


# ----------------------------------------------------------------------------- argument checks

def _check_int(fn: str, name: str, value, low: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        _checks.fail(fn, f"{name} must be an int {what}, got {value!r}")
    return int(value)


def _extra_float(fn: str, state, key: str, positive: bool = False) -> float:
    """``state[key]`` of a saved extra state: a finite real number (``> 0`` if ``positive``)."""
    value = state.get(key) if isinstance(state, dict) else None
    if (isinstance(value, bool) or not isinstance(value, numbers.Real)
            or not math.isfinite(value) or (positive and not float(value) > 0)):
        _checks.fail(fn, f"expected a finite{' positive' if positive else ''} {key!r} in the "
                         f"extra state, got {state!r}")
    return float(value)


def _extra_origins(fn: str, state, knots: Tensor) -> Tensor:
    """``state["origin"]`` of a layer with ``(..., K)`` knots: a finite float64 tensor
    ``(..., 1)`` (one origin per trajectory), moved to the knots' device."""
    value = state.get("origin") if isinstance(state, dict) else None
    shape = (*knots.shape[:-1], 1)
    if (not isinstance(value, Tensor) or value.dtype != torch.float64
            or tuple(value.shape) != shape or not bool(torch.isfinite(value).all())):
        _checks.fail(fn, f"expected a finite float64 'origin' tensor of shape "
                         f"{_checks.shape_str(shape)} (one per trajectory) in the extra state, "
                         f"got {state!r}")
    return value.detach().to(knots.device)


def _poses_to_dq(fn: str, rotations, translations) -> Tensor:
    """``(..., N, 8)`` dual quaternions from quaternions or matrices and translations."""
    _checks.tensor(fn, "rotations", rotations)
    _checks.tensor(fn, "translations", translations, 3)
    _checks.same_dtype_device(fn, rotations=rotations, translations=translations)
    if rotations.dim() >= 3 and tuple(rotations.shape[-2:]) == (3, 3):
        q, nd = quat.from_matrix(rotations), 2
    elif rotations.dim() >= 2 and rotations.shape[-1] == 4:
        q, nd = quat.normalize(rotations), 1
    else:
        _checks.fail(fn, f"expected (..., N, 4) quaternions or (..., N, 3, 3) matrices for "
                         f"rotations, got shape {_checks.shape_str(rotations.shape)}")
    if translations.dim() < 2:
        _checks.fail(fn, f"expected a (..., N, 3) tensor for translations, got shape "
                         f"{_checks.shape_str(translations.shape)}")
    if translations.shape[-2] != rotations.shape[rotations.dim() - nd - 1]:
        _checks.fail(fn, f"rotations and translations must hold the same number N of poses, "
                         f"got rotations {_checks.shape_str(rotations.shape)} and "
                         f"translations {_checks.shape_str(translations.shape)}")
    _checks.broadcast_batch(fn, rotations=(q, 2), translations=(translations, 2))
    return dualquat.from_rt(q, translations)


def _chosen_n_ctrl(fn: str, x: Tensor, t64: Tensor, degree: int, form: str) -> int:
    """``n_ctrl`` from the knot spacing chosen from the data (``from_poses(n_ctrl=None)``)."""
    if x.dim() > 2 or t64.dim() > 1:
        batch = torch.broadcast_shapes(x.shape[:-2], t64.shape[:-1])
        _checks.fail(fn, f"n_ctrl=None chooses the knots from one trajectory's poses; pass "
                         f"n_ctrl for a batch of shape {_checks.shape_str(batch)}")
    from ._spacing import choose_knot_spacing  # it builds layers: imported when used

    h = choose_knot_spacing(t64, x.detach().to(torch.float64).cpu(), degree, form=form)
    return min(math.ceil((float(t64[-1]) - float(t64[0])) / h) + degree, x.shape[-2])


# The start on knots finer than the poses (from_poses(knot_spacing=)): the poses' start on
# coarse knots (a control point per this many poses), sampled this many times per fine span.
_POSES_PER_COARSE_CTRL = 2
_SAMPLES_PER_SPAN = 4


def _uniform(n: int, degree: int, t0: float | Tensor, t1: float | Tensor) -> Tensor:
    """Clamped uniform knots of ``n`` control points over ``[t0, t1]`` (float64; a row per
    trajectory for ``(..., 1)`` tensors)."""
    return t0 + curves.clamped_uniform_knots(n, degree, dtype=torch.float64) * (t1 - t0)


def _check_seconds(fn: str, name: str, value, low: float | None) -> float:
    """A finite real ``value`` (seconds): ``>= low``, or ``> 0`` where ``low`` is None."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(
            value) or (value < low if low is not None else value <= 0):
        what = f">= {low!r}" if low is not None else "> 0"
        _checks.fail(fn, f"{name} must be a finite number {what} (in the times' units), got "
                         f"{value!r}")
    return float(value)


def _start_rows(x: Tensor, rel: Tensor, dom: KnotDomain, n: int, split: bool) -> Tensor:
    """The least-squares start of each trajectory of a batch on its own knots (rows of
    ``dom.knots``) and its own relative times ``rel (..., N)``: ``(..., n, 8)`` float64."""
    batch = torch.broadcast_shapes(x.shape[:-2], dom.knots.shape[:-1], rel.shape[:-1])
    N, K = x.shape[-2], dom.knots.shape[-1]
    rows = zip(x.expand(*batch, N, 8).reshape(-1, N, 8), rel.expand(*batch, N).reshape(-1, N),
               dom.knots.expand(*batch, K).reshape(-1, K), strict=True)
    out = []
    for xb, tb, kb in rows:  # a constructor's loop: each row its own windows and charts
        one = KnotDomain(kb, dom.degree)
        first, values = one.basis(tb)
        out.append(_start.least_squares_start(xb, tb, first, values, n, one.greville(),
                                              split))
    return torch.stack(out).view(*batch, n, 8)


# ----------------------------------------------------------------------------- 0.1 compatibility

def _deprecated(what: str, instead: str) -> None:
    warnings.warn(f"{what} is deprecated: {instead}", DeprecationWarning, stacklevel=3)


def _rebuild(cls: type[Curve], state: dict[str, Any], settings: dict[str, bool]) -> Curve:
    """Unpickle a curve layer (see :meth:`Curve.__reduce_ex__`)."""
    module = cls.from_state_dict(state)
    module.check, module.extrapolate = settings["check"], settings["extrapolate"]
    return module.train(settings["training"])


class _Compat01(torch.nn.Module):
    """What 0.1 code needs (deprecated, with a ``DeprecationWarning``): loading a 0.1
    ``state_dict`` (a ``time_range`` buffer and knots on the domain it maps onto),
    :meth:`normalize_time` and :attr:`time_range`."""

    _name: str

    if TYPE_CHECKING:
        parametrizations: _Parametrizations

        @property
        def domain(self) -> tuple[float, float] | tuple[Tensor, Tensor]: ...

        def _convert_01(self, state_dict: dict[str, Any], prefix: str, start: float,
                        end: float) -> None: ...

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if prefix + "time_range" in state_dict and prefix + "_extra_state" not in state_dict:
            warnings.warn(f"{self._name}.load_state_dict: converting a 0.1 state_dict "
                          f"(time_range) to the caller's time; save it again to update it",
                          DeprecationWarning, stacklevel=4)
            start, end = (float(v) for v in state_dict.pop(prefix + "time_range").tolist())
            self._convert_01(state_dict, prefix, start, end)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @staticmethod
    def _time_range_knots(fn: str, k64: Tensor, degree: int, time_range) -> Tensor:
        """0.1's ``time_range=``: the knots mapped affinely so that the domain is it."""
        _deprecated(f"{fn}(time_range=...)", "pass knots in the caller's time (or build with "
                                             "from_poses)")
        span = time_pair(fn, "time_range", time_range)
        n = k64.shape[0] - degree - 1
        lo, hi = k64[degree], k64[n]
        k64 = span[0] + (k64 - lo) * ((span[1] - span[0]) / (hi - lo))
        k64[degree], k64[n] = span  # exact ends
        return k64

    def normalize_time(self, times: Tensor) -> Tensor:
        """Deprecated: the identity (modules now take the caller's time directly).

        0.1 mapped raw times onto ``[0, 1]``; since 0.2 a module's time is the caller's, so
        ``module(times)`` replaces ``module(module.normalize_time(times))``.
        """
        _deprecated(f"{self._name}.normalize_time",
                    "modules take the caller's time directly; call module(times)")
        _checks.tensor(f"{self._name}.normalize_time", "times", times)
        return times

    @property
    def time_range(self) -> Tensor:
        """The :attr:`~Curve.domain` as a float64 ``(2,)`` tensor (deprecated since 0.2)."""
        _deprecated(f"{self._name}.time_range", "use module.domain")
        like = self.parametrizations.ctrl.original
        ends = self.domain
        if isinstance(ends[0], Tensor):  # a row per trajectory: (..., 2)
            return torch.stack(torch.broadcast_tensors(*ends), -1)
        return torch.tensor(ends, dtype=torch.float64, device=like.device)


# ----------------------------------------------------------------------------- constructors

class _Construction(torch.nn.Module):
    """Making a curve layer: from poses (the least-squares start of :mod:`torch_dq._start`),
    matrices, dual quaternions; and saving: the extra state, :meth:`from_state_dict`,
    pickling."""

    _name: str

    if TYPE_CHECKING:
        _origin: float | Tensor
        check: bool
        extrapolate: bool

        @property
        def time_model(self) -> KnotDomain: ...

        @property
        def _min_samples(self) -> int: ...

        @property
        def n_ctrl(self) -> int: ...

        @property
        def control_points(self) -> Tensor: ...

        @control_points.setter
        def control_points(self, value: Tensor) -> None: ...

        @classmethod
        def _from_dq(cls, fn: str, x: Tensor, times: Tensor, *args: Any,
                     **kwargs: Any) -> Self: ...

        @classmethod
        def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                             ) -> dict[str, Any]: ...

        def _state(self) -> dict[str, Any]: ...

        def _restore(self, fn: str, state: dict[str, Any]) -> None: ...

    def _fill(self, fn: str, x: Tensor, t64: Tensor) -> Self:
        """Set the control points from the local least-squares start
        (:func:`torch_dq._start.least_squares_start`) on poses ``x`` at float64 times."""
        n, N = self.n_ctrl, x.shape[-2]
        if n > N:
            low = self._min_samples
            fix = (f"use n_ctrl <= {N}" if N >= low else
                   f"a degree-{low - 1} curve needs at least {low} samples: add samples or "
                   f"lower the degree")
            _checks.fail(fn, f"the fit is underdetermined: n_ctrl = {n} control points for "
                             f"N = {N} samples; {fix} (BSpline.from_poses(..., knot_spacing=) "
                             f"starts knots finer than the poses, smoothing between them)")
        x64 = x.detach().to(dtype=torch.float64, device="cpu")
        if not bool(torch.isfinite(x64).all()):
            _checks.fail(fn, "the poses must be finite, with non-zero rotations")
        dom = self.time_model
        origin = dom.origin.cpu() if isinstance(dom.origin, Tensor) else dom.origin
        dom = KnotDomain(dom.knots.detach().cpu(), dom.degree, origin)
        rel = dom.relative(t64, torch.float64)
        split = getattr(self, "form", None) == "split"  # its own charts (_start)
        if dom.knots.dim() > 1:
            ctrl = _start_rows(x64, rel, dom, n, split)
        else:
            first, values = dom.basis(rel)
            ctrl = _start.least_squares_start(x64, rel, first, values, n, dom.greville(),
                                              split)
        self.control_points = ctrl.to(dtype=x.dtype, device=x.device)
        return self

    @classmethod
    def from_matrices(cls, T: Tensor, times: Tensor, **kwargs: Any) -> Self:
        """``from_poses`` with ``(..., N, 4, 4)`` homogeneous matrices ``T``.

        Keywords as for :meth:`BSpline.from_poses` / :meth:`Bezier.from_poses`.
        """
        fn = f"{cls._name}.from_matrices"
        _checks.tensor(fn, "T", T, (4, 4))
        if T.dim() < 3:
            _checks.fail(fn, f"expected a (..., N, 4, 4) tensor for T, got shape "
                             f"{_checks.shape_str(T.shape)}")
        return cls._from_dq(fn, dualquat.from_matrix(T), times, **kwargs)

    @classmethod
    def from_dualquats(cls, x: Tensor, times: Tensor, **kwargs: Any) -> Self:
        """``from_poses`` with ``(..., N, 8)`` unit dual quaternions ``x`` (any signs).

        Keywords as for :meth:`BSpline.from_poses` / :meth:`Bezier.from_poses`.
        """
        fn = f"{cls._name}.from_dualquats"
        _checks.tensor(fn, "x", x, 8)
        if x.dim() < 2:
            _checks.fail(fn, f"expected a (..., N, 8) tensor for x, got shape "
                             f"{_checks.shape_str(x.shape)}")
        return cls._from_dq(fn, dualquat.normalize(x), times, **kwargs)

    def get_extra_state(self) -> dict[str, Any]:
        return {"origin": self._origin, **self._state()}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        fn = f"{self._name}.load_state_dict"
        knots = self.time_model.knots
        if knots.dim() > 1:  # a float64 origin per trajectory
            self._origin = _extra_origins(fn, state, knots)
        else:
            self._origin = _extra_float(fn, state, "origin")
        self._restore(fn, state)

    @classmethod
    def from_state_dict(cls, state_dict: Mapping[str, Any], *, check: bool = True,
                        extrapolate: bool = False) -> Self:
        """Rebuild a saved module from its ``state_dict`` alone.

        The shape, dtype and device of the control points, and the degree, knots, form and
        time origin (or a Bézier's domain) come from ``state_dict``: the caller need not
        know them. 0.1 and 0.2 state dicts load too (a 0.1 one with a
        ``DeprecationWarning``).

        Args:
            state_dict: what ``module.state_dict()`` returned (or ``torch.load`` of it).
            check: the new module's ``check``.
            extrapolate: the new module's ``extrapolate``.

        Returns:
            A module equal to the saved one (same outputs at every time).

        Raises:
            TypeError: ``state_dict`` not a mapping.
            ValueError: no raw control points in it, or an inconsistent state.

        Example:
            >>> import torch_dq.dualquat as dq
            >>> saved = BSpline(dq.identity((7,)), degree=2, form="cumulative").state_dict()
            >>> loaded = BSpline.from_state_dict(saved)
            >>> loaded.n_ctrl, loaded.degree, loaded.form, loaded.domain
            (7, 2, 'cumulative', (0.0, 1.0))
        """
        fn = f"{cls._name}.from_state_dict"
        if not isinstance(state_dict, Mapping):
            _checks.fail(fn, f"expected a state_dict (a mapping), got "
                             f"{type(state_dict).__name__}", TypeError)
        raw = state_dict.get(_RAW)
        if not isinstance(raw, Tensor) or raw.dim() < 2 or raw.shape[-1] != 8:
            _checks.fail(fn, f"expected a state_dict of {cls._name} with a (..., n, 8) tensor "
                             f"{_RAW!r}, got keys {sorted(state_dict)}")
        kwargs = cls._args_from_state(fn, state_dict, raw)
        ctrl = dualquat.identity(tuple(raw.shape[:-1]), dtype=raw.dtype, device=raw.device)
        module = cls(ctrl, check=check, extrapolate=extrapolate, **kwargs)
        module.load_state_dict(dict(state_dict))
        return module


    def __reduce_ex__(self, protocol):
        # Parametrized modules do not pickle (their class is made on the fly): rebuilt from
        # the state_dict by from_state_dict, so torch.save(module) works.
        settings = {"check": self.check, "extrapolate": self.extrapolate,
                    "training": self.training}
        return _rebuild, (parametrize.type_before_parametrizations(self),
                          dict(self.state_dict()), settings)


# ----------------------------------------------------------------------------- the contract

class Curve(_Compat01, _Construction, abc.ABC):
    """A curve layer: learnable unit-dual-quaternion control points on a time model.

    The contract that :class:`Bezier` and :class:`BSpline` implement and that
    :mod:`torch_dq.fitting` relies on. Concrete here: the parametrized control points
    (:attr:`control_points`, :attr:`n_ctrl`), the time (:attr:`domain`, the domain rules of
    the module docstring), :meth:`forward`, :meth:`derivatives`, :meth:`kinematics`,
    :meth:`imu`, the Euclidean :meth:`basis` and :meth:`greville` abscissae of the
    least-squares problems, saving and loading (extra state, :meth:`from_state_dict`,
    pickling) and the constructors from poses. A subclass supplies its time model
    (:attr:`time_model`), its evaluation (``_curve``, ``_curve_derivatives``), its extra
    state (``_state``, ``_restore``, ``_args_from_state``, ``_convert_01``), its
    constructor from poses (``_from_dq``) and the fewest samples its least-squares start
    needs (``_min_samples``).

    Attributes:
        check: whether evaluations check ``t`` against the domain (one host sync per call;
            skipped under ``torch.compile`` and on meta tensors).
        extrapolate: the default of the ``extrapolate=`` argument of the evaluations.
    """

    _name = "nn.Curve"

    if TYPE_CHECKING:  # attributes set by _setup and parametrize
        ctrl: Tensor
        parametrizations: _Parametrizations
        check: bool
        extrapolate: bool
        _origin: float | Tensor

    # -- the hooks of a curve
    @property
    @abc.abstractmethod
    def time_model(self) -> KnotDomain:
        """The module's time (:class:`torch_dq._time.KnotDomain`): knots relative to the
        float64 origin, on the module's device."""

    @property
    @abc.abstractmethod
    def _min_samples(self) -> int:
        """The fewest samples that can determine a curve of this kind."""

    @abc.abstractmethod
    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        """Poses at admitted relative times ``rel`` (:meth:`KnotDomain.admit`)."""

    @abc.abstractmethod
    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int,
                           ) -> tuple[Tensor, ...]:
        """Poses and time derivatives to ``order`` at admitted relative times ``rel``."""

    @abc.abstractmethod
    def _state(self) -> dict[str, Any]:
        """Extra state besides the origin (saved in the ``state_dict``)."""

    @abc.abstractmethod
    def _restore(self, fn: str, state: dict[str, Any]) -> None:
        """Set what :meth:`_state` saved (checked)."""

    @classmethod
    @abc.abstractmethod
    def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                         ) -> dict[str, Any]:
        """Constructor keywords of a module that can load ``state_dict``."""

    @abc.abstractmethod
    def _convert_01(self, state_dict: dict[str, Any], prefix: str, start: float,
                    end: float) -> None:
        """Rewrite a 0.1 ``state_dict`` on the domain ``(start, end)`` in place."""

    @classmethod
    @abc.abstractmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, *args: Any, **kwargs: Any) -> Self:
        """A module fit to unit dual quaternions ``x`` at ``times`` (``from_poses``)."""

    # -- control points
    def _setup(self, ctrl: Tensor, min_points: int, check: bool, extrapolate: bool) -> None:
        fn = self._name
        _checks.tensor(fn, "ctrl", ctrl, 8)
        if ctrl.dim() < 2 or ctrl.shape[-2] < min_points:
            _checks.fail(fn, f"expected a (..., n, 8) tensor for ctrl with n >= {min_points}, "
                             f"got shape {_checks.shape_str(ctrl.shape)}")
        for name, value in (("check", check), ("extrapolate", extrapolate)):
            if not isinstance(value, bool):
                _checks.fail(fn, f"{name} must be a bool, got {value!r}", TypeError)
        self.check, self.extrapolate = check, extrapolate
        self.ctrl = torch.nn.Parameter(ctrl.detach().clone())
        parametrize.register_parametrization(self, "ctrl", UnitDualQuaternion())

    @property
    def n_ctrl(self) -> int:
        """Number ``n`` of control points."""
        return self.parametrizations.ctrl.original.shape[-2]

    @property
    def control_points(self) -> Tensor:
        """The ``(..., n, 8)`` unit dual quaternion control points (differentiable).

        Assigning a ``(..., n, 8)`` tensor of the same shape sets them (projected onto unit
        dual quaternions); ``module.ctrl = value`` does the same through ``parametrize``.
        """
        return self.ctrl

    @control_points.setter
    def control_points(self, value: Tensor) -> None:
        _checks.tensor(self._name, "control_points", value, 8)
        shape = self.parametrizations.ctrl.original.shape
        if value.shape != shape:
            _checks.fail(self._name, f"expected control_points of shape "
                                     f"{_checks.shape_str(shape)}, got "
                                     f"{_checks.shape_str(value.shape)}")
        self.ctrl = value

    def _resolve(self, fn: str, ctrl: Tensor | None) -> Tensor:
        if ctrl is None:
            return self.ctrl
        _checks.tensor(fn, "ctrl", ctrl, 8)
        n = self.n_ctrl
        if ctrl.dim() < 2 or ctrl.shape[-2] != n:
            _checks.fail(fn, f"expected a (..., {n}, 8) tensor for ctrl ({n} control points), "
                             f"got shape {_checks.shape_str(ctrl.shape)}")
        return self.parametrizations.ctrl[0](ctrl)

    # -- time
    @property
    def domain(self) -> tuple[float, float] | tuple[Tensor, Tensor]:
        """The module's time domain ``(start, end)`` in the caller's units: Python floats;
        for a :class:`BSpline` with a row of knots per trajectory two float64 tensors of
        the knots' batch shape (row ``b``: trajectory ``b``'s domain)."""
        return self.time_model.domain()

    def _times(self, fn: str, t: Tensor, like: Tensor, extrapolate: bool | None) -> Tensor:
        """``t - origin`` in the wider of ``t``'s and ``like``'s dtypes, admitted by the time
        model (checked when ``self.check``)."""
        _checks.tensor(fn, "t", t)
        if t.dim() < 1:
            _checks.fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
        if t.device != like.device:
            _checks.fail(fn, f"t is on {t.device} but the control points are on {like.device}",
                         TypeError)
        extrapolate = (self.extrapolate if extrapolate is None
                       else _checks.flag(fn, "extrapolate", extrapolate))
        return self.time_model.prepare(
            fn, t, like.dtype, check=self.check, extrapolate=extrapolate, knots=None,
            what="the module's time domain", fix="evaluate inside it (the caller's units; "
                                                "from_poses places it over [times[0], times[-1]])")

    # -- evaluation
    def forward(self, t: Tensor, ctrl: Tensor | None = None,
                extrapolate: bool | None = None) -> Tensor:
        """Poses at times ``t`` of the module's domain (the caller's units).

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`, any floating dtype (float64
                absolute timestamps work with a float32 module), on the module's device;
                batch dims broadcast with those of the control points.
            ctrl: optional ``(..., n, 8)`` control points (e.g. a network's raw outputs)
                used instead of the module's own, projected like them; ``n`` must be the
                module's.
            extrapolate: continue the end spans beyond the domain (default: the module's
                ``extrapolate``); otherwise the domain rules of the module docstring. The
                continuation is the end span's polynomial (in the chart of its screw
                motions), accurate only a fraction of a knot spacing beyond the end: it is
                no prediction of the motion.

        Returns:
            ``(..., T, 8)`` unit dual quaternions of the control points' dtype.

        Raises:
            ValueError: ``t`` outside the domain (with ``check``), bad shapes.
        """
        fn = f"{self._name}.forward"
        ctrl = self._resolve(fn, ctrl)
        return self._curve(ctrl, self._times(fn, t, ctrl, extrapolate))

    def derivatives(self, t: Tensor, order: int = 2, ctrl: Tensor | None = None,
                    extrapolate: bool | None = None) -> tuple[Tensor, ...]:
        r"""Poses and their exact time derivatives ``(x, dx/dt, ..., d^order x/dt^order)``.

        Derivatives are with respect to the caller's time (the module's own), through
        :func:`torch_dq.curves.bspline_derivatives` / :func:`torch_dq.curves.bezier_derivatives`:
        exact, differentiable (twice) with respect to the control points and ``t``.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain` (see :meth:`forward`).
            order: highest derivative, 0 to 3.
            ctrl: optional predicted control points (see :meth:`forward`).
            extrapolate: see :meth:`forward`.

        Returns:
            ``order + 1`` tensors, each ``(..., T, 8)``.
        """
        fn = f"{self._name}.derivatives"
        order = _check_int(fn, "order", order, 0, "in 0..3")
        if order > 3:
            _checks.fail(fn, f"order must be an int in 0..3, got {order!r}")
        ctrl = self._resolve(fn, ctrl)
        return self._curve_derivatives(ctrl, self._times(fn, t, ctrl, extrapolate), order)

    def kinematics(self, t: Tensor, frame: str = "world", ctrl: Tensor | None = None,
                   extrapolate: bool | None = None) -> curves.Kinematics:
        r"""Angular and linear velocities and accelerations at ``t`` (caller's units).

        As :func:`torch_dq.curves.kinematics` on :meth:`derivatives` of order 2: with
        ``x = (R, p)``, world frame ``dR/dt = [w]x R``, ``v = dp/dt``, ``alpha = dw/dt``,
        ``a = d^2 p/dt^2``; ``frame="body"`` gives the same vectors in body axes.
        Differentiable (twice) with respect to the control points.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`.
            frame: ``"world"`` or ``"body"``.
            ctrl: optional predicted control points (see :meth:`forward`).
            extrapolate: see :meth:`forward`.

        Returns:
            Named tuple ``(angular_velocity, linear_velocity, angular_acceleration,
            linear_acceleration)``, each ``(..., T, 3)``.

        Example:
            >>> import torch_dq.dualquat as dq
            >>> xi = torch.tensor([0.0, 0.0, 0.5, 2.0, 0.0, 0.0])  # per second
            >>> ctrl = dq.exp(torch.linspace(0.0, 4.0, 2)[:, None] * xi)
            >>> curve = Bezier(ctrl.double(), domain=(10.0, 14.0))  # seconds 10 to 14
            >>> k = curve.kinematics(torch.tensor([12.0], dtype=torch.float64))
            >>> k.angular_velocity.detach()  # rad/s
            tensor([[0.0000, 0.0000, 0.5000]], dtype=torch.float64)
        """
        x, dx, ddx = self.derivatives(t, 2, ctrl, extrapolate)
        return curves.kinematics(x, dx, ddx, frame=frame)

    def imu(self, t: Tensor, gravity: Tensor | Sequence[float] = (0.0, 0.0, -9.81),
            ctrl: Tensor | None = None, extrapolate: bool | None = None,
            ) -> tuple[Tensor, Tensor]:
        r"""What an ideal IMU rigidly attached at the body origin reads at ``t``.

        As :func:`torch_dq.curves.imu` on :meth:`derivatives` of order 2: gyroscope
        :math:`R^T \omega` and accelerometer (specific force) :math:`R^T (a - g)`.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`.
            gravity: gravity ``g`` in world axes (default ``(0, 0, -9.81)``).
            ctrl: optional predicted control points (see :meth:`forward`).
            extrapolate: see :meth:`forward`.

        Returns:
            ``(gyro, accel)``, each ``(..., T, 3)``.
        """
        x, dx, ddx = self.derivatives(t, 2, ctrl, extrapolate)
        return curves.imu(x, dx, ddx, gravity=gravity)

    # -- the Euclidean basis of the least-squares problems
    def basis(self, t: Tensor) -> tuple[Tensor, Tensor]:
        r"""Euclidean basis at ``t``: ``(first (T,), values (T, w))``.

        The pose at ``t[i]`` depends on the control points ``first[i] .. first[i] + w - 1``
        only, with the Euclidean basis functions ``values[i, j]`` (Cox-de Boor for a
        B-spline of degree ``p``, ``w = p + 1``: local support; Bernstein for a Bézier
        curve, ``w = n``, ``first = 0``; non-negative, summing to 1): the design matrix of
        the least-squares start and of the Gauss-Newton fit, for either B-spline form (the
        linearization of both in local charts, :mod:`torch_dq._start`).

        Args:
            t: ``(T,)`` times in the domain (caller's units; the domain rules apply, checked
                whatever ``check``), any floating dtype; for a module with a row of knots
                per trajectory also ``(..., T)``, broadcasting against the knots' batch.

        Returns:
            ``(first, values)``: ``(T,)`` int64 and ``(T, w)`` float64; with a row of
            knots per trajectory ``(..., T)`` and ``(..., T, w)``, ``first`` indexing each
            trajectory's own control points.

        Raises:
            ValueError: ``t`` not 1-D (batched: not broadcastable), or outside the domain.
        """
        fn = f"{self._name}.basis"
        _checks.tensor(fn, "t", t)
        dom = self.time_model
        if dom.knots.dim() > 1:  # a row per trajectory: (T,) or (..., T) times
            if t.dim() < 1:
                _checks.fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
            _checks.broadcast_batch(fn, t=(t, 1), knots=(dom.knots, 1))
        elif t.dim() != 1:
            _checks.fail(fn, f"expected a (T,) tensor for t, got shape "
                             f"{_checks.shape_str(t.shape)}")
        rel = dom.prepare(fn, t.detach().to(dom.knots.device), torch.float64, check=True,
                          extrapolate=False, knots=None, what="the module's time domain",
                          fix="evaluate inside it")
        return dom.basis(rel)

    def greville(self) -> Tensor:
        """The Greville abscissae ``(..., n)`` of the control points, float64, in the
        caller's units (where each control point acts most)."""
        return self.time_model.greville() + self._origin

    def _get_name(self) -> str:  # the repr's name: BSpline, not ParametrizedBSpline
        return parametrize.type_before_parametrizations(self).__name__

    def extra_repr(self) -> str:
        raw = self.parametrizations.ctrl.original
        batch = _checks.shape_str(raw.shape[:-2])
        start, end = self.domain
        extra = "".join(f", {k}={v!r}" for k, v in self._state().items() if k != "length")
        domain = (f"({start!r}, {end!r})" if not isinstance(start, Tensor) else
                  f"per trajectory {_checks.shape_str(start.shape)}")
        return (f"n_ctrl={self.n_ctrl}{extra}, batch_shape={batch}, domain={domain}, "
                f"dtype={raw.dtype}")

# ----------------------------------------------------------------------------- the curves

class Bezier(Curve):
    r"""Bézier curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bezier` (De Casteljau with ``sclerp``, paper 4.1) on
    its ``domain`` in the caller's units. The control points are the parameter ``ctrl``
    under the :class:`UnitDualQuaternion` parametrization: the raw tensor
    (``parametrizations.ctrl.original``) is what optimizers update, and
    ``.control_points`` (= ``.ctrl``) is always its unit projection. Save and load through
    ``state_dict`` (the domain is extra state) and :meth:`~Curve.from_state_dict`, or
    ``torch.save(module)``.

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n >= 2`` (degree ``n - 1``),
            projected onto unit dual quaternions; leading dims give a batch of curves.
            dtype and device of the module.
        domain: ``(t0, t1)``, the time span of the curve in the caller's units (kept as
            Python floats: absolute timestamps are safe with a float32 module).
        time_range: deprecated alias of ``domain`` (0.1).
        check: check at every call that ``t`` lies in the domain (one device sync; skipped
            under ``torch.compile``, where times outside give NaN).
        extrapolate: default of the evaluations' ``extrapolate=``: continue the curve
            beyond its domain instead of the domain rules.

    Shape:
        ``forward(t)``: ``t`` ``(T,)`` or ``(..., T)`` in the domain -> ``(..., T, 8)``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> curve = Bezier(dq.identity((4,)), domain=(2.0, 3.0))
        >>> curve(torch.linspace(2, 3, 5)).shape
        torch.Size([5, 8])
    """

    _name = "nn.Bezier"

    def __init__(self, ctrl: Tensor, domain: Sequence[float] | Tensor = (0.0, 1.0), *,
                 time_range: Sequence[float] | Tensor | None = None, check: bool = True,
                 extrapolate: bool = False):
        super().__init__()
        fn = self._name
        self._setup(ctrl, 2, check, extrapolate)
        if time_range is not None:
            _deprecated(f"{fn}(time_range=...)", "pass domain=(t0, t1)")
            domain = time_range
        start, end = time_pair(fn, "domain", domain)
        self._origin = start
        self._length = end - start

    @property
    def time_model(self) -> KnotDomain:
        raw = self.parametrizations.ctrl.original
        return KnotDomain.bezier(self.n_ctrl, self._length, float(self._origin),
                                 device=raw.device)

    @property
    def _min_samples(self) -> int:
        return 2

    def _state(self) -> dict[str, Any]:
        return {"length": self._length}

    def _restore(self, fn: str, state: dict[str, Any]) -> None:
        self._length = _extra_float(fn, state, "length", positive=True)

    @classmethod
    def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                         ) -> dict[str, Any]:
        return {}  # the domain is extra state

    def _convert_01(self, state_dict, prefix, start: float, end: float) -> None:
        state_dict[prefix + "_extra_state"] = {"origin": start, "length": end - start}

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bezier(ctrl, rel, domain=(0.0, self._length), check=False,
                             extrapolate=True)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bezier_derivatives(ctrl, rel, order=order, domain=(0.0, self._length),
                                         check=False, extrapolate=True)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 4,
                 check: bool = True) -> Self:
        n = _check_int(fn, "n_ctrl", n_ctrl, 2, ">= 2")
        if isinstance(times, Tensor) and times.dim() > 1:
            _checks.fail(fn, f"expected (N,) times shared by the batch, got shape "
                             f"{_checks.shape_str(times.shape)}: a Bezier module has one domain "
                             f"(t0, t1) for all its curves; for per-trajectory times use "
                             f"BSpline.from_poses(..., n_ctrl={n}, degree={n - 1}), the same "
                             f"curves (clamped knots) on each row's own domain")
        t64 = _start.check_sample_times(fn, times, x.shape[-2]).detach().to(torch.float64).cpu()
        module = cls(dualquat.identity((*x.shape[:-2], n), dtype=x.dtype, device=x.device),
                     domain=(float(t64[0]), float(t64[-1])), check=check)
        return module._fill(fn, x, t64)

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,
                   n_ctrl: int = 4, check: bool = True) -> Self:
        r"""Bézier curve with ``n_ctrl`` control points fit to timestamped poses.

        The domain is ``[times[0], times[-1]]`` in the caller's units, so ``curve(times)``
        evaluates the fit at the sample times. The control points come from the
        least-squares start (:mod:`torch_dq._start`): the poses lifted into a chart at the
        middle of the trajectory (relative rotations up to a full turn either side of it)
        and fit there by the Bernstein basis; exact for a constant screw motion. Refine the
        result with :func:`torch_dq.fitting.fit`.

        Args:
            rotations: ``(..., N, 4)`` quaternions ``(w, x, y, z)`` (normalised here) or
                ``(..., N, 3, 3)`` rotation matrices; extra leading dims give a batch of
                curves.
            translations: ``(..., N, 3)``, same dtype and device as ``rotations``.
            times: ``(N,)`` strictly increasing finite times in the caller's units, any
                floating dtype (float64 UNIX seconds with float32 poses lose nothing beyond
                float32 rounding of the time since the first sample). Shared by the batch: a
                Bezier module has one domain; for per-trajectory ``(B, N)`` times use
                :meth:`BSpline.from_poses` with ``n_ctrl`` and ``degree = n_ctrl - 1`` (the
                same curves: clamped knots), which holds a domain per row.
            n_ctrl: number of control points, ``2 <= n_ctrl <= N`` (degree ``n_ctrl - 1``).
            check: the module's ``check``.

        Returns:
            The module, with control points of the dtype and device of ``rotations``.

        Raises:
            ValueError: bad shapes, non-increasing times, non-finite poses, more control
                points than samples (underdetermined).

        Example:
            >>> import torch_dq.dualquat as dq
            >>> times = torch.linspace(100.0, 102.0, 9, dtype=torch.float64)
            >>> xi = torch.tensor([0.0, 0.0, 0.3, 1.0, 0.0, 0.0], dtype=torch.float64)
            >>> q, p = dq.to_rt(dq.exp((times - 100.0)[:, None] * xi))
            >>> curve = Bezier.from_poses(q, p, times, n_ctrl=3)
            >>> curve.domain
            (100.0, 102.0)
            >>> torch.allclose(dq.to_rt(curve(times))[1], p)
            True
        """
        fn = f"{cls._name}.from_poses"
        x = _poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, n_ctrl=n_ctrl, check=check)


class BSpline(Curve):
    r"""B-spline curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bspline` on the knot domain
    ``[knots[degree], knots[n]]`` in the caller's units, in one of three forms: ``"de_boor"``
    (De Boor's pyramid of sclerps, paper 4.2, :math:`C^1`), ``"cumulative"`` (Kim-Kim-Shin's
    product of screw powers, :math:`C^{p-1}`: continuous accelerations and IMU readings for
    cubics) or ``"split"`` (a cumulative SO(3) spline for the rotation and a Euclidean one for
    the translation, :math:`C^{p-1}`; see :mod:`torch_dq.curves`). See :class:`Bezier` for
    the parametrization. The knots are not learned: the module keeps their origin
    ``knots[degree]`` as a Python float and the knots relative to it as a buffer (it follows
    ``.to()``), so absolute timestamps survive a float32 module; :attr:`knots` returns them
    in the caller's units (float64). The origin, the degree and
    the form are the extra state of the ``state_dict``.

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n > degree``, projected onto unit
            dual quaternions; leading dims give a batch of curves.
        degree: polynomial degree ``>= 1`` (3: cubic).
        knots: ``(n + degree + 1,)`` non-decreasing finite knots in the caller's units
            (any floating dtype; float64 for absolute timestamps) with
            ``knots[degree] < knots[n]``; or ``(..., n + degree + 1)``, a row per
            trajectory whose batch broadcasts with ``ctrl``'s (each row its own domain and
            float64 origin ``knots[..., degree]``); default clamped uniform on ``[0, 1]``
            (:func:`torch_dq.curves.clamped_uniform_knots`). Meta knots are kept as they
            are (relative to origin 0, unchecked).
        form: ``"de_boor"`` (default), ``"cumulative"`` or ``"split"``; every evaluation
            follows it.
        time_range: deprecated (0.1): ``(t0, t1)`` rescales the knots affinely so that the
            domain becomes ``[t0, t1]`` (``(K,)`` knots only).
        check: check at every call that ``t`` lies in the domain (one device sync; skipped
            under ``torch.compile``, where times outside give NaN).
        extrapolate: default of the evaluations' ``extrapolate=``: continue the end spans
            beyond the domain instead of the domain rules.

    Shape:
        ``forward(t)``: ``t`` ``(T,)`` or ``(..., T)`` in the domain -> ``(..., T, 8)``;
        with knots ``(B, K)``, ``t (B, T)`` (row ``b`` in trajectory ``b``'s domain) or
        ``(T,)`` (the same times for every row) -> ``(B, T, 8)``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> spline = BSpline(dq.identity((6,)), degree=3)
        >>> spline.extra_repr()
        "n_ctrl=6, degree=3, form='de_boor', batch_shape=(), domain=(0.0, 1.0), dtype=torch.float32"
        >>> spline(torch.rand(2, 7)).shape  # a (2, 7) batch of times
        torch.Size([2, 7, 8])
    """

    _name = "nn.BSpline"

    if TYPE_CHECKING:  # a buffer (register_buffer)
        _knots: Tensor

    def __init__(self, ctrl: Tensor, degree: int = 3, knots: Tensor | None = None,
                 form: str = "de_boor", *, time_range: Sequence[float] | Tensor | None = None,
                 check: bool = True, extrapolate: bool = False):
        super().__init__()
        fn = self._name
        degree = _check_int(fn, "degree", degree, 1, ">= 1")
        self.form = curves.check_form(fn, form)
        self._setup(ctrl, 2, check, extrapolate)
        raw = self.parametrizations.ctrl.original
        n = raw.shape[-2]
        if degree >= n:
            _checks.fail(fn, f"degree must be < the number of control points n = {n}, got "
                             f"degree {degree}")
        self.degree = degree
        if knots is not None:
            curves.check_knots(fn, knots, raw, n + degree + 1)
            if knots.dim() > 1 and time_range is not None:
                _checks.fail(fn, "time_range (deprecated) rescales one knot vector; pass knots "
                                 "with a row per trajectory in the caller's time instead")
        if knots is not None and knots.device.type == "meta":  # no values: origin 0
            self._origin = 0.0
            self.register_buffer("_knots", knots.to(dtype=raw.dtype, device=raw.device))
            return
        k64 = (curves.clamped_uniform_knots(n, degree, dtype=torch.float64) if knots is None
               else knots.detach().to(dtype=torch.float64, device="cpu"))
        empty = k64.new_zeros(0)
        KnotDomain(k64, degree).check(fn, empty, knots="knots", extrapolate=True, fix="")
        if time_range is not None:
            k64 = self._time_range_knots(fn, k64, degree, time_range)
        origin: float | Tensor = (float(k64[degree]) if k64.dim() == 1 else
                                  k64[..., degree:degree + 1].to(raw.device))
        self._origin = origin
        self.register_buffer("_knots", (k64.to(raw.device) - origin).to(raw.dtype))

    @property
    def knots(self) -> Tensor:
        """The ``(n + degree + 1,)`` knots (``(..., n + degree + 1)``: a row per trajectory)
        in the caller's units (float64, module's device)."""
        return self._knots.to(torch.float64) + self._origin

    def _apply(self, fn, recurse=True):
        out = super()._apply(fn, recurse)
        if isinstance(self._origin, Tensor):  # per-row origins: float64 whatever .to() says
            self._origin = self._origin.to(self._knots.device)
        return out

    @property
    def time_model(self) -> KnotDomain:
        return KnotDomain(self._knots, self.degree, self._origin)

    @property
    def _min_samples(self) -> int:
        return self.degree + 1

    def _state(self) -> dict[str, Any]:
        return {"degree": self.degree, "form": self.form}

    def _restore(self, fn: str, state: dict[str, Any]) -> None:
        degree = state.get("degree", self.degree)  # 0.2 saved the origin only
        if degree != self.degree:
            _checks.fail(fn, f"the state_dict holds a degree-{degree!r} spline, this module "
                             f"has degree {self.degree}; rebuild it with "
                             f"{self._name}.from_state_dict")
        self.form = curves.check_form(fn, state.get("form", "de_boor"))

    @classmethod
    def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                         ) -> dict[str, Any]:
        extra = state_dict.get("_extra_state")
        extra = extra if isinstance(extra, dict) else {}
        knots = state_dict.get("_knots", state_dict.get("knots"))  # 0.2, 0.1
        degree = extra.get("degree")
        if degree is None:
            degree = knots.shape[-1] - raw.shape[-2] - 1 if isinstance(knots, Tensor) else 3
        args = {"degree": degree, "form": extra.get("form", "de_boor")}
        if isinstance(knots, Tensor) and knots.dim() > 1:  # a row per trajectory
            args["knots"] = knots.to(torch.float64) + _extra_origins(fn, extra, knots)
        return args

    def _convert_01(self, state_dict, prefix, start: float, end: float) -> None:
        p, n = self.degree, self.n_ctrl
        k = state_dict.pop(prefix + "knots", None)
        k = (curves.clamped_uniform_knots(n, p, dtype=torch.float64) if k is None else
             k.detach().to(dtype=torch.float64, device="cpu"))
        k = (k - k[p]) * ((end - start) / float(k[n] - k[p]))  # time since start
        state_dict[prefix + "_knots"] = k.to(self._knots.dtype)
        state_dict[prefix + "_extra_state"] = {"origin": start}

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bspline(ctrl, rel, self.degree, self._knots.to(rel.device), check=False,
                              extrapolate=True, form=self.form)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bspline_derivatives(ctrl, rel, order=order, degree=self.degree,
                                          knots=self._knots.to(rel.device), check=False,
                                          extrapolate=True, form=self.form)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int | None = None,
                 degree: int = 3, form: str = "de_boor", check: bool = True, *,
                 knot_spacing: float | None = None, margin: float = 0.0) -> Self:
        degree = _check_int(fn, "degree", degree, 1, ">= 1")
        form = curves.check_form(fn, form)
        margin = _check_seconds(fn, "margin", margin, 0.0)
        if knot_spacing is not None:
            knot_spacing = _check_seconds(fn, "knot_spacing", knot_spacing, None)
            if n_ctrl is not None:
                _checks.fail(fn, f"pass n_ctrl or knot_spacing, not both (got n_ctrl={n_ctrl!r}"
                                 f", knot_spacing={knot_spacing!r})")
        t64 = _start.check_sample_times(fn, times, x.shape[-2], batched=True)
        t64 = t64.detach().to(torch.float64).cpu()
        batch = x.shape[:-2]
        t0: float | Tensor
        t1: float | Tensor
        if t64.dim() > 1:  # each trajectory its own times: its own knots and origin
            batch = _checks.broadcast_batch(fn, poses=(x, 2), times=(t64, 1))
            t64 = t64.expand(*batch, t64.shape[-1])
            t0, t1 = t64[..., :1] - margin, t64[..., -1:] + margin
        else:
            t0, t1 = float(t64[0]) - margin, float(t64[-1]) + margin
        if knot_spacing is not None:  # the longest row's span at most knot_spacing apart
            span = float(torch.as_tensor(t1 - t0).max())
            n_ctrl = max(math.ceil(span / knot_spacing - 1e-9), 1) + degree
        elif n_ctrl is None:  # chosen from the data
            n_ctrl = _chosen_n_ctrl(fn, x, t64, degree, form)
        n = _check_int(fn, "n_ctrl", n_ctrl, degree + 1, f"> degree = {degree}")
        module = cls(dualquat.identity((*batch, n), dtype=x.dtype, device=x.device), degree=degree,
                     knots=_uniform(n, degree, t0, t1), form=form, check=check)
        coarse = max(degree + 1, x.shape[-2] // _POSES_PER_COARSE_CTRL)
        if knot_spacing is None or n <= coarse:
            return module._fill(fn, x, t64)
        # finer than the poses: their start on coarse knots, sampled densely (each fine
        # knot span _SAMPLES_PER_SPAN times), is the fine curve's data
        dense = t0 + (t1 - t0) * torch.linspace(0.0, 1.0, _SAMPLES_PER_SPAN * (n - degree) + 1,
                                                dtype=torch.float64)
        start = cls(dualquat.identity((*batch, coarse), dtype=x.dtype, device=x.device),
                    degree=degree, knots=_uniform(coarse, degree, t0, t1), form=form,
                    check=check)
        with torch.no_grad():
            xd = start._fill(fn, x, t64)(dense.to(x.device))
        return module._fill(fn, xd, dense)

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,
                   n_ctrl: int | None = None, degree: int = 3, form: str = "de_boor",
                   check: bool = True, *, knot_spacing: float | None = None,
                   margin: float = 0.0) -> Self:
        r"""B-spline with ``n_ctrl`` control points fit to timestamped poses.

        The knots are clamped uniform over ``[times[0], times[-1]]`` in the caller's units
        (with ``(..., N)`` times, each trajectory's over ``[times[b, 0], times[b, -1]]``: a
        row of knots and an origin per trajectory, and each row's own least-squares start),
        so ``spline(times)`` evaluates the fit at the sample times; for a knot every ``h``
        seconds, take ``n_ctrl = ceil((times[-1] - times[0]) / h) + degree``. The control
        points come from the local least-squares start (:mod:`torch_dq._start`): each
        control point is fit in its own chart (the pose interpolated at the middle of a
        window of a few knot spans around it) to the samples of that window, by the
        Euclidean B-spline basis (:meth:`~Curve.basis`), which is the linearization of both
        forms in such a chart. So the start is sane on long trajectories with loops and
        extents of kilometres, costs :math:`O(N)`, does not depend on where the world
        origin is, and is exact for a constant screw motion. Control points that the samples
        do not determine (a time gap longer than a knot span) stay on the screw motion
        between the samples on either side. Keep the rotation per knot span below about
        1 rad (a window then turns less than a full turn); refine the start with
        :func:`torch_dq.fitting.fit`.

        Args:
            rotations: ``(..., N, 4)`` quaternions ``(w, x, y, z)`` (normalised here) or
                ``(..., N, 3, 3)`` rotation matrices; extra leading dims give a batch of
                curves (sharing ``(N,)`` times, or each with its row of ``(..., N)`` times).
            translations: ``(..., N, 3)``, same dtype and device as ``rotations``.
            times: ``(N,)`` strictly increasing finite times in the caller's units, any
                floating dtype (float64 UNIX seconds with float32 poses lose nothing beyond
                float32 rounding of the time since the first sample); or ``(..., N)``, a row
                of such times per trajectory, whose batch broadcasts with the poses'. Rows
                share ``N``: for unequal counts fit each trajectory separately, or pad and
                leave the padding out with the estimation terms' ``mask``
                (:mod:`torch_dq.fitting`).
            n_ctrl: number of control points, ``degree < n_ctrl <= N``; ``None`` (the
                default): chosen from the data, ``ceil(duration / h) + degree`` with the
                knot spacing ``h`` of :func:`torch_dq.fitting.choose_knot_spacing` (the
                largest whose held-out error of the start is within 2 % of the best;
                unbatched poses and ``(N,)`` times, at least ``2 (degree + 2)`` of them).
            degree: polynomial degree ``>= 1`` (3: cubic).
            form: ``"de_boor"`` (default), ``"cumulative"`` or ``"split"`` (see
                :class:`BSpline`).
            check: the module's ``check``.
            knot_spacing: instead of ``n_ctrl``: knots at most this far apart (the times'
                units), ``n_ctrl = ceil(span / knot_spacing) + degree`` over the domain
                (with the margins), finer than the poses if asked (the IMU sets the spacing
                of an estimate): the start is then the regularised least squares of
                ``torch_dq._start.least_squares_start`` (``smooth``: the smoothest
                curve in the local charts between the poses, exact for a constant screw
                motion), and more control points than poses are allowed.
            margin: widen the domain by this much (``>= 0``, the times' units) before the
                first and after the last time: measurements with a time offset up to
                ``margin`` (:mod:`torch_dq.fitting`'s ``max_time_offset``) stay inside it
                without trimming them; the curve continues the end poses there.

        Returns:
            The module, with control points of the dtype and device of ``rotations``.

        Raises:
            ValueError: bad shapes, non-increasing times (the message names the first bad
                row of ``(..., N)`` times), non-finite poses, an unknown ``form``, more
                control points than samples without ``knot_spacing`` (underdetermined),
                ``n_ctrl=None`` with a batch, ``n_ctrl`` and ``knot_spacing`` both given,
                a non-positive ``knot_spacing`` or a negative ``margin``.

        Example:
            >>> import torch_dq.dualquat as dq
            >>> times = 1.7e9 + torch.linspace(0.0, 3.0, 31, dtype=torch.float64)  # UNIX s
            >>> xi = torch.tensor([0.0, 0.2, 0.0, 0.5, 0.0, 0.1], dtype=torch.float64)
            >>> q, p = dq.to_rt(dq.exp((times - times[0])[:, None] * xi))
            >>> spline = BSpline.from_poses(q.float(), p.float(), times, n_ctrl=6)
            >>> spline.domain == (float(times[0]), float(times[-1]))
            True
            >>> err = (dq.to_rt(spline(times))[1] - p).norm(dim=-1).max()  # float64 times
            >>> bool(err < 1e-5)
            True
        """
        fn = f"{cls._name}.from_poses"
        x = _poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, n_ctrl=n_ctrl, degree=degree, form=form,
                            check=check, knot_spacing=knot_spacing, margin=margin)

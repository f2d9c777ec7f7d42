r"""The curve layers' base: :class:`Curve`, the contract of a curve layer, and
:class:`UnitDualQuaternion`, the parametrization of its control points.

Public through :mod:`torch_dq.nn` (``torch_dq.nn.Curve``, ``torch_dq.nn.UnitDualQuaternion``),
where the concrete layers (:class:`torch_dq.nn.Bezier`, :class:`torch_dq.nn.BSpline`) and the
time and domain rules are documented. :mod:`torch_dq.fitting` imports this module only:
the estimation works on any :class:`Curve` through its span contract
(:meth:`Curve.support`, :meth:`Curve.local_times`, :meth:`Curve.evaluate_span`, and
:meth:`Curve.span_derivatives` for many samples at once).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor
from torch.nn.utils import parametrize

from . import _checks, _compat01, _start, curves, dualquat
from ._core import aligned_chain
from ._curve_args import check_int, extra_float, extra_origins
from ._fused_curves import span_points as gather_span_points
from ._time import EXTRAPOLATE_HINT, KnotDomain

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

__all__ = ["Curve", "UnitDualQuaternion", "span_points"]

_RAW = "parametrizations.ctrl.original"  # state_dict key of the raw control points


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


# ----------------------------------------------------------------------------- helpers

def _start_rows(fn: str, x: Tensor, rel: Tensor, dom: KnotDomain, n: int, split: bool,
                ) -> Tensor:
    """The least-squares start of each trajectory of a batch on its own knots (rows of
    ``dom.knots``) and its own relative times ``rel (..., N)``: ``(..., n, 8)`` float64."""
    batch = _checks.broadcast_shapes(x.shape[:-2], dom.knots.shape[:-1], rel.shape[:-1])
    N, K = x.shape[-2], dom.knots.shape[-1]
    rows = zip(x.expand(*batch, N, 8).reshape(-1, N, 8), rel.expand(*batch, N).reshape(-1, N),
               dom.knots.expand(*batch, K).reshape(-1, K), strict=True)
    out = []
    for xb, tb, kb in rows:  # a constructor's loop: each row its own windows and charts
        one = KnotDomain(kb, dom.degree)
        first, values = one.basis(tb)
        out.append(_start.least_squares_start(fn, xb, tb, first, values, n, one.greville(),
                                              split))
    return torch.stack(out).view(*batch, n, 8)


def span_points(ctrl: Tensor, first: Tensor, count: int) -> Tensor:
    """``(..., N, count, 8)``: the control points ``first .. first + count - 1`` (at most the
    last) of each sample (``first (..., N)``, broadcasting against ``ctrl``'s batch) of the
    sign-aligned chain of ``ctrl (..., n, 8)`` (:func:`torch_dq._core.align_chain`): what
    every evaluation reads, so per-sample copies and the shared points give one sign."""
    batch = torch.Size(_checks.broadcast_shapes(ctrl.shape[:-2], first.shape[:-1]))
    return gather_span_points(aligned_chain(ctrl), first + count - 1, count - 1, batch)


# ----------------------------------------------------------------------------- pickling


def _rebuild(cls: type[Curve], state: dict[str, Any], settings: dict[str, bool]) -> Curve:
    """Unpickle a curve layer (see :meth:`Curve.__reduce_ex__`)."""
    module = cls.from_state_dict(state)
    module.check, module.extrapolate = settings["check"], settings["extrapolate"]
    return module.train(settings["training"])


# ----------------------------------------------------------------------------- the contract


class Curve(torch.nn.Module, abc.ABC):
    """A curve layer: learnable unit-dual-quaternion control points on a time model.

    The contract that :class:`torch_dq.nn.Bezier` and :class:`torch_dq.nn.BSpline` implement and
    that :mod:`torch_dq.fitting` relies on (nothing else of a layer). Concrete here: the
    parametrized control points (:attr:`control_points`, :attr:`n_ctrl`), the time
    (:attr:`domain`, the domain rules of :mod:`torch_dq.nn`), :meth:`forward`,
    :meth:`derivatives`, :meth:`kinematics`, :meth:`imu`, the Euclidean :meth:`basis` and
    :meth:`greville` abscissae of the least-squares problems, saving and loading (extra state,
    :meth:`from_state_dict`, pickling), the constructors from poses, and the span structure that
    the estimation uses: :meth:`support` (which control points a time depends on) and
    :meth:`local_times` (the time since the start of its span), both from the time model.

    A subclass supplies its time model (:attr:`time_model`), its evaluation (``_curve``,
    ``_curve_derivatives``) and its span evaluation (:meth:`evaluate_span`, what the
    estimation differentiates); a subclass saved with more than its origin overrides
    ``_state``, ``_restore`` and ``_args_from_state``, one built from poses ``_from_dq``
    (and ``_min_samples``: the fewest samples its least-squares start needs).

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

    @abc.abstractmethod
    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        """Poses at admitted relative times ``rel`` (:meth:`KnotDomain.admit`)."""

    @abc.abstractmethod
    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        """Poses and time derivatives to ``order`` at admitted relative times ``rel``."""

    @abc.abstractmethod
    def evaluate_span(self, points: Tensor, local: Tensor, first: Tensor, order: int,
                      ) -> tuple[Tensor, ...]:
        r"""The curve of one span from given control points, at its local times.

        The span contract of the estimation (basalt's ``evaluate`` with ``start_idx``):
        the pose at a time ``t`` of span ``first`` (:meth:`support`) is this function of the
        span's :attr:`span_size` control points ``c_first .. c_first + w - 1`` and of the
        local time ``t - s`` (:meth:`local_times`) only, whatever the other control points.
        Differentiable (twice) with respect to ``points`` and ``local``.

        Args:
            points: ``(..., w, 8)`` unit dual quaternions, the span's control points
                (``w = span_size``), per sample; leading dims beyond the samples' (copies,
                a batch) are evaluated with the same spans.
            local: ``(...)`` local times (float64, in the span: :meth:`local_times`),
                broadcasting against ``points.shape[:-2]``.
            first: ``(...)`` int64 first control point of each sample's span
                (:meth:`support`): the trailing dims of ``points.shape[:-2]``, a row of
                knots per trajectory in its leading dims where the layer has them.
            order: highest time derivative, 0 to 3.

        Returns:
            ``order + 1`` tensors ``(..., 8)`` (``points.shape[:-2]``): the pose and its
            derivatives with respect to time, of ``points``' dtype.
        """

    def span_derivatives(self, ctrl: Tensor, local: Tensor, first: Tensor, order: int,
                         memo: dict | None = None) -> tuple[Tensor, ...]:
        r""":meth:`evaluate_span` of every sample at once, the span points read from the
        shared control points ``ctrl (..., n, 8)`` (``torch_dq._curve.span_points``): what the
        estimation's costs and linearisation points evaluate (its Jacobians differentiate
        :meth:`evaluate_span` on per-sample copies). A layer whose evaluation shares work
        between the samples of a span (a B-spline's span tables) overrides it; the values
        agree with :meth:`evaluate_span` to rounding.

        Args:
            ctrl: ``(..., n, 8)`` unit dual quaternions.
            local: ``(..., N)`` local times (:meth:`local_times`).
            first: ``(..., N)`` int64 spans (:meth:`support`).
            order: highest time derivative, 0 to 3.
            memo: a dict for what depends on the times and knots alone, kept between calls.

        Returns:
            ``order + 1`` tensors ``(..., N, 8)``.
        """
        return self.evaluate_span(span_points(ctrl, first, self.span_size), local, first, order)

    def span_vjp(self, points: Tensor, local: Tensor, first: Tensor, cotangents: Tensor,
                 pose: Tensor, second: slice | None = None, tables: Tensor | None = None,
                 memo: dict | None = None) -> Tensor | None:
        r"""Closed-form vector-Jacobian products of :meth:`evaluate_span` (arguments as
        there; a span's samples share its points), ``(..., k, w, 6)`` for right steps
        :math:`c_j \exp(\delta_j)` of the points, from ``cotangents (..., k, O, 8)`` of the
        pose ``pose (..., 8)`` and its time derivatives ``0 .. O - 1 <= 2`` (of order 2 the
        rows ``second`` alone nonzero, None: all); ``tables``: :meth:`span_vjp_tables` of
        the points' curve, or None; ``memo``: :meth:`span_derivatives`'. None where the
        layer has none: reverse passes then."""
        return None

    def span_vjp_tables(self, ctrl: Tensor) -> Tensor | None:
        """:meth:`span_vjp`'s per-span work for every span of ``ctrl (..., n, 8)``, or None."""

    @property
    def _min_samples(self) -> int:
        """The fewest samples that can determine a curve of this kind."""
        return self.time_model.degree + 1

    def _state(self) -> dict[str, Any]:
        """Extra state besides the origin (saved in the ``state_dict``)."""
        return {}

    def _restore(self, fn: str, state: dict[str, Any]) -> None:
        """Set what :meth:`_state` saved (checked)."""

    @classmethod
    def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                         ) -> dict[str, Any]:
        """Constructor keywords of a module that can load ``state_dict``."""
        return {}

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, *args: Any, **kwargs: Any) -> Self:
        """A module fit to unit dual quaternions ``x`` at ``times`` (``from_poses``)."""
        _checks.fail(fn, f"{cls.__name__} is not built from poses", TypeError)

    #: whether the least-squares start fits in the split form's charts (:mod:`torch_dq._start`)
    _split_charts = False
    #: float64 times ``(...)`` of the first and last pose ``_from_dq`` fit, else None (margin hint)
    _poses_span: tuple[Tensor, Tensor] | None = None

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
        _checks.poses(fn, "ctrl", ctrl)
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
        _checks.poses(self._name, "control_points", value)
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

    # -- construction and saving
    def _fill(self, fn: str, x: Tensor, t64: Tensor) -> Self:
        """Set the control points to :meth:`_fitted`'s (in ``x``'s dtype and device)."""
        self.control_points = self._fitted(fn, x, t64).to(dtype=x.dtype, device=x.device)
        return self

    def _fitted(self, fn: str, x: Tensor, t64: Tensor) -> Tensor:
        """``(..., n, 8)`` float64 control points of the local least-squares start
        (:func:`torch_dq._start.least_squares_start`) on poses ``x`` at float64 times ``t64``,
        on this curve's knots (the layer left as it is); computed on the CPU, returned on
        ``x``'s device."""
        n, N = self.n_ctrl, x.shape[-2]
        if n > N:
            low = self._min_samples
            fix = (f"a degree-{low - 1} curve needs at least {low} samples: add samples or "
                   f"lower the degree" if N < low else f"use n_ctrl <= {N} (from_poses(..., "
                   f"knot_spacing=) starts knots finer than the poses, smoothing between them)")
            _checks.fail(fn, f"the fit is underdetermined: n_ctrl = {n} control points for "
                             f"N = {N} samples; {fix}")
        x64 = x.detach().to(dtype=torch.float64, device="cpu")
        if not bool((ok := torch.isfinite(x64).all(-1)).all()):
            at = ", ".join(map(str, _checks.first_index(~ok)))
            _checks.fail(fn, f"the poses must be finite, with non-zero rotations (not poses[{at}])")
        dom = self.time_model
        origin = dom.origin.cpu() if isinstance(dom.origin, Tensor) else dom.origin
        dom = KnotDomain(dom.knots.detach().cpu(), dom.degree, origin)
        rel, split = dom.relative(t64.detach().cpu(), torch.float64), self._split_charts
        if dom.knots.dim() > 1:
            return _start_rows(fn, x64, rel, dom, n, split).to(x.device)
        first, values = dom.basis(rel)
        return _start.least_squares_start(fn, x64, rel, first, values, n, dom.greville(),
                                          split).to(x.device)

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
        _checks.rigid_matrix(fn, "T", T)
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
            self._origin = extra_origins(fn, state, knots)
        else:
            self._origin = extra_float(fn, state, "origin")
        self._restore(fn, state)
        self._poses_span = None  # the knots may be another curve's

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

    # -- time
    @property
    def domain(self) -> tuple[float, float] | tuple[Tensor, Tensor]:
        """The module's time domain ``(start, end)`` in the caller's units: Python floats;
        for a :class:`BSpline` with a row of knots per trajectory two float64 tensors of
        the knots' batch shape (row ``b``: trajectory ``b``'s domain)."""
        return self.time_model.domain()

    def _times(self, fn: str, t: Tensor, like: Tensor, extrapolate: bool | None,
               fix: str = f"or {EXTRAPOLATE_HINT}", since_origin: bool = False) -> Tensor:
        """``t - origin`` in the wider of ``t``'s and ``like``'s dtypes, admitted by the time
        model (checked when ``self.check``; ``fix``: the last advice on other times;
        ``since_origin``: ``t`` is such a time already)."""
        _checks.tensor(fn, "t", t)
        if t.dim() < 1:
            _checks.fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
        knots = self.time_model.knots  # (..., K): a row per trajectory when batched
        _checks.broadcast_batch(fn, ctrl=(like, 2), t=(t, 1),
                                **({"knots": (knots, 1)} if knots.dim() > 1 else {}))
        if t.device != like.device:
            _checks.fail(fn, f"t is on {t.device} but the control points are on {like.device}",
                         TypeError)
        extrapolate = (self.extrapolate if extrapolate is None
                       else _checks.flag(fn, "extrapolate", extrapolate))
        return self.time_model.prepare(
            fn, t, like.dtype, check=self.check, extrapolate=extrapolate, knots=None,
            since_origin=since_origin,
            what="the module's time domain", fix="evaluate inside it (the caller's units; "
            f"from_poses places it over [times[0], times[-1]]), {fix}")

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
                    extrapolate: bool | None = None, *, since_origin: bool = False,
                    ) -> tuple[Tensor, ...]:
        r"""Poses and their exact time derivatives ``(x, dx/dt, ..., d^order x/dt^order)``.

        Derivatives are with respect to the caller's time (the module's own), through
        :func:`torch_dq.curves.bspline_derivatives` / :func:`torch_dq.curves.bezier_derivatives`:
        exact, differentiable (twice) with respect to the control points and ``t``.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain` (see :meth:`forward`).
            order: highest derivative, 0 to 3.
            ctrl: optional predicted control points (see :meth:`forward`).
            extrapolate: see :meth:`forward`.
            since_origin: ``t`` are times since the module's origin (``domain[0]``, per
                trajectory for batched knots): ``(t - origin) + dt`` stays exact at UNIX
                stamps, where ``t + dt`` rounds to ``2.4e-7`` s.

        Returns:
            ``order + 1`` tensors, each ``(..., T, 8)``.
        """
        fn = f"{self._name}.derivatives"
        order = check_int(fn, "order", order, 0, "in 0..3")
        if order > 3:
            _checks.fail(fn, f"order must be an int in 0..3, got {order!r}")
        ctrl = self._resolve(fn, ctrl)
        rel = self._times(fn, t, ctrl, extrapolate, since_origin=since_origin)
        return self._curve_derivatives(ctrl, rel, order)

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

    # -- the span structure (what the estimation uses)
    @property
    def span_size(self) -> int:
        """Control points ``w`` that a time depends on: ``degree + 1`` of the time model (a
        B-spline's ``p + 1``; a Bézier curve's ``n``)."""
        return self.time_model.degree + 1

    def support(self, t: Tensor, since_origin: bool = False) -> tuple[Tensor, int]:
        r"""The control points that the poses at ``t`` depend on: ``(first, w)``.

        The pose at ``t[..., i]`` is :meth:`evaluate_span` of the control points
        ``first[..., i] .. first[..., i] + w - 1`` only (``w =`` :attr:`span_size`): the span
        of the time model (``KnotDomain.span``) holding ``t``; times beyond the domain take
        the end spans. No domain check, no gradient.

        Args:
            t: ``(..., T)`` times in the caller's units (float64 UNIX times welcome;
                ``since_origin``: since the time model's origin, exact where ``t + dt``
                rounds); with a row of knots per trajectory its leading dims broadcast.

        Returns:
            ``first`` ``(..., T)`` int64 (each trajectory's own index) and ``w``.
        """
        dom = self.time_model
        rel = dom.relative(t.detach(), torch.float64, since_origin)
        return dom.span(rel) - dom.degree, self.span_size

    def local_times(self, t: Tensor, first: Tensor, since_origin: bool = False) -> Tensor:
        r"""Time since the start of span ``first``: ``t - origin - u_{first + p}`` (float64).

        Clamped into the span ``[0, u_{first + p + 1} - u_{first + p}]`` (times beyond the
        domain by a rounding: evaluated at the end); differentiable with respect to ``t``.

        Args:
            t: ``(..., T)`` times in the caller's units (``since_origin``: :meth:`support`).
            first: ``(..., T)`` int64 spans of them (:meth:`support`); ``t`` may have more
                leading dims (copies), broadcasting against it.

        Returns:
            ``(...)`` float64 local times, ``t``'s and ``first``'s broadcast shape.
        """
        dom = self.time_model
        return dom.local_times(t, first + dom.degree, since_origin)

    def acceleration_jumps(self) -> str | None:
        """None where the accelerations are continuous in time (the curve is C2); else what
        the curve is and what to do instead, for the estimation's warning when an
        accelerometer reads them (a B-spline of form ``"de_boor"`` and degree >= 2: C1)."""
        return None

    def acceleration_kinks(self) -> str | None:
        """None where the accelerations are C1 in time; else what the curve is, for the
        estimation's warning on an accelerometer's estimated time offset (its cost kinks)."""
        return None

    # -- 0.1 (deprecated, through the converter torch_dq._compat01)
    def normalize_time(self, times: Tensor) -> Tensor:
        """Deprecated: the identity (modules now take the caller's time directly).

        0.1 mapped raw times onto ``[0, 1]``; since 0.2 a module's time is the caller's, so
        ``module(times)`` replaces ``module(module.normalize_time(times))``.
        """
        _compat01.deprecated(f"{self._name}.normalize_time",
                             "modules take the caller's time directly; call module(times)")
        _checks.tensor(f"{self._name}.normalize_time", "times", times)
        return times

    @property
    def time_range(self) -> Tensor:
        """The :attr:`~Curve.domain` as a float64 ``(2,)`` tensor (deprecated since 0.2)."""
        _compat01.deprecated(f"{self._name}.time_range", "use module.domain")
        return _compat01.domain_tensor(self.domain, self.parametrizations.ctrl.original.device)

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

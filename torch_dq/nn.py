r"""Curve layers with learnable unit-dual-quaternion control points, in the caller's time.

- :class:`UnitDualQuaternion`: a parametrization in PyTorch's sense
  (:func:`torch.nn.utils.parametrize.register_parametrization`): the stored raw ``(..., 8)``
  tensor is unconstrained and ``forward`` projects it with
  :func:`torch_dq.dualquat.normalize`, so the parameter seen by the module is a unit dual
  quaternion whatever an optimizer does to the raw tensor.
- :class:`Bezier` and :class:`BSpline`: ``nn.Module`` wrappers of
  :func:`torch_dq.curves.bezier` and :func:`torch_dq.curves.bspline` whose control points
  are such a parameter; ``forward(t, ctrl=...)`` (and :meth:`~BSpline.derivatives`,
  :meth:`~BSpline.kinematics`, :meth:`~BSpline.imu`) use control points predicted by another
  network instead. ``from_poses`` / ``from_matrices`` / ``from_dualquats`` build a curve by
  local least squares on timestamped poses (:mod:`torch_dq.fitting`).
- :func:`fit` and :class:`FitHistory` (from :mod:`torch_dq.fitting`): refine a curve on
  timestamped poses (Levenberg-Marquardt in local charts, or any ``torch.optim`` optimizer).

Time is the caller's (seconds, frames, ...): a :class:`Bezier` lives on its ``domain``
``(t0, t1)`` and a :class:`BSpline` on ``[knots[degree], knots[n]]``, and ``module(t)``
takes ``t`` in those units. ``from_poses`` places the curve over ``[times[0], times[-1]]``,
so ``module(times)`` is the fit at those very times. Absolute timestamps (UNIX seconds,
~1.7e9) are welcome in float64 even for a float32 module: the module keeps its time origin
(the start of its domain) as a Python float (float64, saved in the ``state_dict`` as extra
state and untouched by ``.to(dtype)``) and its knots relative to it, and evaluates
``t - origin`` in the wider of the two dtypes, so nothing is lost beyond the rounding of the
time since the origin in the module's dtype.

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

import math
import numbers
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor
from torch.nn.utils import parametrize

from . import _checks, curves, dualquat, fitting, quat
from .fitting import FitHistory, fit

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

__all__ = ["BSpline", "Bezier", "FitHistory", "UnitDualQuaternion", "fit"]

_ULPS = 4.0  # tolerance of the domain check, in units of eps * scale of the relative domain


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


def _time_pair(fn: str, name: str, value) -> tuple[float, float]:
    """Two finite increasing times ``(t0, t1)`` from a pair of numbers or a ``(2,)`` tensor."""
    try:
        pair = tuple(float(v) for v in (value.detach().cpu().tolist() if isinstance(
            value, Tensor) else value))
    except (TypeError, ValueError):
        pair = ()
    if len(pair) != 2 or not all(math.isfinite(v) for v in pair) or not pair[0] < pair[1]:
        _checks.fail(fn, f"{name} must be two finite increasing times (t0, t1), got {value!r}")
    return pair[0], pair[1]


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


def _deprecated(what: str, instead: str) -> None:
    warnings.warn(f"{what} is deprecated: {instead}", DeprecationWarning, stacklevel=3)


# ----------------------------------------------------------------------------- curve layers

class _Curve(torch.nn.Module):
    """Shared machinery: the parametrized ``ctrl``, the time origin, evaluation, derivatives
    and the constructors from poses. Subclasses define ``_relative_domain``, ``_curve``,
    ``_curve_derivatives``, ``basis`` and ``_from_dq``."""

    _name = "nn._Curve"

    if TYPE_CHECKING:  # attributes set by _setup and parametrize, hooks of the subclasses
        ctrl: Tensor
        parametrizations: _Parametrizations
        check: bool
        _origin: float

        def _relative_domain(self) -> tuple[Tensor | float, Tensor | float]: ...

        def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor: ...

        def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int,
                               ) -> tuple[Tensor, ...]: ...

        def basis(self, t: Tensor) -> tuple[Tensor, Tensor]: ...

        def _greville(self) -> Tensor: ...

        def _convert_01(self, state_dict: dict[str, Any], prefix: str, start: float,
                        end: float) -> None: ...

        @classmethod
        def _from_dq(cls, fn: str, x: Tensor, times: Tensor, *args: Any,
                     **kwargs: Any) -> Self: ...

    def _setup(self, ctrl: Tensor, min_points: int, check: bool) -> None:
        fn = self._name
        _checks.tensor(fn, "ctrl", ctrl, 8)
        if ctrl.dim() < 2 or ctrl.shape[-2] < min_points:
            _checks.fail(fn, f"expected a (..., n, 8) tensor for ctrl with n >= {min_points}, "
                             f"got shape {_checks.shape_str(ctrl.shape)}")
        if not isinstance(check, bool):
            _checks.fail(fn, f"check must be a bool, got {check!r}", TypeError)
        self.check = check
        self.ctrl = torch.nn.Parameter(ctrl.detach().clone())
        parametrize.register_parametrization(self, "ctrl", UnitDualQuaternion())

    # -- control points
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
    def domain(self) -> tuple[float, float]:
        """The module's time domain ``(start, end)`` in the caller's units (Python floats)."""
        lo, hi = self._relative_domain()
        return self._origin + float(lo), self._origin + float(hi)

    def get_extra_state(self) -> dict:
        return {"origin": self._origin}

    def set_extra_state(self, state: dict) -> None:
        origin = state.get("origin") if isinstance(state, dict) else None
        if isinstance(origin, bool) or not isinstance(origin, numbers.Real) or not math.isfinite(
                origin):
            _checks.fail(f"{self._name}.load_state_dict", f"expected extra state "
                                                          f"{{'origin': float}}, got {state!r}")
        self._origin = float(origin)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # A 0.1 state_dict: a ``time_range`` buffer (and knots on the domain it maps onto)
        # instead of the time origin: converted, with a DeprecationWarning.
        if prefix + "time_range" in state_dict and prefix + "_extra_state" not in state_dict:
            warnings.warn(f"{self._name}.load_state_dict: converting a 0.1 state_dict "
                          f"(time_range) to the caller's time; save it again to update it",
                          DeprecationWarning, stacklevel=4)
            start, end = (float(v) for v in state_dict.pop(prefix + "time_range").tolist())
            self._convert_01(state_dict, prefix, start, end)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _local_time(self, fn: str, t: Tensor, like: Tensor) -> Tensor:
        """``t - origin`` in the wider of ``t``'s and ``like``'s dtypes, checked against the
        domain when ``self.check``."""
        _checks.tensor(fn, "t", t)
        if t.dim() < 1:
            _checks.fail(fn, "expected a (T,) or (..., T) tensor for t, got shape ()")
        if t.device != like.device:
            _checks.fail(fn, f"t is on {t.device} but the control points are on {like.device}",
                         TypeError)
        wide = torch.promote_types(t.dtype, like.dtype)
        rel = t.to(wide) - self._origin if self._origin != 0.0 else t.to(wide)
        if self.check:
            lo, hi = self._relative_domain()
            # the relative knots are stored in the module's dtype, maybe narrower than like's
            stored = self.parametrizations.ctrl.original.dtype
            eps = max(torch.finfo(stored).eps, torch.finfo(like.dtype).eps)
            tol = _ULPS * eps * max(abs(float(lo)), abs(float(hi)))
            outside = ((rel < float(lo) - tol) | (rel > float(hi) + tol)).any()
            try:
                bad = bool(outside)
            except RuntimeError as e:  # a transform with no host values, e.g. vmap over t
                raise RuntimeError(f"{fn}: the domain check reads t on the host, which this "
                                   f"transform does not allow; build the module with "
                                   f"check=False") from e
            if bad:
                start, end = self.domain
                finite = t.detach()[torch.isfinite(t.detach())]
                seen = (f"values in [{float(finite.min())!r}, {float(finite.max())!r}]"
                        if finite.numel() else "no finite value")
                nonfinite = t.numel() - finite.numel()
                _checks.fail(fn, f"t must lie in the module's time domain [{start!r}, {end!r}] "
                                 f"(the caller's units; from_poses places it over "
                                 f"[times[0], times[-1]]), got {seen}"
                                 + (f" and {nonfinite} non-finite" if nonfinite else ""))
        return rel

    def forward(self, t: Tensor, ctrl: Tensor | None = None) -> Tensor:
        """Poses at times ``t`` of the module's domain (the caller's units).

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`, any floating dtype (float64
                absolute timestamps work with a float32 module), on the module's device;
                batch dims broadcast with those of the control points.
            ctrl: optional ``(..., n, 8)`` control points (e.g. a network's raw outputs)
                used instead of the module's own, projected like them; ``n`` must be the
                module's.

        Returns:
            ``(..., T, 8)`` unit dual quaternions of the control points' dtype.

        Raises:
            ValueError: ``t`` outside the domain (with ``check``), bad shapes.
        """
        fn = f"{self._name}.forward"
        ctrl = self._resolve(fn, ctrl)
        return self._curve(ctrl, self._local_time(fn, t, ctrl))

    def derivatives(self, t: Tensor, order: int = 2, ctrl: Tensor | None = None,
                    ) -> tuple[Tensor, ...]:
        r"""Poses and their exact time derivatives ``(x, dx/dt, ..., d^order x/dt^order)``.

        Derivatives are with respect to the caller's time (the module's own), through
        :func:`torch_dq.curves.bspline_derivatives` / :func:`torch_dq.curves.bezier_derivatives`:
        exact, differentiable (twice) with respect to the control points and ``t``.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain` (see :meth:`forward`).
            order: highest derivative, 0 to 3.
            ctrl: optional predicted control points (see :meth:`forward`).

        Returns:
            ``order + 1`` tensors, each ``(..., T, 8)``.
        """
        fn = f"{self._name}.derivatives"
        order = _check_int(fn, "order", order, 0, "in 0..3")
        if order > 3:
            _checks.fail(fn, f"order must be an int in 0..3, got {order!r}")
        ctrl = self._resolve(fn, ctrl)
        return self._curve_derivatives(ctrl, self._local_time(fn, t, ctrl), order)

    def kinematics(self, t: Tensor, frame: str = "world", ctrl: Tensor | None = None,
                   ) -> curves.Kinematics:
        r"""Angular and linear velocities and accelerations at ``t`` (caller's units).

        As :func:`torch_dq.curves.kinematics` on :meth:`derivatives` of order 2: with
        ``x = (R, p)``, world frame ``dR/dt = [w]x R``, ``v = dp/dt``, ``alpha = dw/dt``,
        ``a = d^2 p/dt^2``; ``frame="body"`` gives the same vectors in body axes.
        Differentiable (twice) with respect to the control points.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`.
            frame: ``"world"`` or ``"body"``.
            ctrl: optional predicted control points (see :meth:`forward`).

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
        x, dx, ddx = self.derivatives(t, 2, ctrl)
        return curves.kinematics(x, dx, ddx, frame=frame)

    def imu(self, t: Tensor, gravity: Tensor | Sequence[float] = (0.0, 0.0, -9.81),
            ctrl: Tensor | None = None,
            ) -> tuple[Tensor, Tensor]:
        r"""What an ideal IMU rigidly attached at the body origin reads at ``t``.

        As :func:`torch_dq.curves.imu` on :meth:`derivatives` of order 2: gyroscope
        :math:`R^T \omega` and accelerometer (specific force) :math:`R^T (a - g)`.

        Args:
            t: ``(T,)`` or ``(..., T)`` times in :attr:`domain`.
            gravity: gravity ``g`` in world axes (default ``(0, 0, -9.81)``).
            ctrl: optional predicted control points (see :meth:`forward`).

        Returns:
            ``(gyro, accel)``, each ``(..., T, 3)``.
        """
        x, dx, ddx = self.derivatives(t, 2, ctrl)
        return curves.imu(x, dx, ddx, gravity=gravity)

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
        """Deprecated: the :attr:`domain` as a float64 ``(2,)`` tensor."""
        _deprecated(f"{self._name}.time_range", "use module.domain")
        like = self.parametrizations.ctrl.original
        return torch.tensor(self.domain, dtype=torch.float64, device=like.device)

    def extra_repr(self) -> str:
        raw = self.parametrizations.ctrl.original
        batch = _checks.shape_str(raw.shape[:-2])
        start, end = self.domain
        deg = f", degree={self.degree}" if hasattr(self, "degree") else ""
        return (f"n_ctrl={self.n_ctrl}{deg}, batch_shape={batch}, domain=({start!r}, "
                f"{end!r}), dtype={raw.dtype}")

    # -- constructors from poses
    def _fill(self, fn: str, x: Tensor, t64: Tensor) -> Self:
        """Set the control points from the local least-squares start
        (:func:`torch_dq.fitting.least_squares_start`) on poses ``x`` at float64 times."""
        n, N = self.n_ctrl, x.shape[-2]
        if n > N:
            low = self.degree + 1 if isinstance(self, BSpline) else 2
            fix = (f"use n_ctrl <= {N}" if N >= low else
                   f"a degree-{low - 1} curve needs at least {low} samples: add samples or "
                   f"lower the degree")
            _checks.fail(fn, f"the fit is underdetermined: n_ctrl = {n} control points for "
                             f"N = {N} samples; {fix}")
        x64 = x.detach().to(dtype=torch.float64, device="cpu")
        if not bool(torch.isfinite(x64).all()):
            _checks.fail(fn, "the poses must be finite, with non-zero rotations")
        first, values = self.basis(t64.to(x.device))
        first, values = first.cpu(), values.cpu()
        ctrl = fitting.least_squares_start(x64, t64 - self._origin, first, values, n,
                                           self._greville())
        self.control_points = ctrl.to(dtype=x.dtype, device=x.device)
        return self

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,
                   **kwargs: Any) -> Self:
        r"""Curve over ``[times[0], times[-1]]`` fit to timestamped rigid poses.

        The time domain is placed over the samples in the caller's units, so
        ``module(times)`` evaluates the fit at the sample times. The control points come
        from a local least-squares start (:func:`torch_dq.fitting.least_squares_start`):
        each control point is fit in a local chart (the pose interpolated at its Greville
        abscissa) to the samples of a window around it, so the start is sane on long
        trajectories with loops and extents of kilometres, costs :math:`O(N)`, and does not
        depend on where the world origin is. Control points that the samples do not
        determine (a time gap longer than a knot span) are bridged: they stay on the screw
        motion between the samples on either side of the gap. Refine the start with
        :func:`fit`.

        Args:
            rotations: ``(..., N, 4)`` quaternions ``(w, x, y, z)`` (normalised here) or
                ``(..., N, 3, 3)`` rotation matrices. Extra leading dims give a batch of
                curves.
            translations: ``(..., N, 3)``, same dtype and device as ``rotations``.
            times: ``(N,)`` strictly increasing finite times in the caller's units, any
                floating dtype (float64 UNIX seconds with float32 poses lose nothing beyond
                float32 rounding of the time since the first sample).
            **kwargs: ``n_ctrl`` (and ``degree`` for :class:`BSpline`), ``check``.

        Returns:
            The module, with control points of the dtype and device of ``rotations``.

        Raises:
            ValueError: bad shapes, non-increasing times, non-finite poses, more control
                points than samples (``n_ctrl > N``: underdetermined).
        """
        fn = f"{cls._name}.from_poses"
        x = _poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, **kwargs)

    @classmethod
    def from_matrices(cls, T: Tensor, times: Tensor, **kwargs: Any) -> Self:
        """:meth:`from_poses` with ``(..., N, 4, 4)`` homogeneous matrices ``T``.

        Keywords as for :meth:`from_poses` (``n_ctrl``, ``degree`` for a B-spline, ``check``).
        """
        fn = f"{cls._name}.from_matrices"
        _checks.tensor(fn, "T", T, (4, 4))
        if T.dim() < 3:
            _checks.fail(fn, f"expected a (..., N, 4, 4) tensor for T, got shape "
                             f"{_checks.shape_str(T.shape)}")
        return cls._from_dq(fn, dualquat.from_matrix(T), times, **kwargs)

    @classmethod
    def from_dualquats(cls, x: Tensor, times: Tensor, **kwargs: Any) -> Self:
        """:meth:`from_poses` with ``(..., N, 8)`` unit dual quaternions ``x`` (any signs)."""
        fn = f"{cls._name}.from_dualquats"
        _checks.tensor(fn, "x", x, 8)
        if x.dim() < 2:
            _checks.fail(fn, f"expected a (..., N, 8) tensor for x, got shape "
                             f"{_checks.shape_str(x.shape)}")
        return cls._from_dq(fn, dualquat.normalize(x), times, **kwargs)


class Bezier(_Curve):
    r"""Bézier curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bezier` (De Casteljau with ``sclerp``, paper 4.1) on
    its ``domain`` in the caller's units. The control points are the parameter ``ctrl``
    under the :class:`UnitDualQuaternion` parametrization: the raw tensor
    (``parametrizations.ctrl.original``) is what optimizers update, and
    ``.control_points`` (= ``.ctrl``) is always its unit projection. Save and load through
    ``state_dict`` (the domain is extra state; parametrized modules do not pickle).

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n >= 2`` (degree ``n - 1``),
            projected onto unit dual quaternions; leading dims give a batch of curves.
            dtype and device of the module.
        domain: ``(t0, t1)``, the time span of the curve in the caller's units (kept as
            Python floats: absolute timestamps are safe with a float32 module).
        time_range: deprecated alias of ``domain`` (0.1).
        check: check at every call that ``t`` lies in the domain (one device sync).

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
                 time_range: Sequence[float] | Tensor | None = None, check: bool = True):
        super().__init__()
        fn = self._name
        self._setup(ctrl, 2, check)
        if time_range is not None:
            _deprecated(f"{fn}(time_range=...)", "pass domain=(t0, t1)")
            domain = time_range
        start, end = _time_pair(fn, "domain", domain)
        self._origin = start
        self._length = end - start

    def get_extra_state(self) -> dict:
        return {"origin": self._origin, "length": self._length}

    def set_extra_state(self, state: dict) -> None:
        super().set_extra_state(state)
        length = state.get("length")
        if isinstance(length, bool) or not isinstance(length, numbers.Real) or not (
                math.isfinite(length) and float(length) > 0):
            _checks.fail(f"{self._name}.load_state_dict", f"expected a finite length > 0 in "
                                                          f"the extra state, got {state!r}")
        self._length = float(length)

    def _convert_01(self, state_dict, prefix, start: float, end: float) -> None:
        state_dict[prefix + "_extra_state"] = {"origin": start, "length": end - start}

    def _relative_domain(self) -> tuple[float, float]:
        return 0.0, self._length

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bezier(ctrl, rel, domain=(0.0, self._length), check=False)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bezier_derivatives(ctrl, rel, order=order, domain=(0.0, self._length),
                                         check=False)

    def basis(self, t: Tensor) -> tuple[Tensor, Tensor]:
        r"""Euclidean Bernstein basis at ``t``: ``(first (T,), values (T, n))``.

        ``values[i, j]`` is :math:`\binom{n-1}{j} u^j (1-u)^{n-1-j}` at the local parameter
        ``u`` of ``t[i]``; every pose depends on all ``n`` control points (``first = 0``).
        This is the design matrix of the least-squares start.

        Args:
            t: ``(T,)`` times in the domain (caller's units), any floating dtype.

        Returns:
            ``(first, values)``: ``(T,)`` int64 zeros and ``(T, n)`` float64 values.
        """
        fn = f"{self._name}.basis"
        rel = self._local_time(fn, t, self.parametrizations.ctrl.original).to(torch.float64)
        if rel.dim() != 1:
            _checks.fail(fn, f"expected a (T,) tensor for t, got shape "
                             f"{_checks.shape_str(t.shape)}")
        u = (rel / self._length)[:, None]
        n = self.n_ctrl
        j = torch.arange(n, dtype=torch.float64, device=rel.device)
        binom = torch.tensor([math.comb(n - 1, k) for k in range(n)], dtype=torch.float64,
                             device=rel.device)
        values = binom * u**j * (1.0 - u) ** (n - 1 - j)
        return torch.zeros(rel.shape, dtype=torch.int64, device=rel.device), values

    def _greville(self) -> Tensor:
        return torch.linspace(0.0, self._length, self.n_ctrl, dtype=torch.float64)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 4,
                 check: bool = True) -> Self:
        n = _check_int(fn, "n_ctrl", n_ctrl, 2, ">= 2")
        t64 = fitting.check_times(fn, times, x.shape[-2]).detach().to(torch.float64).cpu()
        module = cls(dualquat.identity((*x.shape[:-2], n), dtype=x.dtype, device=x.device),
                     domain=(float(t64[0]), float(t64[-1])), check=check)
        return module._fill(fn, x, t64)

    # The override spells out the keywords that _Curve.from_poses takes as **kwargs.
    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,  # type: ignore[override]
                   n_ctrl: int = 4, check: bool = True) -> Bezier:
        """Bézier curve with ``n_ctrl`` control points fit to poses over
        ``[times[0], times[-1]]`` (Bernstein basis; see :meth:`_Curve.from_poses`).

        ``n_ctrl >= 2`` (degree ``n_ctrl - 1``), at most the number of samples.

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
        return super().from_poses(rotations, translations, times, n_ctrl=n_ctrl, check=check)


class BSpline(_Curve):
    r"""B-spline curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bspline` (De Boor with ``sclerp``, paper 4.2) on the
    knot domain ``[knots[degree], knots[n]]`` in the caller's units; see :class:`Bezier`
    for the parametrization. The knots are not learned: the module keeps their origin
    ``knots[degree]`` as a Python float (extra state of the ``state_dict``) and the knots
    relative to it as a buffer (it follows ``.to()``), so absolute timestamps survive a
    float32 module; :attr:`knots` returns them in the caller's units (float64).

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n > degree``, projected onto unit
            dual quaternions; leading dims give a batch of curves.
        degree: polynomial degree ``>= 1`` (3: cubic).
        knots: ``(n + degree + 1,)`` non-decreasing finite knots in the caller's units
            (any floating dtype; float64 for absolute timestamps) with
            ``knots[degree] < knots[n]``; default clamped uniform on ``[0, 1]``
            (:func:`torch_dq.curves.clamped_uniform_knots`).
        time_range: deprecated (0.1): ``(t0, t1)`` rescales the knots affinely so that the
            domain becomes ``[t0, t1]``.
        check: check at every call that ``t`` lies in the domain (one device sync).

    Shape:
        ``forward(t)``: ``t`` ``(T,)`` or ``(..., T)`` in the domain -> ``(..., T, 8)``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> spline = BSpline(dq.identity((6,)), degree=3)
        >>> spline.extra_repr()
        'n_ctrl=6, degree=3, batch_shape=(), domain=(0.0, 1.0), dtype=torch.float32'
        >>> spline(torch.rand(2, 7)).shape  # a (2, 7) batch of times
        torch.Size([2, 7, 8])
    """

    _name = "nn.BSpline"

    if TYPE_CHECKING:  # a buffer (register_buffer)
        _knots: Tensor

    def __init__(self, ctrl: Tensor, degree: int = 3, knots: Tensor | None = None, *,
                 time_range: Sequence[float] | Tensor | None = None, check: bool = True):
        super().__init__()
        fn = self._name
        degree = _check_int(fn, "degree", degree, 1, ">= 1")
        self._setup(ctrl, 2, check)
        raw = self.parametrizations.ctrl.original
        n = raw.shape[-2]
        if degree >= n:
            _checks.fail(fn, f"degree must be < the number of control points n = {n}, got "
                             f"degree {degree}")
        self.degree = degree
        if knots is None:
            k64 = curves.clamped_uniform_knots(n, degree, dtype=torch.float64)
        else:
            _checks.tensor(fn, "knots", knots)
            if knots.dim() != 1 or knots.shape[0] != n + degree + 1:
                _checks.fail(fn, f"expected a 1-D knots tensor of n + degree + 1 = "
                                 f"{n + degree + 1} entries, got shape "
                                 f"{_checks.shape_str(knots.shape)}")
            k64 = knots.detach().to(dtype=torch.float64, device="cpu")
            bad = torch.stack((~torch.isfinite(k64).all(), (k64[1:] < k64[:-1]).any(),
                               ~(k64[degree] < k64[n]))).tolist()
            if any(bad):
                _checks.fail(fn, f"knots must be finite and non-decreasing with "
                                 f"knots[degree] < knots[n], got {k64.tolist()}")
        if time_range is not None:  # affine map of the knot domain onto time_range
            _deprecated(f"{fn}(time_range=...)", "pass knots in the caller's time (or build "
                                                 "with from_poses)")
            span = _time_pair(fn, "time_range", time_range)
            lo, hi = k64[degree], k64[n]
            k64 = span[0] + (k64 - lo) * ((span[1] - span[0]) / (hi - lo))
            k64[degree], k64[n] = span  # exact ends
        self._origin = float(k64[degree])
        self.register_buffer("_knots", (k64 - self._origin).to(dtype=raw.dtype,
                                                                 device=raw.device))

    def _convert_01(self, state_dict, prefix, start: float, end: float) -> None:
        p, n = self.degree, self.n_ctrl
        k = state_dict.pop(prefix + "knots", None)
        k = (curves.clamped_uniform_knots(n, p, dtype=torch.float64) if k is None else
             k.detach().to(dtype=torch.float64, device="cpu"))
        k = (k - k[p]) * ((end - start) / float(k[n] - k[p]))  # time since start
        state_dict[prefix + "_knots"] = k.to(self._knots.dtype)
        state_dict[prefix + "_extra_state"] = {"origin": start}

    @property
    def knots(self) -> Tensor:
        """The ``(n + degree + 1,)`` knots in the caller's units (float64, module's device)."""
        return self._knots.to(torch.float64) + self._origin

    def _relative_domain(self) -> tuple[Tensor, Tensor]:
        return self._knots[self.degree], self._knots[self.n_ctrl]

    def _knots_like(self, rel: Tensor) -> Tensor:
        return self._knots.to(dtype=rel.dtype, device=rel.device)

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bspline(ctrl, rel, self.degree, self._knots_like(rel), check=False)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bspline_derivatives(ctrl, rel, order=order, degree=self.degree,
                                          knots=self._knots_like(rel), check=False)

    def basis(self, t: Tensor) -> tuple[Tensor, Tensor]:
        r"""Euclidean B-spline basis at ``t``: ``(first (T,), values (T, degree + 1))``.

        The pose at ``t[i]`` depends on the control points ``first[i] .. first[i] + degree``
        only (local support), with the Cox-de Boor basis functions
        ``values[i, j] = N_{first[i] + j, degree}(t[i])`` (non-negative, summing to 1): the
        banded design matrix of the least-squares start and of the Gauss-Newton fit.

        Args:
            t: ``(T,)`` times in the domain (caller's units), any floating dtype.

        Returns:
            ``(first, values)``: ``(T,)`` int64 and ``(T, degree + 1)`` float64.
        """
        fn = f"{self._name}.basis"
        rel = self._local_time(fn, t, self.parametrizations.ctrl.original).to(torch.float64)
        if rel.dim() != 1:
            _checks.fail(fn, f"expected a (T,) tensor for t, got shape "
                             f"{_checks.shape_str(t.shape)}")
        return fitting.bspline_basis(rel, self._knots.to(torch.float64), self.degree)

    def _greville(self) -> Tensor:
        k = self._knots.detach().to(dtype=torch.float64, device="cpu")
        p, n = self.degree, self.n_ctrl
        return k[1:n + p].unfold(0, p, 1).mean(-1)  # mean of knots[j + 1 .. j + p]

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 8, degree: int = 3,
                 check: bool = True) -> Self:
        degree = _check_int(fn, "degree", degree, 1, ">= 1")
        n = _check_int(fn, "n_ctrl", n_ctrl, degree + 1, f"> degree = {degree}")
        t64 = fitting.check_times(fn, times, x.shape[-2]).detach().to(torch.float64).cpu()
        t0, t1 = float(t64[0]), float(t64[-1])
        knots = t0 + curves.clamped_uniform_knots(n, degree, dtype=torch.float64) * (t1 - t0)
        module = cls(dualquat.identity((*x.shape[:-2], n), dtype=x.dtype, device=x.device),
                     degree=degree, knots=knots, check=check)
        return module._fill(fn, x, t64)

    # The override spells out the keywords that _Curve.from_poses takes as **kwargs.
    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,  # type: ignore[override]
                   n_ctrl: int = 8, degree: int = 3, check: bool = True) -> BSpline:
        """B-spline with ``n_ctrl`` control points fit to poses (see
        :meth:`_Curve.from_poses`), on clamped uniform knots over ``[times[0], times[-1]]``.

        ``degree < n_ctrl <= N``. For a knot every ``h`` seconds, take
        ``n_ctrl = ceil((times[-1] - times[0]) / h) + degree``.

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
        return super().from_poses(rotations, translations, times, n_ctrl=n_ctrl,
                                  degree=degree, check=check)

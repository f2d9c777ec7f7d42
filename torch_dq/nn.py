r"""Curve layers with learnable unit-dual-quaternion control points, in the caller's time.

- :class:`UnitDualQuaternion`: a parametrization in PyTorch's sense
  (:func:`torch.nn.utils.parametrize.register_parametrization`): the stored raw ``(..., 8)``
  tensor is unconstrained and ``forward`` projects it with
  :func:`torch_dq.dualquat.normalize`, so the parameter seen by the module is a unit dual
  quaternion whatever an optimizer does to the raw tensor.
- :class:`Curve` (defined in ``torch_dq._curve``, below :mod:`torch_dq.fitting`): the
  contract of a curve layer (an abstract base class): learnable control points, a time
  model (:attr:`Curve.time_model`: knots relative to a float64 origin), evaluation with
  exact time derivatives, kinematics and IMU readings, the Euclidean basis of its
  least-squares problems (:meth:`Curve.basis`), construction from poses and from a saved
  ``state_dict``, and the span structure that :mod:`torch_dq.fitting` uses and nothing
  else (:meth:`Curve.support`, :meth:`Curve.local_times`, :meth:`Curve.evaluate_span`).
- :class:`Bezier` and :class:`BSpline`: the two curves, wrapping
  :func:`torch_dq.curves.bezier` and :func:`torch_dq.curves.bspline` (any B-spline form,
  ``form="de_boor"``, ``"cumulative"`` or ``"split"``); ``forward(t, ctrl=...)`` (and
  :meth:`~Curve.derivatives`, :meth:`~Curve.kinematics`, :meth:`~Curve.imu`) use control
  points predicted by another network instead. ``from_poses`` / ``from_matrices`` /
  ``from_dualquats`` build a curve by local least squares on timestamped poses.
- :func:`fit` and :class:`FitHistory` (re-exported from :mod:`torch_dq.fitting`, which works
  on the contract :class:`Curve` alone): refine a curve on timestamped poses.

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

import math
import numbers
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

from . import _checks, _compat01, _cumulative_lie, _start, curves, dualquat
from ._core import aligned_chain, distinct
from ._curve import Curve, UnitDualQuaternion
from ._curve_args import check_int, extra_float, extra_origins, poses_to_dq
from ._fused_curves import fused_cumulative
from ._kernels.layout import chunks
from ._time import KnotDomain, time_pair
from .fitting import FitHistory, fit
from .fitting._knots import check_fineness, choose_knot_spacing

if TYPE_CHECKING:
    from typing_extensions import Self

__all__ = ["BSpline", "Bezier", "Curve", "FitHistory", "UnitDualQuaternion", "fit"]


# ----------------------------------------------------------------------------- helpers

def _chosen_n_ctrl(fn: str, x: Tensor, t64: Tensor, degree: int, form: str) -> int:
    """``n_ctrl`` from the knot spacing chosen from the data (``from_poses(n_ctrl=None)``)."""
    if x.dim() > 2 or t64.dim() > 1:
        batch = _checks.broadcast_shapes(x.shape[:-2], t64.shape[:-1])
        _checks.fail(fn, f"n_ctrl=None chooses the knots from one trajectory's poses; pass "
                         f"n_ctrl for a batch of shape {_checks.shape_str(batch)}")
    n, least = x.shape[-2], 2 * (degree + 2)
    if n < least:
        fix = (f"pass n_ctrl (degree < n_ctrl <= N), e.g. n_ctrl={n}" if n > degree else
               f"with {n} poses, lower the degree below {n} and pass n_ctrl, e.g. "
               f"degree={n - 1}, n_ctrl={n}")
        _checks.fail(fn, f"n_ctrl=None chooses the knot spacing from the poses "
                         f"(fitting.choose_knot_spacing), which needs at least {least} of them "
                         f"for degree {degree}, got N = {n}; {fix}")
    h = choose_knot_spacing(t64, x.detach().to(torch.float64).cpu(), degree, form=form)
    return min(math.ceil((float(t64[-1]) - float(t64[0])) / h) + degree, x.shape[-2])


# The start on knots finer than the poses (from_poses(knot_spacing=)): the poses' start on
# coarse knots (a control point per this many poses), sampled this many times per fine span.
_POSES_PER_COARSE_CTRL = 2
_TABLE_CHUNK = 2048  # spans per chunk of the cumulative form's span tables (_span_parts)
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
            _compat01.deprecated(f"{fn}(time_range=...)", "pass domain=(t0, t1)")
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
        self._length = extra_float(fn, state, "length", positive=True)

    @classmethod
    def _args_from_state(cls, fn: str, state_dict: Mapping[str, Any], raw: Tensor,
                         ) -> dict[str, Any]:
        return {}  # the domain is extra state

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if _compat01.is_01(state_dict, prefix):  # a 0.1 state_dict: its domain as extra state
            _compat01.upgrade(self._name, state_dict, prefix, None, self.n_ctrl,
                              self.parametrizations.ctrl.original.dtype)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bezier(ctrl, rel, domain=(0.0, self._length), check=False,
                             extrapolate=True)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bezier_derivatives(ctrl, rel, order=order, domain=(0.0, self._length),
                                         check=False, extrapolate=True)

    def evaluate_span(self, points: Tensor, local: Tensor, first: Tensor, order: int,
                      ) -> tuple[Tensor, ...]:
        lead = points.shape[:-2]
        ctrl, tt = points.reshape(-1, *points.shape[-2:]), local.expand(lead).reshape(-1, 1)
        kw: dict[str, Any] = dict(domain=(0.0, self._length), check=False, extrapolate=True)
        out = ((curves.bezier(ctrl, tt, **kw),) if order == 0 else
               curves.bezier_derivatives(ctrl, tt, order=order, **kw))
        return tuple(d.reshape(*lead, 8) for d in out)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 4,
                 check: bool = True) -> Self:
        n = check_int(fn, "n_ctrl", n_ctrl, 2, ">= 2")
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
        x = poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, n_ctrl=n_ctrl, check=check)


def _span_parts(spans: Tensor) -> Tensor:
    """``torch_dq._cumulative_lie.span_parts`` of ``spans (U, p + 1, 8)``, ``(80, p, U)``,
    ``_TABLE_CHUNK`` spans at a time: a long curve's in cache-sized temporaries (all 12,000
    spans of 600 s at once took 1.5x the time)."""
    out = spans.new_empty(80, spans.shape[-2] - 1, spans.shape[0])
    for c in chunks(spans.shape[0], _TABLE_CHUNK, spans.device):
        out[..., c] = _cumulative_lie.span_parts(spans[c])
    return out


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
        degree = check_int(fn, "degree", degree, 1, ">= 1")
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
            k64 = _compat01.time_range_knots(fn, k64, degree, time_range)
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
            args["knots"] = knots.to(torch.float64) + extra_origins(fn, extra, knots)
        return args

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        if _compat01.is_01(state_dict, prefix):  # a 0.1 state_dict: knots in the caller's time
            _compat01.upgrade(self._name, state_dict, prefix, self.degree, self.n_ctrl,
                              self._knots.dtype)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def _split_charts(self) -> bool:  # type: ignore[override]
        return self.form == "split"

    def _curve(self, ctrl: Tensor, rel: Tensor) -> Tensor:
        return curves.bspline(ctrl, rel, self.degree, self._knots.to(rel.device), check=False,
                              extrapolate=True, form=self.form)

    def _curve_derivatives(self, ctrl: Tensor, rel: Tensor, order: int) -> tuple[Tensor, ...]:
        return curves.bspline_derivatives(ctrl, rel, order=order, degree=self.degree,
                                          knots=self._knots.to(rel.device), check=False,
                                          extrapolate=True, form=self.form)

    def evaluate_span(self, points: Tensor, local: Tensor, first: Tensor, order: int,
                      ) -> tuple[Tensor, ...]:
        p, lead = self.degree, points.shape[:-2]
        first = first.expand(lead[len(lead) - first.dim():])
        k = self._knots.detach().to(torch.float64)
        idx = first[..., None] + torch.arange(2 * p + 2, device=first.device)  # u_f .. u_f+2p+1
        if k.dim() > 1:  # each trajectory's spans with its own knots
            rows = first.shape[:-1]
            win = k.expand(*rows, k.shape[-1]).gather(-1, idx.reshape(*rows, -1))
            win = win.reshape(idx.shape)
        else:
            win = k[idx]
        win = (win - win[..., p:p + 1]).expand(*lead, 2 * p + 2)  # u_r = 0 (r = f + p)
        ctrl, tt = points.reshape(-1, p + 1, 8), local.expand(lead).reshape(-1, 1)
        kw: dict[str, Any] = dict(degree=p, knots=win.reshape(-1, 2 * p + 2), check=False,
                                  extrapolate=True, form=self.form)
        out = ((curves.bspline(ctrl, tt, **kw),) if order == 0 else
               curves.bspline_derivatives(ctrl, tt, order=order, **kw))
        return tuple(d.reshape(*lead, 8) for d in out)

    def span_derivatives(self, ctrl: Tensor, local: Tensor, first: Tensor, order: int,
                         memo: dict | None = None) -> tuple[Tensor, ...]:
        # the form's own evaluation at the given spans: the cumulative form's span tables
        # are built once per span, not once per sample
        r = first + self.degree
        rel = self.time_model.span_bounds(r)[0] + local
        batch = _checks.broadcast_shapes(ctrl.shape[:-2], rel.shape[:-1],
                                         self._knots.shape[:-1])
        if self.form == "cumulative" and ctrl.dtype == torch.float64:
            # the estimation's evaluations, nothing differentiated: by the Lie recursions
            # (torch_dq._cumulative_lie) where they apply; the public curve functions keep the
            # span tables whatever a batch holds (a non-unit element would switch the path,
            # and the rounding, of its neighbours)
            weights = self.time_model.bases(rel, r, order, cumulative=True, memo=memo)
            aligned, at = aligned_chain(ctrl), r
            if not batch and r.numel():  # one curve: the points its times read (a part of a
                a, b = torch.stack(torch.aminmax(r)).tolist()  # long record reads a stretch)
                aligned, at = aligned[a - self.degree:b + 1], r - (a - self.degree)
            if _cumulative_lie.applies(aligned, weights):
                return tuple(fused_cumulative(aligned, at, weights, self.degree, batch,
                                              _cumulative_lie.derivatives))
        return curves._bspline_jets(ctrl, self.time_model, rel, self.form, order, batch, r=r)

    def span_vjp(self, points: Tensor, local: Tensor, first: Tensor, cotangents: Tensor,
                 pose: Tensor, second: slice | None = None, tables: Tensor | None = None,
                 memo: dict | None = None) -> Tensor | None:
        # the cumulative form's in its Lie algebra (torch_dq._cumulative_lie), the span
        # quantities once per distinct span (or the curve's, tables); the other forms' by
        # reverse passes
        if self.form != "cumulative" or cotangents.shape[-2] > 3:
            return None
        p, (k, O) = self.degree, cotangents.shape[-3:-1]
        lead = _checks.broadcast_shapes(points.shape[:-2], cotangents.shape[:-3],
                                        pose.shape[:-1])
        first = first.expand(lead[len(lead) - first.dim():])
        r = first + p
        rel, r = (self.time_model.span_bounds(r)[0] + local).expand(lead), r.expand(lead)
        weights = self.time_model.bases(rel, r, O - 1, cumulative=True, memo=memo)
        N, n = (lead[-1] if lead else 1), self.n_ctrl - p  # spans
        key = first.expand(lead).reshape(-1) + n * torch.arange(
            math.prod(lead), device=first.device).div(N, rounding_mode="floor")
        if tables is None or tables.shape[2:] != (*lead[:-1], n):
            _, key, pick = distinct(key)  # the samples' spans, from their points
            tables = _span_parts(points.expand(*lead, p + 1, 8).reshape(-1, p + 1, 8)[pick])
        G = _cumulative_lie.vjp(tables, key,
                                [w.to(points.dtype).reshape(-1, p) for w in weights],
                                cotangents.expand(*lead, k, O, 8).reshape(-1, k, O, 8),
                                pose.expand(*lead, 8).reshape(-1, 8), second)
        return G.reshape(*lead, k, p + 1, 6)

    def span_vjp_tables(self, ctrl: Tensor) -> Tensor | None:
        # (80, p, ..., n - p): every span of the sign-aligned chain (span_points'
        # representatives), step j of span u the parts of the pair (u + j, u + j + 1): each
        # pair's once (p times fewer than per span and step), then laid out per span
        if self.form != "cumulative":
            return None
        pairs = aligned_chain(ctrl).unfold(-2, 2, 1).movedim(-1, -2)  # (..., n - 1, 2, 8)
        parts = _span_parts(pairs.reshape(-1, 2, 8)).view(80, *pairs.shape[:-2])
        return parts.unfold(-1, self.degree, 1).movedim(-1, 1).contiguous()

    def acceleration_jumps(self) -> str | None:
        p, form = self.degree, self.form
        if form == "de_boor" and p >= 2:
            return (f"a degree-{p} B-spline of form='de_boor', which is only C1 (its "
                    f"accelerations jump at the knots); build it with form='cumulative' for "
                    f"IMU work")
        if form == "cumulative" and p < 3:
            return (f"a degree-{p} B-spline of form='cumulative', which is only C{p - 1} (its "
                    f"accelerations jump at the knots); use degree >= 3 for IMU work")
        return None

    def acceleration_kinks(self) -> str | None:
        # a de Boor B-spline is C1, a cumulative or split degree-p one C(p-1): its
        # accelerations are C1 from degree 4 on (a single span is smooth)
        if self.n_ctrl <= self.degree + 1 or (self.form != "de_boor" and self.degree >= 4):
            return None
        return f"a degree-{self.degree} B-spline of form={self.form!r}"

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int | None = None,
                 degree: int = 3, form: str = "de_boor", check: bool = True, *,
                 knot_spacing: float | None = None, margin: float = 0.0) -> Self:
        degree = check_int(fn, "degree", degree, 1, ">= 1")
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
            check_fineness(fn, t64, knot_spacing, degree, margin)
            span = float(torch.as_tensor(t1 - t0, dtype=torch.float64).max())
            n_ctrl = max(math.ceil(span / knot_spacing - 1e-9), 1) + degree
        elif n_ctrl is None:  # chosen from the data
            n_ctrl = _chosen_n_ctrl(fn, x, t64, degree, form)
        n = check_int(fn, "n_ctrl", n_ctrl, degree + 1, f"> degree = {degree}")
        module = cls(dualquat.identity((*batch, n), dtype=x.dtype, device=x.device), degree=degree,
                     knots=_uniform(n, degree, t0, t1), form=form, check=check)
        module._poses_span = (t64[..., 0], t64[..., -1])
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
                motion), and more control points than poses are allowed, up to a spacing
                1000 times finer than the poses' mean spacing (finer is refused as a unit
                mistake, e.g. nanosecond times with a spacing in seconds).
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
                a non-positive ``knot_spacing``, one over 1000 times finer than the poses,
                or a negative ``margin``.

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
        x = poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, n_ctrl=n_ctrl, degree=degree, form=form,
                            check=check, knot_spacing=knot_spacing, margin=margin)

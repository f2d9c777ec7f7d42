r"""Curve layers with learnable unit-dual-quaternion control points, and fitting.

- :class:`UnitDualQuaternion`: a parametrization in PyTorch's sense
  (:func:`torch.nn.utils.parametrize.register_parametrization`): the stored raw ``(..., 8)``
  tensor is unconstrained and ``forward`` projects it with
  :func:`torch_dq.dualquat.normalize`, so the parameter seen by the module is a unit dual
  quaternion whatever an optimizer does to the raw tensor.
- :class:`Bezier` and :class:`BSpline`: ``nn.Module`` wrappers of
  :func:`torch_dq.curves.bezier` and :func:`torch_dq.curves.bspline` whose control points
  are such a parameter; ``forward(t, ctrl=...)`` uses control points predicted by another
  network instead. ``from_poses`` / ``from_matrices`` / ``from_dualquats`` build a curve by
  a linear least-squares fit to timestamped poses.
- :func:`fit`: fits a curve module to timestamped poses with Adam, SGD, LBFGS or any
  ``torch.optim`` optimizer (a plain ``torch.optim`` loop works just as well).

Time: a module's ``forward`` takes times in its *curve domain* (``[0, 1]`` for
:class:`Bezier` and for the default clamped knots of :class:`BSpline`, otherwise
``[knots[degree], knots[n]]``). The ``time_range`` buffer ``(t0, t1)`` records the raw
times that map onto that domain (the first and last sample for ``from_poses``, the domain
itself otherwise), and :meth:`normalize_time` applies that affine map; :func:`fit` takes
raw times and applies it for you.

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
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor
from torch.nn.utils import parametrize

from . import _checks, curves, dualquat, quat
from ._core import align_chain, twist_translation
from .losses import pose_loss

__all__ = ["BSpline", "Bezier", "FitHistory", "UnitDualQuaternion", "fit"]


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


# ----------------------------------------------------------------------------- least squares

def _bspline_basis(u: Tensor, knots: Tensor, degree: int, n: int) -> Tensor:
    """``(N, n)`` B-spline basis at ``u`` by Cox-de Boor (right end: left limit)."""
    p = degree
    inner = knots[p + 1:n]
    r = p + torch.searchsorted(inner, u.contiguous(), right=True)
    r_end = p + torch.searchsorted(inner, knots[n:n + 1], right=False)
    r = torch.minimum(r, r_end)
    B = torch.nn.functional.one_hot(r, n + p).to(u.dtype)
    uu = u[:, None]
    for k in range(1, p + 1):
        m = n + p - k  # basis functions of degree k
        ti, tik = knots[:m], knots[k:k + m]
        ti1, tik1 = knots[1:1 + m], knots[k + 1:k + 1 + m]
        dl, dr = tik - ti, tik1 - ti1
        left = torch.where(dl > 0, (uu - ti) / torch.where(dl > 0, dl, 1.0), 0.0)
        right = torch.where(dr > 0, (tik1 - uu) / torch.where(dr > 0, dr, 1.0), 0.0)
        B = left * B[:, :-1] + right * B[:, 1:]
    return B


def _bernstein_basis(u: Tensor, n: int) -> Tensor:
    """``(N, n)`` Bernstein basis of degree ``n - 1`` at ``u``."""
    i = torch.arange(n, dtype=u.dtype, device=u.device)
    binom = torch.tensor([math.comb(n - 1, k) for k in range(n)], dtype=u.dtype,
                         device=u.device)
    uu = u[:, None]
    return binom * uu**i * (1.0 - uu) ** (n - 1 - i)


def _lifted_twists(x: Tensor, ref: int) -> tuple[Tensor, Tensor]:
    r"""Twists :math:`\xi_i` with :math:`\exp(\xi_i) = \pm x_{ref}^{-1} x_i`, continuous in i.

    The samples are first sign-aligned along the sequence, so the relative real parts form
    a continuous path from ``+1`` at ``ref``; their rotation angle
    ``2 atan2(|v|, w)`` then runs over ``[0, 2 pi)`` without the jump at pi of the principal
    logarithm (relative rotations up to a full turn either side of the reference).

    Returns ``(x_ref (..., 1, 8), xi (..., N, 6))`` in float64.
    """
    x = align_chain(x)
    x_ref = x[..., ref:ref + 1, :]
    y = dualquat.mul(dualquat.conj(x_ref), x)
    r, t = dualquat.to_rt(y)
    w, v = r[..., 0], r[..., 1:]
    s = torch.linalg.vector_norm(v, dim=-1)
    theta = 2.0 * torch.atan2(s, w)  # in [0, 2 pi]
    axis = v / torch.where(s > 0, s, 1.0)[..., None]
    theta = torch.where(theta > 2.0 * math.pi - 1e-6, theta - 2.0 * math.pi, theta)
    omega = theta[..., None] * axis
    lin = twist_translation(omega, t)
    return x_ref, torch.cat((omega, lin), dim=-1)


def _check_int(fn: str, name: str, value, low: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low:
        _checks.fail(fn, f"{name} must be an int {what}, got {value!r}")
    return int(value)


def _check_times_1d(fn: str, times, n: int | None) -> Tensor:
    _checks.tensor(fn, "times", times)
    if times.dim() != 1 or times.shape[0] < 2 or (n is not None and times.shape[0] != n):
        want = "(N,) with N >= 2" if n is None else f"({n},) matching the N = {n} poses"
        _checks.fail(fn, f"expected a {want} tensor for times, got shape "
                         f"{_checks.shape_str(times.shape)}")
    tt = times.detach()
    bad = torch.stack((~torch.isfinite(tt).all(), (tt[1:] <= tt[:-1]).any())).tolist()
    if bad[0]:
        _checks.fail(fn, "times must be finite")
    if bad[1]:
        _checks.fail(fn, "times must be strictly increasing")
    return times


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


# ----------------------------------------------------------------------------- curve layers

class _Curve(torch.nn.Module):
    """Shared machinery: the parametrized ``ctrl``, ``time_range`` and pose constructors."""

    _name = "nn._Curve"

    def _setup(self, ctrl: Tensor, min_points: int, check: bool) -> None:
        fn = self._name
        _checks.tensor(fn, "ctrl", ctrl, 8)
        if ctrl.dim() < 2 or ctrl.shape[-2] < min_points:
            _checks.fail(fn, f"expected a (..., n, 8) tensor for ctrl with n >= {min_points}, "
                             f"got shape {_checks.shape_str(ctrl.shape)}")
        self.check = bool(check)
        self.ctrl = torch.nn.Parameter(ctrl.detach().clone())
        parametrize.register_parametrization(self, "ctrl", UnitDualQuaternion())

    def _set_time_range(self, time_range, lo: Tensor, hi: Tensor) -> None:
        fn = self._name
        like = self.parametrizations.ctrl.original
        if time_range is None:
            tr = torch.stack((lo, hi)).to(like.dtype)
        else:
            tr = torch.as_tensor(time_range, dtype=like.dtype, device=like.device)
            if tr.shape != (2,) or not bool(torch.isfinite(tr).all() & (tr[0] < tr[1])):
                _checks.fail(fn, f"time_range must be two finite increasing times (t0, t1), "
                                 f"got {time_range!r}")
        self.register_buffer("time_range", tr.to(like.device))

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

    def _resolve(self, ctrl: Tensor | None) -> Tensor:
        if ctrl is None:
            return self.ctrl
        fn = f"{self._name}.forward"
        _checks.tensor(fn, "ctrl", ctrl, 8)
        n = self.n_ctrl
        if ctrl.dim() < 2 or ctrl.shape[-2] != n:
            _checks.fail(fn, f"expected a (..., {n}, 8) tensor for ctrl ({n} control points), "
                             f"got shape {_checks.shape_str(ctrl.shape)}")
        return self.parametrizations.ctrl[0](ctrl)

    # -- time
    def _domain(self) -> tuple[Tensor, Tensor]:
        raise NotImplementedError

    def normalize_time(self, times: Tensor) -> Tensor:
        r"""Map raw times affinely onto the curve domain: ``time_range`` -> domain.

        ``u = lo + (times - t0) / (t1 - t0) * (hi - lo)`` with ``(t0, t1) = time_range`` and
        ``[lo, hi]`` the domain (``[0, 1]`` unless custom knots). The identity for a module
        built without ``time_range``. Computed in the module's dtype (for absolute
        timestamps in float32, subtract a reference time first).

        Args:
            times: ``(..., T)`` floating times, cast to the module's dtype and device.
        """
        _checks.tensor(f"{self._name}.normalize_time", "times", times)
        tr = self.time_range
        lo, hi = self._domain()
        times = times.to(dtype=tr.dtype, device=tr.device)
        return lo + (times - tr[0]) / (tr[1] - tr[0]) * (hi - lo)

    def extra_repr(self) -> str:
        raw = self.parametrizations.ctrl.original
        batch = _checks.shape_str(raw.shape[:-2])
        tr = ", ".join(f"{v:g}" for v in self.time_range.tolist())
        deg = f", degree={self.degree}" if hasattr(self, "degree") else ""
        return (f"n_ctrl={self.n_ctrl}{deg}, batch_shape={batch}, time_range=({tr}), "
                f"dtype={raw.dtype}")

    # -- constructors from poses
    @classmethod
    def _ls_ctrl(cls, fn: str, x: Tensor, times: Tensor, basis: Callable[[Tensor], Tensor],
                 ) -> Tensor:
        """Least-squares control points: ``x_ref exp(C)``, ``C`` fit to the twists."""
        dtype, device = x.dtype, x.device
        x64 = x.detach().to(torch.float64).cpu()
        if not bool(torch.isfinite(x64).all()):
            _checks.fail(fn, "the poses must be finite, with non-zero rotations (every sample "
                             "enters every control point of the least-squares fit)")
        t64 = times.detach().to(torch.float64).cpu()
        N = x64.shape[-2]
        x_ref, xi = _lifted_twists(x64, N // 2)
        u = (t64 - t64[0]) / (t64[-1] - t64[0])
        A = basis(u)  # (N, n)
        C = torch.linalg.lstsq(A.expand(*xi.shape[:-2], *A.shape), xi, driver="gelsd").solution
        ctrl = dualquat.mul(x_ref, dualquat.exp(C))
        return ctrl.to(dtype=dtype, device=device)

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor, **kwargs):
        r"""Curve fit to timestamped rigid poses by linear least squares on twists.

        With ``x_i`` the poses, ``x_ref`` the middle sample and
        :math:`\xi_i = \log(x_{ref}^{-1} x_i)` (continuous along the samples, see below),
        the Euclidean curve coefficients :math:`C` minimising
        :math:`\sum_i |\sum_j B_j(u_i) C_j - \xi_i|^2` (``torch.linalg.lstsq`` on the
        basis matrix at the normalised times :math:`u_i \in [0, 1]`) give the control
        points :math:`x_{ref} \exp(C_j)`. The curve through them is close to the samples
        for smooth motions (exact for a constant screw motion) and is a good start for
        :func:`fit`. Relative rotations to the middle sample may reach a full turn on
        either side (the twists' rotation angle is unwrapped over ``[0, 2 pi)``).

        Times are mapped affinely onto ``[0, 1]`` (first sample -> 0, last -> 1) and that
        map is stored as the ``time_range`` buffer: evaluate with
        ``module(module.normalize_time(times))``.

        Args:
            rotations: ``(..., N, 4)`` quaternions ``(w, x, y, z)`` (normalised here) or
                ``(..., N, 3, 3)`` rotation matrices. Extra leading dims give a batch of
                curves.
            translations: ``(..., N, 3)``, same dtype and device as ``rotations``.
            times: ``(N,)`` strictly increasing finite times (any floating dtype).
            **kwargs: ``n_ctrl`` (and ``degree`` for :class:`BSpline`), ``check``.

        Returns:
            The module, with control points of the dtype and device of ``rotations``.
        """
        fn = f"{cls._name}.from_poses"
        x = _poses_to_dq(fn, rotations, translations)
        return cls._from_dq(fn, x, times, **kwargs)

    @classmethod
    def from_matrices(cls, T: Tensor, times: Tensor, **kwargs):
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
    def from_dualquats(cls, x: Tensor, times: Tensor, **kwargs):
        """:meth:`from_poses` with ``(..., N, 8)`` unit dual quaternions ``x`` (any signs)."""
        fn = f"{cls._name}.from_dualquats"
        _checks.tensor(fn, "x", x, 8)
        if x.dim() < 2:
            _checks.fail(fn, f"expected a (..., N, 8) tensor for x, got shape "
                             f"{_checks.shape_str(x.shape)}")
        return cls._from_dq(fn, dualquat.normalize(x), times, **kwargs)


class Bezier(_Curve):
    r"""Bézier curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bezier` (De Casteljau with ``sclerp``, paper 4.1). The
    control points are the parameter ``ctrl`` under the :class:`UnitDualQuaternion`
    parametrization: the raw tensor (``parametrizations.ctrl.original``) is what optimizers
    update, and ``.control_points`` (= ``.ctrl``) is always its unit projection.
    Save and load through ``state_dict`` (parametrized modules do not pickle).

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n >= 2`` (degree ``n - 1``),
            projected onto unit dual quaternions; leading dims give a batch of curves.
            dtype and device of the module.
        time_range: raw times ``(t0, t1)`` mapped onto ``[0, 1]`` by
            :meth:`normalize_time` (default ``(0, 1)``).
        check: check at every call that ``t`` lies in ``[0, 1]`` (one device sync).

    Shape:
        ``forward(t)``: ``t`` ``(T,)`` or ``(..., T)`` in ``[0, 1]`` -> ``(..., T, 8)``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> curve = Bezier(dq.identity((4,)))
        >>> curve(torch.linspace(0, 1, 5)).shape
        torch.Size([5, 8])
    """

    _name = "nn.Bezier"

    def __init__(self, ctrl: Tensor, *, time_range=None, check: bool = True):
        super().__init__()
        self._setup(ctrl, 2, check)
        one = self.parametrizations.ctrl.original.new_ones(())
        self._set_time_range(time_range, 0.0 * one, one)

    def _domain(self) -> tuple[Tensor, Tensor]:
        return 0.0, 1.0

    def forward(self, t: Tensor, ctrl: Tensor | None = None) -> Tensor:
        """Poses at times ``t`` in ``[0, 1]``.

        Args:
            t: ``(T,)`` or ``(..., T)`` times, same dtype and device as the control points.
            ctrl: optional ``(..., n, 8)`` control points (e.g. a network's raw outputs)
                used instead of the module's own, projected like them; ``n`` must be the
                module's.

        Returns:
            ``(..., T, 8)`` unit dual quaternions.
        """
        return curves.bezier(self._resolve(ctrl), t, check=self.check)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 4, check: bool = True):
        n = _check_int(fn, "n_ctrl", n_ctrl, 2, ">= 2")
        _check_times_1d(fn, times, x.shape[-2])
        ctrl = cls._ls_ctrl(fn, x, times, lambda u: _bernstein_basis(u, n))
        tt = times.detach()
        return cls(ctrl, time_range=(float(tt[0]), float(tt[-1])), check=check)

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,
                   n_ctrl: int = 4, check: bool = True) -> Bezier:
        """Bézier curve with ``n_ctrl`` control points fit to poses (Bernstein basis).

        See :meth:`_Curve.from_poses`; ``n_ctrl >= 2`` (degree ``n_ctrl - 1``).
        """
        return super().from_poses(rotations, translations, times, n_ctrl=n_ctrl, check=check)


class BSpline(_Curve):
    r"""B-spline curve of rigid motions with learnable unit-dual-quaternion control points.

    Evaluates :func:`torch_dq.curves.bspline` (De Boor with ``sclerp``, paper 4.2); see
    :class:`Bezier` for the parametrization. The knots are a buffer (they follow
    ``.to()`` and are saved in the ``state_dict``), not learned.

    Args:
        ctrl: ``(..., n, 8)`` initial control points, ``n > degree``, projected onto unit
            dual quaternions; leading dims give a batch of curves.
        degree: polynomial degree ``>= 1`` (3: cubic).
        knots: ``(n + degree + 1,)`` non-decreasing finite knots with
            ``knots[degree] < knots[n]``; default clamped uniform on ``[0, 1]``
            (:func:`torch_dq.curves.clamped_uniform_knots`).
        time_range: raw times ``(t0, t1)`` mapped onto the domain
            ``[knots[degree], knots[n]]`` by :meth:`normalize_time` (default: the domain).
        check: check at every call that ``t`` lies in the domain (one device sync).

    Shape:
        ``forward(t)``: ``t`` ``(T,)`` or ``(..., T)`` in the domain -> ``(..., T, 8)``.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> spline = BSpline(dq.identity((6,)), degree=3)
        >>> spline.extra_repr()
        'n_ctrl=6, degree=3, batch_shape=(), time_range=(0, 1), dtype=torch.float32'
        >>> spline(torch.rand(2, 7)).shape  # a (2, 7) batch of times
        torch.Size([2, 7, 8])
    """

    _name = "nn.BSpline"

    def __init__(self, ctrl: Tensor, degree: int = 3, knots: Tensor | None = None, *,
                 time_range=None, check: bool = True):
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
            knots = curves.clamped_uniform_knots(n, degree, dtype=raw.dtype, device=raw.device)
        else:
            _checks.tensor(fn, "knots", knots)
            if knots.dim() != 1 or knots.shape[0] != n + degree + 1:
                _checks.fail(fn, f"expected a 1-D knots tensor of n + degree + 1 = "
                                 f"{n + degree + 1} entries, got shape "
                                 f"{_checks.shape_str(knots.shape)}")
            k = knots.detach()
            bad = torch.stack((~torch.isfinite(k).all(), (k[1:] < k[:-1]).any(),
                               ~(k[degree] < k[n]))).tolist()
            if any(bad):
                _checks.fail(fn, f"knots must be finite and non-decreasing with "
                                 f"knots[degree] < knots[n], got {k.tolist()}")
            knots = knots.detach().to(dtype=raw.dtype, device=raw.device).clone()
        self.register_buffer("knots", knots)
        self._set_time_range(time_range, knots[degree], knots[n])

    def _domain(self) -> tuple[Tensor, Tensor]:
        return self.knots[self.degree], self.knots[self.n_ctrl]

    def forward(self, t: Tensor, ctrl: Tensor | None = None) -> Tensor:
        """Poses at times ``t`` in the knot domain (``[0, 1]`` by default).

        Args:
            t: ``(T,)`` or ``(..., T)`` times, same dtype and device as the control points.
            ctrl: optional ``(..., n, 8)`` control points (e.g. a network's raw outputs)
                used instead of the module's own, projected like them; ``n`` must be the
                module's.

        Returns:
            ``(..., T, 8)`` unit dual quaternions.
        """
        ctrl = self._resolve(ctrl)
        knots = self.knots.to(dtype=ctrl.dtype, device=ctrl.device)
        return curves.bspline(ctrl, t, self.degree, knots, check=self.check)

    @classmethod
    def _from_dq(cls, fn: str, x: Tensor, times: Tensor, n_ctrl: int = 8, degree: int = 3,
                 check: bool = True):
        degree = _check_int(fn, "degree", degree, 1, ">= 1")
        n = _check_int(fn, "n_ctrl", n_ctrl, degree + 1, f"> degree = {degree}")
        _check_times_1d(fn, times, x.shape[-2])
        knots = curves.clamped_uniform_knots(n, degree, dtype=torch.float64)
        ctrl = cls._ls_ctrl(fn, x, times, lambda u: _bspline_basis(u, knots, degree, n))
        tt = times.detach()
        return cls(ctrl, degree=degree, time_range=(float(tt[0]), float(tt[-1])), check=check)

    @classmethod
    def from_poses(cls, rotations: Tensor, translations: Tensor, times: Tensor,
                   n_ctrl: int = 8, degree: int = 3, check: bool = True) -> BSpline:
        """B-spline with ``n_ctrl`` control points fit to poses (Cox-de Boor basis).

        Clamped uniform knots on ``[0, 1]``; see :meth:`_Curve.from_poses`.
        ``n_ctrl > degree``.
        """
        return super().from_poses(rotations, translations, times, n_ctrl=n_ctrl,
                                  degree=degree, check=check)


# ----------------------------------------------------------------------------- fitting

@dataclass
class FitHistory:
    """What :func:`fit` did.

    Attributes:
        loss: the loss before each optimizer step (``len(loss) == steps``).
        steps: number of optimizer steps taken.
        final_loss: the loss after the last step.
        converged: True when the early-stopping test held (the loop stopped there).
        seconds: wall-clock time of the loop.
    """

    loss: list[float] = field(default_factory=list)
    steps: int = 0
    final_loss: float = math.nan
    converged: bool = False
    seconds: float = 0.0


_DEFAULT_LR = {"adam": 1e-2, "sgd": 1e-2, "lbfgs": 1.0}


def _make_optimizer(fn: str, optimizer, params: list, lr):
    if isinstance(optimizer, str):
        name = optimizer.lower()
        if name not in _DEFAULT_LR:
            _checks.fail(fn, f"optimizer must be 'adam', 'sgd', 'lbfgs', a torch.optim "
                             f"optimizer or a callable(params) -> optimizer, got {optimizer!r}")
        lr = _DEFAULT_LR[name] if lr is None else lr
        if isinstance(lr, bool) or not isinstance(lr, numbers.Real) or not lr > 0:
            _checks.fail(fn, f"lr must be a real number > 0, got {lr!r}")
        if name == "adam":
            return torch.optim.Adam(params, lr=lr)
        if name == "sgd":
            return torch.optim.SGD(params, lr=lr, momentum=0.9)
        return torch.optim.LBFGS(params, lr=lr, line_search_fn="strong_wolfe")
    if lr is not None:
        _checks.fail(fn, "lr applies to named optimizers only; set it in the optimizer or "
                         "factory")
    if isinstance(optimizer, torch.optim.Optimizer):
        return optimizer
    if callable(optimizer):
        opt = optimizer(params)
        if not isinstance(opt, torch.optim.Optimizer):
            _checks.fail(fn, f"the optimizer factory must return a torch.optim.Optimizer, "
                             f"got {type(opt).__name__}", TypeError)
        return opt
    _checks.fail(fn, f"optimizer must be 'adam', 'sgd', 'lbfgs', a torch.optim optimizer or a "
                     f"callable(params) -> optimizer, got {type(optimizer).__name__}")


def _progress(total: int, enabled: bool):
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=total, desc="torch_dq.fit", leave=False)


def fit(module: torch.nn.Module, times: Tensor, poses: Tensor, optimizer="adam",
        steps: int = 500, lr: float | None = None, tol: float = 1e-9, window: int = 10,
        loss: Callable[[Tensor, Tensor], Tensor] = pose_loss,
        verbose: bool = True) -> FitHistory:
    r"""Fit a curve module to timestamped poses by gradient-based optimisation.

    Minimises ``loss(module(module.normalize_time(times)), poses)`` over all the module's
    parameters (for :class:`Bezier` / :class:`BSpline`, the raw control points: the curve's
    control points stay unit dual quaternions whatever the optimizer). Each step calls
    ``optimizer.step(closure)`` (so LBFGS's line search works; one LBFGS step runs up to
    its ``max_iter = 20`` inner iterations). Early stopping: after ``window`` steps, stop
    when :math:`|L_{k-w} - L_k| \le tol \cdot |L_{k-w}|` (relative change over the window)
    or the loss is exactly 0; a non-finite loss also stops the loop (its
    ``final_loss`` is then not finite). A plain ``torch.optim`` loop does the same thing.

    Args:
        module: a :class:`Bezier` / :class:`BSpline` (or any module mapping ``(N,)`` times
            to ``(..., N, 8)`` poses; ``normalize_time`` is used when it has one).
        times: ``(N,)`` raw times (mapped by ``module.normalize_time``); cast to the
            module's dtype and device.
        poses: ``(..., N, 8)`` unit dual quaternions or ``(..., N, 4, 4)`` homogeneous
            matrices, cast to the dtype and device of ``times`` after normalisation.
        optimizer: ``"adam"`` (default), ``"sgd"`` (momentum 0.9), ``"lbfgs"`` (strong
            Wolfe line search), a ``torch.optim.Optimizer`` instance over the module's
            parameters, or a callable ``params -> Optimizer``
            (e.g. ``lambda p: torch.optim.AdamW(p, lr=3e-3)``).
        steps: maximum number of optimizer steps (``>= 1``).
        lr: learning rate of a named optimizer (default 1e-2 for Adam and SGD, 1 for
            LBFGS); must be None with an instance or a factory.
        tol: relative loss change over ``window`` steps below which to stop (0: never).
        window: steps between the compared losses (``>= 1``).
        loss: ``loss(pred, target) -> 0-d tensor``; default :func:`torch_dq.losses.pose_loss`
            (mean of rad² + length²; use ``functools.partial(pose_loss, trans_weight=...)``
            to balance the units).
        verbose: show a tqdm progress bar when stderr is a terminal and tqdm is installed.

    Returns:
        :class:`FitHistory` with the per-step losses.

    Raises:
        ValueError: bad shapes, unknown optimizer name, bad ``steps``/``lr``/``tol``/
            ``window``, non-increasing times.
        TypeError: non-module ``module``, non-floating tensors, a factory that does not
            return an optimizer.

    Example:
        >>> import torch_dq.dualquat as dq
        >>> t = torch.linspace(0.0, 2.0, 30)
        >>> target = dq.exp(t[:, None] * torch.tensor([0.0, 0.0, 1.0, 0.5, 0.0, 0.0]))
        >>> spline = BSpline(dq.identity((6,)), time_range=(0.0, 2.0))
        >>> history = fit(spline, t, target, steps=50, verbose=False)
        >>> history.final_loss < history.loss[0]
        True
    """
    fn = "nn.fit"
    if not isinstance(module, torch.nn.Module):
        _checks.fail(fn, f"expected a torch.nn.Module for module, got {type(module).__name__}",
                     TypeError)
    steps = _check_int(fn, "steps", steps, 1, ">= 1")
    window = _check_int(fn, "window", window, 1, ">= 1")
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not tol >= 0:
        _checks.fail(fn, f"tol must be a real number >= 0, got {tol!r}")
    if not callable(loss):
        _checks.fail(fn, f"expected a callable for loss, got {type(loss).__name__}", TypeError)
    _checks.tensor(fn, "poses", poses)
    if poses.dim() >= 3 and tuple(poses.shape[-2:]) == (4, 4):
        poses = dualquat.from_matrix(poses)
    elif poses.dim() < 2 or poses.shape[-1] != 8:
        _checks.fail(fn, f"expected (..., N, 8) dual quaternions or (..., N, 4, 4) matrices "
                         f"for poses, got shape {_checks.shape_str(poses.shape)}")
    _check_times_1d(fn, times, poses.shape[-2])
    params = [p for p in module.parameters() if p.requires_grad]
    if not params:
        _checks.fail(fn, "module has no parameters that require grad")
    u = module.normalize_time(times) if hasattr(module, "normalize_time") else times
    u = u.detach().to(dtype=params[0].dtype, device=params[0].device)
    target = poses.detach().to(dtype=u.dtype, device=u.device)
    opt = _make_optimizer(fn, optimizer, params, lr)

    def closure():
        opt.zero_grad(set_to_none=True)
        value = loss(module(u), target)
        value.backward()
        return value

    history = FitHistory()
    bar = _progress(steps, verbose and sys.stderr.isatty())
    start = time.perf_counter()
    try:
        for k in range(steps):
            value = float(opt.step(closure).detach())
            history.loss.append(value)
            history.steps = k + 1
            if bar is not None:
                bar.update(1)
                if k % 10 == 0:
                    bar.set_postfix(loss=f"{value:.3e}")
            if not math.isfinite(value):
                break
            if value == 0.0 or (k >= window and tol > 0 and
                                abs(history.loss[k - window] - value)
                                <= tol * abs(history.loss[k - window])):
                history.converged = True
                break
    finally:
        if bar is not None:
            bar.close()
    with torch.no_grad():
        history.final_loss = float(loss(module(u), target))
    history.seconds = time.perf_counter() - start
    return history

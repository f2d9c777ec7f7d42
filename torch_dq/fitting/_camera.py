r"""The reprojection term: pixels of target points seen by a camera on the moving body.

A camera mounted on the body at ``e`` (its pose in body axes, ``p_body = e p_cam``: Kalibr's
``T_imu_cam``) sees points ``p`` fixed in a target frame posed in the world at ``T`` (default
the identity: the world is the target's frame). The observation stamped ``t`` with the
measured pixel ``(u, v)`` is predicted as

.. math::
    \hat u = \pi_\theta\big((T^{-1} x(t') e)^{-1} p\big), \qquad
    t' = t + \delta t + \ell v,

``\pi_\theta`` the camera model with intrinsics ``\theta`` (:func:`torch_dq.camera.project`),
``\delta t`` the time offset and ``\ell`` the rolling shutter's line delay (seconds per row;
``v`` the measured row). Both move the sample along the curve: the solver chains them through
the curve's time derivative (:meth:`Term.time_rates`), ``dt'_i / d\ell = v_i``.

Observations whose point has no image (behind the camera, outside the double sphere's
field) are excluded: their residual and Jacobian rows are zero (no NaN reaches the normal
equations), and :func:`~torch_dq.fitting.estimate` counts them at the solution
(``term.invalid``) with a warning naming the term. A zero residual would make hiding an
observation pay, so Levenberg-Marquardt rejects every step that loses one predicted at the
current point (:meth:`Term.seen`; one that gains one is fine): from a far start it turned the
camera away from the whole target and reported a zero loss. Intrinsics outside the model's domain (a
camera that sees nothing: ``fu <= 0``, the double sphere's ``alpha`` outside ``[0, 1]``)
give every observation an error of the image's width plus height on both axes, so that a
step of estimated intrinsics out of the domain never passes for a better fit.
"""

from __future__ import annotations

import math
import numbers
import warnings
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from .. import _checks, camera, dualquat
from .._camera_values import LONGEST_LINE_DELAY, normalised_hint, outside, seconds_hint
from ..camera import _in_domain
from ._charts import Pose, Scalar, Vector
from ._nuisance import Slot
from ._terms import Options, Term, _masked, _nuisance, _sigma

__all__ = ["Reprojections"]

_SLACK = 0.1  # measured pixels may stray this fraction of the image's size outside it (a
# simulation that projects without cropping; a refined corner at the border)


def _check_domain(fn: str, model: str, slot: Slot) -> None:
    """Raise where the fixed intrinsics, or an estimate's start (a ``Free``'s), lie outside
    the ``model``'s domain."""
    known = slot.fixed if slot.free is None else slot.free.start
    known = None if known is None else torch.as_tensor(known, dtype=torch.float64)
    if known is not None and not bool(_in_domain(model, list(known.unbind(-1))).all()):
        _checks.fail(fn, f"intrinsics outside the {model!r} model's domain (fu, fv > 0; the "
                         f"double sphere's xi > -1, alpha in [0, 1]): {known.tolist()}")


def _check_line_delay(fn: str, slot: Slot, given, rows: int) -> None:
    """Raise where the fixed line delay, or an estimate's start (a ``Free``'s), is below
    zero; warn where it exceeds ``LONGEST_LINE_DELAY`` per row of the ``rows`` (another
    unit: microseconds?)."""
    known = slot.fixed if slot.free is None else slot.free.start
    if known is None:
        return
    known = torch.as_tensor(known)
    if not bool((known >= 0).all()):
        _checks.fail(fn, f"line_delay must be >= 0 (seconds per row), got {given!r}")
    if bool((known > LONGEST_LINE_DELAY).any()):
        v = float(known.max())
        warnings.warn(f"{fn}: line_delay {v:g} s per row reads {rows} rows in {v * rows:.3g} s "
                      f"(seconds per row expected):{seconds_hint(v, LONGEST_LINE_DELAY)}",
                      UserWarning, stacklevel=3)


def _intrinsics(fn: str, cam) -> tuple[str, Tensor]:
    """The model name and ``(P,)`` float64 parameters of a :class:`torch_dq.camera.Camera`."""
    if not isinstance(cam, camera.Camera):
        _checks.fail(fn, f"camera must be a torch_dq.camera.Camera, got "
                         f"{type(cam).__name__}", TypeError)
    return cam.model, cam.params.detach().to(torch.float64)


class Reprojections(Term):
    r"""Pixels of target points seen by a camera on the body (module docstring).

    Args:
        times: ``(N,)`` or ``(B, N)`` the frames' timestamps (one row per observation,
            non-decreasing; the trajectory's time).
        points: ``(..., N, 3)`` the observed points in target coordinates.
        pixels: ``(..., N, 2)`` the measured pixels ``(u, v)`` (``v`` the row).
        camera: a :class:`torch_dq.camera.Camera` (its model and parameters).
        sigma: pixel noise, a float or 2 (``u``, ``v``).
        extrinsic: ``(8,)`` the camera's pose on the body ``e`` (``p_body = e p_cam``;
            None: identity), fixed or estimated (chart ``e exp(delta)``).
        target: ``(8,)`` the target's pose in the world (None: identity), fixed or estimated
            (chart ``T exp(delta)``).
        intrinsics: None (the camera's parameters, fixed), ``True`` (estimated from them),
            a :class:`~torch_dq.fitting.Free` or a fixed ``(P,)`` tensor; chart
            ``params + delta``.
        time_offset: the camera's clock offset (seconds), see :mod:`torch_dq.fitting`.
        line_delay: the rolling shutter's delay per row (seconds, ``>= 0``; None: global
            shutter), fixed or estimated (start 0) within ``[0, max_line_delay]``.
        max_time_offset: bound on an estimated time offset (seconds).
        max_line_delay: bound on an estimated line delay (seconds per row, default
            ``1e-4``: a 1000-row image read in 0.1 s); the domain check widens the times by
            ``max_line_delay * v``.
        robust: None, ``"huber"`` or ``"cauchy"``; robust_k: its scale (default 2.4477).
        mask: ``(..., N)`` bool, False excludes an observation.

    Residual ``(..., N, 2)``: predicted minus measured pixel over ``sigma``; zero for masked
    observations and for points without an image (``term.invalid`` counts them after
    :func:`~torch_dq.fitting.estimate`, which raises a ``ValueError`` where none is left).

    Raises:
        ValueError: shapes that do not match, points that are not finite, pixels (not
            masked) outside ``camera.resolution`` by over 10 % of its size (another camera's
            or another image size's pixels), a bad ``sigma``, ``line_delay`` or bound,
            ``intrinsics`` (fixed, or a ``Free``'s start) outside the model's domain.

    Warns:
        UserWarning: pixels that look like normalised coordinates (all within 4 of the
        origin ``(0, 0)`` while the principal point is not).
        RuntimeWarning: (an optimum's first uncertainty) a global shutter (line delay
        fixed at 0 or None) whose pixels ask for a rolling shutter, a ``"pinhole"`` camera
        whose pixels ask for radial distortion: the score test of the line delay, of
        ``k1``, beyond 5 of its standard deviations (``torch_dq.fitting._score``,
        ``_omitted``; the warning gives the value one Gauss-Newton step suggests).

    Example (the body at rest at the origin, the camera on it, two points 1 m ahead):
        >>> import torch_dq.dualquat as dq
        >>> from torch_dq.camera import Camera
        >>> from torch_dq.nn import BSpline
        >>> f64 = torch.float64
        >>> cam = Camera("pinhole", torch.tensor([400.0, 400.0, 320.0, 240.0], dtype=f64),
        ...              (640, 480))
        >>> spline = BSpline(dq.identity((4,), dtype=f64))  # domain [0, 1]
        >>> t = torch.full((2,), 0.5, dtype=f64)
        >>> pts = torch.tensor([[0.0, 0.0, 1.0], [0.1, -0.05, 1.0]], dtype=f64)
        >>> pix = torch.tensor([[320.0, 240.0], [361.0, 220.0]], dtype=f64)
        >>> term = Reprojections(t, pts, pix, camera=cam, sigma=0.5)
        >>> term(spline).detach()  # predicted minus measured, over sigma
        tensor([[ 0.,  0.],
                [-2.,  0.]], dtype=torch.float64)
    """

    dim = 2
    _fn = "fitting.Reprojections"
    max_line_delay: float

    if TYPE_CHECKING:  # buffers (registered in __init__)
        points: Tensor
        pixels: Tensor
        rows: Tensor
        camera_params: Tensor

    def __init__(self, times: Tensor, points: Tensor, pixels: Tensor, *, camera, sigma,
                 extrinsic=None, target=None, intrinsics=None, time_offset=None,
                 line_delay=None, max_time_offset: float = 0.1, max_line_delay: float = 1e-4,
                 robust: str | None = None, robust_k: float | None = None,
                 mask: Tensor | None = None) -> None:
        fn = self._fn
        self.model, params = _intrinsics(fn, camera)
        self.resolution = camera.resolution
        _checks.tensor(fn, "pixels", pixels, 2)
        _checks.tensor(fn, "points", points, 3)
        if pixels.dim() < 2 or points.dim() < 2:
            _checks.fail(fn, f"expected (..., N, 3) points and (..., N, 2) pixels, got "
                             f"{_checks.shape_str(points.shape)} and "
                             f"{_checks.shape_str(pixels.shape)}")
        try:
            batch = torch.broadcast_shapes(points.shape[:-1], pixels.shape[:-1])
        except RuntimeError:
            _checks.fail(fn, f"points {_checks.shape_str(points.shape)} and pixels "
                             f"{_checks.shape_str(pixels.shape)} do not broadcast")
        pixels = pixels.detach().expand(*batch, 2)
        super().__init__([times], ["times"], pixels, 1, _sigma(fn, "sigma", sigma, 2),
                         Options(time_offset, max_time_offset, robust, robust_k, mask))
        points = points.detach().expand(*batch, 3)
        finite = torch.isfinite(points).all(-1)
        if bool((self.mask & ~finite).any()):
            _checks.fail(fn, "the points must be finite (mask the observations that are not)")
        if isinstance(max_line_delay, bool) or not isinstance(max_line_delay, numbers.Real) or \
                not (math.isfinite(max_line_delay) and float(max_line_delay) > 0):
            _checks.fail(fn, f"max_line_delay must be a positive finite float, got "
                             f"{max_line_delay!r}")
        self.max_line_delay = float(max_line_delay)
        hint = normalised_hint(pixels[self.mask], params)
        if hint is not None:
            warnings.warn(f"{fn}: {hint}", UserWarning, stacklevel=2)
        else:
            out = outside(pixels[self.mask], camera.resolution, _SLACK)
            if out is not None:
                _checks.fail(fn, f"pixels reach {out[0]} = {out[1]:.6g}, outside "
                                 f"camera.resolution = {camera.resolution} by over "
                                 f"{_SLACK:.0%} of its size (expected {out[2]}; is that the "
                                 f"camera's (width, height)?)")
        self._buffer("points", _masked(points, self.mask, 1.0), 1)
        self._buffer("pixels", _masked(pixels, self.mask, 0.0), 1)
        self._buffer("rows", self.pixels[..., 1].to(torch.float64), 0)
        self._buffer("camera_params", params.to(pixels.device))
        if intrinsics is None or intrinsics is False:
            intrinsics = params
        self._slots["extrinsic"] = Slot(fn, "extrinsic", Pose(), extrinsic)
        self._slots["target"] = Slot(fn, "target", Pose(), target)
        self._slots["intrinsics"] = Slot(fn, "intrinsics", Vector(params.shape[0]), intrinsics,
                                         kind=f"{self.model} intrinsics")  # one Free: one model
        self._slots["line_delay"] = Slot(fn, "line_delay", Scalar(0.0, self.max_line_delay),
                                         line_delay)
        _check_domain(fn, self.model, self._slots["intrinsics"])
        _check_line_delay(fn, self._slots["line_delay"], line_delay, self.resolution[1])
        self.invalid: Tensor | None = None

    extrinsic = _nuisance("extrinsic", "The camera's pose on the body ``e`` ``(..., 8)``.")
    target = _nuisance("target", "The target's pose in the world ``(..., 8)``.")
    intrinsics = _nuisance("intrinsics", "The camera's parameters ``(..., P)``.")
    line_delay = _nuisance("line_delay", "The rolling shutter's line delay (s per row).")

    def time_rates(self) -> dict[str, Tensor | float]:
        """``t' - t = time_offset + line_delay * v``: rates 1 and the rows ``v (..., N)``."""
        rates: dict[str, Tensor | float] = {"time_offset": 1.0}
        if self._slots["line_delay"].present:
            rates["line_delay"] = self.rows
        return rates

    def default_start(self, name, trajectory, ctrl, values):
        if name == "intrinsics":
            return self.camera_params.clone()
        return super().default_start(name, trajectory, ctrl, values)

    def _project(self, x: Tensor, p: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        """Predicted pixels ``(..., N, 2)`` and ``valid (..., N)`` from the body poses ``x``."""
        m = x
        if self._slots["target"].present:
            m = dualquat.mul(dualquat.conj(p["target"].to(x.dtype)), m)
        if self._slots["extrinsic"].present:
            m = dualquat.mul(m, p["extrinsic"].to(x.dtype))
        cam = dualquat.apply(dualquat.conj(m), self.points.to(x.dtype))
        return camera.project(self.model, p["intrinsics"].to(x.dtype), cam)

    def _residual(self, ev, p):
        """Pixel errors ``(..., N, 2)``: zero where a point has no image, the image's width
        plus height where the intrinsics leave the model's domain (module docstring: else a
        step out of the domain would empty the term and be taken for a better fit)."""
        pix, valid = self._project(ev[0][0], p)
        r = pix - self.pixels.to(pix.dtype)
        r = torch.where(valid[..., None], r, 0.0)
        seen = _in_domain(self.model, list(p["intrinsics"].unbind(-1)))[..., None]
        return torch.where(seen, r, float(sum(self.resolution)))

    def seen(self, derivs, p):
        return self._project(derivs[0][0], p)[1] & self.mask

    def _predict(self, trajectory, shift: float = 0.0) -> tuple[Tensor, Tensor]:
        """Predicted pixels and ``valid`` at the current values, the times moved by
        ``shift`` seconds more (no gradient)."""
        values = self.values(trajectory)
        like = trajectory.control_points
        with torch.no_grad():
            p = self.per_sample({k: v.to(like.dtype) for k, v in values.items()})
            t = self.times + self.time_shift(p).to(self.times.dtype) + shift
            lo, hi = (torch.as_tensor(e, dtype=t.dtype, device=t.device)
                      for e in trajectory.domain)
            x = trajectory(torch.minimum(torch.maximum(t, lo[..., None]), hi[..., None]))
            return self._project(x, p)

    def _rate(self, trajectory) -> Tensor:
        """``(..., N, 2)`` float64: the predicted pixels' rate in time (pixels per second,
        a central difference over 2 ms)."""
        h = 1e-3
        rate = (self._predict(trajectory, h)[0] - self._predict(trajectory, -h)[0]) / (2 * h)
        return rate.to(torch.float64)

    def _omitted(self, trajectory) -> dict[str, Tensor]:
        r"""The predicted pixels' derivatives ``(..., N, 2)`` (float64) at the current values
        with respect to the parameters this term's model leaves out, as
        ``torch_dq.fitting._score``'s tests of them read them: ``"line_delay"`` where the
        line delay is fixed at 0 or absent (a global shutter: :math:`v_i \dot u_i`, the
        row times the pixel's rate in time) and ``"k1"`` for a ``"pinhole"`` camera (the
        first radial coefficient of ``"pinhole-radtan"`` at 0:
        :math:`(u - c_u,\ v - c_v)\, r^2`, :math:`r^2 = a^2 + b^2` of the normalised
        coordinates :math:`a = (u - c_u) / f_u`, :math:`b = (v - c_v) / f_v`)."""
        out: dict[str, Tensor] = {}
        slot = self._slots["line_delay"]
        if not slot.estimated and (slot.fixed is None or not bool(
                torch.as_tensor(slot.fixed).ne(0).any())):
            out["line_delay"] = self._rate(trajectory) * self.rows[..., None]
        if self.model == "pinhole":
            k = self.values(trajectory)["intrinsics"].to(torch.float64)[..., None, :]
            d = self._predict(trajectory)[0].to(torch.float64) - k[..., 2:4]
            out["k1"] = d * (d / k[..., 0:2]).square().sum(-1, keepdim=True)
        return out

    def visible(self, trajectory) -> Tensor:
        """``(..., N)`` bool: the observations that project valid at the current values and
        are not masked."""
        return self._predict(trajectory)[1] & self.mask

    def solved(self, trajectory) -> Tensor:
        r"""The observations with an image at the solution ``(..., N)`` bool (those counted by
        :attr:`~torch_dq.fitting.Estimate.chi2` and ``dof``); count those without
        (``invalid (...)``, int64 per batch element) and warn when there are any (raise
        where a batch element has none with an image: the term says nothing); warn when
        an estimated line delay meets too little motion: its information
        :math:`\sum_i (v_i |\dot u_i| / \sigma)^2` (``\dot u`` the predicted pixel velocity)
        leaves it a standard deviation above ``max_line_delay``."""
        valid = self.visible(trajectory)
        self.invalid = (self.mask & ~valid).sum(-1)
        blind = ~valid.any(-1)  # a camera that sees nothing at the solution: no information
        if bool(blind.any()):
            i = tuple(int(v) for v in torch.nonzero(blind.reshape(blind.shape or (1,)))[0])
            where = f" (batch element {list(i)})" if blind.dim() else ""
            _checks.fail("fitting.estimate", f"every observation of Reprojections (camera "
                         f"{self.model!r}){where} projects invalid at the solution (behind the "
                         f"camera or outside the model's domain): the term carries no "
                         f"information, and a result would ignore it; check the extrinsic (the "
                         f"camera's pose on the body, p_body = e p_cam: Kalibr's T_imu_cam, not "
                         f"T_cam_imu), the target's pose and the trajectory's start")
        n = int(self.invalid.sum())
        if n:
            warnings.warn(f"fitting.estimate: {n} observation(s) of Reprojections (camera "
                          f"{self.model!r}) project invalid at the solution (behind the camera "
                          f"or outside the model's domain): excluded; their count is "
                          f"term.invalid", RuntimeWarning, stacklevel=3)
        if self._slots["line_delay"].estimated:
            w = (self._rate(trajectory) * self.rows[..., None] / self.sigma).square().sum(-1)
            info = torch.where(valid, w, 0.0).sum(-1)
            if bool((info * self.max_line_delay ** 2 < 1.0).any()):
                warnings.warn("fitting.estimate: the Reprojections line_delay is undetermined: "
                              "the camera barely moves during its frames (the pixels move less "
                              "than sigma over a readout); fix it (None: global shutter)",
                              RuntimeWarning, stacklevel=3)
        return valid


Reprojections.__init__.__doc__ = Reprojections.__doc__

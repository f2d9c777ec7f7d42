r"""Camera models: pixels from points (:func:`project`), rays from pixels (:func:`unproject`).

Camera axes are OpenCV's and Kalibr's: ``x`` right, ``y`` down, ``z`` forward; a pixel
``(u, v)`` has ``(0, 0)`` at the centre of the top-left pixel, ``v`` the row. A model is a
name and a parameter vector ``(..., P)`` in Kalibr's and basalt's order:

=========================  ======================================  ==========================
model                      params                                  source
=========================  ======================================  ==========================
``"pinhole"``              ``fu, fv, cu, cv``                      the pinhole camera
``"pinhole-radtan"``       ``fu, fv, cu, cv, k1, k2, p1, p2``      OpenCV's plumb bob with
                                                                   ``k3 = 0``; Kalibr radtan
``"pinhole-equidistant"``  ``fu, fv, cu, cv, k1, k2, k3, k4``      Kannala-Brandt; OpenCV
                                                                   fisheye; Kalibr
                                                                   equidistant
``"double-sphere"``        ``fu, fv, cu, cv, xi, alpha``           Usenko, Demmel, Cremers
                                                                   2018; basalt ``ds``
=========================  ======================================  ==========================

Both functions broadcast ``params`` against the points or pixels like torch ops, follow
their dtype and device (float16/bfloat16 compute in float32) and are exact and twice
differentiable w.r.t. both arguments. Each returns a ``valid`` mask: where it is False
the outputs are finite, with finite gradients (safe where: the unsafe inputs are replaced
by a harmless constant before the formula), and must be masked by the caller. NaN or inf
in an element's inputs gives NaN or inf outputs in that element only.

Unprojection of the distorted pinhole models has no closed form: it runs a fixed number
of safeguarded Newton iterations (no data-dependent branching or host reads: ``torch.func.vmap`` and
``torch.compile(fullgraph=True)`` go through) without autograd, then attaches the
derivatives by two Newton steps from that detached root. One Newton step
``x - J(x)^{-1} (F(x) - y)`` from a detached root has the implicit function's exact first
derivatives; a second step from it has the exact second derivatives too (the Newton map's
derivative in ``x`` vanishes at the root), so gradients and Hessians are exact without
differentiating through the iteration.

:class:`Camera` is a small value (model, ``(P,)`` params, resolution) that reads and writes
one camera of a Kalibr ``camchain.yaml``.

Example:
    >>> import torch
    >>> from torch_dq import camera
    >>> params = torch.tensor([458.654, 457.296, 367.215, 248.375,
    ...                        -0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
    ...                       dtype=torch.float64)
    >>> px, ok = camera.project("pinhole-radtan", params, torch.tensor([0.1, -0.2, 1.0],
    ...                                                                  dtype=torch.float64))
    >>> [round(float(c), 3) for c in px], bool(ok)
    ([412.436, 158.206], True)
    >>> ray, ok = camera.unproject("pinhole-radtan", params, px)
    >>> [round(float(c), 6) for c in ray / ray[2]]
    [0.1, -0.2, 1.0]
"""

from __future__ import annotations

import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import torch
from torch import Tensor

from . import _camera_models as _models
from . import _camera_values as _values
from . import _checks
from ._numerics import compute_dtype, nan_unless
from ._undistort import unproject_equidistant, unproject_radtan

__all__ = ["MODELS", "Camera", "project", "unproject"]

#: The models and their parameter names, in the order of the ``params`` vector.
MODELS: dict[str, tuple[str, ...]] = {
    "pinhole": ("fu", "fv", "cu", "cv"),
    "pinhole-radtan": ("fu", "fv", "cu", "cv", "k1", "k2", "p1", "p2"),
    "pinhole-equidistant": ("fu", "fv", "cu", "cv", "k1", "k2", "k3", "k4"),
    "double-sphere": ("fu", "fv", "cu", "cv", "xi", "alpha"),
}



def _checked(fn: str, model, params, x, name: str, event: int) -> torch.Size:
    """Validate a call of project/unproject; return the broadcast batch shape."""
    if not isinstance(model, str) or model not in MODELS:
        _checks.fail(fn, f"expected model to be one of {', '.join(map(repr, MODELS))}, "
                         f"got {model!r}")
    _checks.tensor(fn, "params", params, len(MODELS[model]))
    _checks.tensor(fn, name, x, event)
    _checks.same_dtype_device(fn, params=params, **{name: x})
    return _checks.broadcast_batch(fn, params=(params, 1), **{name: (x, 1)})


# Parameter values that replace those outside a model's domain (safe where): unit focal
# lengths, no distortion, the double sphere's alpha = 1/2 and xi = 0.
_SAFE = {model: (1.0, 1.0) + (0.0,) * (len(names) - 2) for model, names in MODELS.items()}
_SAFE["double-sphere"] = (1.0, 1.0, 0.0, 0.0, 0.0, 0.5)


def _in_domain(model: str, p: list[Tensor]) -> Tensor:
    """The ``(...)`` mask of parameters (``p`` unbound) inside the model's domain."""
    ok = (p[0] > 0) & (p[1] > 0)
    return ok & (p[4] > -1) & (p[5] >= 0) & (p[5] <= 1) if model == "double-sphere" else ok


def _parts(model: str, params: Tensor, x: Tensor) -> tuple[list[Tensor], list[Tensor], Tensor]:
    """The parameters and coordinates as lists of tensors in the compute dtype, and the
    ``(...)`` mask of finite parameters in the model's domain (``fu, fv > 0``; the double
    sphere's ``alpha`` in ``[0, 1]``, ``xi > -1``: else no point has ``xi d1 + z > 0``).
    Outside it the parameters are ``_SAFE``'s, and non-finite coordinates are 0 (safe where:
    finite outputs, and gradients without 0 * NaN reaching shared arguments; no host read)."""
    cd = compute_dtype(x.dtype)
    p = list(params.to(cd).unbind(-1))
    ok = _in_domain(model, p) & torch.isfinite(params).all(-1)
    p = [torch.where(ok, c, s) for c, s in zip(p, _SAFE[model], strict=True)]
    return p, list(torch.where(torch.isfinite(x), x, 0.0).to(cd).unbind(-1)), ok


def _outputs(batch: torch.Size, parts: tuple[Tensor, ...], valid: Tensor, params: Tensor,
             x: Tensor) -> tuple[Tensor, Tensor]:
    """Stack the output's components, NaN where an input is not finite (the formulas'
    finite limits, a point at infinity's pixel, must not come back; the safe-where
    replacements of the models do not look at finiteness), and ``valid`` False there."""
    finite = torch.isfinite(params).all(-1) & torch.isfinite(x).all(-1)
    out = nan_unless(finite[..., None], torch.stack(torch.broadcast_tensors(*parts), -1))
    return out.to(x.dtype).expand(*batch, len(parts)), (valid & finite).expand(batch)


def project(model: str, params: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
    r"""Pixels of points in camera axes under a camera model.

    Args:
        model: ``"pinhole"``, ``"pinhole-radtan"``, ``"pinhole-equidistant"`` or
            ``"double-sphere"`` (:data:`MODELS`).
        params: ``(..., P)`` the model's parameters in :data:`MODELS`' order; broadcasts
            against ``points``' batch.
        points: ``(..., 3)`` points in camera axes (``z`` forward).

    Returns:
        ``(pixels, valid)``: ``(..., 2)`` pixels ``(u, v)`` and a ``(...)`` bool mask, False
        where the point has no image: ``z <= 0`` for the pinhole models (and points within
        ``eps`` radians of the plane ``z = 0``, ``max(|x|, |y|) >= z / eps``, whose pixels
        or derivatives would overflow); for the double sphere where the paper's condition
        :math:`z > -w_2 d_1` (eq. 43) fails (the origin is invalid) or, for
        :math:`\xi < 0` where eq. 43 is not exact, the point lies beyond the part of the
        second sphere that the projection sees, :math:`w \le -w_1 d_2` (its pixel would
        pass through infinity to the other side of the image); where the parameters
        lie outside the model's domain (``fu <= 0`` or ``fv <= 0``; for the double sphere
        ``xi <= -1`` or ``alpha`` outside ``[0, 1]``): every element of that camera is
        invalid, a mask and not an error (no host read); and where an input is not finite
        (the pixels are NaN there). Invalid points get finite pixels with finite gradients
        (they are computed at a replacement point, out-of-domain parameters at replacement
        parameters): mask them.

    Formulas (normalised coordinates :math:`a = x/z,\ b = y/z`, :math:`r^2 = a^2 + b^2`):

    - pinhole: :math:`u = f_u a + c_u,\ v = f_v b + c_v`;
    - radtan (OpenCV ``projectPoints`` with ``k3 = 0``): :math:`a' = a (1 + k_1 r^2 +
      k_2 r^4) + 2 p_1 a b + p_2 (r^2 + 2 a^2)`, :math:`b' = b (1 + k_1 r^2 + k_2 r^4) +
      p_1 (r^2 + 2 b^2) + 2 p_2 a b`;
    - equidistant (OpenCV ``fisheye.projectPoints``): :math:`\theta = \arctan r`,
      :math:`\theta_d = \theta (1 + k_1 \theta^2 + k_2 \theta^4 + k_3 \theta^6 +
      k_4 \theta^8)`, :math:`(a', b') = (\theta_d / r) (a, b)`, evaluated through
      :math:`\arctan(r)/r` as an even function of :math:`r` (smooth on the axis);
    - double sphere (eqs. 40-43): :math:`d_1 = |p|`, :math:`d_2 = |(x, y, \xi d_1 + z)|`,
      :math:`u = f_u x / (\alpha d_2 + (1 - \alpha)(\xi d_1 + z)) + c_u` (and ``v``).

    Example:
        >>> px, ok = project("pinhole", torch.tensor([500.0, 500.0, 320.0, 240.0]),
        ...                  torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, -1.0]]))
        >>> px[0].tolist(), ok.tolist()
        ([320.0, 240.0], [True, False])
    """
    fn = "camera.project"
    batch = _checked(fn, model, params, points, "points", 3)
    p, (x, y, z), ok = _parts(model, params, points)
    u, v, valid = _PROJECT[model](p, x, y, z)
    return _outputs(batch, (u, v), valid & ok, params, points)


_PROJECT: dict[str, Callable] = {
    "pinhole": _models.project_pinhole, "pinhole-radtan": _models.project_radtan,
    "pinhole-equidistant": _models.project_equidistant, "double-sphere": _models.project_ds}


def unproject(model: str, params: Tensor, pixels: Tensor) -> tuple[Tensor, Tensor]:
    r"""Unit rays of pixels under a camera model (the inverse of :func:`project`).

    Args:
        model: a name of :data:`MODELS`.
        params: ``(..., P)`` the model's parameters; broadcasts against ``pixels``' batch.
        pixels: ``(..., 2)`` pixels ``(u, v)``.

    Returns:
        ``(rays, valid)``: ``(..., 3)`` unit vectors in camera axes and a ``(...)`` bool
        mask, False where the pixel is not the image of a ray under :func:`project`, and
        everywhere for parameters outside the model's domain (``fu <= 0`` or ``fv <= 0``;
        for the double sphere ``xi <= -1`` or ``alpha`` outside ``[0, 1]``; a mask, not an
        error: no host read). Invalid rays are finite with finite gradients (out-of-domain
        parameters are replaced before the formulas); mask them:

        - pinhole: closed form, valid within :func:`project`'s ``1 / eps`` of the axis.
        - radtan: 2-D damped Newton on the distortion map from the distorted point over its
          radial factor (16 iterations; a step is taken where it lowers the error and stays
          inside the fold's disk, else it is halved: globalised Newton; then two
          differentiable steps, see the module's notes). Valid where the root lies inside
          the fold, the first zero of :math:`d(r\,(1 + k_1 r^2 + k_2 r^4))/dr = 1 + 3 k_1
          r^2 + 5 k_2 r^4`, with a positive Jacobian determinant, and the iteration
          converged (``256 eps`` relative); invalid beyond (no preimage inside the fold: a
          pixel beyond the largest distorted radius). Near a fold the root is
          ill-conditioned: pixels whose root lies within 2e-5 of the fold's radius or where
          the map's Jacobian determinant is below 1e-5 (3e-5 of the pixels inside a k1 =
          -0.4 lens's fold) may come back invalid. A lens without a fold (:math:`9 k_1^2 <
          20 k_2`) inverts every pixel.
        - equidistant: 1-D Newton on :math:`\theta_d(\theta) = |m|` (``m`` the normalised
          pixel) safeguarded by bisection in a bracket of the first root within
          :math:`[0, \pi/2]`. Invalid where the root is at
          or beyond 90 degrees (``z <= 0``: not an image of :func:`project`), where
          :math:`d\theta_d/d\theta \le 0` at the root (fold-over) or where it did not
          converge.
        - double sphere (eqs. 47-50): closed form; invalid outside the paper's unprojection
          domain, :math:`r^2 \ge 1/(2\alpha - 1)` for :math:`\alpha > 0.5`, where
          :math:`m_z^2 + (1 - \xi^2) r^2 \le 0` (no real point of the first sphere, possible
          for :math:`\xi > 1`), where the ray fails :func:`project`'s domain (for
          :math:`\xi \ne 0` the boundary of eq. 50 maps slightly outside it) and, for
          :math:`\xi > 1`, where it is not on the first sphere's near side,
          :math:`1 + \xi z \le 0` (eq. 50's root is then a negative distance: the ray would
          point away from the pixel's point).

    The iterations' accuracy: ``project(unproject(px)) == px`` to 1e-10 px in float64 over
    the whole image of EuRoC's cam0 (radtan) and of a 190-degree fisheye (tested). In
    float32 (params and pixels) the rays re-project within 3e-4 px over a 752 x 480 image
    (measured 1.8e-4 px, every model; :func:`project`'s float32 pixels are within 2e-6 of
    the larger of the pixel and ``fu``: tests/test_cam13_contract.py).

    Example:
        >>> ray, ok = unproject("pinhole", torch.tensor([500.0, 500.0, 320.0, 240.0]),
        ...                     torch.tensor([320.0, 240.0]))
        >>> ray.tolist(), bool(ok)
        ([0.0, 0.0, 1.0], True)
    """
    fn = "camera.unproject"
    batch = _checked(fn, model, params, pixels, "pixels", 2)
    p, (u, v), ok = _parts(model, params, pixels)
    a, b = (u - p[2]) / p[0], (v - p[3]) / p[1]  # normalised (distorted) coordinates
    x, y, z, valid = _UNPROJECT[model](p, a, b)
    return _outputs(batch, (x, y, z), valid & ok, params, pixels)


_UNPROJECT: dict[str, Callable] = {
    "pinhole": _models.unproject_pinhole, "pinhole-radtan": unproject_radtan,
    "pinhole-equidistant": unproject_equidistant, "double-sphere": _models.unproject_ds}


@dataclass(frozen=True, eq=False)
class Camera:
    r"""A camera: a model of :data:`MODELS`, its ``(P,)`` parameters and its resolution.

    A small frozen value; :meth:`project` and :meth:`unproject` are :func:`project` and
    :func:`unproject` with this camera's model and parameters. Two cameras are equal when
    their models, resolutions and parameters (dtype included) are. ``params`` is a copy of
    the tensor given (changing that tensor later does not change the camera; gradients flow
    back to it); changing ``camera.params`` in place makes the camera's methods raise
    ``ValueError`` instead of silently using the new values.

    Args:
        model: a name of :data:`MODELS`.
        params: ``(P,)`` floating tensor in the model's order (a sequence of numbers is
            turned into a float64 tensor).
        resolution: ``(width, height)`` in pixels, positive ints.

    Raises:
        ValueError: an unknown model, params of the wrong shape, not finite or outside the
            model's domain (``fu``, ``fv`` not positive; for the double sphere ``xi <= -1``
            or ``alpha`` outside ``[0, 1]``: a camera that projects nothing), a bad
            resolution.
        TypeError: params that are not floating point.

    Example:
        >>> cam = Camera.from_kalibr({
        ...     "camera_model": "pinhole", "distortion_model": "radtan",
        ...     "intrinsics": [458.654, 457.296, 367.215, 248.375],
        ...     "distortion_coeffs": [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05],
        ...     "resolution": [752, 480]})
        >>> cam.model, cam.resolution, cam.params.dtype
        ('pinhole-radtan', (752, 480), torch.float64)
        >>> Camera.from_kalibr(cam.to_kalibr()) == cam
        True
    """

    model: str
    params: Tensor
    resolution: tuple[int, int]
    _version: int = field(init=False, repr=False, default=0)  # params' at construction

    def __post_init__(self) -> None:
        fn = "camera.Camera"
        if not isinstance(self.model, str) or self.model not in MODELS:
            _checks.fail(fn, f"expected model to be one of {', '.join(map(repr, MODELS))}, "
                             f"got {self.model!r}")
        params = self.params
        if not isinstance(params, Tensor):
            params = torch.tensor(
                _values.numbers_list(fn, "params", params, len(MODELS[self.model])),
                dtype=torch.float64)
        _checks.tensor(fn, "params", params)
        if params.shape != (len(MODELS[self.model]),):
            _checks.fail(fn, f"expected a ({len(MODELS[self.model])},) tensor for params of a "
                             f"{self.model!r} camera, got shape {_checks.shape_str(params.shape)}")
        values = params.detach()
        if not bool((torch.isfinite(values).all() & _in_domain(self.model, list(values))).item()):
            limits = " > -1, alpha in [0, 1]" if self.model == "double-sphere" else ""
            _checks.fail(fn, f"expected finite params of a {self.model!r} camera with fu, fv "
                             f"> 0{' and xi' + limits if limits else ''} ("
                             f"{', '.join(MODELS[self.model])}), got {values.tolist()}")
        params = params.clone()  # not the caller's tensor (gradients still flow back to it)
        object.__setattr__(self, "params", params)
        object.__setattr__(self, "_version", params._version)
        object.__setattr__(self, "resolution", _values.width_height(fn, self.resolution))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Camera):
            return NotImplemented
        return (self.model == other.model and self.resolution == other.resolution
                and self.params.dtype == other.params.dtype
                and torch.equal(self.params.cpu(), other.params.cpu()))

    __hash__ = None  # type: ignore[assignment]  # equal by value, and tensors are mutable

    def _params(self, fn: str) -> Tensor:
        """``params``, unchanged since the camera was made: an in-place change through
        ``camera.params`` raises (a frozen value; it would change the results silently)."""
        if self.params._version != self._version:
            _checks.fail(fn, "the camera's params were changed in place after it was made "
                             "(a Camera is a frozen value): make a new one, Camera(cam.model, "
                             "new_params, cam.resolution)")
        return self.params

    def project(self, points: Tensor) -> tuple[Tensor, Tensor]:
        """:func:`project` with this camera: ``(pixels (..., 2), valid (...))``."""
        return project(self.model, self._params("camera.Camera.project"), points)

    def unproject(self, pixels: Tensor) -> tuple[Tensor, Tensor]:
        """:func:`unproject` with this camera: ``(rays (..., 3), valid (...))``."""
        return unproject(self.model, self._params("camera.Camera.unproject"), pixels)

    def to(self, *args, **kwargs) -> Camera:
        """The camera with its params moved or cast by ``Tensor.to(*args, **kwargs)``."""
        return Camera(self.model, self._params("camera.Camera.to").to(*args, **kwargs),
                      self.resolution)

    @classmethod
    def from_kalibr(cls, entry: Mapping, *, dtype: torch.dtype = torch.float64,
                    device=None) -> Camera:
        """Read one camera of a Kalibr ``camchain.yaml`` (the mapping under ``cam0``, ...).

        Args:
            entry: with ``camera_model`` (``pinhole`` or ``ds``), ``distortion_model``
                (``none``, ``radtan``, ``equidistant``; absent means ``none``),
                ``intrinsics`` (``[fu, fv, pu, pv]``; ``[xi, alpha, fu, fv, pu, pv]`` for
                ``ds``), ``distortion_coeffs`` (4 numbers for radtan and equidistant, none
                or zeros otherwise) and ``resolution`` (``[width, height]``, ints or
                integral floats); other keys (``T_cam_imu``, ``rostopic``, ...) are
                ignored. Numbers written without a dot (``2e-4``), which YAML 1.1 (PyYAML)
                reads as strings, are read as numbers.
            dtype, device: of the params tensor.

        Raises:
            ValueError: an unknown camera or distortion model (Kalibr's ``omni``, ``eucm``,
                ``fov``, ... are not supported), or malformed numbers, naming the key.
        """
        fn = "camera.Camera.from_kalibr"
        if not isinstance(entry, Mapping):
            _checks.fail(fn, f"expected a mapping (one camera of a camchain), got "
                             f"{type(entry).__name__}", TypeError)
        names = (entry.get("camera_model"), entry.get("distortion_model", "none"))
        if not all(isinstance(n, str) for n in names) or names not in _values.FROM_KALIBR:
            _checks.fail(fn, f"unsupported camera_model {names[0]!r} with distortion_model "
                             f"{names[1]!r}: expected pinhole with none, radtan or "
                             f"equidistant, or ds with none")
        model = _values.FROM_KALIBR[names]
        intr = _values.numbers_list(fn, "intrinsics", _values.kalibr_list(entry.get("intrinsics")),
                        6 if names[0] == "ds" else 4)
        if names[1] != "none" and "distortion_coeffs" not in entry:
            _checks.fail(fn, f"distortion_model {names[1]!r} needs distortion_coeffs (4 "
                             f"numbers); the entry has none")
        raw = _values.kalibr_list(entry.get("distortion_coeffs", []))
        if names[1] == "none" and isinstance(raw, list) and all(
                isinstance(v, numbers.Real) and v == 0 for v in raw):
            raw = []  # no distortion written as zeros
        coeffs = _values.numbers_list(fn, "distortion_coeffs", raw,
                                      0 if names[1] == "none" else 4)
        params = intr[2:] + intr[:2] if names[0] == "ds" else intr + coeffs
        res = _values.kalibr_list(entry.get("resolution"))
        if isinstance(res, list):  # 752.0: an integral float is the int
            res = [int(v) if isinstance(v, float) and v.is_integer() else v for v in res]
        return cls(model, torch.tensor(params, dtype=dtype, device=device),
                   _values.width_height(fn, res))

    def to_kalibr(self) -> dict:
        """This camera as one entry of a Kalibr ``camchain.yaml``: a dict of plain Python
        strings, floats and lists (``yaml.safe_dump`` writes it), the inverse of
        :meth:`from_kalibr` (float64 parameters round-trip exactly)."""
        camera_model, distortion = _values.KALIBR[self.model]
        p = [float(v) for v in self._params("camera.Camera.to_kalibr").detach().cpu().double()
             .tolist()]
        intrinsics, coeffs = (p[4:] + p[:4], []) if camera_model == "ds" else (p[:4], p[4:])
        return {"camera_model": camera_model, "intrinsics": intrinsics,
                "distortion_model": distortion, "distortion_coeffs": coeffs,
                "resolution": list(self.resolution)}

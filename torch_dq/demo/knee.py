r"""A synthetic knee-flexion motion: poses of the tibia relative to the femur, in mm.

Used by the demo (``python -m torch_dq demo``) and the notebooks as a small, embedded,
reproducible data set (no download). It is a *kinematic caricature* of a healthy knee
flexing from full extension, with the textbook couplings, not a fitted anatomical model.

Frames and units (a right knee):

- **Femur frame** (fixed): origin at the midpoint of the transepicondylar axis,
  ``x`` lateral (along the medial-lateral flexion axis), ``y`` anterior, ``z`` proximal
  (along the femoral shaft). Lengths in millimetres, angles in degrees at the interface.
- **Tibia frame** (moving): origin at the centre of the tibial plateau, the same axes as
  the femur frame at full extension. At full extension the tibia sits ``axis_height_mm``
  below the femoral origin, with no rotation.

The pose :math:`T(t)` of the tibia frame in the femur frame (``x_femur = R x_tibia + p``)
is the composition, for flexion :math:`\varphi`, internal rotation :math:`\psi`, varus
:math:`\beta` and rollback :math:`b`,

.. math::
    T = R_x(-\varphi)\; \mathrm{Tr}(0,\, b,\, -h)\; R_y(\beta)\;
        \big[\mathrm{Tr}(c)\, R_z(\psi)\, \mathrm{Tr}(-c)\big],
    \qquad c = (-m, 0, 0),

that is :math:`R = R_x(-\varphi) R_y(\beta) R_z(\psi)` (intrinsic ``"XYZ"`` Euler angles
``(-phi, beta, psi)``) and :math:`p = R_x(-\varphi)\,[(0, b, -h) + R_y(\beta)(c - R_z(\psi) c)]`:

- **flexion** :math:`\varphi(t)` from 0 to ``flexion_deg`` (120) about the medial-lateral
  axis ``x`` (the distal tibia swings posteriorly), with a smooth speed profile
  :math:`\varphi = \varphi_{max}\,(s - \tfrac{1}{4\pi}\sin 2\pi s)`, :math:`s = t / T_{dur}`
  (half speed at the ends, 1.5 times the mean speed at mid-motion; never at rest, so the
  instantaneous screw axis exists at every time);
- **femoral rollback**: the flexion axis migrates posteriorly on the tibial plateau by
  :math:`b(\varphi) = b_{max} (1 - \cos(\pi\varphi / \varphi_{max})) / 2`, ``rollback_mm``
  (10 mm) at full flexion (the femur rolls and slides back: anterior-posterior sliding of
  the tibia relative to the femur);
- **screw-home coupling**: tibial internal rotation about the tibial long axis
  :math:`\psi = \psi_{max} (1 - e^{-\varphi/\varphi_c}) / (1 - e^{-\varphi_{max}/\varphi_c})`,
  ``internal_rotation_deg`` (18) at full flexion, two thirds of it within the first
  ``screw_home_deg`` (30) degrees (read backwards: the tibia rotates externally in the last
  degrees of extension, the screw-home mechanism). The rotation axis passes
  ``medial_pivot_mm`` (10) medial of the plateau centre (medial-pivot pattern: the lateral
  compartment moves more than the medial one);
- **varus**: a small ab/adduction :math:`\beta = \beta_{max}\,\varphi / \varphi_{max}`
  (``varus_deg``, 2).

The instantaneous screw axis of this motion is close to the medial-lateral axis and moves
posteriorly and distally with flexion while tilting with the coupled rotation: the ruled
surface it sweeps (the fixed axode) is the paper's Fig. 2 idea.

:func:`sample_poses` draws noisy observations (isotropic Gaussian rotation noise in
degrees, right-multiplied in the tibia frame; Gaussian translation noise in mm) from a
seeded ``torch.Generator``.

Example:
    >>> knee = KneeModel()
    >>> t = torch.linspace(0.0, knee.duration_s, 5, dtype=torch.float64)
    >>> knee.angles(t)[0]  # flexion in degrees
    tensor([  0.0000,  20.4507,  60.0000,  99.5493, 120.0000], dtype=torch.float64)
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import Tensor

from .. import _checks, dualquat, quat

__all__ = ["KneeModel", "KneeSamples", "sample_poses"]


@dataclass(frozen=True)
class KneeModel:
    """Parameters of the synthetic knee flexion (see the module docstring for the model).

    Attributes:
        flexion_deg: flexion at the end of the motion (degrees), from 0 at full extension.
        internal_rotation_deg: tibial internal rotation at full flexion (degrees).
        screw_home_deg: flexion scale (degrees) of the screw-home coupling: two thirds of
            the internal rotation happen within this much flexion.
        varus_deg: varus (adduction) of the tibia at full flexion (degrees).
        rollback_mm: posterior migration of the flexion axis on the tibia at full flexion.
        axis_height_mm: distance from the femoral flexion axis to the tibial plateau.
        medial_pivot_mm: distance of the internal-rotation axis medial of the plateau centre.
        duration_s: duration of the motion (seconds); times run over ``[0, duration_s]``.
    """

    flexion_deg: float = 120.0
    internal_rotation_deg: float = 18.0
    screw_home_deg: float = 30.0
    varus_deg: float = 2.0
    rollback_mm: float = 10.0
    axis_height_mm: float = 22.0
    medial_pivot_mm: float = 10.0
    duration_s: float = 2.0

    def __post_init__(self):
        if not 0.0 < self.flexion_deg < 180.0:
            raise ValueError(f"KneeModel: flexion_deg must be in (0, 180), got "
                             f"{self.flexion_deg!r}")
        if not self.screw_home_deg > 0.0:
            raise ValueError(f"KneeModel: screw_home_deg must be > 0, got "
                             f"{self.screw_home_deg!r}")
        if not self.duration_s > 0.0:
            raise ValueError(f"KneeModel: duration_s must be > 0, got {self.duration_s!r}")

    def as_dict(self) -> dict:
        """The parameters as a plain dict (for JSON summaries)."""
        return asdict(self)

    def _check_t(self, fn: str, t) -> Tensor:
        _checks.tensor(f"KneeModel.{fn}", "t", t)
        return t

    def flexion(self, t: Tensor) -> Tensor:
        """Flexion angle (degrees) at times ``t`` (seconds, in ``[0, duration_s]``)."""
        t = self._check_t("flexion", t)
        s = t / self.duration_s
        return self.flexion_deg * (s - torch.sin(2.0 * math.pi * s) / (4.0 * math.pi))

    def angles(self, t: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Flexion, tibial internal rotation and varus (degrees) at times ``t``.

        Args:
            t: ``(...)`` times in seconds, in ``[0, duration_s]``.

        Returns:
            ``(flexion, internal_rotation, varus)``, each ``(...)`` in degrees.
        """
        phi = self.flexion(self._check_t("angles", t))
        c = self.screw_home_deg
        psi = (self.internal_rotation_deg * (1.0 - torch.exp(-phi / c))
               / (1.0 - math.exp(-self.flexion_deg / c)))
        beta = self.varus_deg * phi / self.flexion_deg
        return phi, psi, beta

    def rollback(self, t: Tensor) -> Tensor:
        """Posterior migration (mm) of the flexion axis on the tibial plateau at ``t``."""
        phi = self.flexion(self._check_t("rollback", t))
        return 0.5 * self.rollback_mm * (1.0 - torch.cos(math.pi * phi / self.flexion_deg))

    def poses(self, t: Tensor) -> Tensor:
        r"""Noise-free poses of the tibia in the femur frame (mm) at times ``t``.

        Differentiable in ``t`` (also in forward mode, so
        :func:`torch_dq.curves.velocity` gives the exact velocity of the model).

        Args:
            t: ``(...)`` floating times in seconds, in ``[0, duration_s]``.

        Returns:
            ``(..., 8)`` unit dual quaternions, translations in mm, dtype and device of ``t``.
        """
        t = self._check_t("poses", t)
        phi, psi, beta = self.angles(t)
        deg = math.pi / 180.0
        zero = torch.zeros_like(t)
        one = torch.ones_like(t)
        qx = quat.from_axis_angle(torch.stack((one, zero, zero), -1), -phi * deg)
        qy = quat.from_axis_angle(torch.stack((zero, one, zero), -1), beta * deg)
        qz = quat.from_axis_angle(torch.stack((zero, zero, one), -1), psi * deg)
        q = quat.mul(qx, quat.mul(qy, qz))  # R = Rx(-phi) Ry(beta) Rz(psi)
        c = torch.stack((zero - self.medial_pivot_mm, zero, zero), -1)
        offset = torch.stack((zero, self.rollback(t), zero - self.axis_height_mm), -1)
        p = quat.rotate(qx, offset + quat.rotate(qy, c - quat.rotate(qz, c)))
        return dualquat.from_rt(q, p)

    def __call__(self, t: Tensor) -> Tensor:
        """Same as :meth:`poses`."""
        return self.poses(t)


@dataclass
class KneeSamples:
    """Noisy observations of a :class:`KneeModel`.

    Attributes:
        times: ``(N,)`` increasing sample times (seconds).
        poses: ``(N, 8)`` noisy unit dual quaternions (mm).
        truth: ``(N, 8)`` the noise-free poses at ``times``.
        rotations: ``(N, 4)`` the noisy rotation quaternions ``(w, x, y, z)``.
        translations: ``(N, 3)`` the noisy translations (mm).
        rot_noise_deg: per-axis standard deviation of the rotation noise (degrees).
        trans_noise_mm: per-axis standard deviation of the translation noise (mm).
    """

    times: Tensor
    poses: Tensor
    truth: Tensor
    rotations: Tensor
    translations: Tensor
    rot_noise_deg: float
    trans_noise_mm: float


def sample_poses(model: KneeModel | None = None, n: int = 60, rot_noise_deg: float = 1.0,
                 trans_noise_mm: float = 1.0, *, generator: torch.Generator | None = None,
                 dtype: torch.dtype | None = None,
                 device: torch.device | str | None = None) -> KneeSamples:
    r"""Noisy poses of the knee model at ``n`` uniform times over the motion.

    Noise: :math:`R_i = R(t_i) \exp([\delta_i]_\times)` with
    :math:`\delta_i \sim \mathcal N(0, \sigma_r^2 I_3)` (a rotation vector in the tibia
    frame, :math:`\sigma_r` = ``rot_noise_deg`` in radians) and
    :math:`p_i = p(t_i) + \epsilon_i`, :math:`\epsilon_i \sim \mathcal N(0, \sigma_t^2 I_3)`
    (``trans_noise_mm``). All draws use ``generator`` (CPU draws, then moved to ``device``),
    so a seeded generator gives the same samples on every device.

    Args:
        model: the motion (default :class:`KneeModel`).
        n: number of samples, ``>= 2``.
        rot_noise_deg: rotation noise per axis (degrees), ``>= 0``.
        trans_noise_mm: translation noise per axis (mm), ``>= 0``.
        generator: a CPU ``torch.Generator`` (e.g. ``torch.Generator().manual_seed(0)``).
        dtype: floating dtype (default ``torch.get_default_dtype()``).
        device: device of the tensors.

    Returns:
        :class:`KneeSamples`.

    Example:
        >>> s = sample_poses(n=10, generator=torch.Generator().manual_seed(0))
        >>> s.poses.shape, s.times[-1].item()
        (torch.Size([10, 8]), 2.0)
    """
    model = KneeModel() if model is None else model
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise ValueError(f"sample_poses: n must be an int >= 2, got {n!r}")
    for name, value in (("rot_noise_deg", rot_noise_deg), ("trans_noise_mm", trans_noise_mm)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
            raise ValueError(f"sample_poses: {name} must be a finite number >= 0, got {value!r}")
    dtype = torch.get_default_dtype() if dtype is None else dtype
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"sample_poses: expected a floating dtype, got {dtype!r}")
    times = torch.linspace(0.0, model.duration_s, n, dtype=torch.float64)
    truth = model.poses(times)
    q, p = dualquat.to_rt(truth)
    delta = torch.randn(n, 3, generator=generator, dtype=torch.float64)
    eps = torch.randn(n, 3, generator=generator, dtype=torch.float64)
    q_noisy = quat.mul(q, quat.from_rotvec(delta * math.radians(rot_noise_deg)))
    p_noisy = p + eps * trans_noise_mm
    poses = dualquat.from_rt(q_noisy, p_noisy)

    def cast(x: Tensor) -> Tensor:
        return x.to(dtype=dtype, device=device)

    return KneeSamples(times=cast(times), poses=cast(poses), truth=cast(truth),
                       rotations=cast(q_noisy), translations=cast(p_noisy),
                       rot_noise_deg=float(rot_noise_deg), trans_noise_mm=float(trans_noise_mm))

"""What :func:`~torch_dq.calibration.camera_imu` returns, and its assembly from the estimate
(private)."""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field

import torch
from torch import Tensor

from .. import dualquat
from ..fitting import Reprojections
from ..nn import BSpline
from ._cameras import kalibr_entries

_FN = "calibration.camera_imu"


@dataclass
class CameraImuCalibration:
    r"""What :func:`camera_imu` returns.

    Attributes:
        cameras: the :class:`~torch_dq.camera.Camera` list given (intrinsics fixed).
        extrinsics: ``(C, 8)`` each camera's pose on the body (IMU) frame,
            ``p_imu = e p_cam`` (Kalibr's ``T_imu_cam``).
        time_offsets: ``(C,)`` seconds, IMU time = camera stamp + offset (Kalibr's
            ``timeshift_cam_imu``).
        line_delays: ``(C,)`` seconds per image row (zero for a global shutter).
        gyro_bias, accel_bias: ``(3,)`` IMU axes; with ``bias_walk``, ``(K, 3)``: one per
            segment of :attr:`bias_edges`.
        gravity: ``(3,)`` in the target's frame (m/s^2).
        std: standard deviations with the same keys: ``"extrinsics" (C, 6)`` in the chart
            ``e exp(delta)`` (rotation then translation, camera axes), ``"time_offsets"``
            and ``"line_delays"`` ``(C,)``, ``"gyro_bias"``, ``"accel_bias"``,
            ``"gravity"`` ``(3,)`` (the biases ``(K, 3)`` with ``bias_walk``).
        reprojection_rms: ``(C,)`` root mean square of the pixel error's norm over the
            observations used (pixels).
        trajectory: the body's :class:`~torch_dq.nn.BSpline` (IMU frame in the target
            frame, IMU clock).
        estimate: the :class:`~torch_dq.fitting.Estimate` (per-term ``chi2``, ``dof``).
        terms: the terms of the estimate, one ``Reprojections`` per camera, then ``Gyro``,
            ``Accel``.
        warnings: the warnings issued (degenerate motion), as text.
        timings: seconds per stage: ``"start"`` (target poses, offsets, orientations),
            ``"trajectory"`` (the knot spacing's choice, the start spline), ``"estimate"``,
            ``"uncertainties"``.
        bias_edges: ``(K + 1,)`` the edges (IMU clock, seconds) of the biases' segments with
            ``bias_walk``; None for constant biases.
        knot_spacing: the trajectory's knot spacing (seconds): the one given, or the one
            chosen from the IMU readings (``knot_spacing=None``).

    The calibration computes in float64 on the CPU (a problem of a few thousand control
    points and host-side starts); the tensors above and :attr:`trajectory` are on the IMU
    times' device, :attr:`estimate` and :attr:`terms` stay on the CPU.
    """

    cameras: list
    extrinsics: Tensor
    time_offsets: Tensor
    line_delays: Tensor
    gyro_bias: Tensor
    accel_bias: Tensor
    gravity: Tensor
    std: dict = field(repr=False)
    reprojection_rms: Tensor = field(repr=False)
    trajectory: BSpline = field(repr=False)
    estimate: object = field(repr=False)
    terms: list = field(repr=False)
    warnings: list = field(default_factory=list, repr=False)
    timings: dict = field(default_factory=dict, repr=False)
    bias_edges: Tensor | None = field(default=None, repr=False)
    knot_spacing: float = field(default=0.0, repr=False)

    def to(self, device) -> CameraImuCalibration:
        """The result with its tensors and :attr:`trajectory` on ``device`` (itself, moved:
        :func:`camera_imu` returns it on the IMU times' device). The trajectory moved is a
        copy: :attr:`estimate` keeps the one it was computed with (on its device; its
        ``pose_std`` and ``kinematics_std`` answer times on any device)."""
        for name in ("extrinsics", "time_offsets", "line_delays", "gyro_bias", "accel_bias",
                     "gravity", "reprojection_rms", "bias_edges"):
            value = getattr(self, name)
            if value is not None:
                setattr(self, name, value.to(device))
        self.std = {k: v.to(device) for k, v in self.std.items()}
        if self.trajectory.control_points.device != torch.device(device):
            self.trajectory = copy.deepcopy(self.trajectory).to(device)
        return self

    def to_kalibr(self, rostopics: list[str] | None = None) -> dict:
        """Kalibr's ``camchain-imucam.yaml`` as a dict of plain lists and floats: per camera
        ``camN`` with ``T_cam_imu`` (4 x 4, the inverse of the extrinsic), ``T_cn_cnm1``
        (``N >= 1``: camera ``N-1`` to camera ``N``), ``cam_overlaps``, the camera model
        and intrinsics (:meth:`torch_dq.camera.Camera.to_kalibr`), ``rostopic``
        (``/camN/image_raw`` unless given), ``timeshift_cam_imu`` and, for a camera with a
        line delay above 0 (rolling shutter), ``line_delay`` (seconds per row;
        :func:`torch_dq.calibration.read_camchain` reads it back)."""
        e = self.extrinsics.detach().double().cpu()
        T_cam_imu = dualquat.to_matrix(dualquat.inv(e))
        out = kalibr_entries(self.cameras, rostopics, "calibration.CameraImuCalibration.to_kalibr")
        for i in range(len(self.cameras)):
            entry: dict = {"T_cam_imu": T_cam_imu[i].tolist()}
            if i > 0:
                entry["T_cn_cnm1"] = (T_cam_imu[i] @ torch.linalg.inv(T_cam_imu[i - 1])).tolist()
            entry.update(out[f"cam{i}"])
            entry["timeshift_cam_imu"] = float(self.time_offsets[i])
            if float(self.line_delays[i]) > 0:
                entry["line_delay"] = float(self.line_delays[i])
            out[f"cam{i}"] = entry
        return out


def _reprojection_rms(term: Reprojections, spline) -> Tensor:
    with torch.no_grad():
        r = term(spline) * term.sigma
    used = term.mask.sum() - (0 if term.invalid is None else term.invalid.sum())
    return ((r ** 2).sum() / used.clamp_min(1)).sqrt()


def result(cams, terms, spline, est, rolling, notes) -> CameraImuCalibration:
    reps, gyro, accel = terms[:-2], terms[-2], terms[-1]
    zero = torch.zeros((), dtype=torch.float64)
    ext = torch.stack([t.extrinsic.detach() for t in reps])
    offs = torch.stack([t.time_offset.detach().reshape(()) for t in reps])
    delays = torch.stack([t.line_delay.detach().reshape(()) if rolling else zero
                          for t in reps])
    std = {"extrinsics": torch.stack([est.std(t, "extrinsic") for t in reps]),
           "time_offsets": torch.stack([est.std(t, "time_offset").reshape(()) for t in reps]),
           "line_delays": torch.stack([est.std(t, "line_delay").reshape(()) if rolling
                                       else zero for t in reps]),
           "gyro_bias": _bias(est.std, gyro), "accel_bias": _bias(est.std, accel),
           "gravity": est.std(accel, "gravity")}
    rms = torch.stack([_reprojection_rms(t, spline) for t in reps])
    notes = list(notes)
    for key, v in std.items():
        if not bool(torch.isfinite(v).all()):
            text = f"{_FN}: {key} has no information from the data (standard deviation inf)"
            warnings.warn(text, UserWarning, stacklevel=3)
            notes.append(text)
    return CameraImuCalibration(
        cams, ext, offs, delays, _bias(lambda t, n: t._value(n), gyro),
        _bias(lambda t, n: t._value(n), accel), accel.gravity.detach(),
        {k: v.detach() for k, v in std.items()}, rms, spline, est, terms, notes,
        bias_edges=getattr(gyro, "edges", None))


def _bias(read, term) -> Tensor:
    """``read(term, name)`` of the term's bias, ``(3,)``, or of each segment's, ``(K, 3)``
    (a random-walk bias)."""
    names = getattr(term, "names", None)
    if names is None:
        return read(term, "bias").detach()
    return torch.stack([read(term, n).detach() for n in names])

r"""Kalibr's camchain yaml read back (private; the public names are
:mod:`torch_dq.calibration`'s).

What :meth:`CameraCalibration.to_kalibr <torch_dq.calibration.CameraCalibration.to_kalibr>`,
:meth:`CameraImuCalibration.to_kalibr <torch_dq.calibration.CameraImuCalibration.to_kalibr>`
and ``python -m torch_dq calibrate`` write, and what Kalibr writes (``camchain.yaml``,
``camchain-imucam.yaml``), read into the library's conventions: the cameras
(:meth:`torch_dq.camera.Camera.from_kalibr`), their poses in camera 0's frame from the
chain of ``T_cn_cnm1`` (``p_camN = T p_camN-1``), the extrinsics from ``T_cam_imu``
(inverted: ``p_imu = e p_cam``) and the clock offsets ``timeshift_cam_imu``.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import _checks, dualquat
from .._camera_values import LONGEST_LINE_DELAY, seconds_hint
from ..camera import Camera
from ._targets import load_yaml

__all__ = ["Camchain", "read_camchain"]


@dataclass(frozen=True)
class Camchain:
    r"""A camera chain read from Kalibr's yaml (:func:`read_camchain`).

    Attributes:
        cameras: one :class:`torch_dq.camera.Camera` per ``camN``, in order.
        relative_poses: ``(C - 1, 8)`` float64 camera ``i``'s pose in camera 0's frame
            (``p_cam0 = T p_cami``, as :class:`CameraCalibration`), chained from every
            camera's ``T_cn_cnm1``; ``None`` when a camera ``N >= 1`` has none.
        extrinsics: ``(C, 8)`` float64 each camera's pose on the IMU (``p_imu = e p_cam``,
            the inverse of ``T_cam_imu``, as :class:`CameraImuCalibration`); ``None``
            unless every camera has ``T_cam_imu``.
        time_offsets: ``(C,)`` float64 seconds, ``timeshift_cam_imu`` (IMU time = camera
            stamp + offset); ``None`` unless every camera has it.
        rostopics: each camera's ``rostopic`` (``None`` where absent).
        line_delays: ``(C,)`` float64 seconds per image row (rolling shutter), from
            ``line_delay`` (seconds, as
            :meth:`torch_dq.calibration.CameraImuCalibration.to_kalibr` writes it)
            or ``line_delay_nanoseconds`` (the rolling-shutter Kalibr fork's and okvis'
            key), 0 for a camera stating neither; ``None`` when no camera states one.
    """

    cameras: list[Camera]
    relative_poses: Tensor | None
    extrinsics: Tensor | None
    time_offsets: Tensor | None
    rostopics: list[str | None]
    line_delays: Tensor | None = None


# Largest plausible values in Kalibr's units (seconds, metres): a camera-IMU clock offset
# (Kalibr estimates milliseconds; camera_imu's bound is 0.1 s), a rolling shutter's delay
# per row (1 ms reads 480 rows in 0.48 s) and a camera's distance from the IMU or from
# the previous camera (a vehicle's rig). Beyond them a file is in another unit: warned.
_LARGEST = {"timeshift_cam_imu": 1.0, "line_delay": LONGEST_LINE_DELAY, "translation": 10.0}

# Defect of a rotation block accepted, max |R^T R - I| (det R > 0): a camchain a user
# rounded to 4 decimals is off by up to ~3e-4, Kalibr's own output by ~1e-9; a scaled,
# sheared or hand-edited matrix by far more. Accepted ones are projected onto the nearest
# rotation (Frobenius norm: the polar factor, by SVD).
_ORTHONORMAL_ATOL = 1e-3


def _rigid(fn: str, where: str, value) -> Tensor:
    """A 4 x 4 rigid transform of the yaml as a unit dual quaternion, or an error naming
    ``where``: not 4 x 4 numbers, a last row other than ``0 0 0 1``, a rotation block not
    orthonormal within ``_ORTHONORMAL_ATOL`` or with determinant <= 0. The rotation
    block is replaced by the nearest rotation (rounded files: exact rigid transforms)."""
    try:
        T = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError):
        T = None
    if T is None or T.shape != (4, 4) or not bool(torch.isfinite(T).all()):
        _checks.fail(fn, f"{where} must be a 4 x 4 matrix of finite numbers, got {value!r}")
    R = T[:3, :3]
    bad_row = float((T[3] - T.new_tensor([0.0, 0.0, 0.0, 1.0])).abs().max())
    bad_rot = float((R.T @ R - torch.eye(3, dtype=R.dtype)).abs().max())
    det = float(torch.linalg.det(R))
    if bad_row > 1e-9 or bad_rot > _ORTHONORMAL_ATOL or det <= 0:
        _checks.fail(fn, f"{where} is not a rigid transform (last row {T[3].tolist()}, "
                         f"|R^T R - I| up to {bad_rot:.2g} (accepted: "
                         f"{_ORTHONORMAL_ATOL:g}), det R {det:.6g})")
    _warn_unit(fn, where.rsplit(".", 1)[0], where.rsplit(".", 1)[1], float(T[:3, 3].norm()), 2)
    U, _, Vh = torch.linalg.svd(R)  # det R > 0 and R near orthonormal: U Vh is a rotation
    T = T.clone()
    T[:3, :3] = U @ Vh
    return dualquat.normalize(dualquat.from_matrix(T))


def _warn_unit(fn: str, where: str, key: str, value: float, depth: int = 1) -> None:
    """Warn (naming ``where``, the file and camera) where ``key``'s ``value`` exceeds
    :data:`_LARGEST`: seconds that are milli-, micro- or nanoseconds (``seconds_hint`` of
    ``torch_dq._camera_values``), metres that
    are centimetres or millimetres (``depth``: the calls between ``read_camchain`` and
    here)."""
    limit = _LARGEST["translation" if key.startswith("T_") else key]
    if abs(value) <= limit:
        return
    if key.startswith("T_"):
        frame = "the IMU" if key == "T_cam_imu" else "the previous camera"
        unit = f"{key}'s translation is {value:.4g} m, the camera that far from {frame}: " \
               f"centimetres or millimetres? Kalibr's transforms are in metres"
    else:
        unit = f"{key} = {value:g} s is over {limit:g} s ({'per row, ' * (key == 'line_delay')}" \
               f"seconds in Kalibr's files):{seconds_hint(value, limit)}"
    warnings.warn(f"{fn}: {where}: {unit}", UserWarning, stacklevel=2 + depth)


def _number(v):
    """``v``, or the float of a string PyYAML left unread: YAML 1.1 wants a dot in a float,
    so a hand-written ``3e-05`` is a string."""
    if isinstance(v, str):
        try:
            return float(v)
        except ValueError:
            pass
    return v


def _line_delay(fn: str, where: str, entry: dict) -> float | None:
    """The camera's line delay in seconds per row from ``line_delay`` (seconds) or
    ``line_delay_nanoseconds``, None if it states neither; an error naming ``where`` and
    the key for a value that is not a finite number ``>= 0`` (a number PyYAML read as a
    string, ``3e-05``, taken as the number), or for both keys."""
    keys = [k for k in ("line_delay", "line_delay_nanoseconds") if k in entry]
    if len(keys) == 2:
        _checks.fail(fn, f"{where}: give line_delay (seconds per row) or "
                         f"line_delay_nanoseconds, not both")
    if not keys:
        return None
    v = _number(entry[keys[0]])
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < math.inf:
        _checks.fail(fn, f"{where}: {keys[0]} must be a finite number >= 0 (per image row), "
                         f"got {v!r}")
    seconds = float(v) * (1e-9 if keys[0] == "line_delay_nanoseconds" else 1.0)
    _warn_unit(fn, where, "line_delay", seconds, 2)
    return seconds


def read_camchain(path: str | os.PathLike[str]) -> Camchain:
    r"""Read Kalibr's ``camchain.yaml`` or ``camchain-imucam.yaml``.

    The file maps ``cam0``, ``cam1``, ... to one camera each: ``camera_model``,
    ``distortion_model``, ``intrinsics``, ``distortion_coeffs``, ``resolution``
    (:meth:`torch_dq.camera.Camera.from_kalibr`) and, where known, ``T_cn_cnm1`` (4 x 4,
    ``p_camN = T p_camN-1``), ``T_cam_imu`` (4 x 4, ``p_cam = T p_imu``),
    ``timeshift_cam_imu`` (seconds), ``line_delay`` (seconds per row) or
    ``line_delay_nanoseconds`` and ``rostopic``; other keys are ignored. Needs PyYAML
    (the ``calib`` extra).

    Args:
        path: the yaml file.

    Returns:
        A :class:`Camchain`: ``cameras``, ``relative_poses`` ``(C - 1, 8)`` (camera ``i`` in
        camera 0's frame, as :func:`cameras` returns them), ``extrinsics`` ``(C, 8)`` and
        ``time_offsets`` ``(C,)`` (as :func:`camera_imu` returns them), each ``None`` where
        the file does not state it for every camera, ``rostopics`` and ``line_delays``
        ``(C,)`` (``None`` where no camera states one).

    Raises:
        ValueError: naming the file and the camera: not a yaml mapping, no ``cam0`` or a
            gap in the numbering, an entry that is not a mapping, a camera the library does
            not model (from :meth:`~torch_dq.camera.Camera.from_kalibr`), a transform that
            is not a rigid 4 x 4 matrix (its key named; rotation blocks orthonormal within
            ``1e-3``, ``max |R^T R - I|``, with ``det R > 0``, are accepted and projected
            onto the nearest rotation: files rounded to 4 decimals read), a
            ``timeshift_cam_imu`` that is not a finite number (``2e-3``, a string to
            PyYAML, is read as the number), a line delay that is not a number
            ``>= 0`` (or given under both keys).
        TypeError: ``path`` is not a path.
        ImportError: PyYAML is not installed.
        OSError: the file cannot be opened.

    Warns:
        UserWarning: values that are not in Kalibr's units (naming the file, camera, key and
        the likely unit): a ``timeshift_cam_imu`` over 1 s, a line delay over 1 ms per row
        (milli-, micro- or nanoseconds), a transform's translation over 10 m (centimetres
        or millimetres).

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "camchain.yaml")
        >>> with open(path, "w") as f:
        ...     _ = f.write("cam0:\n  camera_model: pinhole\n  distortion_model: none\n"
        ...                 "  intrinsics: [458.7, 457.3, 367.2, 248.4]\n"
        ...                 "  resolution: [752, 480]\n"
        ...                 "cam1:\n  camera_model: pinhole\n  distortion_model: none\n"
        ...                 "  intrinsics: [457.6, 456.1, 380.0, 255.2]\n"
        ...                 "  resolution: [752, 480]\n"
        ...                 "  T_cn_cnm1: [[1, 0, 0, -0.11], [0, 1, 0, 0], [0, 0, 1, 0],"
        ...                 " [0, 0, 0, 1]]\n")
        >>> chain = read_camchain(path)
        >>> [c.model for c in chain.cameras], chain.extrinsics
        (['pinhole', 'pinhole'], None)
        >>> from torch_dq import dualquat
        >>> dualquat.to_rt(chain.relative_poses[0])[1]  # cam1 0.11 m along cam0's x
        tensor([0.1100, 0.0000, 0.0000], dtype=torch.float64)
    """
    fn = "calibration.read_camchain"
    _, _, doc = load_yaml(fn, path, "with cam0, cam1, ... (one camera each)")
    file = os.fspath(path)
    names = [k for k in doc if isinstance(k, str) and k.startswith("cam") and k[3:].isdigit()]
    names.sort(key=lambda k: int(k[3:]))
    if names != [f"cam{i}" for i in range(len(names))] or not names:
        _checks.fail(fn, f"{file}: expected cameras cam0, cam1, ... in order, got "
                         f"{sorted(map(str, doc))}")
    entries = [doc[k] for k in names]
    cams = []
    for k, e in zip(names, entries, strict=True):
        if not isinstance(e, dict):
            _checks.fail(fn, f"{file}: {k} must be a mapping (camera_model, intrinsics, ...), "
                             f"got {e!r}")
        try:
            cams.append(Camera.from_kalibr(e))
        except (ValueError, TypeError) as exc:
            _checks.fail(fn, f"{file}: {k}: {exc}")
    rel = None
    if all("T_cn_cnm1" in e for e in entries[1:]):
        poses = [dualquat.identity(dtype=torch.float64)]
        for k, e in zip(names[1:], entries[1:], strict=True):
            step = _rigid(fn, f"{file}: {k}.T_cn_cnm1", e["T_cn_cnm1"])
            poses.append(dualquat.mul(poses[-1], dualquat.inv(step)))
        rel = torch.stack(poses).narrow(0, 1, len(poses) - 1)
    ext = None
    if all("T_cam_imu" in e for e in entries):
        mounts = []  # a loop, not a comprehension: the warnings' stack levels (_warn_unit)
        for k, e in zip(names, entries, strict=True):
            mounts.append(dualquat.inv(_rigid(fn, f"{file}: {k}.T_cam_imu", e["T_cam_imu"])))
        ext = torch.stack(mounts)
    shifts = None
    if all("timeshift_cam_imu" in e for e in entries):
        values = [_number(e["timeshift_cam_imu"]) for e in entries]
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                   and math.isfinite(v) for v in values):
            _checks.fail(fn, f"{file}: timeshift_cam_imu must be numbers (seconds), got "
                             f"{values}")
        for k, v in zip(names, values, strict=True):
            _warn_unit(fn, f"{file}: {k}", "timeshift_cam_imu", float(v))
        shifts = torch.tensor(values, dtype=torch.float64)
    topics = [e.get("rostopic") if isinstance(e.get("rostopic"), str) else None
              for e in entries]
    delays = [_line_delay(fn, f"{file}: {k}", e) for k, e in zip(names, entries, strict=True)]
    lines = (None if all(d is None for d in delays) else
             torch.tensor([d or 0.0 for d in delays], dtype=torch.float64))
    return Camchain(cams, rel, ext, shifts, topics, lines)

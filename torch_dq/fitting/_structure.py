"""What the terms cannot determine, found before solving (:func:`check`)."""

from __future__ import annotations

import torch

from .. import _checks
from ._camera import Reprojections
from ._imu import Accel, Gyro
from ._terms import Poses, Positions, RelativePoses, Term

__all__ = ["check"]


def _unknown(slot) -> bool:
    """Estimated without a prior: only the data can determine it (a ``Free`` with
    ``prior_std`` is determined by its prior whatever the data)."""
    return slot.estimated and slot.free.prior_std is None


def _rotation_from_positions(positions: list[Positions]) -> bool:
    """Known lever arms of several position terms span a plane (3 non-collinear points)."""
    like = torch.empty((), dtype=torch.float64)
    arms = [p.slots()["lever_arm"].value(like) for p in positions
            if not _unknown(p.slots()["lever_arm"])]
    arms = [a.reshape(-1, 3)[0].cpu() for a in arms if a is not None]
    if len(arms) < 3:
        return False
    A = torch.stack(arms[1:]) - arms[0]
    return int(torch.linalg.matrix_rank(A, atol=1e-9)) >= 2


def check(fn: str, terms: list[Term]) -> None:
    """Raise ``ValueError`` naming the parameters that the terms cannot determine under any
    motion: an estimated extrinsic with no term fixing the body frame, every term's time
    offset estimated (no clock), absolute pose from inertial or relative data alone,
    rotation or a lever arm from positions alone, an accelerometer bias with an estimated
    gravity direction where the rotation is known only through that accelerometer.

    Parameters with a prior (``Free(prior_std=...)``) are always determined. What varied
    motion determines passes: positions with a gyroscope and an accelerometer give the
    rotation (the world accelerations of the positions against the specific forces, the
    heading through their changing direction; the gyroscope ties the instants together),
    and then a bias and gravity's direction apart (``R(t)^T (a(t) - g) + b`` with ``a(t)``
    known); positions with odometry give it too (the odometry's translations in the
    from-frame against the positions' displacements in the world).
    """
    _check_cameras(fn, terms)
    poses = [t for t in terms if isinstance(t, Poses) or (  # a camera with a fixed target too
        isinstance(t, Reprojections) and not _unknown(t.slots()["target"]))]
    positions = [t for t in terms if isinstance(t, Positions)]
    fixed_poses = [t for t in poses if not _unknown(t.slots()["extrinsic"])]
    gyro = any(isinstance(t, Gyro) for t in terms)
    accel = any(isinstance(t, Accel) for t in terms)
    relative = [t for t in terms if isinstance(t, RelativePoses)]
    extrinsic = len(fixed_poses) < len(poses)  # some Poses term's extrinsic is unknown
    if extrinsic and not (fixed_poses or gyro or accel or relative):
        _checks.fail(fn, "the extrinsic is undetermined: no term fixes the body frame "
                         "(x(t) e = (x(t) g)(g^-1 e) for any g); fix one Poses term's "
                         "extrinsic or add an IMU term")
    if extrinsic and not (fixed_poses or relative or accel or any(
            not _unknown(t.slots()["lever_arm"]) for t in positions)):
        _checks.fail(fn, "the extrinsic's translation is undetermined: a Gyro measures "
                         "rotation rates only and an estimated lever arm absorbs it (x(t) g "
                         "with g a pure translation changes no reading); add an Accel, "
                         "RelativePoses or Positions term with a fixed lever_arm, or fix one "
                         "Poses term's extrinsic")
    if all(_unknown(t.slots()["time_offset"]) for t in terms):
        _checks.fail(fn, "every term's time_offset is estimated: no term defines the "
                         "trajectory's clock; fix one term's time_offset (None or a value)")
    if not poses and not positions:
        names = sorted({type(t).__name__ for t in terms})
        _checks.fail(fn, f"the absolute pose (position and heading) is undetermined: "
                         f"{', '.join(names)} measure only motion; add Poses or Positions")
    for t in positions:
        if _unknown(t.slots()["lever_arm"]) and not (poses or gyro or accel or relative):
            _checks.fail(fn, "the lever_arm is undetermined by positions alone (R(t) l "
                             "trades against the body's rotation); add Poses or an IMU")
    absolute = bool(poses) or _rotation_from_positions(positions)
    if not absolute and not accel and not relative and gyro:
        _checks.fail(fn, "the trajectory's rotation is undetermined by Positions and Gyro: "
                         "the gyroscope measures only its rate and a point's track does not "
                         "fix the body's rotation; add an Accel (the IMU's accelerometer), "
                         "Poses, odometry, or Positions of three non-collinear fixed lever "
                         "arms")
    if not absolute and not accel and not relative:
        _checks.fail(fn, "the trajectory's rotation is undetermined by positions alone "
                         "(a point's track does not fix the body's rotation); add Poses, an "
                         "IMU, odometry, or Positions of three non-collinear fixed lever arms")
    rotation = absolute or bool(relative) or gyro  # known apart from the accelerometer
    for term in terms:
        if isinstance(term, Accel) and not rotation and _unknown(
                term.slots()["bias"]) and _unknown(term.slots()["gravity"]):
            _checks.fail(fn, "the accelerometer bias and the gravity direction are "
                             "undetermined together without a rotation known apart from the "
                             "accelerometer (R^T g + b): add Poses, a Gyro or odometry, fix "
                             "the bias or gravity, or give one a prior (Free(prior_std=...))")


def _check_cameras(fn: str, terms: list[Term]) -> None:
    """What :class:`~torch_dq.fitting.Reprojections` terms cannot determine: an extrinsic
    that no term fixes the body frame for, a target pose that no term fixes the world for
    (both together: the message names both), intrinsics from one view of a planar target,
    a line delay whose observations are all on one row (:func:`check` then treats a camera
    with a fixed target as a pose measurement)."""
    cameras = [t for t in terms if isinstance(t, Reprojections)]
    mounts = [t for t in cameras if _unknown(t.slots()["extrinsic"])]
    targets = [t for t in cameras if _unknown(t.slots()["target"])]
    body = any(isinstance(t, (Gyro, Accel, RelativePoses)) or (
        isinstance(t, (Poses, Reprojections)) and not _unknown(t.slots()["extrinsic"]))
        for t in terms)
    world = any(isinstance(t, (Poses, Positions)) or (
        isinstance(t, Reprojections) and not _unknown(t.slots()["target"])) for t in terms)
    if mounts and targets and not (body and world):
        _checks.fail(fn, "the Reprojections extrinsic and target are both estimated with "
                         "nothing else fixing the body and the world (T^-1 x e = (g T)^-1 (g x "
                         "h) (h^-1 e) for any g, h); fix the target (the world is its frame) or "
                         "the extrinsic, or add terms that fix them (an IMU, Poses)")
    if mounts and not body:
        _checks.fail(fn, "the Reprojections extrinsic is undetermined: no term fixes the body "
                         "frame (x(t) e = (x(t) g)(g^-1 e) for any g); fix it or add an IMU")
    if mounts and not any(isinstance(t, (Accel, RelativePoses)) or (
            isinstance(t, (Poses, Reprojections)) and not _unknown(t.slots()["extrinsic"])) or (
            isinstance(t, Positions) and not _unknown(t.slots()["lever_arm"])) for t in terms):
        _checks.fail(fn, "the Reprojections extrinsic's translation is undetermined: a Gyro "
                         "measures rotation rates only; add an Accel or fix the extrinsic")
    if targets and not world:
        _checks.fail(fn, "the Reprojections target is undetermined: no term fixes the world "
                         "frame (T^-1 x(t) = (g T)^-1 (g x(t)) for any g); fix the target (None: "
                         "the world is the target's frame) or add Poses or Positions")
    _check_camera_data(fn, cameras)


def _check_camera_data(fn: str, cameras: list[Reprojections]) -> None:
    """Intrinsics from one view of a planar target (one :class:`Free` shared by cameras
    counts their views together), a line delay whose observations are all on one row."""
    views: dict[int, int] = {}
    for t in cameras:
        slot = t.slots()["intrinsics"]
        if _unknown(slot):
            distinct = [int(torch.unique(row[m]).numel()) for row, m in zip(
                t.times.expand(t.mask.shape).reshape(-1, t.N), t.mask.reshape(-1, t.N),
                strict=True)]
            views[id(slot.free)] = views.get(id(slot.free), 0) + min(distinct)
            pts = t.points[t.mask].double()
            planar = int(torch.linalg.matrix_rank(pts - pts.mean(0), atol=1e-9)) < 3
            if views[id(slot.free)] < 2 and planar:
                _checks.fail(fn, "the Reprojections intrinsics are estimated from one view "
                                 "of a planar target (its homography does not determine them); "
                                 "add views at other times or fix the intrinsics")
        if _unknown(t.slots()["line_delay"]):
            rows = t.rows[t.mask]
            if float(rows.max() - rows.min()) == 0.0:
                _checks.fail(fn, "the Reprojections line_delay is undetermined: every "
                                 "observation is on one row (line_delay * v is a constant time "
                                 "shift); fix it or observe points over the image")

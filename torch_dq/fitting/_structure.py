"""What the terms cannot determine, found before solving (:func:`check`)."""

from __future__ import annotations

import torch

from .. import _checks
from ._camera import Reprojections
from ._terms import Accel, Gyro, Poses, Positions, RelativePoses, Term

__all__ = ["check"]


def _rotation_from_positions(positions: list[Positions]) -> bool:
    """Fixed lever arms of several position terms span a plane (3 non-collinear points)."""
    arms = [p.slots()["lever_arm"].value(torch.empty((), dtype=torch.float64)).reshape(-1, 3)[0]
            for p in positions if not p.slots()["lever_arm"].estimated]
    if len(arms) < 3:
        return False
    A = torch.stack([a.cpu().double() for a in arms[1:]]) - arms[0].cpu().double()
    return int(torch.linalg.matrix_rank(A, atol=1e-9)) >= 2


def check(fn: str, terms: list[Term]) -> None:
    """Raise ``ValueError`` naming the parameters that the terms structurally cannot
    determine: an estimated extrinsic with no term fixing the body frame, every term's time
    offset estimated (no clock), absolute pose from inertial or relative data alone,
    rotation or a lever arm from positions alone, an accelerometer bias with an estimated
    gravity direction and no absolute rotation; for cameras (:func:`_check_cameras`) an
    extrinsic or a target pose that nothing else fixes, intrinsics from one view of a planar
    target, a line delay whose rows do not vary."""
    poses = [t for t in terms if isinstance(t, Poses)]
    positions = [t for t in terms if isinstance(t, Positions)]
    fixed_poses = [t for t in poses if not t.slots()["extrinsic"].estimated]
    inertial = [t for t in terms if isinstance(t, (Gyro, Accel))]
    relative = [t for t in terms if isinstance(t, RelativePoses)]
    extrinsic = len(fixed_poses) < len(poses)  # some Poses term's extrinsic is estimated
    cameras = [t for t in terms if isinstance(t, Reprojections)]
    fixed_cams = [t for t in cameras if not t.slots()["extrinsic"].estimated]
    world_cams = [t for t in cameras if not t.slots()["target"].estimated]
    _check_cameras(fn, terms, cameras)  # a fixed camera mount fixes the body frame too
    if extrinsic and not (fixed_poses or fixed_cams or inertial or relative):
        _checks.fail(fn, "the extrinsic is undetermined: no term fixes the body frame "
                         "(x(t) e = (x(t) g)(g^-1 e) for any g); fix one Poses term's "
                         "extrinsic or add an IMU term")
    if extrinsic and not (
            fixed_poses or fixed_cams or relative or any(isinstance(t, Accel) for t in terms)
            or any(not t.slots()["lever_arm"].estimated for t in positions)):
        _checks.fail(fn, "the extrinsic's translation is undetermined: a Gyro measures "
                         "rotation rates only and an estimated lever arm absorbs it (x(t) g "
                         "with g a pure translation changes no reading); add an Accel, "
                         "RelativePoses or Positions term with a fixed lever_arm, or fix one "
                         "Poses term's extrinsic")
    if all(t.slots()["time_offset"].estimated for t in terms):
        _checks.fail(fn, "every term's time_offset is estimated: no term defines the "
                         "trajectory's clock; fix one term's time_offset (None or a value)")
    if not poses and not positions and not world_cams:
        names = sorted({type(t).__name__ for t in terms})
        _checks.fail(fn, f"the absolute pose (position and heading) is undetermined: "
                         f"{', '.join(names)} measure only motion; add Poses or Positions")
    for t in positions:
        if t.slots()["lever_arm"].estimated and not (poses or inertial or relative or cameras):
            _checks.fail(fn, "the lever_arm is undetermined by positions alone (R(t) l "
                             "trades against the body's rotation); add Poses or an IMU")
    absolute_rotation = bool(poses or world_cams) or _rotation_from_positions(positions)
    if not poses and not absolute_rotation and not any(isinstance(t, Accel) for t in terms):
        _checks.fail(fn, "the trajectory's rotation is undetermined by positions alone "
                         "(a point's track does not fix the body's rotation); add Poses, an "
                         "IMU, or Positions of three non-collinear fixed lever arms")
    for term in terms:
        if isinstance(term, Accel) and term.slots()["bias"].estimated and term.slots()[
                "gravity"].estimated and not absolute_rotation:
            _checks.fail(fn, "the accelerometer bias and the gravity direction are "
                             "undetermined together without absolute rotation (R^T g + b); "
                             "add Poses, fix the bias, or fix gravity")


def _check_cameras(fn: str, terms: list[Term], cameras: list[Reprojections]) -> None:
    """The cameras' gauges and degenerate configurations (see :func:`check`)."""
    mounts = [t for t in cameras if t.slots()["extrinsic"].estimated]
    targets = [t for t in cameras if t.slots()["target"].estimated]
    body = any(isinstance(t, (Gyro, Accel, RelativePoses)) or (
        isinstance(t, (Poses, Reprojections)) and not t.slots()["extrinsic"].estimated)
        for t in terms)
    world = any(isinstance(t, (Poses, Positions)) or (
        isinstance(t, Reprojections) and not t.slots()["target"].estimated) for t in terms)
    if mounts and targets and not (body and world):
        _checks.fail(fn, "the Reprojections extrinsic and target are both estimated with "
                         "nothing else fixing the body and the world (T^-1 x e = (g T)^-1 (g x "
                         "h) (h^-1 e) for any g, h); fix the target (the world is its frame) or "
                         "the extrinsic, or add terms that fix them (an IMU, Poses)")
    if mounts and not body:
        _checks.fail(fn, "the Reprojections extrinsic is undetermined: no term fixes the body "
                         "frame (x(t) e = (x(t) g)(g^-1 e) for any g); fix it or add an IMU")
    if mounts and not any(isinstance(t, (Accel, RelativePoses)) or (
            isinstance(t, (Poses, Reprojections)) and not t.slots()["extrinsic"].estimated)
            for t in terms):
        _checks.fail(fn, "the Reprojections extrinsic's translation is undetermined: a Gyro "
                         "measures rotation rates only; add an Accel or fix the extrinsic")
    if targets and not world:
        _checks.fail(fn, "the Reprojections target is undetermined: no term fixes the world "
                         "frame (T^-1 x(t) = (g T)^-1 (g x(t)) for any g); fix the target (None: "
                         "the world is the target's frame) or add Poses or Positions")
    views: dict[int, int] = {}
    for t in cameras:
        slot = t.slots()["intrinsics"]
        if slot.estimated and slot.free is not None:
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
        if t.slots()["line_delay"].estimated:
            rows = t.rows[t.mask]
            if float(rows.max() - rows.min()) == 0.0:
                _checks.fail(fn, "the Reprojections line_delay is undetermined: every "
                                 "observation is on one row (line_delay * v is a constant time "
                                 "shift); fix it or observe points over the image")

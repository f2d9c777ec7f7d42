"""What the terms cannot determine, found before solving (:func:`check`)."""

from __future__ import annotations

import torch

from .. import _checks
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
    gravity direction and no absolute rotation."""
    poses = [t for t in terms if isinstance(t, Poses)]
    positions = [t for t in terms if isinstance(t, Positions)]
    fixed_poses = [t for t in poses if not t.slots()["extrinsic"].estimated]
    inertial = [t for t in terms if isinstance(t, (Gyro, Accel))]
    relative = [t for t in terms if isinstance(t, RelativePoses)]
    extrinsic = len(fixed_poses) < len(poses)  # some Poses term's extrinsic is estimated
    if extrinsic and not (fixed_poses or inertial or relative):
        _checks.fail(fn, "the extrinsic is undetermined: no term fixes the body frame "
                         "(x(t) e = (x(t) g)(g^-1 e) for any g); fix one Poses term's "
                         "extrinsic or add an IMU term")
    if extrinsic and not (
            fixed_poses or relative or any(isinstance(t, Accel) for t in terms) or any(
                not t.slots()["lever_arm"].estimated for t in positions)):
        _checks.fail(fn, "the extrinsic's translation is undetermined: a Gyro measures "
                         "rotation rates only and an estimated lever arm absorbs it (x(t) g "
                         "with g a pure translation changes no reading); add an Accel, "
                         "RelativePoses or Positions term with a fixed lever_arm, or fix one "
                         "Poses term's extrinsic")
    if all(t.slots()["time_offset"].estimated for t in terms):
        _checks.fail(fn, "every term's time_offset is estimated: no term defines the "
                         "trajectory's clock; fix one term's time_offset (None or a value)")
    if not poses and not positions:
        names = sorted({type(t).__name__ for t in terms})
        _checks.fail(fn, f"the absolute pose (position and heading) is undetermined: "
                         f"{', '.join(names)} measure only motion; add Poses or Positions")
    for t in positions:
        if t.slots()["lever_arm"].estimated and not (poses or inertial or relative):
            _checks.fail(fn, "the lever_arm is undetermined by positions alone (R(t) l "
                             "trades against the body's rotation); add Poses or an IMU")
    absolute_rotation = bool(poses) or _rotation_from_positions(positions)
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

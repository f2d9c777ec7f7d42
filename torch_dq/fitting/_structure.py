"""What the terms cannot determine, found before solving (:func:`check`)."""

from __future__ import annotations

import torch

from .. import _checks
from ._terms import Accel, Gyro, Poses, Positions, RelativePoses, Term

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
    poses = [t for t in terms if isinstance(t, Poses)]
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

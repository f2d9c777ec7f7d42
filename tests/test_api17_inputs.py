"""Nuisance arguments a user gets wrong (session 17): an extrinsic or target pose given as
the 4 x 4 matrix a calibration file holds (Kalibr's ``T_cam_imu``) was refused as "expected
extrinsic of shape (..., 8)" without saying how to get one; the error now names
``torch_dq.dualquat.from_matrix``, and the converted matrix is accepted (the reference: the
numpy matrix of the pose the term then holds)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.camera import Camera

F64 = torch.float64
T = np.eye(4)
T[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
T[:3, 3] = [0.05, -0.02, 0.01]
TIMES = torch.linspace(0.0, 1.0, 5, dtype=F64)
CAM = Camera("pinhole", torch.tensor([400.0, 400.0, 320.0, 240.0], dtype=F64), (640, 480))


def _poses(**kw):
    return fitting.Poses(TIMES, dq.identity((5,), dtype=F64), rot_sigma=1e-3, trans_sigma=1e-3,
                         **kw)


def _camera(**kw):
    pts = torch.tensor([[0.0, 0.0, 2.0]], dtype=F64).expand(5, 3)
    pix = torch.tensor([[320.0, 240.0]], dtype=F64).expand(5, 2)
    return fitting.Reprojections(TIMES, pts, pix, camera=CAM, sigma=1.0, **kw)


@pytest.mark.parametrize("make, name", [(_poses, "extrinsic"), (_camera, "extrinsic"),
                                        (_camera, "target")])
@pytest.mark.parametrize("free", [False, True])
def test_matrix_pose_names_from_matrix(make, name, free):
    value = torch.tensor(T)
    with pytest.raises(ValueError, match=rf"expected {name}( start)? of shape \(\.\.\., 8\).*"
                                         r"got \(4, 4\): a 4 x 4 matrix\? convert it with "
                                         r"torch_dq.dualquat.from_matrix"):
        make(**{name: fitting.Free(start=value) if free else value})
    term = make(**{name: dq.from_matrix(value)})
    np.testing.assert_allclose(dq.to_matrix(getattr(term, name)).numpy(), T, atol=1e-12)


def test_other_shapes_keep_the_plain_message():
    with pytest.raises(ValueError, match=r"got \(7,\)$"):
        _poses(extrinsic=torch.zeros(7, dtype=F64))


def test_gravity_magnitude_as_a_0d_tensor():
    """``gravity``: "a float magnitude whose direction is estimated"; a magnitude computed
    with torch (``readings.norm(dim=-1).mean()``, a 0-d tensor) was refused as "expected
    gravity of shape (..., 3)". It is a magnitude: a body at rest, tilted by a known
    rotation (scipy), its readings ``R^T (0 - g)``; the estimated gravity is ``g``."""
    import warnings

    from torch_dq.nn import BSpline

    rot = Rotation.from_rotvec([0.3, -0.2, 0.1])
    g = np.array([0.0, 0.0, -9.81])
    t = torch.linspace(0.0, 2.0, 401, dtype=F64)
    x = dq.from_matrix(torch.tensor(np.block([[rot.as_matrix(), np.zeros((3, 1))],
                                              [np.zeros((1, 3)), np.ones((1, 1))]])))
    readings = torch.tensor(rot.inv().apply(-g)).expand(401, 3)
    spline = BSpline.from_dualquats(x.expand(41, 8), t[::10], n_ctrl=10, form="cumulative")
    pose = fitting.Poses(t[::10], x.expand(41, 8), rot_sigma=1e-4, trans_sigma=1e-4)
    accel = fitting.Accel(t, readings, sigma=1e-2, gravity=readings.norm(dim=-1).mean())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # exact data: chi2/dof far below 1
        fitting.estimate(spline, [pose, accel], verbose=False)
    np.testing.assert_allclose(accel.gravity.numpy(), g, atol=1e-6)


@pytest.mark.parametrize("delay, unit", [(30.0, "microseconds"), (0.03, "milliseconds")])
def test_line_delay_in_another_unit_warns(delay, unit):
    """A fixed rolling-shutter line delay of 30 (microseconds per row) was taken as 30 s per
    row; ``estimate`` then asked to "extend the trajectory's domain by 9322". It warns at
    construction, naming the readout it implies and the likely unit."""
    with pytest.warns(UserWarning, match=rf"line_delay {delay:g} s per row reads 480 rows in "
                                         rf".* s \(seconds per row expected\): {unit}\? "
                                         rf"\({delay:g} of them: 3e-05 s\)"):
        _camera(line_delay=delay)


def test_a_camera_line_delay_is_silent():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        term = _camera(line_delay=3e-5)
    assert float(term.line_delay) == 3e-5

"""Round trips with the libraries users come from (the README's "Interop" table).

Each peer is imported here only (the library never imports them) and skipped cleanly when it
is missing. References are the peers' own matrices, or matrices built by scipy; float64.
Quaternion layouts: ours (w, x, y, z); scipy, roma, pypose, ROS and TUM (x, y, z, w);
pytransform3d (w, x, y, z). Pose 7-vectors: ROS/TUM/pypose (x, y, z, qx, qy, qz, qw),
pytransform3d's ``pq`` (x, y, z, qw, qx, qy, qz).
"""

import inspect
import io
import os
import subprocess
import sys

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import DualQuaternion, quat

F64 = torch.float64
N = 64
ATOL = 1e-12

scipy_transform = pytest.importorskip("scipy.spatial.transform")
Rotation = scipy_transform.Rotation


def _random_transforms(seed: int, n: int = N) -> np.ndarray:
    """``(n, 4, 4)`` rigid transforms from scipy (uniform rotations, translations ~10)."""
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    T[:, :3, 3] = rng.normal(scale=10.0, size=(n, 3))
    return T


def _same_pose(x: torch.Tensor, y: torch.Tensor) -> None:
    """``x`` and ``y`` are the same transforms: equal up to the sign of each element."""
    sign = torch.where((x[..., :4] * y[..., :4]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    torch.testing.assert_close(x, sign * y, rtol=0, atol=ATOL)


def _t(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=F64)


# ----------------------------------------------------------------------------- scipy

def test_scipy_rotation_as_quat_is_xyzw():
    r = Rotation.random(N, random_state=0)
    q = quat.from_xyzw(_t(r.as_quat()))
    torch.testing.assert_close(quat.to_matrix(q), _t(r.as_matrix()), rtol=0, atol=ATOL)
    back = Rotation.from_quat(quat.to_xyzw(q).numpy())
    np.testing.assert_allclose(back.as_matrix(), r.as_matrix(), rtol=0, atol=ATOL)
    if "scalar_first" in inspect.signature(Rotation.as_quat).parameters:  # scipy >= 1.14
        torch.testing.assert_close(q, _t(r.as_quat(scalar_first=True)), rtol=0, atol=0)


def test_scipy_xyzw_read_as_wxyz_is_another_rotation():
    """The trap the README warns about: no error, a rotation far from the right one."""
    r = Rotation.from_euler("xyz", [30.0, 40.0, 50.0], degrees=True)
    wrong = quat.to_matrix(_t(r.as_quat()))  # (x, y, z, w) taken as (w, x, y, z)
    err = Rotation.from_matrix(wrong.numpy()) * r.inv()
    assert err.magnitude() > np.radians(30.0)


def test_scipy_rigid_transform_matrices_and_dual_quaternions():
    rigid = getattr(scipy_transform, "RigidTransform", None)
    if rigid is None:
        pytest.skip("scipy.spatial.transform.RigidTransform needs scipy >= 1.16")
    T = _random_transforms(1)
    tf = rigid.from_matrix(T)
    x = dq.from_matrix(_t(T))
    torch.testing.assert_close(dq.to_matrix(x), _t(tf.as_matrix()), rtol=0, atol=ATOL)
    # scipy's dual quaternions: real then dual part, each (x, y, z, w) by default
    sd = _t(tf.as_dual_quat())
    ours = torch.cat((quat.from_xyzw(sd[:, :4]), quat.from_xyzw(sd[:, 4:])), -1)
    _same_pose(ours, x)
    _same_pose(_t(tf.as_dual_quat(scalar_first=True)), x)
    back = rigid.from_dual_quat(
        torch.cat((quat.to_xyzw(x[:, :4]), quat.to_xyzw(x[:, 4:])), -1).numpy())
    np.testing.assert_allclose(back.as_matrix(), T, rtol=0, atol=ATOL)


# ----------------------------------------------------------------------------- pytransform3d

def test_pytransform3d_dual_quaternions_matrices_and_pq():
    pt = pytest.importorskip("pytransform3d.transformations")
    T = _random_transforms(2)
    for A2B in T:
        x = dq.from_matrix(_t(A2B))
        # dual quaternions: the same (real, dual) layout, (w, x, y, z) quaternions
        _same_pose(x, _t(pt.dual_quaternion_from_transform(A2B)))
        np.testing.assert_allclose(pt.transform_from_dual_quaternion(x.numpy()), A2B,
                                   rtol=0, atol=ATOL)
        # pq = (x, y, z, qw, qx, qy, qz): translation then a scalar-first quaternion
        pq = _t(pt.pq_from_transform(A2B))
        _same_pose(dq.from_rt(pq[3:], pq[:3]), x)
        q, t = dq.to_rt(x)
        np.testing.assert_allclose(pt.transform_from_pq(torch.cat((t, q)).numpy()), A2B,
                                   rtol=0, atol=ATOL)


def test_pytransform3d_sclerp_matches():
    pt = pytest.importorskip("pytransform3d.transformations")
    T0, T1 = _random_transforms(3, 2)
    a, b = dq.from_matrix(_t(T0)), dq.from_matrix(_t(T1))
    b = torch.where((a[:4] * b[:4]).sum() < 0, -b, b)  # pytransform3d takes no shortest path
    for s in (0.0, 0.3, 0.5, 1.0):
        ref = pt.dual_quaternion_sclerp(a.numpy(), b.numpy(), s)
        _same_pose(dq.sclerp(a, b, s), _t(ref))


# ----------------------------------------------------------------------------- pypose

def test_pypose_se3_lietensor_is_pose7():
    pp = pytest.importorskip("pypose")
    T = _t(_random_transforms(4))
    x = dq.from_matrix(T)
    X = pp.SE3(dq.to_pose7(x))  # (tx, ty, tz, qx, qy, qz, qw): pypose's own layout
    torch.testing.assert_close(X.matrix(), T, rtol=0, atol=ATOL)
    torch.testing.assert_close(X.translation(), T[:, :3, 3], rtol=0, atol=ATOL)
    S = _random_transforms(8)  # a pypose LieTensor built from scipy's (x, y, z, w)
    Y = pp.SE3(_t(np.concatenate((S[:, :3, 3], Rotation.from_matrix(S[:, :3, :3]).as_quat()),
                                 -1)))
    y = dq.from_pose7(Y.tensor())
    torch.testing.assert_close(dq.to_matrix(y), _t(S), rtol=0, atol=ATOL)
    torch.testing.assert_close(dq.to_matrix(y), Y.matrix(), rtol=0, atol=ATOL)
    # composition and action agree
    z = dq.mul(x, y)
    torch.testing.assert_close(dq.to_matrix(z), (X @ Y).matrix(), rtol=0, atol=1e-10)
    p = torch.randn(N, 3, dtype=F64, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(dq.apply(x, p), X.Act(p), rtol=0, atol=1e-10)
    # SO3 LieTensors are (qx, qy, qz, qw) quaternions
    R = pp.SO3(quat.to_xyzw(x[:, :4]))
    torch.testing.assert_close(R.matrix(), T[:, :3, :3], rtol=0, atol=ATOL)


# ----------------------------------------------------------------------------- roma

def test_roma_unit_quaternions_are_xyzw():
    roma = pytest.importorskip("roma")
    T = _random_transforms(5)
    q = quat.from_matrix(_t(T[:, :3, :3]))
    torch.testing.assert_close(roma.unitquat_to_rotmat(quat.to_xyzw(q)), _t(T[:, :3, :3]),
                               rtol=0, atol=ATOL)
    q_roma = roma.rotmat_to_unitquat(_t(T[:, :3, :3]))
    torch.testing.assert_close(quat.to_matrix(quat.from_xyzw(q_roma)), _t(T[:, :3, :3]),
                               rtol=0, atol=ATOL)
    rigid = roma.RigidUnitQuat(linear=quat.to_xyzw(q), translation=_t(T[:, :3, 3]))
    torch.testing.assert_close(rigid.to_homogeneous(), _t(T), rtol=0, atol=ATOL)
    x = dq.from_rt(quat.from_xyzw(rigid.linear), rigid.translation)
    torch.testing.assert_close(dq.to_matrix(x), _t(T), rtol=0, atol=ATOL)


# ----------------------------------------------------------------------------- ROS / TUM

def test_tum_and_ros_pose7_order():
    """TUM lines are ``timestamp tx ty tz qx qy qz qw``; a ROS Pose is position, then
    orientation (x, y, z, w): the order of ``dualquat.from_pose7`` / ``to_pose7``."""
    T = _random_transforms(6, 5)
    quats_xyzw = Rotation.from_matrix(T[:, :3, :3]).as_quat()
    stamps = 1.7e9 + np.arange(5) * 0.033  # UNIX seconds: keep them float64
    text = "# timestamp tx ty tz qx qy qz qw\n" + "".join(
        f"{s:.4f} {' '.join(f'{v:.17g}' for v in (*T[i, :3, 3], *quats_xyzw[i]))}\n"
        for i, s in enumerate(stamps))
    data = np.loadtxt(io.StringIO(text))
    times, p7 = _t(data[:, 0]), _t(data[:, 1:])
    torch.testing.assert_close(times, _t(stamps), rtol=0, atol=1e-4)
    x = dq.from_pose7(p7)
    torch.testing.assert_close(dq.to_matrix(x), _t(T), rtol=0, atol=ATOL)
    _same_pose(dq.from_pose7(dq.to_pose7(x)), x)
    # the object API speaks the same order
    obj = DualQuaternion.from_pose7(p7)
    torch.testing.assert_close(obj.to_matrix(), _t(T), rtol=0, atol=ATOL)
    p = obj.to_pose7()
    torch.testing.assert_close(p[:, :3], _t(T[:, :3, 3]), rtol=0, atol=ATOL)
    same_sign = torch.where((p[:, 3:] * p7[:, 3:]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    torch.testing.assert_close(p[:, 3:] * same_sign, p7[:, 3:], rtol=0, atol=ATOL)


def test_pose7_is_not_pytransform3d_pq():
    """(x, y, z, qx, qy, qz, qw) and pq = (x, y, z, qw, qx, qy, qz) differ: mixing them up
    gives another rotation, so the docs name both."""
    pt = pytest.importorskip("pytransform3d.transformations")
    A2B = _random_transforms(7, 1)[0]
    pq = pt.pq_from_transform(A2B)
    wrong = dq.to_matrix(dq.from_pose7(_t(pq))).numpy()
    assert np.abs(wrong[:3, :3] - A2B[:3, :3]).max() > 0.1


def test_the_library_never_imports_a_peer():
    """The peers are optional: importing every public module loads none of them."""
    code = (
        "import importlib, pkgutil, sys, torch_dq\n"
        "for m in pkgutil.walk_packages(torch_dq.__path__, 'torch_dq.'):\n"
        "    if m.name != 'torch_dq.__main__':\n"
        "        importlib.import_module(m.name)\n"
        "print(sorted(p for p in ('scipy', 'pytransform3d', 'pypose', 'roma') if p in sys.modules))"
    )
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "[]", res.stdout

"""Non-rigid matrices (0.5.0 new-user trial): a reflection, a scale, a shear or a bottom row
other than (0, 0, 0, 1) gave some unit (dual) quaternion without a word, in
``dualquat.from_matrix``, ``quat.from_matrix``, ``BSpline.from_poses`` / ``from_matrices`` and
``fitting.Poses``. ``check=True`` (and the constructors, always) now raise."""

from __future__ import annotations

import pytest
import torch
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq import fitting, nn, quat

F64 = torch.float64


def _rigid(shape, seed=0):
    """``shape + (4, 4)`` rigid transforms from scipy (an independent construction)."""
    n = int(torch.tensor(shape).prod()) if shape else 1
    R = torch.as_tensor(Rotation.random(n, random_state=seed).as_matrix())
    T = torch.eye(4, dtype=F64).repeat(n, 1, 1)
    T[:, :3, :3] = R
    T[:, :3, 3] = torch.linspace(-1, 1, 3 * n, dtype=F64).reshape(n, 3)
    return T.reshape(*shape, 4, 4)


_BAD = {"reflection": lambda T: T @ torch.diag(torch.tensor([1.0, 1.0, -1.0, 1.0], dtype=F64)),
        "scale": lambda T: 2.0 * T,
        "shear": lambda T: T @ torch.tensor([[1.0, 0.3, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0],
                                             [0, 0, 0, 1]], dtype=F64),
        "bottom row": lambda T: T + torch.tensor([0.0, 0, 0, 0.1, 0, 0, 0, 0, 0, 0, 0, 0, 0.2,
                                                  0, 0, 0], dtype=F64).reshape(4, 4).mT,
        "nan": lambda T: T * float("nan")}


@pytest.mark.parametrize("shape", [(), (1,), (5,), (2, 5), (3, 1, 5)])
def test_from_matrix_check_accepts_rigid_and_names_the_first_bad(shape):
    T = _rigid(shape)
    x = dq.from_matrix(T, check=True)
    assert torch.equal(x, dq.from_matrix(T))  # the check changes nothing on rigid input
    assert torch.equal(quat.from_matrix(T[..., :3, :3], check=True), x[..., :4])
    ref = torch.as_tensor(Rotation.from_matrix(T[..., :3, :3].reshape(-1, 3, 3).numpy())
                          .as_quat(scalar_first=True)).reshape(*shape, 4)
    assert torch.allclose(x[..., :4], ref * ref[..., :1].sign(), atol=1e-14)
    for name, make in _BAD.items():
        bad = T.clone()
        if shape:
            bad.view(-1, 4, 4)[-1] = make(T.reshape(-1, 4, 4)[-1])
        else:
            bad = make(T)
        where = r"T\[" + ", ".join(str(s - 1) for s in shape) + r"\]" if shape else "T"
        with pytest.raises(ValueError, match=r"dualquat.from_matrix: " + where
                           + " is not a rigid transform"):
            dq.from_matrix(bad, check=True)
        if name != "bottom row":
            with pytest.raises(ValueError, match=r"quat.from_matrix: .* is not a rotation"):
                quat.from_matrix(bad[..., :3, :3], check=True)
    with pytest.raises(TypeError, match=r"expected check to be a bool"):
        dq.from_matrix(T, check="yes")


def test_constructors_refuse_non_rigid_matrices():
    t = torch.linspace(0.0, 2.0, 20, dtype=F64)
    T = _rigid((20,), seed=1)
    mirrored = _BAD["reflection"](T)
    with pytest.raises(ValueError, match=r"nn.BSpline.from_poses: rotations\[0\] is not a "
                                         r"rotation: .*det R = -1"):
        nn.BSpline.from_poses(mirrored[:, :3, :3], T[:, :3, 3], t, n_ctrl=6)
    with pytest.raises(ValueError, match=r"BSpline.from_matrices: T\[0\] is not a rigid "
                                         r"transform"):
        nn.BSpline.from_matrices(_BAD["scale"](T), t, n_ctrl=6)
    with pytest.raises(ValueError, match=r"fitting.Poses: poses must be rigid .*sample 0"):
        fitting.Poses(t, _BAD["shear"](T), rot_sigma=1e-3, trans_sigma=1e-3)
    fitting.Poses(t, T, rot_sigma=1e-3, trans_sigma=1e-3)  # rigid matrices still work

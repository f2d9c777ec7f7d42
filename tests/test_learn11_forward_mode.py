"""Forward mode (``torch.func.jvp``, ``hessian`` = jacfwd of jacrev) of unbatched float32
``dualquat.log`` / ``quat.to_rotvec`` / ``quat.log``: a 0-dim float32 intermediate times a
Python float got a float64 tangent (pytorch#90065), so ``dualquat.log`` raised "expected
scalar type Double but found Float" and the others returned float64 tangents. Reference:
central finite differences of the same public function in float64."""
import pytest
import torch

import torch_dq.dualquat as dq
import torch_dq.quat as Q

F32, F64 = torch.float32, torch.float64


def _pose(rotvec, t):
    return dq.from_rt(Q.from_rotvec(torch.tensor(rotvec, dtype=F64)), torch.tensor(t, dtype=F64))


POSES = {
    "generic": _pose([0.3, -0.2, 0.5], [1.0, 2.0, -0.5]),
    "identity": _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
    "near_identity": _pose([1e-7, 0.0, 0.0], [1e-6, 0.0, 0.0]),
    "large": _pose([2.5, 0.1, 0.0], [1e4, 0.0, 3.0]),
}
FUNCS = {
    "dq.log": dq.log,
    "q.to_rotvec": lambda x: Q.to_rotvec(x[:4]),
    "q.log": lambda x: Q.log(x[:4]),
}


def _fd(f, x, direction, eps=1e-6):
    return (f(x + eps * direction) - f(x - eps * direction)) / (2 * eps)


@pytest.mark.parametrize("pose", sorted(POSES))
@pytest.mark.parametrize("name", sorted(FUNCS))
def test_jvp_unbatched_float32(name, pose):
    f, x64 = FUNCS[name], POSES[pose]
    direction = torch.tensor([0.3, -0.1, 0.2, 0.4, -0.2, 0.1, 0.5, -0.3], dtype=F64)
    out, tangent = torch.func.jvp(f, (x64.to(F32),), (direction.to(F32),))
    assert out.dtype == F32 and tangent.dtype == F32
    ref = _fd(f, x64, direction)
    assert (tangent.double() - ref).abs().max() <= 2e-4 * max(1.0, float(ref.abs().max()))


@pytest.mark.parametrize("pose", ["generic", "identity"])
def test_hessian_unbatched_float32_dq_log(pose):
    x64 = POSES[pose]
    w = torch.tensor([0.7, -0.4, 0.2, 0.5, 0.3, -0.6], dtype=F64)

    def scalar(x):
        return (dq.log(x) * w.to(x.dtype)).sum()

    hess = torch.func.hessian(scalar)(x64.to(F32))
    assert hess.dtype == F32 and hess.shape == (8, 8)
    eps, eye = 1e-4, torch.eye(8, dtype=F64)
    ref = torch.stack([torch.stack([
        (scalar(x64 + eps * (eye[i] + eye[j])) - scalar(x64 + eps * (eye[i] - eye[j]))
         - scalar(x64 - eps * (eye[i] - eye[j])) + scalar(x64 - eps * (eye[i] + eye[j])))
        / (4 * eps * eps) for j in range(8)]) for i in range(8)])
    assert (hess.double() - ref).abs().max() <= 2e-3 * max(1.0, float(ref.abs().max()))

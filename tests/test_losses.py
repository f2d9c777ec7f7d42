"""torch_dq.losses: against scipy's relative-rotation magnitude and numpy translation norms,
sign invariance, reductions, gradcheck away from 0 and finite gradients at 0 and pi."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from strategies import adversarial_dqs, unit_dq

import torch_dq.dualquat as dq
from torch_dq.losses import pose_loss, rotation_angle, squared_rotation_angle, translation_error

F64 = torch.float64


def scipy_angle(a, b):
    """Magnitude of Ra^-1 Rb with scipy (scalar-last quaternions)."""
    qa = a[..., [1, 2, 3, 0]].double().reshape(-1, 4).numpy()
    qb = b[..., [1, 2, 3, 0]].double().reshape(-1, 4).numpy()
    return (Rotation.from_quat(qa).inv() * Rotation.from_quat(qb)).magnitude()


def numpy_dist(a, b):
    ta = dq.to_rt(a.double())[1].reshape(-1, 3).numpy()
    tb = dq.to_rt(b.double())[1].reshape(-1, 3).numpy()
    return np.linalg.norm(ta - tb, axis=-1)


def pairs(gen, dtype=F64):
    """Random pairs, adversarial poses against random ones, near-equal and near-opposite pairs."""
    a = unit_dq((64,), gen, scale=2.0)
    b = unit_dq((64,), gen, scale=2.0)
    adv = adversarial_dqs()
    other = unit_dq((adv.shape[0],), gen)
    tiny = dq.exp(1e-7 * torch.randn(16, 6, generator=gen, dtype=F64))
    half = dq.exp(torch.cat((math.pi * torch.eye(3, dtype=F64),
                             torch.zeros(3, 3, dtype=F64)), -1))
    base = unit_dq((19,), gen)
    near = torch.cat((dq.mul(base[:16], tiny), dq.mul(base[16:], half)))
    a = torch.cat((a, adv, adv, base))
    b = torch.cat((b, other, adv, near))
    return a.to(dtype), b.to(dtype)


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
def test_rotation_angle_matches_scipy(dtype, gen):
    a, b = pairs(gen, dtype)
    got = rotation_angle(a, b)
    assert got.shape == a.shape[:-1] and got.dtype == dtype
    ref = scipy_angle(a, b)
    tol = 1e-12 if dtype == F64 else 1e-5
    np.testing.assert_allclose(got.double().numpy(), ref, rtol=0, atol=tol)
    assert float(got.min()) >= 0.0 and got.max() <= torch.tensor(math.pi, dtype=dtype)


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
def test_squared_rotation_angle_matches_scipy(dtype, gen):
    a, b = pairs(gen, dtype)
    got = squared_rotation_angle(a, b)
    assert got.shape == a.shape[:-1] and got.dtype == dtype
    tol = 1e-12 if dtype == F64 else 4e-5
    np.testing.assert_allclose(got.double().numpy(), scipy_angle(a, b) ** 2, rtol=0, atol=tol)


@pytest.mark.parametrize("dtype", [torch.float32, F64], ids=["float32", "float64"])
def test_translation_error_matches_numpy(dtype, gen):
    a, b = pairs(gen, dtype)
    got = translation_error(a, b)
    ref = numpy_dist(a, b)
    tol = 1e-12 if dtype == F64 else 1e-6
    np.testing.assert_allclose(got.double().numpy(), ref, rtol=tol, atol=tol)


def test_sign_invariance(gen):
    a, b = pairs(gen)
    for f in (rotation_angle, squared_rotation_angle, translation_error,
              lambda x, y: pose_loss(x, y, 0.7, 3.0, reduction="none")):
        ref = f(a, b)
        for sa in (1.0, -1.0):
            for sb in (1.0, -1.0):
                assert torch.equal(f(sa * a, sb * b), ref)


def test_pose_loss_formula_and_reductions(batch_shape, gen):
    a = unit_dq((*batch_shape, 3), gen, scale=2.0)
    b = unit_dq((3,), gen, scale=2.0)  # broadcasts against a
    ang, dist = rotation_angle(a, b), translation_error(a, b)
    per = pose_loss(a, b, rot_weight=2.0, trans_weight=0.25, reduction="none")
    assert per.shape == (*batch_shape, 3)
    torch.testing.assert_close(per, 2.0 * ang**2 + 0.25 * dist**2, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(pose_loss(a, b, 2.0, 0.25), per.mean())
    torch.testing.assert_close(pose_loss(a, b, 2.0, 0.25, reduction="sum"), per.sum())
    assert pose_loss(a, b).shape == ()


def test_units_example():
    """One radian about z weighs like one length unit with the default weights."""
    q = torch.tensor([math.cos(0.5), 0.0, 0.0, math.sin(0.5)], dtype=F64)
    a = dq.from_rt(q, torch.tensor([0.0, 0.0, 0.0], dtype=F64))
    b = dq.from_rt(torch.tensor([1.0, 0, 0, 0], dtype=F64), torch.tensor([0.0, 2.0, 0.0],
                                                                         dtype=F64))
    torch.testing.assert_close(rotation_angle(a, b), torch.tensor(1.0, dtype=F64))
    torch.testing.assert_close(pose_loss(a, b), torch.tensor(5.0, dtype=F64))
    torch.testing.assert_close(pose_loss(a, b, trans_weight=1 / 2.0**2),
                               torch.tensor(2.0, dtype=F64))


@pytest.mark.parametrize("k", [2.0**-100, 2.0**-83, 2.0**66, 2.0**100], ids=lambda k: f"{k:g}")
def test_scaled_inputs_float32(k, gen):
    """Real parts are normalised and translations taken as 2 vec(d r*) / |r|^2 for any scale
    of the dual quaternions (here 1e-30 to 1e30, powers of two so that the scaled inputs are
    exact, except for components that become subnormal), without under/overflow in float32."""
    a, b = pairs(gen, torch.float32)
    for f in (rotation_angle, squared_rotation_angle, translation_error):
        torch.testing.assert_close(f(k * a, b), f(a, b), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16], ids=["f16", "bf16"])
def test_half_precision_computes_in_float32(dtype, gen):
    a, b = unit_dq((8,), gen), unit_dq((8,), gen)
    got = rotation_angle(a.to(dtype), b.to(dtype))
    assert got.dtype == dtype
    torch.testing.assert_close(got.double(), rotation_angle(a, b), atol=2e-2, rtol=0)
    assert pose_loss(a.to(dtype), b.to(dtype)).dtype == dtype


def test_nan_stays_in_its_element(gen):
    a, b = unit_dq((4,), gen), unit_dq((4,), gen)
    a[1, 0] = torch.nan
    a[2, 5] = torch.inf
    ang, dist = rotation_angle(a, b), translation_error(a, b)
    per = pose_loss(a, b, reduction="none")
    assert torch.isnan(ang[1]) and torch.isfinite(ang[[0, 2, 3]]).all()
    assert not torch.isfinite(dist[1:3]).any() and torch.isfinite(dist[[0, 3]]).all()
    assert not torch.isfinite(per[1:3]).any() and torch.isfinite(per[[0, 3]]).all()


# ----------------------------------------------------------------------------- gradients

LOSSES = {
    "rotation_angle": rotation_angle,
    "squared_rotation_angle": squared_rotation_angle,
    "translation_error": translation_error,
    "pose_loss": lambda x, y: pose_loss(x, y, 1.5, 0.5, reduction="sum"),
}


@pytest.mark.parametrize("name", list(LOSSES))
def test_gradcheck_away_from_zero(name, gen):
    a = unit_dq((3,), gen, scale=1.5).requires_grad_()
    b = unit_dq((3,), gen, scale=1.5)
    b[1] = -b[1]  # the opposite representative: still away from the kinks
    b = b.requires_grad_()
    assert torch.autograd.gradcheck(LOSSES[name], (a, b))
    if name in ("pose_loss", "squared_rotation_angle"):
        assert torch.autograd.gradgradcheck(LOSSES[name], (a, b))


@pytest.mark.parametrize("name", ["pose_loss", "squared_rotation_angle"])
@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["same", "opposite"])
def test_gradgradcheck_at_zero_error(name, sign, gen):
    """The squared errors are smooth at zero error: second derivatives pass gradgradcheck
    there (0.1 squared the angle, a cone, and had a zero Hessian at zero error)."""
    x = unit_dq((2,), gen, scale=1.5)
    a, b = x.clone().requires_grad_(), (sign * x).requires_grad_()
    assert torch.autograd.gradgradcheck(LOSSES[name], (a, b))


@pytest.mark.parametrize("name", list(LOSSES))
@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["same", "opposite"])
def test_finite_zero_gradient_at_zero_error(name, sign, gen):
    x = unit_dq((5,), gen, scale=2.0)
    a = x.clone().requires_grad_()
    b = (sign * x).requires_grad_()
    LOSSES[name](a, b).sum().backward()
    for g in (a.grad, b.grad):
        assert torch.isfinite(g).all()
        assert float(g.abs().max()) == 0.0  # the zero subgradient at the kink / minimum


def test_finite_gradient_at_half_turn(gen):
    x = unit_dq((3,), gen)
    half = dq.from_rt(torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64), torch.zeros(3, dtype=F64))
    a = x.clone().requires_grad_()
    b = dq.mul(x, half).requires_grad_()
    rotation_angle(a, b).sum().backward()
    assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all()


# ----------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("fn", [rotation_angle, squared_rotation_angle, translation_error,
                                pose_loss])
def test_bad_inputs(fn):
    a = dq.identity((3,), dtype=F64)
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\).*for a"):
        fn(torch.zeros(3, 7, dtype=F64), a)
    with pytest.raises(ValueError, match=r"\(\.\.\., 8\).*for b"):
        fn(a, torch.zeros(3, 4, dtype=F64))
    with pytest.raises(ValueError, match="do not broadcast"):
        fn(a, dq.identity((4,), dtype=F64))
    with pytest.raises(TypeError, match="dtype"):
        fn(a, dq.identity((3,)))
    with pytest.raises(TypeError, match="floating"):
        fn(a, torch.zeros(3, 8, dtype=torch.int64))


def test_pose_loss_bad_arguments():
    a = dq.identity((2,))
    with pytest.raises(ValueError, match="reduction"):
        pose_loss(a, a, reduction="avg")
    with pytest.raises(ValueError, match="rot_weight"):
        pose_loss(a, a, rot_weight=-1.0)
    with pytest.raises(ValueError, match="trans_weight"):
        pose_loss(a, a, trans_weight=math.nan)
    with pytest.raises(ValueError, match="trans_weight"):
        pose_loss(a, a, trans_weight="1")

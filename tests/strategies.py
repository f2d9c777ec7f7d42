"""Random samplers (seeded torch draws), hypothesis strategies and small assertion helpers
shared by the tests."""

import math
import re

import torch
from hypothesis import strategies as st

from torch_dq import curves


def unit_quat(shape, gen, dtype=torch.float64):
    """Uniformly random unit quaternions ``(*shape, 4)``."""
    q = torch.randn((*shape, 4), generator=gen, dtype=torch.float64)
    return (q / q.norm(dim=-1, keepdim=True)).to(dtype)


def rotvec(shape, gen, max_angle=math.pi, dtype=torch.float64):
    """Random rotation vectors with angles uniform in [0, max_angle)."""
    axis = torch.randn((*shape, 3), generator=gen, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    angle = torch.rand(shape, generator=gen, dtype=torch.float64) * max_angle
    return (axis * angle[..., None]).to(dtype)


# Adversarial rotations: identity, half turns about each axis and a diagonal, tiny angles.
SPECIAL_QUATS = [
    (1.0, 0.0, 0.0, 0.0),
    (0.0, 1.0, 0.0, 0.0),
    (0.0, 0.0, 1.0, 0.0),
    (0.0, 0.0, 0.0, 1.0),
    (0.0, 1 / math.sqrt(3), 1 / math.sqrt(3), 1 / math.sqrt(3)),
    (0.0, math.sqrt(0.5), -math.sqrt(0.5), 0.0),
    (math.cos(5e-9), math.sin(5e-9), 0.0, 0.0),
    (math.cos(math.pi / 2 - 1e-9), 0.0, math.sin(math.pi / 2 - 1e-9), 0.0),
    (-1.0, 0.0, 0.0, 0.0),
]


@st.composite
def quats(draw, allow_special=True):
    """A unit quaternion as a float64 tensor ``(4,)``: random or adversarial."""
    if allow_special and draw(st.booleans()):
        return torch.tensor(draw(st.sampled_from(SPECIAL_QUATS)), dtype=torch.float64)
    comps = draw(st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4))
    q = torch.tensor(comps, dtype=torch.float64)
    n = q.norm()
    return q / n if n > 1e-3 else torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)


def _axis_angle_quat(axis, angle):
    n = math.sqrt(sum(a * a for a in axis))
    s = math.sin(angle / 2) / n
    return (math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s)


_AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, -1), (1, 1, 1), (-1, 2, 3)]


def adversarial_quats(dtype=torch.float64):
    """``(N, 4)`` unit quaternions at and near the singular points of the conversions.

    ``SPECIAL_QUATS`` plus, about each axis and several diagonals: half turns, angles
    1e-9 and 1e-6, and half turns missed by 1e-9 and 1e-6 on either side.
    """
    angles = (math.pi, 1e-9, 1e-6, math.pi - 1e-9, math.pi - 1e-6, math.pi + 1e-9)
    extra = [_axis_angle_quat(ax, a) for ax in _AXES for a in angles]
    return torch.tensor(SPECIAL_QUATS + extra, dtype=torch.float64).to(dtype)


def unit_dq(shape, gen, scale=1.0, dtype=torch.float64):
    """Random unit dual quaternions ``(*shape, 8)``: uniform rotations, Gaussian translations."""
    from torch_dq.dualquat import from_rt

    t = torch.randn((*shape, 3), generator=gen, dtype=torch.float64) * scale
    return from_rt(unit_quat(shape, gen), t).to(dtype)


def screw(shape, gen, theta, d, moment_scale=1.0):
    """Random screw parameters ``(axis, moment, theta, d)`` with the given angle and distance."""
    axis = torch.randn((*shape, 3), generator=gen, dtype=torch.float64)
    axis = axis / axis.norm(dim=-1, keepdim=True)
    point = torch.randn((*shape, 3), generator=gen, dtype=torch.float64) * moment_scale
    moment = torch.linalg.cross(point, axis, dim=-1)
    full = torch.broadcast_shapes(tuple(shape))
    return (axis, moment, torch.full(full, float(theta), dtype=torch.float64),
            torch.full(full, float(d), dtype=torch.float64))


# Translations for adversarial poses: none, unit scale, large (1e3), and huge along one axis.
ADVERSARIAL_TRANSLATIONS = [
    (0.0, 0.0, 0.0),
    (0.3, -1.2, 2.0),
    (1e3, -2e3, 5e2),
    (0.0, 0.0, 1e3),
]


def adversarial_dqs(dtype=torch.float64):
    """``(N, 8)`` unit dual quaternions at and near the singular points of the conversions.

    Every rotation of :func:`adversarial_quats` (identity, half turns about axes and
    diagonals, angles 1e-9 and 1e-6, half turns missed by 1e-9 and 1e-6) combined with each
    of ``ADVERSARIAL_TRANSLATIONS`` (so pure translations, tiny rotations with translations
    of size 1e3, and half turns with large translations are all included).
    """
    from torch_dq.dualquat import from_rt

    q = adversarial_quats()
    t = torch.tensor(ADVERSARIAL_TRANSLATIONS, dtype=torch.float64)
    qq = q[:, None].expand(-1, t.shape[0], 4).reshape(-1, 4)
    tt = t[None].expand(q.shape[0], -1, 3).reshape(-1, 3)
    return from_rt(qq, tt).to(dtype)


@st.composite
def dual_quats(draw, allow_special=True):
    """A unit dual quaternion as a float64 tensor ``(8,)``: random or adversarial rotation,
    translation of scale 0, 1 or 100."""
    from torch_dq.dualquat import from_rt

    q = draw(quats(allow_special=allow_special))
    scale = draw(st.sampled_from([0.0, 1.0, 100.0]))
    t = draw(st.lists(st.floats(-1, 1, allow_nan=False), min_size=3, max_size=3))
    return from_rt(q, torch.tensor(t, dtype=torch.float64) * scale)


def gradcheck_at(f, *args):
    """``torch.autograd.gradcheck`` of ``f`` at fresh float64 leaves copied from ``args``."""
    args = [a.detach().clone().requires_grad_(True) for a in args]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-7)


def grads(f, *args):
    """Gradients of the sum of ``f``'s output(s) at fresh leaves copied from ``args``."""
    args = [a.detach().clone().requires_grad_(True) for a in args]
    out = f(*args)
    outs = out if isinstance(out, tuple) else (out,)
    sum(o.sum() for o in outs).backward()
    return [a.grad for a in args]


def raises_exactly(call, error, pattern):
    """``call()`` raises exactly ``error`` (not a subclass) with a message matching ``pattern``."""
    try:
        call()
    except Exception as e:
        assert type(e) is error, f"{type(e).__name__}: {e}"
        assert re.search(pattern, str(e)), str(e)
    else:
        raise AssertionError(f"no {error.__name__} raised")


def knot_vector(kind, n, p, gen):
    """``n + p + 1`` knots: clamped uniform, unclamped uniform, non-uniform (random
    gaps), or non-uniform with a repeated interior knot (multiplicity ``min(p, 2)``)."""
    if kind == "clamped":
        return curves.clamped_uniform_knots(n, p, dtype=torch.float64, domain=(0.0, 2.0))
    if kind == "uniform":
        return torch.arange(n + p + 1, dtype=torch.float64) * 0.5 - 1.0
    gaps = 0.2 + torch.rand(n + p, generator=gen, dtype=torch.float64)
    knots = torch.cat((torch.zeros(1, dtype=torch.float64), gaps.cumsum(0)))
    if kind == "repeated":
        i = p + (n - p) // 2  # an interior knot, repeated
        for k in range(1, min(p, 2)):
            knots[i + k] = knots[i]
        knots = torch.cummax(knots, 0).values
    return knots


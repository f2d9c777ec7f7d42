"""Random samplers (seeded torch draws) and hypothesis strategies shared by the tests."""

import math

import torch
from hypothesis import strategies as st


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

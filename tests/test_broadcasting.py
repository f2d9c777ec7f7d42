"""Broadcasting across batch ranks, as a property of every public function.

For each function of the registry below, operands of batch ranks 0 to 3 (shapes ``()``,
``(1,)``, ``(5,)``, ``(2, 5)``, ``(3, 1, 5)``) are combined; the output's batch shape must be
``torch.broadcast_shapes`` of the operands' batch shapes, and every output element must
equal the function applied to the corresponding (unbatched) operand elements, one at a
time in a Python loop (jaxlie's ``general_group_test`` pattern over batch shapes). The most
common case is the first one 0.1 failed: one ``(4,)`` rotation or ``(8,)`` transform applied
to ``(N, 3)`` points.
"""

import itertools
import random

import pytest
import torch
from strategies import unit_dq, unit_quat

import torch_dq.dualquat as dq
from torch_dq import Dual, losses, quat

SHAPES = ((), (1,), (5,), (2, 5), (3, 1, 5))
F64 = torch.float64


def _vec(shape, gen, n=3):
    return torch.randn((*shape, n), generator=gen, dtype=F64)


def _scalar(shape, gen):
    return torch.rand(shape, generator=gen, dtype=F64) * 1.4 - 0.2


def _twist(shape, gen):
    return torch.randn((*shape, 6), generator=gen, dtype=F64)


def _matrix(shape, gen):
    return quat.to_matrix(unit_quat(shape, gen))


def _homogeneous(shape, gen):
    return dq.to_matrix(unit_dq(shape, gen))


def _pose7(shape, gen):
    return dq.to_pose7(unit_dq(shape, gen))


def _axis(shape, gen):
    a = _vec(shape, gen)
    return a / a.norm(dim=-1, keepdim=True)


def _weights(shape, gen):
    return torch.rand((*shape, 3), generator=gen, dtype=F64) + 0.1


def _xs(shape, gen):
    return unit_dq((*shape, 3), gen)


_Q, _DQ = unit_quat, unit_dq

# name -> (function, [(maker, event ndim)] for each broadcast operand)
REGISTRY = {
    "quat.mul": (quat.mul, [(_Q, 1), (_Q, 1)]),
    "quat.conj": (quat.conj, [(_Q, 1)]),
    "quat.inv": (quat.inv, [(_Q, 1)]),
    "quat.norm": (quat.norm, [(_Q, 1)]),
    "quat.normalize": (quat.normalize, [(_Q, 1)]),
    "quat.dot": (quat.dot, [(_Q, 1), (_Q, 1)]),
    "quat.rotate": (quat.rotate, [(_Q, 1), (_vec, 1)]),
    "quat.slerp": (quat.slerp, [(_Q, 1), (_Q, 1), (_scalar, 0)]),
    "quat.slerp(shortest=False)": (lambda a, b, t: quat.slerp(a, b, t, shortest=False),
                                   [(_Q, 1), (_Q, 1), (_scalar, 0)]),
    "quat.exp": (quat.exp, [(_Q, 1)]),
    "quat.log": (quat.log, [(_Q, 1)]),
    "quat.from_matrix": (quat.from_matrix, [(_matrix, 2)]),
    "quat.to_matrix": (quat.to_matrix, [(_Q, 1)]),
    "quat.from_axis_angle": (quat.from_axis_angle, [(_axis, 1), (_scalar, 0)]),
    "quat.to_axis_angle": (quat.to_axis_angle, [(_Q, 1)]),
    "quat.from_rotvec": (quat.from_rotvec, [(_vec, 1)]),
    "quat.to_rotvec": (quat.to_rotvec, [(_Q, 1)]),
    "quat.from_euler": (lambda a: quat.from_euler(a, "ZYX"), [(_vec, 1)]),
    "quat.to_euler": (lambda q: quat.to_euler(q, "zxz"), [(_Q, 1)]),
    "quat.from_xyzw": (quat.from_xyzw, [(_Q, 1)]),
    "quat.to_xyzw": (quat.to_xyzw, [(_Q, 1)]),
    "dualquat.mul": (dq.mul, [(_DQ, 1), (_DQ, 1)]),
    "dualquat.conj": (dq.conj, [(_DQ, 1)]),
    "dualquat.conj_dual": (dq.conj_dual, [(_DQ, 1)]),
    "dualquat.conj_full": (dq.conj_full, [(_DQ, 1)]),
    "dualquat.inv": (dq.inv, [(_DQ, 1)]),
    "dualquat.norm": (dq.norm, [(_DQ, 1)]),
    "dualquat.dot": (dq.dot, [(_DQ, 1), (_DQ, 1)]),
    "dualquat.normalize": (dq.normalize, [(_DQ, 1)]),
    "dualquat.is_unit": (dq.is_unit, [(_DQ, 1)]),
    "dualquat.from_rt": (dq.from_rt, [(_Q, 1), (_vec, 1)]),
    "dualquat.to_rt": (dq.to_rt, [(_DQ, 1)]),
    "dualquat.from_matrix": (dq.from_matrix, [(_homogeneous, 2)]),
    "dualquat.to_matrix": (dq.to_matrix, [(_DQ, 1)]),
    "dualquat.from_pose7": (dq.from_pose7, [(_pose7, 1)]),
    "dualquat.to_pose7": (dq.to_pose7, [(_DQ, 1)]),
    "dualquat.from_screw": (dq.from_screw, [(_axis, 1), (_vec, 1), (_scalar, 0), (_scalar, 0)]),
    "dualquat.to_screw": (dq.to_screw, [(_DQ, 1)]),
    "dualquat.exp": (dq.exp, [(_twist, 1)]),
    "dualquat.log": (dq.log, [(_DQ, 1)]),
    "dualquat.apply": (dq.apply, [(_DQ, 1), (_vec, 1)]),
    "dualquat.apply_line": (dq.apply_line, [(_DQ, 1), (_axis, 1), (_vec, 1)]),
    "dualquat.angle": (dq.angle, [(_DQ, 1), (_DQ, 1)]),
    "dualquat.sclerp": (dq.sclerp, [(_DQ, 1), (_DQ, 1), (_scalar, 0)]),
    "dualquat.dlb": (dq.dlb, [(_weights, 1), (_xs, 2)]),
    "losses.rotation_angle": (losses.rotation_angle, [(_DQ, 1), (_DQ, 1)]),
    "losses.squared_rotation_angle": (losses.squared_rotation_angle, [(_DQ, 1), (_DQ, 1)]),
    "losses.translation_error": (losses.translation_error, [(_DQ, 1), (_DQ, 1)]),
    "losses.pose_loss": (lambda a, b: losses.pose_loss(a, b, reduction="none"),
                         [(_DQ, 1), (_DQ, 1)]),
}


def _combos(n_args: int) -> list[tuple]:
    """All shape combinations for one or two operands; for more, every pair of shapes on
    each pair of operands (the others of rank 0 or 3) plus a seeded sample of full ones."""
    if n_args <= 2:
        return list(itertools.product(SHAPES, repeat=n_args))
    combos = set()
    for i, j in itertools.combinations(range(n_args), 2):
        for si, sj in itertools.product(SHAPES, repeat=2):
            for rest in ((), (3, 1, 5)):
                c = [rest] * n_args
                c[i], c[j] = si, sj
                combos.add(tuple(c))
    rng = random.Random(0)
    combos |= {tuple(rng.choice(SHAPES) for _ in range(n_args)) for _ in range(10)}
    return sorted(combos)


def _outputs(out) -> list[torch.Tensor]:
    if isinstance(out, Dual):
        return [out.real, out.dual]
    if isinstance(out, tuple):
        return list(out)
    return [out]


def _element(x: torch.Tensor, batch: tuple, index: tuple, event: int) -> torch.Tensor:
    """The operand element that broadcasting pairs with output element ``index``."""
    own = x.shape[: x.dim() - event]
    offset = len(batch) - len(own)
    return x[tuple(0 if own[k] == 1 else index[offset + k] for k in range(len(own)))]


@pytest.mark.parametrize("name", sorted(REGISTRY))
def test_broadcast_shapes_and_values(name):
    fn, makers = REGISTRY[name]
    gen = torch.Generator().manual_seed(7)
    for shapes in _combos(len(makers)):
        args = [make(shape, gen) for (make, _), shape in zip(makers, shapes, strict=True)]
        batch = torch.broadcast_shapes(*shapes)
        outs = _outputs(fn(*args))
        for out in outs:
            assert tuple(out.shape[: len(batch)]) == tuple(batch), (name, shapes, out.shape)
        events = [out.shape[len(batch):] for out in outs]
        for index in itertools.product(*(range(n) for n in batch)):
            elems = [_element(a, batch, index, ev) for a, (_, ev) in zip(args, makers, strict=True)]
            for out, ref, event in zip(outs, _outputs(fn(*elems)), events, strict=True):
                assert ref.shape == event, (name, shapes, index)
                where = f"{name} {shapes} {index}"
                torch.testing.assert_close(out[index], ref, rtol=1e-12, atol=1e-12,
                                           msg=lambda m, where=where: f"{where}: {m}")


def test_one_transform_many_points():
    """The 0.1 failures named in the issue: a (4,) rotation on (N, 3) vectors, an (8,)
    transform on (N, 3) points, and line moments with more batch dims than the transform."""
    gen = torch.Generator().manual_seed(3)
    q, x = unit_quat((), gen), unit_dq((), gen)
    v = torch.randn(7, 3, generator=gen, dtype=F64)
    R = quat.to_matrix(q)
    torch.testing.assert_close(quat.rotate(q, v), v @ R.T)
    T = dq.to_matrix(x)
    torch.testing.assert_close(dq.apply(x, v), v @ T[:3, :3].T + T[:3, 3])
    l = _axis((7,), gen)
    p = torch.randn(2, 7, 3, generator=gen, dtype=F64)  # points on the lines
    m = torch.linalg.cross(p, l.expand(2, 7, 3), dim=-1)
    l2, m2 = dq.apply_line(x[None], l, m)
    assert l2.shape == m2.shape == (2, 7, 3)
    # Reference: the moment of the transformed line, through the transformed points.
    torch.testing.assert_close(m2, torch.linalg.cross(p @ T[:3, :3].T + T[:3, 3], l2, dim=-1))

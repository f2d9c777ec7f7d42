"""Broadcasting across batch ranks, as a property of every public function.

For each function of the one registry (``registry.OPS``, its sampler's ``SHAPES``), operands
of batch ranks 0 to 3 (shapes ``()``, ``(1,)``, ``(5,)``, ``(2, 5)``, ``(3, 1, 5)``) are
combined; the output's batch shape must be ``torch.broadcast_shapes`` of the operands' batch
shapes, and the output elements (all of them up to 10, else the first, the last and a seeded
sample) must equal the function applied to the corresponding (unbatched) operand elements,
one at a time in a Python loop (jaxlie's ``general_group_test`` pattern over batch shapes).
The most common case is the first one 0.1 failed: one ``(4,)`` rotation or ``(8,)``
transform applied to ``(N, 3)`` points.
"""

import itertools
import random

import pytest
import torch
from registry import EVENT, IDS, OPS, SHAPES, outs, sample
from strategies import unit_dq, unit_quat

import torch_dq.dualquat as dq
from torch_dq import quat

F64 = torch.float64
MAX_ELEMENTS = 10  # output elements compared with an unbatched call, per shape combination


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


def _indices(batch: tuple, rng: random.Random) -> list[tuple]:
    """The output elements checked one by one: all of them for batches up to ``MAX_ELEMENTS``,
    else the first, the last and a seeded sample (every operand's own elements still meet
    every broadcast position across the shape combinations)."""
    every = list(itertools.product(*(range(n) for n in batch)))
    if len(every) <= MAX_ELEMENTS:
        return every
    return [every[0], every[-1], *rng.sample(every[1:-1], MAX_ELEMENTS - 2)]


def _element(x: torch.Tensor, batch: tuple, index: tuple, event: int) -> torch.Tensor:
    """The operand element that broadcasting pairs with output element ``index``."""
    own = x.shape[: x.dim() - event]
    offset = len(batch) - len(own)
    return x[tuple(0 if own[k] == 1 else index[offset + k] for k in range(len(own)))]


@pytest.mark.parametrize("op", OPS, ids=IDS)
def test_broadcast_shapes_and_values(op):
    name, fn = op.id, op.fn
    kinds = [kind for _, kind in op.args]
    gen = torch.Generator().manual_seed(7)
    rng = random.Random(7)
    for shapes in _combos(len(kinds)):
        args = [sample(kind, shape, gen) for kind, shape in zip(kinds, shapes, strict=True)]
        batch = torch.broadcast_shapes(*shapes)
        got = outs(fn(*args))
        for out in got:
            assert tuple(out.shape[: len(batch)]) == tuple(batch), (name, shapes, out.shape)
        events = [out.shape[len(batch):] for out in got]
        for index in _indices(batch, rng):
            elems = [_element(a, batch, index, len(EVENT[kind]))
                     for a, kind in zip(args, kinds, strict=True)]
            for out, ref, event in zip(got, outs(fn(*elems)), events, strict=True):
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
    l = sample("dir", (7,), gen)
    p = torch.randn(2, 7, 3, generator=gen, dtype=F64)  # points on the lines
    m = torch.linalg.cross(p, l.expand(2, 7, 3), dim=-1)
    l2, m2 = dq.apply_line(x[None], l, m)
    assert l2.shape == m2.shape == (2, 7, 3)
    # Reference: the moment of the transformed line, through the transformed points.
    torch.testing.assert_close(m2, torch.linalg.cross(p @ T[:3, :3].T + T[:3, 3], l2, dim=-1))

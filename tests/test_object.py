"""torch_dq.DualQuaternion: every method equals its functional call (bitwise), indexing over
the batch only, repr, dtype/device conversion, immutability and errors."""

import copy
import math
import pickle

import pytest
import torch
from strategies import unit_dq

import torch_dq
import torch_dq.dualquat as dq
from torch_dq import DualQuaternion, quat
from torch_dq.dual import Dual

F64 = torch.float64


def _equal(a, b):
    """Bitwise equality of tensors, tuples of tensors, Duals and DualQuaternions."""
    if isinstance(a, DualQuaternion):
        return isinstance(b, DualQuaternion) and torch.equal(a.tensor, b.tensor)
    if isinstance(a, (tuple, Dual)):
        return all(_equal(x, y) for x, y in zip(a, b, strict=True))
    return torch.equal(a, b)


@pytest.fixture
def xs(gen):
    return unit_dq((4, 3), gen), unit_dq((3,), gen)


def test_reexported():
    assert torch_dq.DualQuaternion is DualQuaternion
    assert "DualQuaternion" in torch_dq.__all__


def test_methods_equal_functional_calls(xs, gen):
    x, y = xs
    a, b = DualQuaternion(x), DualQuaternion(y)
    p = torch.randn(4, 3, 3, generator=gen, dtype=F64)
    m = torch.randn(3, 3, generator=gen, dtype=F64)
    t = torch.rand(4, 1, generator=gen, dtype=F64)
    cases = [
        (a * b, DualQuaternion(dq.mul(x, y))),
        (b * a, DualQuaternion(dq.mul(y, x))),
        (a.inverse(), DualQuaternion(dq.inv(x))),
        (a.conj(), DualQuaternion(dq.conj(x))),
        (a.normalize(), DualQuaternion(dq.normalize(x))),
        (a.apply(p), dq.apply(x, p)),
        (a.apply_line(p, m), dq.apply_line(x, p, m)),
        (a.to_matrix(), dq.to_matrix(x)),
        (a.to_rt(), dq.to_rt(x)),
        (a.to_screw(), dq.to_screw(x)),
        (a.to_pose7(), dq.to_pose7(x)),
        (a.log(), dq.log(x)),
        (a.is_unit(), dq.is_unit(x)),
        (a.is_unit(1e-3), dq.is_unit(x, 1e-3)),
        (a.sclerp(b, t), DualQuaternion(dq.sclerp(x, y, t))),
        (a.sclerp(b, 0.3, shortest=False), DualQuaternion(dq.sclerp(x, y, 0.3, False))),
        (a.angle(b), dq.angle(x, y)),
    ]
    for got, ref in cases:
        assert _equal(got, ref)
    assert isinstance(a.angle(b), Dual)
    assert isinstance(a.to_matrix(), torch.Tensor)


def test_constructors_equal_functional_calls(xs, gen):
    x, _ = xs
    q, t = dq.to_rt(x)
    T = dq.to_matrix(x)
    screw = dq.to_screw(x)
    xi = dq.log(x)
    p7 = dq.to_pose7(x)
    cases = [
        (DualQuaternion.from_rt(q, t), dq.from_rt(q, t)),
        (DualQuaternion.from_matrix(T), dq.from_matrix(T)),
        (DualQuaternion.from_screw(*screw), dq.from_screw(*screw)),
        (DualQuaternion.from_screw(screw[0], screw[1], 0.5, 1.0),
         dq.from_screw(screw[0], screw[1], 0.5, 1.0)),
        (DualQuaternion.exp(xi), dq.exp(xi)),
        (DualQuaternion.from_pose7(p7), dq.from_pose7(p7)),
        (DualQuaternion.identity((2, 3), dtype=F64), dq.identity((2, 3), dtype=F64)),
        (DualQuaternion.identity(), dq.identity()),
    ]
    for got, ref in cases:
        assert isinstance(got, DualQuaternion)
        assert torch.equal(got.tensor, ref)


def test_wraps_without_copy_and_reads_attributes(xs):
    x, _ = xs
    a = DualQuaternion(x)
    assert a.tensor is x
    assert a.shape == (4, 3) and a.ndim == 2 and len(a) == 4
    assert a.dtype == F64 and a.device == x.device
    s = DualQuaternion(x[0, 0])
    assert s.shape == () and s.ndim == 0
    with pytest.raises(TypeError, match="len"):
        len(s)


def test_group_use_reads_like_math(xs, gen):
    x, _ = xs
    a = DualQuaternion(x)
    ident = DualQuaternion.identity(a.shape, dtype=F64)
    assert (a * a.inverse()).tensor.sub(ident.tensor).abs().max() < 1e-15
    p = torch.randn(3, generator=gen, dtype=F64)
    # a * b applies b first
    b = a.inverse()[:, :1]
    assert (((a * b).apply(p)) - a.apply(b.apply(p))).abs().max() < 1e-14


# ----------------------------------------------------------------------------- indexing

def test_indexing_applies_to_batch_dims_only(xs):
    x, _ = xs
    a = DualQuaternion(x)
    cases = [
        (0, (3,)),
        (-1, (3,)),
        (slice(1, 3), (2, 3)),
        ((0, 1), ()),
        ((slice(None), 1), (4,)),
        ((Ellipsis, 0), (4,)),
        ((0, Ellipsis), (3,)),
        (Ellipsis, (4, 3)),
        (None, (1, 4, 3)),
        ((None, slice(1, 3)), (1, 2, 3)),
        ((slice(None), None, 2), (4, 1)),
        (torch.tensor([0, 2, 2]), (3, 3)),
        ((torch.tensor([0, 1]), torch.tensor([2, 0])), (2,)),
        (torch.tensor([True, False, True, True]), (3, 3)),
        ((slice(None), slice(None, None, 2)), (4, 2)),
        ((), (4, 3)),
    ]
    for index, shape in cases:
        out = a[index]
        assert isinstance(out, DualQuaternion)
        assert out.shape == shape, index
        idx = index if isinstance(index, tuple) else (index,)
        tail = (slice(None),) if any(i is Ellipsis for i in idx) else (Ellipsis, slice(None))
        assert torch.equal(out.tensor, x[idx + tail])
    mask = torch.zeros(4, 3, dtype=torch.bool)
    mask[1, 2] = mask[3, 0] = True
    assert a[mask].shape == (2,)
    assert torch.equal(a[mask].tensor, torch.stack((x[1, 2], x[3, 0])))
    assert torch.equal(a[1, 2].tensor, x[1, 2])
    assert torch.equal(a[..., 0].tensor, x[:, 0])  # never the 8-component axis


@pytest.mark.parametrize("index", [(0, 0, 0), (0, 0, slice(None)), (Ellipsis, 0, 0, 0), 7])
def test_indexing_past_the_batch_raises(xs, index):
    a = DualQuaternion(xs[0])
    with pytest.raises(IndexError, match=r"DualQuaternion: index .* batch shape \(4, 3\)"):
        a[index]


def test_indexing_a_single_pose_raises():
    a = DualQuaternion.identity()
    for index in (0, slice(None), (Ellipsis, 0)):
        with pytest.raises(IndexError, match=r"batch shape \(\)"):
            a[index]
    assert a[None].shape == (1,) and a[...].shape == ()


def test_not_iterable():
    with pytest.raises(TypeError, match="not iterable"):
        iter(DualQuaternion.identity((3,)))
    with pytest.raises(TypeError, match="not iterable"):
        list(DualQuaternion.identity((3,)))


# ----------------------------------------------------------------------------- repr

def test_repr_single_pose():
    q = quat.from_axis_angle(torch.tensor([0.0, 0.0, 2.0]), math.pi / 2)
    a = DualQuaternion.from_rt(q, torch.tensor([1.0, -2.0, 0.5]))
    assert repr(a) == ("DualQuaternion(shape=(), dtype=torch.float32): "
                       "rotation 90 deg about (0, 0, 1), translation (1, -2, 0.5)")


def test_repr_small_and_large_batches(gen):
    a = DualQuaternion(dq.exp(torch.tensor([[0.0, math.pi, 0, 0, 0, 0], [0, 0, 0, 3, 0, 0]],
                                           dtype=F64))[:, None])
    assert repr(a) == (
        "DualQuaternion(shape=(2, 1), dtype=torch.float64)\n"
        "  [0, 0] rotation 180 deg about (0, 1, 0), translation (0, 0, 0)\n"
        "  [1, 0] rotation 0 deg about (1, 0, 0), translation (3, 0, 0)")
    big = DualQuaternion(unit_dq((3, 5), gen))
    assert repr(big) == "DualQuaternion(shape=(3, 5), dtype=torch.float64)"
    empty = DualQuaternion(torch.zeros(0, 8))
    assert repr(empty) == "DualQuaternion(shape=(0,), dtype=torch.float32)"
    assert "nan" in repr(DualQuaternion(torch.full((8,), math.nan)))  # does not raise
    r = repr(DualQuaternion(unit_dq((2,), gen).requires_grad_()))  # no autograd complaint
    assert r.startswith("DualQuaternion(shape=(2,), dtype=torch.float64)\n  [0] rotation")


# ----------------------------------------------------------------------------- conversions

def test_to_dtype_and_device(xs, device):
    x, _ = xs
    a = DualQuaternion(x.float())
    b = a.to(torch.float64)
    assert isinstance(b, DualQuaternion) and b.dtype == F64 and b.shape == (4, 3)
    assert torch.equal(b.tensor, x.float().double())
    c = a.to(device)
    assert c.device.type == device.type
    assert a.to(device=device, dtype=torch.float16).dtype == torch.float16
    with pytest.raises(TypeError, match=r"DualQuaternion: expected a floating-point tensor"):
        a.to(torch.int32)


def test_autograd_flows_through(xs, gen):
    x, y = xs
    xg = x.clone().requires_grad_()
    a = DualQuaternion(xg)
    p = torch.randn(3, generator=gen, dtype=F64)
    (a * DualQuaternion(y)).apply(p).sum().backward()
    xg2 = x.clone().requires_grad_()
    dq.apply(dq.mul(xg2, y), p).sum().backward()
    assert torch.equal(xg.grad, xg2.grad)
    assert not a.detach().tensor.requires_grad


def test_pytree_vmap_and_pickle(xs, gen):
    x, y = xs

    def f(a, b):
        return (a * b).normalize()

    out = torch.func.vmap(f)(DualQuaternion(x[0]), DualQuaternion(y))
    assert isinstance(out, DualQuaternion)
    assert torch.equal(out.tensor, dq.normalize(dq.mul(x[0], y)))
    a = DualQuaternion(x)
    for b in (pickle.loads(pickle.dumps(a)), copy.deepcopy(a), copy.copy(a)):
        assert isinstance(b, DualQuaternion) and torch.equal(b.tensor, x)


# ----------------------------------------------------------------------------- errors

def test_frozen(xs):
    a = DualQuaternion(xs[0])
    with pytest.raises(AttributeError, match="immutable"):
        a.tensor = xs[1]
    with pytest.raises(AttributeError, match="immutable"):
        a._tensor = xs[1]
    with pytest.raises(AttributeError, match="immutable"):
        a.extra = 1
    with pytest.raises(AttributeError, match="immutable"):
        del a._tensor
    assert a == a and a != DualQuaternion(xs[0])  # identity, not element-wise comparison


@pytest.mark.parametrize(
    ("call", "exc", "match"),
    [
        (lambda a: DualQuaternion(torch.zeros(3, 7)), ValueError,
         r"DualQuaternion: expected a \(\.\.\., 8\) tensor for tensor, got shape \(3, 7\)"),
        (lambda a: DualQuaternion(torch.zeros(8, dtype=torch.int64)), TypeError,
         r"DualQuaternion: expected a floating-point tensor for tensor"),
        (lambda a: DualQuaternion([1.0] + [0.0] * 7), TypeError, r"torch\.Tensor.*list"),
        (lambda a: DualQuaternion(a), TypeError, r"got DualQuaternion"),
        (lambda a: a * a.tensor, TypeError,
         r"DualQuaternion \*: expected a DualQuaternion for other, got Tensor \(wrap"),
        (lambda a: a.tensor * a, TypeError,
         r"DualQuaternion \*: expected a DualQuaternion for left operand, got Tensor"),
        (lambda a: 2.0 * a, TypeError, r"for left operand, got float"),
        (lambda a: a * 2, TypeError, r"for other, got int"),
        (lambda a: a @ a, TypeError, r"unsupported operand"),
        (lambda a: a.sclerp(a.tensor, 0.5), TypeError,
         r"DualQuaternion sclerp: expected a DualQuaternion for other, got Tensor"),
        (lambda a: a.angle(None), TypeError, r"DualQuaternion angle.*other, got NoneType"),
        (lambda a: a * DualQuaternion(torch.zeros(5, 8, dtype=F64)), ValueError,
         r"dualquat\.mul: batch shapes do not broadcast"),
        (lambda a: a * DualQuaternion(torch.zeros(8)), TypeError, r"dualquat\.mul: b has dtype"),
        (lambda a: a.apply(torch.zeros(4, dtype=F64)), ValueError, r"dualquat\.apply.*points"),
        (lambda a: DualQuaternion.from_rt(torch.zeros(3), torch.zeros(3)), ValueError,
         r"dualquat\.from_rt.*for q"),
        (lambda a: DualQuaternion.from_matrix(torch.zeros(3, 3)), ValueError,
         r"dualquat\.from_matrix.*T"),
        (lambda a: DualQuaternion.exp(torch.zeros(8)), ValueError, r"dualquat\.exp.*xi"),
        (lambda a: DualQuaternion.identity(dtype=torch.int64), TypeError, r"dualquat\.identity"),
        (lambda a: a.sclerp(a, torch.zeros(7, dtype=F64)), ValueError, r"sclerp.*t \(7,\)"),
    ],
)
def test_bad_arguments(xs, call, exc, match):
    with pytest.raises(exc, match=match):
        call(DualQuaternion(xs[0]))


def test_compile_fullgraph(xs, gen):
    """The wrapper is a pytree node: compiled code takes and returns DualQuaternions."""
    x, y = xs
    p = torch.randn(3, generator=gen, dtype=F64)

    def f(a, b):
        c = (a * b).normalize()
        return c, c.apply(p)

    compiled = torch.compile(f, backend="aot_eager", fullgraph=True)
    (c1, p1), (c2, p2) = compiled(DualQuaternion(x), DualQuaternion(y)), f(DualQuaternion(x),
                                                                          DualQuaternion(y))
    assert isinstance(c1, DualQuaternion)
    assert torch.equal(c1.tensor, c2.tensor) and torch.equal(p1, p2)

r"""Dual numbers :math:`a + \epsilon b` (:math:`\epsilon^2 = 0`) on pairs of tensors.

A dual number holds a real part ``a`` and a dual part ``b``, two tensors of one shape.
Dual numbers form a ring, not a field: only those with a non-zero real part are
invertible, :math:`(a + \epsilon b)^{-1} = \frac{1}{a^2}(a - \epsilon b)`.
Every real analytic function :math:`f` extends to them by its first-order Taylor expansion
(the paper's section 2.2, "fonction duale"),

.. math::
    f(a + \epsilon b) = f(a) + \epsilon\, b\, f'(a),

so :math:`\cos(a + \epsilon b) = \cos a - \epsilon\, b \sin a` and
:math:`\sin(a + \epsilon b) = \sin a + \epsilon\, b \cos a`. The dual part is the
forward-mode derivative of :math:`f` at ``a`` in the direction ``b`` (``torch.func.jvp``).

Conventions: every function broadcasts like torch ops, dtype and device follow the inputs,
inputs are never modified in place, and everything is built from differentiable torch ops
(``autograd``, ``torch.func.vmap``/``jvp``/``grad`` and ``torch.compile`` all work).

Singular derivatives: where :math:`f'(a)` is infinite (``acos`` at :math:`\pm 1`, ``sqrt``
and ``log`` at 0, ``inv`` and ``div`` at a zero divisor, ``atan2`` at the origin), a zero
dual component contributes exactly 0 to the dual part, never ``0 * inf = NaN``, and the
gradients of the dual part stay finite there; a non-zero dual component gives an infinite
dual part with the sign of the limit (documented per function), a constant that carries no
gradient. Elsewhere the dual parts are torch's own forward-mode (``jvp``) formulas.

Non-finite values: these are elementwise functions with torch's IEEE semantics. A NaN
makes every part that depends on it NaN, in its own element only; :math:`\pm\infty` gives
the IEEE limits of the torch function and of its derivative (``exp(-inf) = 0``,
``1 / inf = 0``, ``atan2(inf, x) = pi / 2``, ``d sqrt(a) = b / (2 sqrt a) -> 0``), exactly
as ``torch.func.jvp`` of the torch function would. float16/bfloat16 parts are computed by
the torch ops in their own dtype.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterator
from typing import Any

import torch
import torch.utils._pytree as _pytree
from torch import Tensor

from . import _checks, _dispatch
from ._core import Frozen
from ._kernels.sincos import SinCos
from ._numerics import power_of_two_scale

__all__ = [
    "Dual",
    "acos",
    "apply",
    "atan2",
    "conj",
    "cos",
    "div",
    "exp",
    "inv",
    "log",
    "mul",
    "sin",
    "sincos",
    "sqrt",
    "tan",
]

_INF = math.inf


def _is_number(x) -> bool:
    """A real Python (or numpy) scalar, excluding ``bool``."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _operator(name: str, op: Callable[[Dual, Any, Tensor | None], Dual]):
    """The binary operator ``name`` of :class:`Dual`: the other operand's ``(real, dual or
    None)`` from :func:`_operand` (``NotImplemented`` for other types), then ``op(self,
    real, dual)``."""
    fn = f"Dual.{name}"

    def method(self: Dual, other: Dual | Tensor | float) -> Dual:
        o = _operand(fn, self, other)
        return o if o is NotImplemented else op(self, *o)

    method.__name__ = method.__qualname__ = name
    return method


class Dual(Frozen):
    r"""A dual number :math:`a + \epsilon b`, two tensors of one shape.

    A small frozen value type (not a ``Tensor`` subclass, not an ``nn.Module``). It is
    registered as a pytree node, so it can be passed to and returned from
    ``torch.func.vmap``/``jvp`` and compiled functions.

    Operators: ``+ - * /`` with another ``Dual``, a tensor or a Python number on either
    side (a tensor or number ``c`` is the dual number :math:`c + \epsilon 0`), and unary
    ``-``. There are no comparisons: ``==`` is identity, as for any Python object.

    Attributes:
        real: ``(...)`` real part ``a``.
        dual: ``(...)`` dual part ``b``, same shape, dtype and device as ``real``.

    Args:
        real: floating tensor or Python number.
        dual: floating tensor or Python number, broadcastable with ``real`` and of the
            same dtype and device. A Python number takes the dtype and device of the other
            part (torch's default dtype if both are numbers). Default 0.

    Raises:
        TypeError: a part that is not a tensor or a number, a non-floating tensor, or
            parts of different dtypes or devices.
        ValueError: parts whose shapes do not broadcast.

    Both parts are stored broadcast to their common shape (as ``expand`` views when the
    shapes differ, so do not modify them in place). ``iter`` unpacks ``(real, dual)``,
    while indexing ``x[i]`` indexes the batch of both parts.

    Example:
        >>> x = Dual(torch.tensor([1.0, 2.0]), 0.5)
        >>> y = x * x + 1.0          # (a^2 + 1) + eps 2ab
        >>> y.real, y.dual
        (tensor([2., 5.]), tensor([1., 2.]))
        >>> real, dual = y
    """

    __slots__ = ("dual", "real")

    real: Tensor
    dual: Tensor

    def __init__(self, real: Tensor | float, dual: Tensor | float = 0.0):
        fn = "Dual"
        for name, part in (("real", real), ("dual", dual)):
            if isinstance(part, Tensor):
                _checks.tensor(fn, name, part)
            elif not _is_number(part):
                _checks.fail(fn, f"expected a tensor or a real number for {name}, "
                                 f"got {type(part).__name__}", TypeError)
        if not isinstance(real, Tensor):
            like = dual if isinstance(dual, Tensor) else None
            real = torch.tensor(float(real), dtype=like.dtype if like is not None else None,
                                device=like.device if like is not None else None)
        if not isinstance(dual, Tensor):
            dual = torch.tensor(float(dual), dtype=real.dtype, device=real.device)
        _checks.same_dtype_device(fn, real=real, dual=dual)
        if real.shape != dual.shape:
            _checks.broadcast_batch(fn, real=(real, 0), dual=(dual, 0))
        _set(self, *_broadcast(real, dual))

    @classmethod
    def _make(cls, real, dual) -> Dual:
        """Build without checks or broadcasting (both parts already valid and of one shape)."""
        self = object.__new__(cls)
        _set(self, real, dual)
        return self

    def __reduce__(self):
        return (Dual, (self.real, self.dual))

    # -- tensor-like attributes ------------------------------------------------------------

    @property
    def shape(self) -> torch.Size:
        """Shape of both parts."""
        return self.real.shape

    @property
    def ndim(self) -> int:
        """Number of dimensions of both parts."""
        return self.real.dim()

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of both parts."""
        return self.real.dtype

    @property
    def device(self) -> torch.device:
        """Device of both parts."""
        return self.real.device

    def __iter__(self) -> Iterator[Tensor]:
        """Unpack as ``real, dual = x``."""
        yield self.real
        yield self.dual

    def __getitem__(self, index: Any) -> Dual:
        """Index the batch of both parts: ``Dual(x.real[index], x.dual[index])``."""
        return Dual._make(self.real[index], self.dual[index])

    def __repr__(self) -> str:
        return f"Dual(real={self.real!r}, dual={self.dual!r})"

    def to(self, *args: Any, **kwargs: Any) -> Dual:
        """Both parts through ``Tensor.to`` (dtype and/or device); must stay floating."""
        return Dual(self.real.to(*args, **kwargs), self.dual.to(*args, **kwargs))

    def detach(self) -> Dual:
        """Both parts detached from the autograd graph."""
        return Dual._make(self.real.detach(), self.dual.detach())

    def conj(self) -> Dual:
        r"""The conjugate :math:`a - \epsilon b`."""
        return Dual._make(self.real, -self.dual)

    # -- arithmetic --------------------------------------------------------------------------

    def __neg__(self) -> Dual:
        return Dual._make(-self.real, -self.dual)

    __add__ = __radd__ = _operator("__add__", lambda x, c, d: _new(
        x.real + c, x.dual if d is None else x.dual + d))
    __sub__ = _operator("__sub__", lambda x, c, d: _new(
        x.real - c, x.dual if d is None else x.dual - d))
    __rsub__ = _operator("__rsub__", lambda x, c, d: _new(
        c - x.real, -x.dual if d is None else d - x.dual))
    __mul__ = __rmul__ = _operator("__mul__", lambda x, c, d: _mul(x.real, x.dual, c, d))
    __truediv__ = _operator("__truediv__", lambda x, c, d: _div(
        x.real, x.dual, _as_like(c, x.real), d))
    __rtruediv__ = _operator("__rtruediv__", lambda x, c, d: _div(c, d, x.real, x.dual))


def _set(self: Dual, real, dual) -> None:
    object.__setattr__(self, "real", real)
    object.__setattr__(self, "dual", dual)


def _broadcast(real: Tensor, dual: Tensor) -> tuple[Tensor, Tensor]:
    """Both parts expanded to their common shape (no copy; unchanged if already equal)."""
    if real.shape == dual.shape:
        return real, dual
    shape = _checks.broadcast_shapes(real.shape, dual.shape)
    return real.expand(shape), dual.expand(shape)


def _new(real: Tensor, dual: Tensor | None) -> Dual:
    """Unchecked constructor; ``dual=None`` means an exact zero dual part."""
    if dual is None:
        return Dual._make(real, torch.zeros_like(real))
    return Dual._make(*_broadcast(real, dual))


def _as_like(c, like: Tensor) -> Tensor:
    """A Python number as a 0-d tensor of ``like``'s dtype and device; tensors unchanged."""
    return c if isinstance(c, Tensor) else torch.tensor(c, dtype=like.dtype, device=like.device)


def _operand(fn: str, self: Dual, other):
    """``(real, dual or None)`` of an operator's other operand, or ``NotImplemented``.

    ``dual`` is ``None`` for a tensor or number (an exact zero dual part). Tensors and duals
    must be floating, of ``self``'s dtype and device, and broadcastable with it.
    """
    if _is_number(other):
        return float(other), None
    if isinstance(other, Dual):
        c, d = other.real, other.dual
    elif isinstance(other, Tensor):
        c, d = _checks.tensor(fn, "other", other), None
    else:
        return NotImplemented
    _checks.same_dtype_device(fn, self=self.real, other=c)
    if c.shape != self.real.shape:
        _checks.broadcast_batch(fn, self=(self.real, 0), other=(c, 0))
    return c, d


def _parts(fn: str, names: tuple[str, str], x, y):
    """Validate the two operands of ``mul``/``div``/``atan2``.

    Each is a ``Dual``, a floating tensor or a Python number (not both numbers). Returns
    ``(a, b, c, d)``: real and dual parts, tensors; ``b``/``d`` is ``None`` for a tensor or
    number operand (exact zero dual part).
    """
    out: dict[str, tuple] = {}
    for name, v in zip(names, (x, y), strict=True):
        if isinstance(v, Dual):
            out[name] = (v.real, v.dual)
        elif isinstance(v, Tensor):
            out[name] = (_checks.tensor(fn, name, v), None)
        elif not _is_number(v):
            _checks.fail(fn, f"expected a Dual, a tensor or a real number for {name}, "
                             f"got {type(v).__name__}", TypeError)
    if not out:
        _checks.fail(fn, f"expected a Dual or a tensor for {names[0]} or {names[1]}, "
                         f"got two numbers", TypeError)
    if len(out) == 2:
        (na, (a, _)), (nc, (c, _)) = out.items()
        _checks.same_dtype_device(fn, **{na: a, nc: c})
        if a.shape != c.shape:
            _checks.broadcast_batch(fn, **{na: (a, 0), nc: (c, 0)})
    like = next(iter(out.values()))[0]
    for name, v in zip(names, (x, y), strict=True):
        if name not in out:
            out[name] = (_as_like(float(v), like), None)
    return (*out[names[0]], *out[names[1]])


def _dual(fn: str, x) -> Dual:
    if not isinstance(x, Dual):
        _checks.fail(fn, f"expected a Dual for x, got {type(x).__name__}", TypeError)
    return x


def _blow_up(u: Tensor, limit: float | Tensor) -> Tensor:
    r"""``u * limit`` for an infinite derivative ``limit``, exactly 0 where ``u == 0``.

    Used on the singular elements only, as a constant (no gradient): a zero dual component
    contributes 0, never ``0 * inf = NaN``; a non-zero one gives :math:`\pm\infty`, a NaN
    stays NaN.
    """
    return torch.where(u == 0, 0.0, u.detach() * limit)


def _guard(regular: Tensor, singular: Tensor, blow_up: Tensor) -> Tensor:
    """``regular`` off ``singular``, ``blow_up`` on it.

    ``regular`` must have been computed from *safe* inputs (the singular real parts
    replaced by a harmless value first), so that its unselected elements are finite and
    reverse mode sends no ``0 * inf`` into the gradients.
    """
    return torch.where(singular, blow_up, regular)


def _mul(a: Tensor, b: Tensor | None, c, d: Tensor | None) -> Dual:
    r"""Unchecked :math:`(a + \epsilon b)(c + \epsilon d) = ac + \epsilon (ad + bc)`."""
    if b is None and d is None:
        return _new(a * c, None)
    if d is None:
        return _new(a * c, b * c)
    if b is None:
        return _new(a * c, a * d)
    return _new(a * c, a * d + b * c)


def _div(a, b: Tensor | None, c: Tensor, d: Tensor | None) -> Dual:
    r"""Unchecked :math:`(a + \epsilon b) / (c + \epsilon d)`; ``None`` = zero dual part."""
    real = a / c
    if b is None and d is None:
        return _new(real, None)
    singular = c == 0
    c_safe = torch.where(singular, torch.ones_like(c), c)
    # Regular elements: (b - (a / c) d) / c, torch's own forward-mode formula for a / c.
    if d is None:
        assert b is not None  # b and d are not both None (returned above)
        regular, blow_up = b / c_safe, _blow_up(b, 1.0 / c.detach())
    else:
        num = -(a / c_safe) * d if b is None else b - (a / c_safe) * d
        regular = num / c_safe
        # c = 0: b / c + d (-a / c^2) term by term, -sign(a d) inf (NaN if a = 0 too).
        a0 = _as_like(a, c).detach()
        blow_up = _blow_up(d, -a0 / c.detach().square())
        if b is not None:
            blow_up = blow_up + _blow_up(b, 1.0 / c.detach())
    return _new(real, _guard(regular, singular, blow_up))


# -- public functions ----------------------------------------------------------------------


def mul(a: Dual | Tensor | float, b: Dual | Tensor | float) -> Dual:
    r"""Product :math:`(a_r + \epsilon a_d)(b_r + \epsilon b_d)
    = a_r b_r + \epsilon (a_r b_d + a_d b_r)`.

    Args:
        a: ``Dual``, floating tensor or Python number.
        b: ``Dual``, floating tensor or Python number, broadcastable with ``a`` and of the
            same dtype and device (not both numbers). A tensor or number ``c`` stands for
            :math:`c + \epsilon 0`.

    Returns:
        ``Dual`` of the broadcast shape.

    Example:
        >>> mul(Dual(torch.tensor(2.0), 1.0), Dual(torch.tensor(3.0), 4.0))
        Dual(real=tensor(6.), dual=tensor(11.))
    """
    return _mul(*_parts("dual.mul", ("a", "b"), a, b))


def div(a: Dual | Tensor | float, b: Dual | Tensor | float) -> Dual:
    r"""Quotient :math:`\frac{a_r + \epsilon a_d}{b_r + \epsilon b_d}
    = \frac{a_r}{b_r} + \epsilon \frac{a_d b_r - a_r b_d}{b_r^2}`.

    Only dual numbers with a non-zero real part are invertible. Where :math:`b_r = 0` the
    real part is :math:`a_r / 0` (:math:`\pm\infty`, or NaN if :math:`a_r = 0`) and the
    dual part is :math:`a_d / b_r - b_d a_r / b_r^2` term by term, a term with a zero
    factor :math:`a_d` or :math:`b_d` being exactly 0 and the other one infinite
    (:math:`a_d / (\pm 0) = \pm\infty` by the sign of the zero,
    :math:`-b_d a_r / 0 = -\operatorname{sign}(a_r b_d)\,\infty`, NaN if :math:`a_r = 0`).
    So a quotient of two real numbers stays real: :math:`x / 0 = \pm\infty + \epsilon 0`.
    Only that element is affected, and the gradients of the dual part stay finite there
    when :math:`a_d = b_d = 0`.

    Args:
        a: ``Dual``, floating tensor or Python number (dividend).
        b: ``Dual``, floating tensor or Python number (divisor), broadcastable with ``a``
            and of the same dtype and device (not both numbers).

    Returns:
        ``Dual`` of the broadcast shape.

    Example:
        >>> div(Dual(torch.tensor(6.0), 1.0), Dual(torch.tensor(2.0), 1.0))
        Dual(real=tensor(3.), dual=tensor(-1.))
    """
    ar, ad, br, bd = _parts("dual.div", ("a", "b"), a, b)
    return _div(ar, ad, br, bd)


def inv(x: Dual) -> Dual:
    r"""Inverse :math:`(a + \epsilon b)^{-1} = \frac{1}{a} - \epsilon \frac{b}{a^2}
    = \frac{1}{a^2}(a - \epsilon b)`.

    At :math:`a = 0` (not invertible): real part :math:`1/a = \pm\infty` (by the sign of
    the zero); dual part 0 if :math:`b = 0`, else :math:`-\operatorname{sign}(b)\,\infty`.

    Args:
        x: ``Dual``.

    Example:
        >>> inv(Dual(torch.tensor(2.0), 1.0))
        Dual(real=tensor(0.5000), dual=tensor(-0.2500))
    """
    a, b = _dual("dual.inv", x)
    real = torch.reciprocal(a)
    singular = a == 0
    r_safe = torch.reciprocal(torch.where(singular, torch.ones_like(a), a))
    # (b / a) / a: no square of a tiny (1e-200) a overflows, none of a huge one underflows
    return Dual._make(real, _guard(-(b * r_safe) * r_safe, singular, _blow_up(b, -_INF)))


def conj(x: Dual) -> Dual:
    r"""Conjugate :math:`a - \epsilon b` (so that :math:`x \bar x = a^2`).

    Args:
        x: ``Dual``.

    Example:
        >>> conj(Dual(torch.tensor(1.0), 2.0))
        Dual(real=tensor(1.), dual=tensor(-2.))
    """
    return _dual("dual.conj", x).conj()


def apply(f: Callable[[Tensor], Tensor], df: Callable[[Tensor], Tensor], x: Dual) -> Dual:
    r"""The dual extension of an analytic function, :math:`f(a) + \epsilon\, b f'(a)`.

    Computed literally as ``Dual(f(x.real), x.dual * df(x.real))``: where ``df`` is
    infinite, a zero dual part gives NaN (``0 * inf``). Guard such points inside ``df`` or
    use the dedicated functions of this module.

    Args:
        f: elementwise function of a tensor.
        df: its derivative.
        x: ``Dual``.

    Returns:
        ``Dual`` (``f`` and ``df`` results broadcast against each other).

    Example:
        >>> apply(torch.sinh, torch.cosh, Dual(torch.tensor(0.0), 2.0))
        Dual(real=tensor(0.), dual=tensor(2.))
    """
    for name, g in (("f", f), ("df", df)):
        if not callable(g):
            _checks.fail("dual.apply", f"expected a callable for {name}, "
                                       f"got {type(g).__name__}", TypeError)
    a, b = _dual("dual.apply", x)
    return Dual(f(a), b * df(a))


def sincos(x: Dual) -> tuple[Dual, Dual]:
    r"""Dual sine and cosine together (paper section 2.2):

    .. math::
        \sin(a + \epsilon b) = \sin a + \epsilon\, b \cos a, \qquad
        \cos(a + \epsilon b) = \cos a - \epsilon\, b \sin a.

    In eager reverse mode a custom ``torch.autograd.Function`` evaluates ``sin a`` and
    ``cos a`` once and saves only ``a`` and ``b`` for the backward (twice differentiable).
    Under ``torch.func`` transforms (``jvp``, ``hessian``, ``vmap``, ...) and forward-mode
    AD the same formulas run as plain torch ops, differentiable to every order in every
    mode (nested ``jvp`` included).

    Args:
        x: ``Dual`` angle (radians).

    Returns:
        ``(sin x, cos x)``, two ``Dual`` of ``x``'s shape.

    Example:
        >>> s, c = sincos(Dual(torch.tensor(0.0), 2.0))
        >>> s, c
        (Dual(real=tensor(0.), dual=tensor(2.)), Dual(real=tensor(1.), dual=tensor(-0.)))
    """
    a, b = _dual("dual.sincos", x)
    if _dispatch.fused_path(a, b):
        s, s_d, c, c_d = SinCos.apply(a, b)
    else:
        s, s_d, c, c_d = _sincos(a, b)
    return Dual._make(s, s_d), Dual._make(c, c_d)


def _sincos(a: Tensor, b: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``(sin a, b cos a, cos a, -b sin a)`` in plain torch ops (reference of
    :class:`~torch_dq._kernels.sincos.SinCos`)."""
    s, c = torch.sin(a), torch.cos(a)
    return s, b * c, c, -b * s


def sin(x: Dual) -> Dual:
    r"""Dual sine, :math:`\sin a + \epsilon\, b \cos a` (paper section 2.2).

    Args:
        x: ``Dual`` angle (radians).

    Example:
        >>> sin(Dual(torch.tensor(0.0), 2.0))
        Dual(real=tensor(0.), dual=tensor(2.))
    """
    return sincos(_dual("dual.sin", x))[0]


def cos(x: Dual) -> Dual:
    r"""Dual cosine, :math:`\cos a - \epsilon\, b \sin a` (paper section 2.2).

    Args:
        x: ``Dual`` angle (radians).

    Example:
        >>> cos(Dual(torch.tensor(0.0), 2.0))
        Dual(real=tensor(1.), dual=tensor(-0.))
    """
    return sincos(_dual("dual.cos", x))[1]


def tan(x: Dual) -> Dual:
    r"""Dual tangent, :math:`\tan a + \epsilon\, b (1 + \tan^2 a)`.

    Args:
        x: ``Dual`` angle (radians).

    Example:
        >>> tan(Dual(torch.tensor(0.0), 2.0))
        Dual(real=tensor(0.), dual=tensor(2.))
    """
    a, b = _dual("dual.tan", x)
    t = torch.tan(a)
    return Dual._make(t, b * (1.0 + t * t))


def acos(x: Dual) -> Dual:
    r"""Dual arc cosine, :math:`\arccos a - \epsilon \frac{b}{\sqrt{1 - a^2}}`.

    The real part is in :math:`[0, \pi]`. At :math:`a = \pm 1` the derivative is
    :math:`-\infty`: the dual part is exactly 0 if :math:`b = 0` (with finite gradients)
    and :math:`-\operatorname{sign}(b)\,\infty` otherwise. For :math:`|a| > 1` both parts
    are NaN, like ``torch.acos``. :math:`1 - a^2` is formed as :math:`(1 - a)(1 + a)`, exact
    to rounding near :math:`|a| = 1` (``1 - a * a`` loses ``eps / (1 - |a|)`` relatively).

    Args:
        x: ``Dual`` cosine, real part in :math:`[-1, 1]`.

    Example:
        >>> acos(Dual(torch.tensor(0.0), 1.0))
        Dual(real=tensor(1.5708), dual=tensor(-1.))
    """
    a, b = _dual("dual.acos", x)
    singular = a.abs() == 1
    a_safe = torch.where(singular, torch.zeros_like(a), a)
    regular = b * -torch.rsqrt((1.0 - a_safe) * (1.0 + a_safe))  # exact near |a| = 1
    return Dual._make(torch.acos(a), _guard(regular, singular, _blow_up(b, -_INF)))


def atan2(y: Dual | Tensor | float, x: Dual | Tensor | float) -> Dual:
    r"""Dual two-argument arc tangent, the angle of the point :math:`(x, y)`:

    .. math::
        \operatorname{atan2}(y_r, x_r)
        + \epsilon\, \frac{x_r y_d - y_r x_d}{x_r^2 + y_r^2}.

    At the origin :math:`x_r = y_r = 0` the real part is ``torch.atan2``'s (0 or
    :math:`\pm\pi` by the signs of the zeros) and the angle jumps to
    :math:`\varphi = \operatorname{atan2}(y_d, x_d)` as soon as the point moves along the
    dual direction: the dual part is exactly 0 if :math:`\varphi = 0` (in particular if
    :math:`x_d = y_d = 0`, with finite gradients), else
    :math:`\operatorname{sign}(\varphi)\,\infty`.

    Args:
        y: ``Dual``, floating tensor or Python number (ordinate).
        x: ``Dual``, floating tensor or Python number (abscissa), broadcastable with ``y``
            and of the same dtype and device (not both numbers).

    Returns:
        ``Dual`` of the broadcast shape, real part in :math:`[-\pi, \pi]`.

    Example:
        >>> atan2(Dual(torch.tensor(1.0), 1.0), Dual(torch.tensor(1.0), 0.0))
        Dual(real=tensor(0.7854), dual=tensor(0.5000))
    """
    ya, yd, xa, xd = _parts("dual.atan2", ("y", "x"), y, x)
    real = torch.atan2(ya, xa)
    singular = (xa == 0) & (ya == 0)
    # Scaled by a power of two (exact): x^2 + y^2 neither overflows (1e200) nor underflows.
    s = power_of_two_scale(torch.stack(torch.broadcast_tensors(xa, ya), -1))[..., 0]
    xs, ys = xa / s, ya / s
    r2_safe = torch.where(singular, torch.ones_like(real), xs * xs + ys * ys)
    num = None
    if yd is not None:
        num = xs * yd
    if xd is not None:
        num = -(ys * xd) if num is None else num - ys * xd
    if num is None:
        return _new(real, None)
    # At the origin num is 0 (both real parts vanish): the regular branch is finite there.
    regular = num / r2_safe / s
    zero = torch.zeros_like(real)
    phi = torch.atan2(zero if yd is None else yd.detach(), zero if xd is None else xd.detach())
    jump = torch.where(phi == 0, zero, phi * _INF)
    return _new(real, torch.where(singular, jump, regular))


def sqrt(x: Dual) -> Dual:
    r"""Dual square root, :math:`\sqrt a + \epsilon \frac{b}{2 \sqrt a}`.

    At :math:`a = 0` the dual part is exactly 0 if :math:`b = 0` (with finite gradients)
    and :math:`\operatorname{sign}(b)\,\infty` otherwise (the derivative's limit from
    :math:`a > 0`). For :math:`a < 0` both parts are NaN, like ``torch.sqrt``.

    Args:
        x: ``Dual``, real part :math:`\ge 0`.

    Example:
        >>> sqrt(Dual(torch.tensor(4.0), 1.0))
        Dual(real=tensor(2.), dual=tensor(0.2500))
    """
    a, b = _dual("dual.sqrt", x)
    root = torch.sqrt(a)
    singular = a == 0
    root_safe = torch.sqrt(torch.where(singular, torch.ones_like(a), a))
    return Dual._make(root, _guard(b / (2.0 * root_safe), singular, _blow_up(b, _INF)))


def exp(x: Dual) -> Dual:
    r"""Dual exponential, :math:`e^a + \epsilon\, b\, e^a`.

    Where :math:`e^a` overflows to :math:`\infty` the dual part is :math:`b \cdot \infty`
    (NaN where :math:`b = 0`), as for ``torch.func.jvp(torch.exp, ...)``.

    Args:
        x: ``Dual``.

    Example:
        >>> exp(Dual(torch.tensor(0.0), 2.0))
        Dual(real=tensor(1.), dual=tensor(2.))
    """
    a, b = _dual("dual.exp", x)
    e = torch.exp(a)
    return Dual._make(e, b * e)


def log(x: Dual) -> Dual:
    r"""Dual natural logarithm, :math:`\log a + \epsilon \frac{b}{a}`.

    At :math:`a = 0` the real part is :math:`-\infty`; the dual part is exactly 0 if
    :math:`b = 0` (with finite gradients) and :math:`\operatorname{sign}(b)\,\infty`
    otherwise (the derivative's limit from :math:`a > 0`). For :math:`a < 0` the real part
    is NaN and the dual part :math:`b / a` (as ``torch.func.jvp(torch.log, ...)``).

    Args:
        x: ``Dual``, real part :math:`> 0`.

    Example:
        >>> log(Dual(torch.tensor(1.0), 2.0))
        Dual(real=tensor(0.), dual=tensor(2.))
    """
    a, b = _dual("dual.log", x)
    singular = a == 0
    a_safe = torch.where(singular, torch.ones_like(a), a)
    return Dual._make(torch.log(a), _guard(b / a_safe, singular, _blow_up(b, _INF)))


_pytree.register_pytree_node(
    Dual,
    lambda x: ([x.real, x.dual], None),
    lambda parts, _: Dual._make(*parts),
    serialized_type_name="torch_dq.dual.Dual",
)

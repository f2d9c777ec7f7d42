r"""Unchecked building blocks shared by every module (private).

The bottom of the import ladder (``_numerics``, ``_checks`` and this module, then ``dual ->
quat -> dualquat -> curves -> nn``): products, conjugates, rotations, translations, sign
alignment (hemispheres, chains), the twist translation and the immutable value base, on
plain tensors with no argument checks. Public modules call these instead of reaching into
each other's private names.
"""

from __future__ import annotations

import weakref

import torch
from torch import Tensor

from ._checks import broadcast_shapes
from ._numerics import compute_dtype, even, may_hold

__all__ = [
    "Frozen", "align", "align_chain", "aligned_chain", "canonical", "distinct", "dq_from_rt",
    "dq_mul", "hemisphere", "join", "lift", "lower", "qconj", "qmul", "qrotate", "split",
    "translation", "twist_translation",
]


def lift(x: Tensor) -> Tensor:
    """``x`` in its compute dtype (float16/bfloat16 compute in float32): ``x`` itself when
    it is float32 or float64 (as ``x.to`` returns it, without its per-call cost)."""
    return x if x.dtype in _COMPUTE else x.to(compute_dtype(x.dtype))


def lower(x: Tensor, dtype: torch.dtype) -> Tensor:
    """``x`` back in the caller's ``dtype`` (the inverse of :func:`lift`): ``x`` itself when
    it already has it (as ``x.to`` returns it, without its per-call cost)."""
    return x if x.dtype == dtype else x.to(dtype)


_COMPUTE = (torch.float32, torch.float64)


# ----------------------------------------------------------------------------- quaternions

def qmul(a: Tensor, b: Tensor) -> Tensor:
    r"""Hamilton product of ``(..., 4)`` quaternions ``(w, x, y, z)``. (The vector form,
    :math:`(a_w b_w - a_v \cdot b_v,\ a_w b_v + b_w a_v + a_v \times b_v)`, has fewer tensor
    ops but was 1.3-1.9x slower from 5,000 to 36,000 products, the estimation's sizes.)"""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def qconj(q: Tensor) -> Tensor:
    """Quaternion conjugate ``(w, -x, -y, -z)``."""
    return q * q.new_tensor([1.0, -1.0, -1.0, -1.0])


def qrotate(q: Tensor, v: Tensor) -> Tensor:
    r"""``q v q*`` for a unit ``q``: :math:`v + w t + u \times t` with :math:`t = 2 u \times v`.

    ``q (..., 4)`` and ``v (..., 3)`` broadcast across any numbers of batch dims.
    """
    shape = (*broadcast_shapes(q.shape[:-1], v.shape[:-1]), 3)
    w, u, v = q[..., :1], q[..., 1:].expand(shape), v.expand(shape)
    t = 2.0 * torch.linalg.cross(u, v, dim=-1)
    return v + w * t + torch.linalg.cross(u, t, dim=-1)


def canonical(q: Tensor) -> Tensor:
    """``q`` or ``-q``, whichever has its first non-zero component (w, x, y, z) positive.

    This is scipy's canonical form: ``w >= 0``, ties at ``w = 0`` broken by x, then y, z.
    The first component that is not zero (``-0.0`` counts as zero; a NaN stops the search
    and flips nothing) is found with one ``argmax`` over ``q != 0``, eager on the CPU only
    where some ``w`` is zero (elsewhere it is ``w``).
    """
    lead = q[..., :1]
    if may_hold(lead == 0):
        lead = torch.gather(q, -1, (q != 0).to(torch.uint8).argmax(-1, keepdim=True))
    return q * torch.where(lead < 0, -1.0, 1.0)  # exact (a where over q is 3x slower on CPU)


# ----------------------------------------------------------------------------- dual quaternions

def split(x: Tensor) -> tuple[Tensor, Tensor]:
    """Real and dual quaternion halves of ``(..., 8)`` as views."""
    return x[..., :4], x[..., 4:]


def join(r: Tensor, d: Tensor) -> Tensor:
    """``(..., 8)`` from real and dual halves (broadcast against each other)."""
    r, d = torch.broadcast_tensors(r, d)
    return torch.cat((r, d), dim=-1)


def dq_mul(a: Tensor, b: Tensor) -> Tensor:
    """Dual-quaternion product :math:`(r_a r_b, r_a d_b + d_a r_b)`."""
    ra, da = split(a)
    rb, db = split(b)
    return join(qmul(ra, rb), qmul(ra, db) + qmul(da, rb))


def translation(r: Tensor, d: Tensor) -> Tensor:
    """Translation ``t = 2 vec(d r*)`` of a unit dual quaternion ``(r, d)``."""
    return 2.0 * qmul(d, qconj(r))[..., 1:]


def dq_from_rt(r: Tensor, t: Tensor) -> Tensor:
    """``(r, 0.5 (0, t) r)`` for a unit quaternion ``r`` and a translation ``t``."""
    t0 = torch.cat((torch.zeros_like(t[..., :1]), t), dim=-1)
    return join(r, 0.5 * qmul(t0, r))


def hemisphere(x: Tensor, ref: Tensor) -> Tensor:
    """``(...)``: -1 where the dot of the rotation quaternions (the first 4 components) of
    ``x`` and ``ref`` (``(..., 4)`` or ``(..., 8)``, broadcast) is negative, else 1 (``-0.0``
    counts as positive), in ``x``'s dtype: the sign that takes ``x`` to its representative
    (``x`` and ``-x`` are the same rotation or pose) on ``ref``'s side."""
    return torch.where((x[..., :4] * ref[..., :4]).sum(-1) < 0, -1.0, 1.0).to(x.dtype)


def align(x: Tensor, ref: Tensor) -> Tensor:
    """The representative ``+-x`` nearest to ``ref`` (:func:`hemisphere`)."""
    return x * hemisphere(x, ref)[..., None]


def align_chain(x: Tensor) -> Tensor:
    """Sign-align a sequence ``(..., N, 8)`` so that each element's real part has a
    non-negative dot with its predecessor's (same poses, continuous representatives)."""
    flips = torch.cumprod(hemisphere(x[..., 1:, :], x[..., :-1, :]), dim=-1)
    return torch.cat((x[..., :1, :], x[..., 1:, :] * flips[..., None]), dim=-2)


#: ``(control points (weak), their version, chain, its version)`` of :func:`aligned_chain`
_LAST_CHAIN: tuple | None = None


def aligned_chain(ctrl: Tensor) -> Tensor:
    """:func:`align_chain` of ``ctrl (..., n, 8)``, kept for the last control points aligned
    while neither they nor the chain change (same tensor, same version) and they need no
    gradient: the estimation reads the chain of the same points once per part of a long
    record (its costs, spans and windows; ``torch_dq._curve.span_points``), an O(n) pass each
    that made an hour's record pay quadratically (136 a cost and system). Callers do not
    modify the chain in place (a modified chain is not reused)."""
    global _LAST_CHAIN
    if torch.compiler.is_compiling() or ctrl.requires_grad or ctrl.is_inference():
        return align_chain(ctrl)
    last = _LAST_CHAIN
    if last is not None and last[0]() is ctrl and last[1] == ctrl._version \
            and last[3] == last[2]._version:
        return last[2]
    out = align_chain(ctrl)
    _LAST_CHAIN = (weakref.ref(ctrl), ctrl._version, out, out._version)
    return out


def twist_translation(omega: Tensor, t: Tensor) -> Tensor:
    r"""Linear part of the twist, :math:`v = V(\omega)^{-1} t`, for angles in ``[0, 2 pi)``.

    :math:`v = t - \frac12 \omega \times t + c_3\,\omega \times (\omega \times t)` with
    :math:`c_3 = (1 - \frac\theta2 \cot\frac\theta2)/\theta^2`, evaluated from
    :math:`\theta^2 = |\omega|^2` (series near 0: smooth to every order at ``omega = 0``).
    ``omega (..., 3)`` and ``t (..., 3)`` broadcast.
    """
    omega, t = torch.broadcast_tensors(omega, t)
    c3 = even("se3_c3", (omega * omega).sum(-1, keepdim=True))
    wxt = torch.linalg.cross(omega, t, dim=-1)
    return t - 0.5 * wxt + c3 * torch.linalg.cross(omega, wxt, dim=-1)


class Frozen:
    """Base of the immutable value types (:class:`~torch_dq.dual.Dual`,
    :class:`~torch_dq.object.DualQuaternion`): their constructors set each slot once with
    ``object.__setattr__``; setting or deleting an attribute afterwards raises."""

    __slots__ = ()

    def __setattr__(self, name, value):
        raise AttributeError(f"{type(self).__name__} is immutable: cannot set {name!r}")

    def __delattr__(self, name):
        raise AttributeError(f"{type(self).__name__} is immutable: cannot delete {name!r}")


def distinct(x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The distinct values ``u (U,)`` of ``x (N,)``, ``inverse (N,)`` (``x = u[inverse]``) and
    the index ``pick (U,)`` of one element holding each."""
    u, inverse = torch.unique(x, return_inverse=True)
    pick = torch.zeros_like(u, dtype=torch.int64).scatter_(
        0, inverse, torch.arange(x.numel(), device=x.device))
    return u, inverse, pick

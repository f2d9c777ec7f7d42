"""The cumulative form's vector-Jacobian products and evaluation in compiled C (private):
``csrc/cumulative_lie.c``, one loop over samples with everything per sample in local arrays,
behind ``torch_dq._cumulative_lie.vjp`` and ``torch_dq._cumulative_lie.derivatives`` (the
readable references, which run where :func:`applies` does not hold; the tests compare
both, ``tests/test_native17_cumulative_lie.py``).

The even functions' series coefficients and switch points are passed to the C from
``torch_dq._numerics`` (``_even_table``), so both paths take the same branch with the
same series.
"""

from __future__ import annotations

import ctypes
from functools import cache

import torch
from torch import Tensor

from .. import _numerics
from . import native

__all__ = ["MAX_STEPS", "applies", "derivatives", "vjp"]

#: The most steps per span (the degree) of the compiled loops (``MAXP`` of the C); higher
#: degrees take the PyTorch path.
MAX_STEPS = 8

_P, _I = ctypes.c_void_p, ctypes.c_int64
_EVENS = ("cos", "sinc", "se3_c1", "se3_c2")  # the C's rows EV_COS, EV_SINC, EV_C1, EV_C2


def applies(steps: int, *tensors: Tensor) -> bool:
    """Whether the compiled loops may run: at most :data:`MAX_STEPS` steps and
    ``torch_dq._kernels.native.enabled`` (the library is there, float64 CPU tensors, eager,
    no tensor recording autograd: reverse mode goes through the PyTorch code)."""
    return steps <= MAX_STEPS and native.enabled(*tensors)


_VJP = ("tdq_lie_vjp", (_P, _I, _I, _P, _I, _P, _I, _P, _P, _I, _P, _P, _P, _P), ctypes.c_int)
_DERIVATIVES = ("tdq_lie_derivatives", (_P, _P, _P, _I, _I, _P, _I, _P, _P))


@cache
def _even_table() -> Tensor:
    """``(4, 9)``: per function of ``_EVENS`` its series coefficients :math:`c_0 \\dots c_7`
    and its switch point in :math:`x_2` (``_numerics.even``'s, float64)."""
    rows = []
    for name in _EVENS:
        coeffs = _numerics._EVEN[name][0]
        switch = _numerics.threshold("even_series", torch.float64, coeffs[-1])
        rows.append([*coeffs[:-1], switch])
    return torch.tensor(rows, dtype=torch.float64)


def vjp(span: Tensor, inverse: Tensor, weights: list[Tensor], cot: Tensor, pose: Tensor,
        second: slice | None) -> Tensor:
    """``torch_dq._cumulative_lie.vjp`` (the same arguments) by the compiled loop:
    ``(S, k, p + 1, 6)``, contiguous (``cot`` read in place through its strides)."""
    p, U = span.shape[1], span[0].numel() // span.shape[1]
    S, k, O = cot.shape[:3]
    span, pose, inverse = span.contiguous(), pose.contiguous(), inverse.long().contiguous()
    strides = (ctypes.c_int64 * 4)(*cot.stride())  # read in place (the callers' are
    # component-major views: a copy would cost a fifth of the loop)
    lam = torch.stack(weights)  # (O, S, p)
    rows = bytes(int(i in range(k)[slice(None) if second is None else second])
                 for i in range(k))
    out = cot.new_empty(S, k, p + 1, 6)
    table = _even_table()
    failed = native.function(*_VJP)(
        native.address(span), p, U, native.address(inverse), S, native.address(lam), O,
        ctypes.c_void_p(cot.data_ptr()), strides, k, native.address(pose), rows,
        native.address(table), native.address(out))
    if failed:
        raise MemoryError("torch_dq: no memory for the compiled vjp's scratch arrays")
    return out


def derivatives(ctrl: Tensor, first: Tensor, twists: Tensor, weights: list[Tensor],
                ) -> list[Tensor]:
    """``torch_dq._cumulative_lie.derivatives`` by the compiled loop, from the times' span
    twists ``(6, p, N)`` (``_pair_twists``): ``order + 1`` tensors ``(N, 8)``."""
    p, N = twists.shape[1:]
    ctrl, first, twists = ctrl.contiguous(), first.long().contiguous(), twists.contiguous()
    lam = torch.stack(weights)  # (O, p, N)
    out = ctrl.new_empty(len(weights), N, 8)
    table = _even_table()
    native.function(*_DERIVATIVES)(
        native.address(ctrl), native.address(first), native.address(twists), p, N,
        native.address(lam), len(weights), native.address(table), native.address(out))
    return list(out.unbind(0))

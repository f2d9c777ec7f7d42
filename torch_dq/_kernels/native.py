"""The compiled kernels (private, optional): plain C loops over float64 arrays in the shared
library ``torch_dq._kernels._native`` (sources in ``torch_dq/_kernels/csrc``, built by
``setup.py`` where a C compiler is found), called through :mod:`ctypes` with the arrays'
addresses.

Each compiled function computes what a PyTorch kernel beside it computes, to rounding, and
is taken only where that kernel would run on contiguous float64 CPU tensors outside autograd
and ``torch.compile``; everywhere else (no compiler at install, another dtype or device, the
environment variable ``TORCH_DQ_NATIVE=0``) the PyTorch kernel runs. The tests run both and
compare them.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
from collections.abc import Callable
from functools import cache
from typing import Any

import torch
from torch import Tensor

__all__ = ["address", "enabled", "function", "library"]


@cache
def _load() -> ctypes.CDLL | None:
    spec = importlib.util.find_spec(f"{__package__}._native")
    if spec is None or spec.origin is None:
        return None
    try:
        return ctypes.CDLL(spec.origin)
    except OSError:
        return None


def library() -> ctypes.CDLL | None:
    """The compiled library, or None where it was not built or ``TORCH_DQ_NATIVE=0``."""
    if os.environ.get("TORCH_DQ_NATIVE", "1") == "0":
        return None
    return _load()


@cache
def function(name: str, argtypes: tuple, restype: type | None = None) -> Callable[..., Any]:
    """The compiled function ``name`` with its argument and result types declared (once per
    name; call it only where :func:`enabled` held: raises where the library is not there)."""
    lib = library()
    if lib is None:
        raise RuntimeError(f"torch_dq: {name}: the compiled kernels are not available")
    f = getattr(lib, name)
    f.argtypes, f.restype = list(argtypes), restype
    return f


def enabled(*tensors: Tensor) -> bool:
    """Whether the compiled kernels may run on ``tensors``: the library is there, every
    tensor is float64 (or an integer index) on the CPU, nothing is traced or compiled, and
    none needs a gradient (autograd recording and a tensor that requires one)."""
    return (library() is not None and not torch.compiler.is_compiling()
            and all(t.device.type == "cpu"
                    and (t.dtype == torch.float64 or not t.is_floating_point())
                    for t in tensors)
            and not (torch.is_grad_enabled() and any(t.requires_grad for t in tensors)))


def address(t: Tensor) -> ctypes.c_void_p:
    """The address of a contiguous tensor's first element (raises for a strided one: the
    compiled loops read arrays densely)."""
    if not t.is_contiguous():
        raise ValueError("the compiled kernels read contiguous tensors")
    return ctypes.c_void_p(t.data_ptr())

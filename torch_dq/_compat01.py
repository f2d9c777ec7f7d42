r"""The 0.1 migration of the curve layers: a standalone converter (deprecated since 0.2).

0.1 layers mapped raw times onto ``[0, 1]`` and saved that map as a ``time_range`` buffer;
since 0.2 a layer's time is the caller's. What 0.1 code still needs, each with a
``DeprecationWarning``:

- loading a 0.1 ``state_dict`` (:func:`is_01`, :func:`upgrade`): the ``time_range``
  buffer becomes the extra state of a 0.2+ layer (its origin, and a Bézier's length or a
  B-spline's relative knots);
- the constructors' ``time_range=`` (:func:`time_range_knots` for a B-spline's knots);
- ``normalize_time`` (now the identity) and ``time_range`` (the ``domain`` as a tensor), kept
  on :class:`torch_dq.nn.Curve` through :func:`deprecated` and :func:`domain_tensor`.

This module knows the 0.1 formats and nothing of the layers beyond the arguments it is given.
"""

from __future__ import annotations

import warnings
from typing import Any

import torch
from torch import Tensor

from . import curves
from ._time import time_pair

__all__ = ["deprecated", "domain_tensor", "is_01", "time_range_knots", "upgrade"]


def deprecated(what: str, instead: str, stacklevel: int = 3) -> None:
    """Warn that ``what`` is deprecated (``DeprecationWarning``), saying what to do instead."""
    warnings.warn(f"{what} is deprecated: {instead}", DeprecationWarning,
                  stacklevel=stacklevel)


def is_01(state_dict: dict[str, Any], prefix: str) -> bool:
    """Whether ``state_dict`` (under ``prefix``) is a 0.1 layer's: a ``time_range`` buffer
    and no extra state."""
    return prefix + "time_range" in state_dict and prefix + "_extra_state" not in state_dict


def upgrade(name: str, state_dict: dict[str, Any], prefix: str, degree: int | None,
            n: int, dtype: torch.dtype) -> None:
    r"""Rewrite a 0.1 ``state_dict`` in place into the current format (with a warning).

    Args:
        name: the layer's name for the warning (``"nn.BSpline"``).
        state_dict: what ``load_state_dict`` was given; its ``time_range`` ``(start, end)``
            becomes the origin ``start``.
        prefix: the layer's prefix in it.
        degree: ``None`` for a Bézier layer (its length ``end - start`` becomes extra state);
            a B-spline's degree ``p``: its 0.1 ``knots`` (clamped uniform where absent),
            mapped so that ``[u_p, u_n]`` is ``[0, end - start]``, become ``_knots``.
        n: the number of control points.
        dtype: the dtype of the layer's knots.
    """
    warnings.warn(f"{name}.load_state_dict: converting a 0.1 state_dict (time_range) to the "
                  f"caller's time; save it again to update it", DeprecationWarning,
                  stacklevel=5)
    start, end = (float(v) for v in state_dict.pop(prefix + "time_range").tolist())
    if degree is None:
        state_dict[prefix + "_extra_state"] = {"origin": start, "length": end - start}
        return
    p = degree
    k = state_dict.pop(prefix + "knots", None)
    k = (curves.clamped_uniform_knots(n, p, dtype=torch.float64) if k is None else
         k.detach().to(dtype=torch.float64, device="cpu"))
    k = (k - k[p]) * ((end - start) / float(k[n] - k[p]))  # time since start
    state_dict[prefix + "_knots"] = k.to(dtype)
    state_dict[prefix + "_extra_state"] = {"origin": start}


def time_range_knots(fn: str, k64: Tensor, degree: int, time_range) -> Tensor:
    """0.1's ``time_range=`` of a B-spline: ``(K,)`` float64 knots mapped affinely so that
    the domain ``[u_p, u_n]`` is ``time_range`` (with a ``DeprecationWarning``)."""
    deprecated(f"{fn}(time_range=...)", "pass knots in the caller's time (or build with "
                                        "from_poses)")
    span = time_pair(fn, "time_range", time_range)
    n = k64.shape[0] - degree - 1
    lo, hi = k64[degree], k64[n]
    k64 = span[0] + (k64 - lo) * ((span[1] - span[0]) / (hi - lo))
    k64[degree], k64[n] = span  # exact ends
    return k64


def domain_tensor(domain: tuple[float, float] | tuple[Tensor, Tensor],
                  device: torch.device) -> Tensor:
    """0.1's ``time_range``: a layer's ``domain`` as a float64 ``(2,)`` tensor (``(..., 2)``
    for a row per trajectory)."""
    if isinstance(domain[0], Tensor):
        return torch.stack(torch.broadcast_tensors(*domain), -1)
    return torch.tensor(domain, dtype=torch.float64, device=device)

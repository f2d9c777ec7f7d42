r"""Random-walk IMU biases for :func:`~torch_dq.calibration.camera_imu` (private).

The bias is piecewise constant: one ``(3,)`` value per segment of the IMU log (``K``
segments of equal length ``h``, about ``bias_interval`` seconds), each an estimated
nuisance parameter of the term (``"bias"`` for segment 0, ``"bias_1"`` .. ``"bias_{K-1}"``
for the others). Consecutive values are tied by the random walk's prior: a bias that is a
Wiener process of intensity :math:`\sigma_w^2` (Kalibr's ``gyroscope_random_walk``,
``accelerometer_random_walk``: rad/s²/√Hz, m/s³/√Hz) has segment means whose difference
over adjacent segments of length ``h`` has the variance
:math:`\frac{1}{h^2}\int_0^h\!\int_0^h \sigma_w^2 (h - |s - u|)\,ds\,du = \tfrac{2}{3}
\sigma_w^2 h` per axis, so each tie is the residual
:math:`(b_{k+1} - b_k) / (\sigma_w \sqrt{2 h / 3})`.

The ties are rows of the term itself (``K - 1`` pseudo-samples at the segment boundaries,
reading zero, their residual the tie instead of the IMU's prediction): the estimate's
chi2 and degrees of freedom of the term count them, and no change of the solver is needed
(a term's residuals may read any of its nuisance parameters). Between segment means, the
walk's variation within a segment is not modelled (its deviation from the segment mean has
the variance :math:`\sigma_w^2 h / 6` averaged over the segment, :math:`\sigma_w^2 h / 3` at
its ends): ``h`` should keep it below the segment mean's uncertainty from the readings'
white noise of density :math:`\sigma_n`, :math:`\sigma_n / \sqrt{h}`, that is
:math:`h \le \sqrt{3}\,\sigma_n / \sigma_w` (:func:`~torch_dq.calibration.camera_imu`'s
``bias_interval``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ..fitting import Accel, Free, Gyro
from ..fitting._imu import check_repeated

__all__ = ["WalkAccel", "WalkGyro", "segments"]


def segments(lo: float, hi: float, interval: float) -> Tensor:
    """``K + 1`` equally spaced segment edges over ``[lo, hi]``, ``K = max(1, round((hi -
    lo) / interval))``."""
    k = max(1, round((hi - lo) / interval))
    return torch.linspace(lo, hi, k + 1, dtype=torch.float64)


def _samples(fn: str, times: Tensor, readings: Tensor, edges: Tensor):
    """Times and readings with a zero pseudo-sample at each inner edge (sorted, stable),
    each sample's segment ``(N + K - 1,)`` and the pseudo-samples' mask. The readings'
    times are checked for repeats here: a pseudo-sample may share a reading's time."""
    check_repeated(fn, times, torch.ones_like(times, dtype=torch.bool))
    inner = edges[1:-1]
    t = torch.cat((times, inner))
    order = torch.argsort(t, stable=True)
    seg = (torch.searchsorted(edges, times, right=True) - 1).clamp(0, edges.numel() - 2)
    link = torch.cat((torch.zeros_like(times, dtype=torch.bool),
                      torch.ones_like(inner, dtype=torch.bool)))
    seg = torch.cat((seg, torch.arange(inner.numel())))  # tie k joins segments k and k + 1
    r = torch.cat((readings, readings.new_zeros(inner.numel(), 3)))
    return t[order], r[order], seg[order], link[order]


class _Walk:
    """Mixin of :class:`WalkGyro` and :class:`WalkAccel`: per-segment biases and ties."""

    sigma: Tensor
    _unique_times = False  # the pseudo-samples may share a reading's time (_samples checks)
    segment: Tensor  # (N,) each sample's segment (a tie's: the first of the two)
    link: Tensor  # (N,) bool: the sample is a tie
    _slots: dict

    def _walk(self, fn: str, seg: Tensor, link: Tensor, walk: float, edges: Tensor,
              starts: Tensor) -> None:
        first = self._slots["bias"]  # the fitting's slot (class and chart) of the bias given
        k, h = starts.shape[0], float(edges[1] - edges[0])
        for i in range(1, k):
            self._slots[f"bias_{i}"] = type(first)(fn, f"bias_{i}", first.chart,
                                                   Free(start=starts[i]))
        self._buffer("segment", seg, 0)  # type: ignore[attr-defined]
        self._buffer("link", link, 0)  # type: ignore[attr-defined]
        self.walk_sigma = walk * math.sqrt(2.0 * h / 3.0)
        self.segments = k
        self.edges = edges

    @property
    def names(self) -> list[str]:
        """The segments' bias parameters, in time order."""
        return ["bias"] + [f"bias_{i}" for i in range(1, self.segments)]

    def _pick(self, p: dict[str, Tensor], seg: Tensor) -> Tensor:
        """Each sample's bias of segment ``seg (N,)``, ``(..., N, 3)``, read from the sample's
        own copy of the parameters (``p``: per-sample values; the solver differentiates
        each sample's residual with respect to its own copy)."""
        b = torch.stack(torch.broadcast_tensors(*[p[n] for n in self.names]), -3)
        b = b.expand(*b.shape[:-2], seg.numel(), 3)  # (..., K, N, 3)
        idx = seg[:, None].expand(seg.numel(), 3).reshape((1,) * (b.dim() - 2) + (-1, 3))
        return torch.take_along_dim(b, idx, -3).squeeze(-3)

    def _tied(self, ev, p, residual) -> Tensor:
        per = self._pick(p, self.segment)
        r = residual(ev, {**p, "bias": per})
        nxt = self._pick(p, (self.segment + 1).clamp(max=self.segments - 1))
        tie = (nxt - per) * (self.sigma.to(per.dtype) / self.walk_sigma)
        return torch.where(self.link[:, None], tie, r)


class WalkGyro(_Walk, Gyro):
    r""":class:`~torch_dq.fitting.Gyro` with a piecewise-constant bias tied by a random
    walk (module docstring); ``edges`` ``(K + 1,)`` the segments' edges, ``walk`` the
    random walk's density, ``starts`` ``(K, 3)`` the biases' starts."""

    _fn = "calibration.camera_imu (gyroscope)"

    def __init__(self, times: Tensor, readings: Tensor, *, sigma: float, edges: Tensor,
                 walk: float, starts: Tensor) -> None:
        t, r, seg, link = _samples(self._fn, times, readings, edges)
        super().__init__(t, r, sigma=sigma, bias=Free(start=starts[0]))
        self._walk(self._fn, seg, link, walk, edges, starts)

    def _residual(self, ev, p):
        return self._tied(ev, p, super()._residual)


class WalkAccel(_Walk, Accel):
    r""":class:`~torch_dq.fitting.Accel` with a piecewise-constant bias tied by a random
    walk (as :class:`WalkGyro`); ``gravity`` as :class:`~torch_dq.fitting.Accel`'s."""

    _fn = "calibration.camera_imu (accelerometer)"

    def __init__(self, times: Tensor, readings: Tensor, *, sigma: float, edges: Tensor,
                 walk: float, starts: Tensor, gravity) -> None:
        t, r, seg, link = _samples(self._fn, times, readings, edges)
        super().__init__(t, r, sigma=sigma, bias=Free(start=starts[0]), gravity=gravity)
        self._walk(self._fn, seg, link, walk, edges, starts)

    def _residual(self, ev, p):
        return self._tied(ev, p, super()._residual)

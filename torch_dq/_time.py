r"""The time model of the curves: one object owns a curve's time (private).

A :class:`KnotDomain` holds a curve's knots *relative to* a float64 time origin, its degree,
and the origin itself, and answers every question about time that the curves, the layers,
the least-squares start and the estimation ask:

- :meth:`~KnotDomain.relative`: ``t - origin`` in the wide time dtype (the only place an
  origin is subtracted);
- :meth:`~KnotDomain.admit`, :meth:`~KnotDomain.check` and :meth:`~KnotDomain.outside`:
  the domain rules of the public contract (see below; one tolerance formula,
  :meth:`~KnotDomain.tolerance`; the only place a domain is validated), and
  :func:`unresolved`, the one rule for a time dtype too coarse for the times;
- :meth:`~KnotDomain.span` and :meth:`~KnotDomain.locate`: the knot span of each time and
  its local parameter ``u = (t - u_r) / (u_{r+1} - u_r)`` with the slope ``du/dt``
  (Sophus' ``index_and_u``; the only span search); :meth:`~KnotDomain.de_boor_levels`: the
  local parameters of every level of De Boor's scheme; :meth:`~KnotDomain.local_times`:
  the time since the start of a span;
- :meth:`~KnotDomain.bases` (:func:`span_bases`, the one Cox-de Boor: plain or cumulative
  basis and their time derivatives), :meth:`~KnotDomain.basis` (its plain form, the design
  matrix of the least-squares start and of Gauss-Newton) and :meth:`~KnotDomain.greville`
  (the Greville abscissae).

A Bézier curve of ``n`` control points on ``[0, L]`` is the B-spline of degree ``n - 1`` on
the clamped knots ``(0, ..., 0, L, ..., L)`` (:meth:`KnotDomain.bezier`): one span, whose
local parameter is De Casteljau's ``s = t / L`` and whose basis is Bernstein's.

Shapes: knots ``(K,)`` shared by every trajectory, or ``(B, K)`` (``(..., K)``) with a
``(B, 1)`` origin for a batch of trajectories with their own times; times ``(..., T)``
broadcast against the knots' batch dims. The B-spline *form* (De Boor or cumulative) is not
the time model's business: both forms read the same spans and local parameters.

Domain rules (``docs/api_contract.md``): times outside the domain ``[t0, t1]`` (absolute,
the origin added) by at most
``tol = max(1e-9 (t1 - t0), 4 eps(t.dtype) max(|t0|, |t1|))`` (plus the rounding
of the stored relative knots) are evaluated at the nearest end; with checks on, times further
out raise ``ValueError`` naming the domain and ``extrapolate=True``; with checks skipped
(``check=False``, under ``torch.compile``, on meta tensors) they give NaN, never a silent
extrapolation; with ``extrapolate=True`` the end spans continue (spans are clamped to the
first and last non-empty ones, local parameters run outside ``[0, 1]``).
"""

from __future__ import annotations

import math
import numbers
from typing import Literal, overload

import torch
from torch import Tensor

from . import _checks
from ._kernels.layout import chunks
from ._numerics import safe_denominator, threshold

__all__ = ["MIN_RESOLUTION", "KnotDomain", "bspline_basis", "checks_possible", "span_bases",
           "time_pair", "time_step", "unresolved"]

BASIS_CHUNK = 16384  # times per eager chunk of the basis (2x faster than 1e5 at once)
_REL_TOL = 1e-9  # relative part of the domain tolerance, of t1 - t0 (docs/api_contract.md)
#: Coarsest step of a time dtype at the times' magnitude, relative to their span (a
#: domain's length, a term's samples), that the checks accept far from 0 (absolute
#: timestamps): float32 UNIX seconds (steps of 128 s) do not pass. The one resolution rule
#: (:func:`unresolved`).
MIN_RESOLUTION = 1e-4
EXTRAPOLATE_HINT = "pass extrapolate=True to continue the end spans"  # ends a ``fix``


def time_step(dtype: torch.dtype, at: float | Tensor) -> Tensor:
    """The spacing of ``dtype``'s values at ``|at|`` (its unit in the last place:
    ``eps 2^floor(log2 |at|)``; 0 at 0), a float64 tensor of ``at``'s shape."""
    a = torch.as_tensor(at, dtype=torch.float64).abs()
    nonzero = a > 0
    exponent = torch.floor(torch.log2(torch.where(nonzero, a, 1.0)))
    return torch.where(nonzero, torch.finfo(dtype).eps * torch.exp2(exponent), 0.0)


def unresolved(dtype: torch.dtype, scale: float | Tensor, length: float | Tensor) -> Tensor:
    """The one time-resolution rule: whether times of ``dtype`` whose largest magnitude is
    ``scale``, spanning ``length``, lie far from 0 (``scale > 10 length``) and step by more
    than :data:`MIN_RESOLUTION` of ``length`` there (float32 UNIX seconds). Times near 0 in
    a narrow dtype (bfloat16 on ``[0, 1]``) are the caller's choice of precision, not a lost
    origin; float64 times always pass (there is no wider dtype to ask for). A bool tensor of
    the broadcast shape."""
    scale = torch.as_tensor(scale, dtype=torch.float64)
    length = torch.as_tensor(length, dtype=torch.float64, device=scale.device)
    step = time_step(dtype, scale).to(scale.device)
    coarse = (step > MIN_RESOLUTION * length) & (scale > 10.0 * length)
    return coarse & (dtype != torch.float64)


def checks_possible(*xs: Tensor) -> bool:
    """Whether value checks that read tensors on the host can run: not under
    ``torch.compile`` (a host sync would break the graph) and not on meta tensors."""
    if torch.compiler.is_compiling():
        return False
    return not any(x.device.type == "meta" for x in xs)


def _fmt(x: float, dtype: torch.dtype) -> str:
    """A time for a message, with the digits its dtype holds (UNIX seconds stay readable)."""
    return f"{x:.{15 if dtype == torch.float64 else 7}g}"


def _take(knots: Tensor, idx: Tensor) -> Tensor:
    """``knots[..., idx]`` for ``(K,)`` knots, or batched ``(..., K)`` knots with indices
    ``(..., T)`` or ``(..., T, m)`` whose leading dims broadcast against the knots'."""
    if knots.dim() == 1:
        return knots[idx]
    extra = idx.dim() - knots.dim()  # 1 for (..., T, m) indices
    flat = idx.flatten(-2) if extra else idx
    lead = _checks.broadcast_shapes(knots.shape[:-1], flat.shape[:-1])
    out = torch.take_along_dim(knots.expand(*lead, knots.shape[-1]),
                               flat.expand(*lead, flat.shape[-1]), -1)
    return out.view(*lead, *idx.shape[idx.dim() - 1 - extra:])


def _malformed(fn: str, name: str, value) -> None:
    _checks.fail(fn, f"expected {name} to be (t0, t1), two real numbers or a (2,) tensor, "
                     f"got {value!r}")


def _pair_end(fn: str, name: str, value, e, keep: bool) -> float | Tensor:
    """One end of a pair: a 0-d floating tensor (kept if ``keep``, else read on the host), a
    symbolic number under ``torch.compile(dynamic=True)`` (kept) or a real number."""
    if isinstance(e, Tensor) and e.dim() == 0 and e.is_floating_point():
        return e if keep else float(e)
    if isinstance(e, torch.SymFloat | torch.SymInt):
        return e  # type: ignore[return-value]  # math.isfinite would specialise on it
    if not isinstance(e, numbers.Real) or isinstance(e, bool):
        _malformed(fn, name, value)
    return float(e)


@overload
def time_pair(fn: str, name: str, value, *, keep_tensors: Literal[False] = False,
              ) -> tuple[float, float]: ...


@overload
def time_pair(fn: str, name: str, value, *, keep_tensors: Literal[True],
              ) -> tuple[float | Tensor, float | Tensor]: ...


def time_pair(fn: str, name: str, value, *, keep_tensors: bool = False,
              ) -> tuple[float | Tensor, float | Tensor]:
    """Parse a time span ``(t0, t1)``: the one parser of domains (``curves.bezier``'s
    ``domain``, the layers' ``domain`` / ``time_range``, ``clamped_uniform_knots``).

    Args:
        fn: public name of the caller, for the messages.
        name: the argument's name (``"domain"``, ``"time_range"``).
        value: two real numbers, two 0-d floating tensors or a ``(2,)`` floating tensor.
        keep_tensors: return tensor ends as 0-d tensors (differentiable; their values are
            checked later, with ``t``: :meth:`KnotDomain.check` with ``knots="domain"``)
            instead of reading them on the host.

    Returns:
        ``(t0, t1)``: Python floats, checked finite with ``t0 < t1``; with ``keep_tensors``
        tensor ends stay 0-d tensors; symbolic ends (``torch.compile(dynamic=True)``) stay
        as they are, unchecked.

    Raises:
        ValueError: not a pair of real numbers, a ``(2,)`` tensor of another shape, ends not
            finite or not increasing.
        TypeError: a non-floating tensor.
    """
    if isinstance(value, Tensor):
        _checks.tensor(fn, name, value)
        if value.shape != (2,):
            _checks.fail(fn, f"expected a (2,) tensor for {name}, got shape "
                             f"{_checks.shape_str(value.shape)}")
        ends = (value[0], value[1])
    else:
        try:
            ends = tuple(value)
        except TypeError:
            _malformed(fn, name, value)
        if len(ends) != 2:
            _malformed(fn, name, value)
    t0, t1 = (_pair_end(fn, name, value, e, keep_tensors) for e in ends)
    if (isinstance(t0, float) and isinstance(t1, float)
            and not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1)):
        _checks.fail(fn, f"{name} must be two finite times t0 < t1, got {value!r}")
    return t0, t1


class KnotDomain:
    """A curve's time: knots relative to a float64 origin, and the degree.

    Args:
        knots: ``(K,)`` or ``(..., K)`` non-decreasing knots relative to ``origin``, ``K =
            n + degree + 1``; any floating dtype (the stored dtype of a layer's knots).
        degree: the polynomial degree ``p >= 1``.
        origin: the absolute time of relative time 0: a Python float, or a float64 tensor of
            the knots' batch shape plus a trailing 1 (per-trajectory origins).
    """

    __slots__ = ("degree", "knots", "origin")

    def __init__(self, knots: Tensor, degree: int, origin: float | Tensor = 0.0):
        self.knots = knots
        self.degree = degree
        self.origin = origin

    @classmethod
    def bezier(cls, n: int, length: float, origin: float = 0.0, *,
               device: torch.device | None = None) -> KnotDomain:
        """The domain ``[origin, origin + length]`` of a Bézier curve of ``n`` control points
        (degree ``n - 1`` on clamped knots: one span)."""
        knots = torch.tensor([0.0] * n + [length] * n, dtype=torch.float64, device=device)
        return cls(knots, n - 1, origin)

    # -- shape of the domain
    @property
    def n(self) -> int:
        """Number of control points, ``K - degree - 1``."""
        return self.knots.shape[-1] - self.degree - 1

    def ends(self, dtype: torch.dtype | None = None) -> tuple[Tensor, Tensor]:
        """Relative ends ``knots[degree], knots[n]`` (``(...)`` tensors), in ``dtype``."""
        k = self.knots if dtype is None else self.knots.to(dtype)
        return k[..., self.degree], k[..., self.n]

    def domain(self) -> tuple[float, float] | tuple[Tensor, Tensor]:
        """The absolute domain ``(t0, t1)``: Python floats for ``(K,)`` knots (one host read;
        NaN for meta knots, which hold no values); for ``(..., K)`` knots two float64
        tensors of their batch shape, row ``b`` the domain of trajectory ``b``."""
        if self.knots.dim() > 1:
            lo, hi = self.ends(torch.float64)
            origin = torch.as_tensor(self.origin, dtype=torch.float64, device=lo.device)
            origin = origin.squeeze(-1) if origin.dim() else origin
            return lo + origin, hi + origin
        if self.knots.device.type == "meta":
            return math.nan, math.nan
        lo, hi = torch.stack(self.ends(torch.float64)).tolist()
        return float(self.origin) + lo, float(self.origin) + hi

    def tolerance(self, dtype: torch.dtype) -> Tensor:
        """The domain tolerance in ``dtype`` (the wide time dtype of the evaluation)."""
        lo, hi = self.ends(dtype)
        origin = torch.as_tensor(self.origin, dtype=dtype, device=lo.device)
        origin = origin.squeeze(-1) if origin.dim() else origin
        scale = torch.maximum((lo + origin).abs(), (hi + origin).abs())
        stored = threshold("domain_rtol", self.knots.dtype) * torch.maximum(lo.abs(), hi.abs())
        return torch.maximum(torch.maximum(_REL_TOL * (hi - lo),
                                           threshold("domain_rtol", dtype) * scale), stored)

    # -- times
    def relative(self, t: Tensor, dtype: torch.dtype, since_origin: bool = False) -> Tensor:
        """``t - origin`` in the wide time dtype ``promote(t.dtype, dtype)`` (``since_origin``:
        ``t`` is such a time already, only widened)."""
        wide = torch.promote_types(t.dtype, dtype)
        origin = self.origin
        if since_origin:
            return t.to(wide)
        if isinstance(origin, Tensor):
            return t.to(wide) - origin.to(wide)
        return t.to(wide) - origin if origin != 0.0 else t.to(wide)

    def _outside(self, rel: Tensor) -> Tensor:
        lo, hi = self.ends(rel.dtype)
        tol = self.tolerance(rel.dtype)
        return (rel < (lo - tol)[..., None]) | (rel > (hi + tol)[..., None])

    def outside(self, t: Tensor) -> Tensor:
        """Whether absolute times ``t (..., T)`` lie outside the domain by more than its
        tolerance (the rule of :meth:`check` and :meth:`admit`, in float64): a bool tensor
        ``(..., T)`` broadcast against the knots' batch, on their device."""
        return self._outside(self.relative(t.detach().to(self.knots.device), torch.float64))

    def admit(self, rel: Tensor, extrapolate: bool) -> Tensor:
        """The relative times to evaluate: those within the tolerance of an end moved onto
        it (value only: the gradient with respect to ``t`` stays 1), those further out NaN;
        ``extrapolate=True`` keeps every time. Branch-free: no host sync."""
        if extrapolate:
            return rel
        lo, hi = self.ends(rel.dtype)
        inside = torch.minimum(torch.maximum(rel, lo.detach()[..., None]), hi.detach()[..., None])
        value = torch.where(self._outside(rel), torch.nan, inside)
        return rel + (value - rel).detach()

    def prepare(self, fn: str, t: Tensor, dtype: torch.dtype, *, check: bool,
                extrapolate: bool, knots: str | None, fix: str,
                what: str = "the domain", since_origin: bool = False) -> Tensor:
        """The relative times to evaluate (:meth:`relative`, ``since_origin`` passed on, then
        :meth:`admit`), checked first (:meth:`check`) when ``check`` and
        :func:`checks_possible`: the one entry of every evaluation."""
        rel = self.relative(t, dtype, since_origin)
        if check and checks_possible(rel, self.knots):
            self.check(fn, rel, knots=knots, extrapolate=extrapolate, fix=fix, what=what,
                       t_dtype=t.dtype)
        return self.admit(rel, extrapolate)

    def check(self, fn: str, rel: Tensor, *, knots: str | None, extrapolate: bool, fix: str,
              what: str = "the domain", t_dtype: torch.dtype | None = None) -> None:
        """All value checks with one host synchronisation: the knots (finite,
        non-decreasing, non-empty domain; ``knots`` names them in the message, ``"knots"``
        or ``"domain"``, ``None``: not checked), and unless ``extrapolate`` the times within
        the domain's tolerance. ``what`` names the domain and ``fix`` how to cover other
        times in the message."""
        k = self.knots.detach()
        lo, hi = self.ends()
        flags = [~torch.isfinite(k).all(), (k[..., 1:] < k[..., :-1]).any(),
                 ~(torch.isfinite(lo) & torch.isfinite(hi) & (lo < hi)).all()] if knots else []
        if t_dtype is not None:  # t's own dtype must resolve the domain (UNIX seconds)
            flags.append(self._unresolved(t_dtype).any())
        if not extrapolate:
            flags.append(self._outside(rel.detach()).any())
        if not flags:
            return
        try:
            bad = torch.stack(flags).tolist()
        except RuntimeError as e:  # a transform with no host values, e.g. vmap over t
            raise RuntimeError(f"{fn}: the value checks read t (and knots) on the host, which "
                               f"this transform does not allow; pass check=False") from e
        if knots == "domain" and any(bad[:3]):
            _checks.fail(fn, f"domain must be two finite times t0 < t1, got "
                             f"{self._ends_str(rel.dtype)}")
        if knots and bad[0]:
            _checks.fail(fn, "knots must be finite" + self._row_str(~torch.isfinite(k)))
        if knots and bad[1]:
            decreasing = k[..., 1:] < k[..., :-1]
            row = self._row_str(decreasing)
            got = k[self._first_row(decreasing)] if row else k
            _checks.fail(fn, f"knots must be non-decreasing{row}, got {got.tolist()}")
        if knots and bad[2]:
            empty = ~(torch.isfinite(lo) & torch.isfinite(hi) & (lo < hi))[..., None]
            if k.dim() > 1:
                first = self._first_row(empty)
                ends = f"[{lo[first].item()!r}, {hi[first].item()!r}]"
            else:
                ends = self._ends_str(rel.dtype)
            _checks.fail(fn, f"knots give an empty domain [knots[degree], knots[n]] = "
                             f"{ends}{self._row_str(empty)}")
        if t_dtype is not None and bad[3 if knots else 0]:
            self._fail_unresolved(fn, t_dtype)
        if not extrapolate and bad[-1]:
            self._fail_outside(fn, rel.detach(), what, fix)

    @staticmethod
    def _first_row(bad: Tensor) -> tuple[int, ...]:
        """The batch index of the first row of ``bad (..., m)`` with a ``True``."""
        return tuple(int(i) for i in bad.any(-1).nonzero()[0])

    def _row_str(self, bad: Tensor) -> str:
        """For batched knots, `` (trajectory (b,))``: the first row with a ``True`` in
        ``bad (..., m)``; empty for ``(K,)`` knots."""
        return f" (trajectory {self._first_row(bad)})" if bad.dim() > 1 else ""

    def _scale_and_length(self) -> tuple[Tensor, Tensor]:
        lo, hi = self.ends(torch.float64)
        origin = torch.as_tensor(self.origin, dtype=torch.float64, device=lo.device)
        origin = origin.squeeze(-1) if origin.dim() else origin
        return torch.maximum((lo + origin).abs(), (hi + origin).abs()), hi - lo

    def _unresolved(self, t_dtype: torch.dtype) -> Tensor:
        """Whether times of ``t_dtype`` cannot resolve the domain (:func:`unresolved` at its
        ends and length)."""
        return unresolved(t_dtype, *self._scale_and_length())

    def _fail_unresolved(self, fn: str, t_dtype: torch.dtype) -> None:
        scale, length = (float(v.max()) for v in self._scale_and_length())
        step = float(time_step(t_dtype, scale))
        _checks.fail(fn, f"t is {t_dtype}, whose values near {scale:.10g} are {step:.3g} apart "
                         f"(t's units), more than {MIN_RESOLUTION:g} of the domain's length "
                         f"{length:.4g}: pass t as torch.float64")

    def _ends_str(self, dtype: torch.dtype) -> str:
        if self.knots.dim() > 1:
            return "(per trajectory)"
        t0, t1 = (float(e) for e in self.domain())
        return f"[{_fmt(t0, dtype)}, {_fmt(t1, dtype)}]"

    def _first_out(self, rel: Tensor) -> tuple[Tensor, str]:
        """For batched knots: the absolute times of the first trajectory with a time
        outside its domain, and that domain for the message (``of trajectory (b,) [t0,
        t1]``)."""
        lead = _checks.broadcast_shapes(rel.shape[:-1], self.knots.shape[:-1])
        rel = rel.expand(*lead, rel.shape[-1])
        row = self._first_row(self._outside(rel))
        t0, t1 = (float(torch.as_tensor(e).expand(lead)[row]) for e in self.domain())
        origin = torch.as_tensor(self.origin, dtype=torch.float64).to(rel.device)
        origin = origin.expand(*lead, 1)[row] if origin.dim() else origin
        ends = f"of trajectory {row} [{_fmt(t0, rel.dtype)}, {_fmt(t1, rel.dtype)}]"
        return rel[row].to(torch.float64) + origin, ends

    def _fail_outside(self, fn: str, rel: Tensor, what: str, fix: str) -> None:
        dt = rel.dtype
        if self.knots.dim() > 1:  # name the first trajectory out, with its own domain
            absolute, ends = self._first_out(rel)
        else:
            origin = (self.origin.to(rel.device) if isinstance(self.origin, Tensor)
                      else self.origin)
            absolute, ends = rel.to(torch.float64) + origin, self._ends_str(dt)
        finite = absolute[torch.isfinite(absolute)]
        n_bad = int((~torch.isfinite(absolute)).sum())
        if finite.numel():
            got = (f"got values in [{_fmt(finite.min().item(), dt)}, "
                   f"{_fmt(finite.max().item(), dt)}]")
            if n_bad:
                got += f" and t contains NaN/inf ({n_bad} values)"
        else:
            got = f"but t contains NaN/inf only ({n_bad} values)"
        _checks.fail(fn, f"t must lie in {what} {ends}, {got}; {fix}")

    # -- spans and local parameters
    def span(self, rel: Tensor) -> Tensor:
        """Span ``r`` of each time, ``knots[r] <= t < knots[r + 1]`` with ``r`` in ``[p,
        n - 1]``: at and beyond ``knots[n]`` the last non-empty span (the right end of the
        domain is a left limit), before ``knots[p]`` the first. ``rel (..., T)`` -> int64."""
        p, n, k = self.degree, self.n, self.knots.detach().to(rel.dtype)
        inner = k[..., p + 1:n]
        if k.dim() > 1:
            lead = _checks.broadcast_shapes(k.shape[:-1], rel.shape[:-1])
            inner, rel = inner.expand(*lead, n - p - 1), rel.expand(*lead, rel.shape[-1])
            end = k[..., n:n + 1].expand(*lead, 1)
        else:
            end = k[n:n + 1]
        r = p + torch.searchsorted(inner.contiguous(), rel.detach().contiguous(), right=True)
        r_end = p + torch.searchsorted(inner.contiguous(), end.contiguous(), right=False)
        return torch.minimum(r, r_end)

    def locate(self, rel: Tensor, dtype: torch.dtype) -> tuple[Tensor, Tensor, Tensor]:
        """``(span, u, du/dt)``: the span of each time, its local parameter
        ``u = (t - u_r) / (u_{r+1} - u_r)`` and slope ``1 / (u_{r+1} - u_r)``, computed in
        ``rel``'s (time) dtype and rounded to ``dtype``."""
        r = self.span(rel)
        k = self.knots.to(rel.dtype)
        left, right = _take(k, r), _take(k, r + 1)
        width = right - left
        return r, ((rel - left) / width).to(dtype), (1.0 / width).to(dtype)

    def local_times(self, t: Tensor, r: Tensor, since_origin: bool = False) -> Tensor:
        """Time since the start of span ``r`` of absolute times ``t``, ``t - origin - u_r``
        (float64, ``(..., T)``: ``t`` and ``r`` broadcast against each other and the knots'
        batch), clamped to the span ``[0, u_{r+1} - u_r]`` (the rounding of times admitted
        at its ends; differentiable with respect to ``t``): a one-span curve's time (the
        per-sample evaluation of ``torch_dq.fitting._local``). ``since_origin``: ``t`` are
        times since the origin (:meth:`relative`)."""
        left, right = self.span_bounds(r)
        rel = self.relative(t, torch.float64, since_origin)
        return torch.minimum((rel - left).clamp_min(0.0), right - left)

    def span_bounds(self, r: Tensor) -> tuple[Tensor, Tensor]:
        """The knots ``u_r`` and ``u_{r+1}`` of spans ``r (..., T)`` relative to the origin,
        float64 (batched knots broadcast against ``r``'s leading dims)."""
        k = self.knots.detach().to(torch.float64)
        if k.dim() == 1:
            return k[r], k[r + 1]
        lead = _checks.broadcast_shapes(k.shape[:-1], r.shape[:-1])  # a row per trajectory
        k, r = k.expand(*lead, k.shape[-1]), r.expand(*lead, r.shape[-1])
        return k.gather(-1, r), k.gather(-1, r + 1)

    def de_boor_levels(self, rel: Tensor, r: Tensor, dtype: torch.dtype,
                       ) -> list[tuple[Tensor, Tensor]]:
        """Per level ``j = 1..p`` of De Boor's scheme the local parameters
        ``alpha_i = (t - u_i) / (u_{i+p+1-j} - u_i)``, ``i = r-p+j .. r``, and their slopes,
        each ``(..., T, p + 1 - j)``, computed in ``rel``'s dtype and rounded to ``dtype``."""
        p = self.degree
        # K[..., m] = knots[r - p + 1 + m], m = 0 .. 2p - 1.
        K = _take(self.knots.to(rel.dtype),
                  r[..., None] + torch.arange(1 - p, p + 1, device=rel.device))
        te = rel[..., None]
        levels = []
        for j in range(1, p + 1):
            left, right = K[..., j - 1:p], K[..., p:2 * p - j + 1]
            denom = right - left
            empty = denom <= 0  # never inside a non-empty span; guards 0 / 0 all the same
            safe = safe_denominator(denom, empty)
            alpha = torch.where(empty, 0.0, (te - left) / safe)
            slope = torch.where(empty, 0.0, 1.0 / safe)
            levels.append((alpha.to(dtype), slope.to(dtype)))
        return levels

    def flat(self, r: Tensor, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
        """The knots in ``dtype`` as one flat vector and the spans ``r`` (from :meth:`span`)
        as indices into it, for the kernels that index one knot vector: ``(K,)`` knots and
        ``r`` as they are; batched ``(..., K)`` knots expanded to ``r``'s batch and
        flattened, each row's spans offset by ``row * K``."""
        k = self.knots.to(dtype)
        if k.dim() == 1:
            return k, r
        K, lead = k.shape[-1], r.shape[:-1]
        offsets = torch.arange(0, lead.numel() * K, K, device=r.device).view(*lead, 1)
        return k.expand(*lead, K).reshape(-1), r + offsets

    # -- the Euclidean basis
    def basis(self, rel: Tensor) -> tuple[Tensor, Tensor]:
        """Cox-de Boor basis at relative times ``rel (T,)`` (or ``(..., T)`` for batched
        knots, broadcasting against their batch): ``(first, values)`` as ``bspline_basis``
        of this module returns them, ``(..., T)`` and ``(..., T, p + 1)``, ``first`` indexing
        each trajectory's own control points."""
        r = self.span(rel)
        return r - self.degree, self.bases(rel, r)[0].contiguous()

    def bases(self, rel: Tensor, r: Tensor, order: int = 0, *, cumulative: bool = False,
              memo: dict | None = None) -> list[Tensor]:
        """The basis of span ``r`` (from :meth:`span`) at relative times ``rel`` and its time
        derivatives up to ``order``, plain or cumulative (:func:`span_bases`), computed in
        ``rel``'s dtype: ``order + 1`` tensors ``(..., T, p + 1)`` or ``(..., T, p)``.
        ``memo``: a dict kept between calls (the estimation's, one per curve) that holds the
        last result per order, form and shape; a call with equal ``rel``, ``r`` and knots
        (compared element by element) and nothing differentiated returns it (not to be
        modified) instead of computing it again."""
        knots, flat_r = self.flat(r, rel.dtype)
        if memo is None or rel.requires_grad or knots.requires_grad:
            return span_bases(knots, flat_r, rel, self.degree, order, cumulative=cumulative)
        key = ("bases", self.degree, order, cumulative, rel.dtype, rel.device, rel.shape)
        args, hit = memo.get(key, ((), None))
        if hit is None or not all(a.shape == b.shape and torch.equal(a, b)
                                  for a, b in zip(args, (rel, flat_r, knots), strict=True)):
            hit = span_bases(knots, flat_r, rel, self.degree, order, cumulative=cumulative)
            memo[key] = (tuple(x.clone() for x in (rel, flat_r, knots)), hit)
        return hit

    def greville(self) -> Tensor:
        """Greville abscissae ``mean(knots[j + 1 .. j + p])``, ``(..., n)`` relative, float64."""
        k = self.knots.detach().to(torch.float64)
        p, n = self.degree, self.n
        return k[..., 1:n + p].unfold(-1, p, 1).mean(-1)


def bspline_basis(t: Tensor, knots: Tensor, degree: int, r: Tensor | None = None,
                  ) -> tuple[Tensor, Tensor]:
    r"""Euclidean B-spline basis functions at ``t``, local form (Cox-de Boor).

    For ``t`` in the span :math:`[u_r, u_{r+1})` (:meth:`KnotDomain.span`), the
    ``degree + 1`` functions :math:`N_{r-p..r,\,p}(t)` that can be non-zero there (Piegl and
    Tiller, *The NURBS Book*, eq. 2.5; :func:`span_bases`).

    Args:
        t: ``(T,)`` times in ``[knots[degree], knots[n]]``.
        knots: ``(n + degree + 1,)`` non-decreasing knots, ``t``'s dtype and device.
        degree: ``p >= 1``.
        r: the spans of ``t`` if known (else searched).

    Returns:
        ``(first, values)``: ``first = r - p`` ``(T,)`` int64 (the first control point the
        time depends on) and ``values`` ``(T, p + 1)``, non-negative, summing to 1.
    """
    if r is None:
        r = KnotDomain(knots, degree).span(t)
    return r - degree, span_bases(knots, r, t, degree)[0].contiguous()
def _span_basis(knots: Tensor, r: Tensor, t: Tensor, degree: int,
                order: int) -> list[Tensor]:
    r"""Taylor coefficients in ``t`` (``0..order``) of :math:`B_{r-p+m,p}`, ``m = 0..p``,
    each ``(p + 1, ..., T)`` (``m`` leading): the polynomial pieces of span ``r``, evaluated
    at ``t``.

    Cox-de Boor on the span's knots :math:`u_{r-p+1}, \dots, u_{r+p}`: with
    :math:`V_0 = (1)` and, for ``k = 1..p``,
    :math:`\alpha_i = (t - u_i) / (u_{i+k} - u_i)`, ``i = r-k+1..r`` (0 where the
    denominator is 0: the 0/0 terms of repeated knots),

    .. math::
        B_{i,k} = \alpha_i B_{i,k-1} + (1 - \alpha_{i+1}) B_{i+1,k-1},

    i.e. :math:`V_k = (0, \alpha V_{k-1}) + ((1 - \alpha) V_{k-1}, 0)`. Every step is a
    polynomial in ``t``, so ``t`` outside the span gives the pieces' continuation.
    """
    p = degree
    # u_{r-p+1..r+p} as leading rows (2p, ..., T): every op below runs over contiguous rows
    # of times (a trailing dim of p + 1 is several times slower on CPU)
    offsets = torch.arange(1 - p, p + 1, device=r.device).view(-1, *[1] * r.dim())
    K = knots.index_select(0, (r + offsets).reshape(-1)).view(2 * p, *r.shape)
    V = [torch.ones_like(t)[None]] + [torch.zeros_like(t)[None] for _ in range(order)]
    zero = torch.zeros_like(t)[None]
    for k in range(1, p + 1):
        left, right = K[p - k:p], K[p:p + k]
        denom = right - left
        empty = denom <= 0  # never inside a non-empty span; 0 / 0 = 0 all the same
        safe = safe_denominator(denom, empty)
        keep = (~empty).to(t.dtype)  # a product, not torch.where (several times slower)
        alpha = (t - left) / safe * keep
        aV = [alpha * V[0]]
        if order:  # (alpha + slope h) V, truncated: the product by an affine function of t
            slope = keep / safe
            aV += [alpha * V[i] + slope * V[i - 1] for i in range(1, order + 1)]
        V = [torch.cat((zero, a)) + torch.cat((v - a, zero))
             for a, v in zip(aV, V, strict=True)]
    return V


def span_bases(knots: Tensor, r: Tensor, t: Tensor, degree: int, order: int = 0, *,
               cumulative: bool = False) -> list[Tensor]:
    r"""The B-spline basis of each time's span and its time derivatives: the one Cox-de Boor
    (``_span_basis``), plain or cumulative (basalt's ``_Cumulative`` flag).

    Plain: :math:`B_{r-p+m,p}(t)`, ``m = 0..p`` (Piegl and Tiller, *The NURBS Book*, eq.
    2.5). Cumulative: :math:`\tilde B_{r-p+j}(t) = \sum_{m=j}^{p} B_{r-p+m,p}(t)`, ``j =
    1..p`` (:math:`\tilde B_{r-p} = 1` by the partition of unity, and :math:`\tilde B_l = 0`
    for ``l > r``, so neither is returned).

    Args:
        knots: ``(K,)`` non-decreasing knots (uniform or not, clamped or not, repeated
            interior knots allowed), in the time dtype (batched knots flattened by
            :meth:`KnotDomain.flat`).
        r: ``(..., T)`` int64 spans, ``knots[r] <= t < knots[r + 1]``, ``r`` in
            ``[p, n - 1]`` (:meth:`KnotDomain.span`).
        t: ``(..., T)`` times in ``knots``' dtype. Times outside their span give the
            polynomial continuation of the span's pieces (extrapolation).
        degree: ``p >= 1``.
        order: highest time derivative, ``>= 0``.
        cumulative: the cumulative basis instead of the plain one.

    Returns:
        ``order + 1`` tensors ``(..., T, w)``, ``w = p + 1`` (plain) or ``p`` (cumulative):
        the basis and its time derivatives up to ``order``, ``[..., m]`` the ``m``-th
        function of the span; differentiable (any order) with respect to ``t`` and
        ``knots``. Each is a view of ``(w, ..., T)`` rows (its transpose, what the kernels
        read, is contiguous).
    """
    r, t = torch.broadcast_tensors(r, t)
    flat_r, flat_t = r.reshape(-1), t.reshape(-1)
    parts = [[math.factorial(k) * (v[1:].flip(0).cumsum(0).flip(0) if cumulative else v)
              for k, v in enumerate(_span_basis(knots, flat_r[i], flat_t[i], degree, order))]
             for i in chunks(flat_r.shape[0], BASIS_CHUNK, t.device)]  # cache-sized temporaries
    width = degree if cumulative else degree + 1
    return [(x[0] if len(x) == 1 else torch.cat(x, -1)).view(width, *r.shape).movedim(0, -1)
            for x in zip(*parts, strict=True)]

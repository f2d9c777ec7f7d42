"""The span Jacobians of the estimation (issue 34): a cumulative cubic B-spline's closed form
(``BSpline.span_vjp``, ``torch_dq._cumulative_lie``) against the ``k`` reverse passes through
per-sample copies of its spans that it replaces (``Curve.evaluate_span`` on
``tangent_step`` copies, what ``fitting._linearize`` runs for the other forms), for the
orders a pose, a gyroscope and an accelerometer term read; then the span derivatives
themselves (``BSpline.span_derivatives``) without a graph (float64: the Lie-algebra
recursions of ``torch_dq._cumulative_lie.derivatives``) against the span tables (what reverse
mode differentiates, forced here by a control-point tensor that requires grad); process CPU,
best of ``--repeats``, and the largest differences.

    python benchmarks/bench_span_jacobians.py [--samples 12000] [--spans 1200] [--threads 1]
"""

from __future__ import annotations

import argparse
import time

import torch

import torch_dq.dualquat as dq
from torch_dq._curve import span_points
from torch_dq.fitting._local import tangent_step
from torch_dq.nn import BSpline


def _reverse(curve, pts, local, first, cot):
    """``(N, k, w, 6)`` by one forward through per-sample copies and ``k`` reverse passes."""
    N, k, O, _ = cot.shape
    delta = pts.new_zeros(N, pts.shape[-2], 6, requires_grad=True)
    with torch.enable_grad():
        D = curve.evaluate_span(tangent_step(pts, delta), local, first, O - 1)
        rows = [torch.autograd.grad(sum((D[o] * cot[:, j, o]).sum() for o in range(O)), delta,
                                    retain_graph=j < k - 1)[0] for j in range(k)]
    return torch.stack(rows, 1)


def _best(fn, repeats: int) -> tuple[float, torch.Tensor]:
    out, best = fn(), float("inf")
    for _ in range(repeats):
        t = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--samples", type=int, default=12000)
    ap.add_argument("--spans", type=int, default=1200)
    ap.add_argument("--rows", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    g = torch.Generator().manual_seed(0)
    steps = dq.exp(0.1 * torch.randn(args.spans + 3, 6, generator=g, dtype=torch.float64))
    ctrl = torch.stack(list(_chain(steps)))
    curve = BSpline(ctrl, degree=3, form="cumulative")
    lo, hi = (float(e) for e in curve.domain)
    t = torch.linspace(lo, hi, args.samples, dtype=torch.float64)
    first = curve.support(t)[0]
    pts = span_points(ctrl, first, 4)
    local = curve.local_times(t, first)
    with torch.no_grad():
        pose = curve.span_derivatives(ctrl, local, first, 0)[0]
    print(f"{args.samples} samples on {args.spans} spans, {args.rows} rows, "
          f"{args.threads} thread(s), torch {torch.__version__}; process CPU, best of "
          f"{args.repeats}")
    for order, term in ((0, "poses"), (1, "gyroscope"), (2, "accelerometer")):
        cot = torch.randn(args.samples, args.rows, order + 1, 8, generator=g, dtype=torch.float64)
        tc, closed = _best(lambda c=cot: curve.span_vjp(pts, local, first, c, pose),
                           args.repeats)
        tr, ref = _best(lambda c=cot: _reverse(curve, pts, local, first, c), args.repeats)
        err = float((closed - ref).abs().max() / ref.abs().max())
        print(f"  order {order} ({term:13s}): closed form {tc * 1e3:7.1f} ms, reverse passes "
              f"{tr * 1e3:7.1f} ms ({tr / tc:.2f}x), max relative difference {err:.1e}")
    graph = ctrl.clone().requires_grad_()
    for order in range(3):
        with torch.no_grad():
            tl, lie = _best(lambda o=order: curve.span_derivatives(ctrl, local, first, o),
                            args.repeats)
        tt, tab = _best(lambda o=order: curve.span_derivatives(graph, local, first, o),
                        args.repeats)
        err = max(float((a - b.detach()).abs().max() / b.detach().abs().max())
                  for a, b in zip(lie, tab, strict=True))
        print(f"  derivatives to order {order}: recursions {tl * 1e3:7.1f} ms, span tables "
              f"(with a graph) {tt * 1e3:7.1f} ms, max relative difference {err:.1e}")


def _chain(steps: torch.Tensor):
    """Control points ``c_i = c_{i-1} exp(step_i)``: a smooth random walk."""
    c = steps[0]
    for s in steps:
        c = dq.mul(c, s)
        yield c


if __name__ == "__main__":
    main()

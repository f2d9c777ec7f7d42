"""Does a fused per-sample kernel (``torch.compile``, inductor's CPU C++ backend) pay for the
closed-form span vjp (``torch_dq._cumulative_lie``)? Session 16's probe (fuse16).

One step of the vjp's backward recursion, the chain its time goes to: rows ``a (6, 2, k, S)``
(the pose's and V's cotangents), ``t = a_0 + a_1 ad_z`` (``_row_ad``), ``c = t J_r``
(``_rows``), ``c += lambda' a_1``, and the rows carried one step back ``a M`` (``_rows``):
the library's in-place eager helpers against the same arithmetic written functionally and
compiled (``dynamic=True``: the sample count changes between calls). Reports the compile
time (cold cache, or warm from inductor's on-disk cache in a fresh process), recompiles, the
steady state (process CPU time, min of alternations in one process, one thread) and the
largest difference from eager, float64 and float32. ``--forward``: the same for the forward
recursions (``_forward``: the per-sample dual matrices ``M_j``, ``lambda_j J_r`` from the
gathered span powers, ``V``, ``dV`` of a cubic's three steps; its even functions, taken
eagerly by both sides, are counted in the compiled side's time), on random small twists.

    python benchmarks/compile_probe.py            # S = 12,001 and 4,096, k = 6
    python benchmarks/compile_probe.py --forward  # the forward recursions, float64
"""

from __future__ import annotations

import argparse
import time

import torch

from torch_dq import _cumulative_lie
from torch_dq._cumulative_lie import _row_ad, _rows


def eager_step(a: torch.Tensor, z: torch.Tensor, jr: tuple, m: tuple, l1: torch.Tensor):
    """The library's helpers, as ``_backward`` calls them (fresh outputs)."""
    t = _row_ad(a[:, 1], z, torch.empty_like(a[:, 0]), a[:, 0])
    c = _rows(t, jr).addcmul_(a[:, 1], l1)
    return c, _rows(a.flatten(1, 2), m).view_as(a)


def _cross(x, y):
    return torch.stack([x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2],
                        x[0] * y[1] - x[1] * y[0]])


def _rows_f(a, A, B):
    """Rows ``a (6, ..., S)`` times the dual matrix ``(A, B)`` ``(3, 3, S)``, functionally."""
    ex = (slice(None), slice(None)) + (None,) * (a.dim() - 2)
    A, B = A[ex], B[ex]
    w = sum(a[i] * A[i] + a[3 + i] * B[i] for i in range(3))
    v = sum(a[3 + i] * A[i] for i in range(3))
    return torch.cat((w, v))


def fused_step(a, z, A, B, MA, MB, l1):
    a0, a1 = a[:, 0], a[:, 1]
    zz = z[:, None]
    t = a0 + torch.cat((_cross(a1[:3], zz[:3]) + _cross(a1[3:], zz[3:]), _cross(a1[3:], zz[:3])))
    c = _rows_f(t, A, B) + a1 * l1
    return c, _rows_f(a, MA, MB)


def inputs(S: int, k: int, dtype: torch.dtype, g: torch.Generator):
    r = lambda *s: torch.randn(*s, S, dtype=dtype, generator=g)  # noqa: E731
    return r(6, 2, k), r(6), (r(3, 3), r(3, 3)), (r(3, 3), r(3, 3)), r(1)


def _polynomial_f(pw, c0, c1, c2):
    """``_cumulative_lie._polynomial`` functionally (``(3, 3, p, S)`` parts)."""
    W, V, W2, WV = pw
    (a1, b1), (a2, b2) = c1, c2
    eye = torch.eye(3, dtype=W.dtype)[:, :, None, None]
    return W2 * a2 + W * a1 + eye * c0, W * b1 + V * a1 + W2 * b2 + WV * a2


def _apply_f(A, B, x):
    w = sum(A[:, i] * x[i] for i in range(3))
    v = sum(A[:, i] * x[3 + i] + B[:, i] * x[i] for i in range(3))
    return torch.cat((w, v))


def _bracket_f(a, b):
    return torch.cat((_cross(a[:3], b[:3]), _cross(a[:3], b[3:]) + _cross(a[3:], b[:3])))


def fused_forward(d, pw, lam, sig, alp, bet):
    """``_forward``'s matrices and recursions (orders 0 to 2), functionally."""
    l0, l1, l2 = lam
    lsq = l0 * l0
    M = _polynomial_f(pw, 1.0, (-l0 * sig[0], -l0 * sig[1]), (lsq * alp[0], lsq * alp[1]))
    Jr = _polynomial_f(pw, l0, (-lsq * alp[0], -lsq * alp[1]),
                       (lsq * l0 * bet[0], lsq * l0 * bet[1]))
    V, Vd, zs = l1[0] * d[0], l2[0] * d[0], []
    for j in range(1, d.shape[0]):
        Mj = (M[0][:, :, j], M[1][:, :, j])
        zs += [_apply_f(*Mj, V), _apply_f(*Mj, Vd)]
        V = zs[-2] + l1[j] * d[j]
        Vd = zs[-1] + l2[j] * d[j] + _bracket_f(V, d[j]) * l1[j]
    return (*M, *Jr, torch.stack(zs), V, Vd)


def forward_probe(S: int, repeats: int, g: torch.Generator) -> None:
    """``--forward``: eager ``_forward`` against :func:`fused_forward` compiled."""
    p, f64 = 3, torch.float64
    d = 0.05 * torch.randn(p, 6, S, dtype=f64, generator=g)
    pw = _cumulative_lie._powers(d.permute(1, 0, 2).reshape(6, -1))
    powers = (*(x.view(3, 3, p, S) for x in pw[:4]), *(x.view(p, S) for x in pw[4:]))
    lam = [torch.rand(p, S, dtype=f64, generator=g) for _ in range(3)]
    comp = torch.compile(fused_forward, dynamic=True)

    def compiled():
        scalars = _cumulative_lie._scalars(("sinc", "se3_c1", "se3_c2"), powers, lam[0])
        return comp(d, powers[:4], lam, *scalars)

    t0, c0 = time.perf_counter(), time.process_time()
    out = compiled()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    ref = _cumulative_lie._forward(d, powers, lam)
    pairs = [(out[0][:, :, 1], ref["M"][1][0]), (out[3][:, :, 2], ref["Jr"][2][1]),
             (out[5], ref["last"][0]), (out[6], ref["last"][1])]
    diff = max(float((x - y).abs().max() / y.abs().max()) for x, y in pairs)
    te, tc = _alternate((_cumulative_lie._forward, (d, powers, lam)), (compiled, ()), repeats)
    print(f"forward  S={S:6d} p=3: first call {wall:6.2f} s wall {cpu:6.2f} s CPU; eager "
          f"{min(te) * 1e3:7.3f} ms, compiled {min(tc) * 1e3:7.3f} ms "
          f"({min(te) / min(tc):4.2f}x); rel diff {diff:.1e}", flush=True)


def _alternate(first: tuple, second: tuple, repeats: int) -> tuple[list, list]:
    """Process CPU seconds of ``fn(*args)`` for each ``(fn, args)``, alternated."""
    times: tuple[list, list] = ([], [])
    for _ in range(repeats):
        for (fn, args), acc in zip((first, second), times, strict=True):
            c0 = time.process_time()
            fn(*args)
            acc.append(time.process_time() - c0)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", default="12001,4096")
    ap.add_argument("--k", type=int, default=6)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--forward", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    g = torch.Generator().manual_seed(0)
    if args.forward:
        for S in (int(s) for s in args.samples.split(",")):
            forward_probe(S, args.repeats, g)
        return
    comp = torch.compile(fused_step, dynamic=True)
    for dtype in (torch.float64, torch.float32):
        for S in (int(s) for s in args.samples.split(",")):
            a, z, jr, m, l1 = inputs(S, args.k, dtype, g)
            t0, c0 = time.perf_counter(), time.process_time()
            out = comp(a, z, *jr, *m, l1)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            ref = eager_step(a, z, jr, m, l1)
            diff = max(float((x - y).abs().max() / y.abs().max()) for x, y in zip(out, ref,
                                                                                    strict=True))
            te, tc = _alternate((eager_step, (a, z, jr, m, l1)),
                                (comp, (a, z, *jr, *m, l1)), args.repeats)
            print(f"{str(dtype)[6:]:8s} S={S:6d} k={args.k}: first call {wall:6.2f} s wall "
                  f"{cpu:6.2f} s CPU; eager {min(te) * 1e3:7.3f} ms, compiled "
                  f"{min(tc) * 1e3:7.3f} ms ({min(te) / min(tc):4.2f}x); rel diff {diff:.1e}",
                  flush=True)


if __name__ == "__main__":
    main()

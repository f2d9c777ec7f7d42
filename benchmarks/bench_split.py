"""Exposure trajectories of a deblurring / rolling-shutter pipeline (issue 35): forward +
backward of every image's pose at its virtual views, torch_dq's split B-spline against our
pypose rewrite of BAD-Gaussians' spline functor (``tests/bad_gaussians.py``) and pypose's
``bspline`` (cumulative SE(3) on uniform knots).

The work: ``--images`` images (1000), each with its own trajectory of 4 control poses
(cubic) or 2 (linear), evaluated at ``--views`` virtual views (10) at local parameters
``u`` in ``[0, 1]``; the loss is a weighted sum of the poses (a stand-in for the renderer's
gradient), backward to the control poses. float32 on the CPU (or ``--device cuda``); the
median of ``--repeats`` runs after a warm-up. pypose's ``bspline`` takes no ``u``: it
samples its own uniform grid (``interval = 1 / views``, ``views + 1`` poses per image).

Run::

    PYTHONPATH=$PWD python benchmarks/bench_split.py [--images 1000] [--views 10]

Figures taken on a loaded shared machine are noisy: compare the ratios, run it twice.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import torch_dq.dualquat as dq
from torch_dq import curves

try:
    import pypose as pp
    from bad_gaussians import badgs_cubic, badgs_linear, to_pypose
except ImportError:  # pypose not installed: torch_dq's rows only
    pp = None


def timed(fns: dict, repeats: int, device: torch.device) -> dict:
    """Median time in ms of each ``fns[name]()`` after two warm-up calls, the candidates
    run in turn within each repeat (paired: a load change on a shared machine hits all of
    them), and the median of each one's ratio to the first's per repeat. Process CPU time
    on the CPU (one thread: steadier than wall time there), wall time on CUDA."""
    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize(device)
    clock = time.perf_counter if device.type == "cuda" else time.process_time
    for fn in fns.values():
        fn()
        fn()
    times: dict = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            sync()
            t0 = clock()
            fn()
            sync()
            times[name].append(clock() - t0)
    base = times[next(iter(fns))]
    return {name: (statistics.median(ts) * 1e3,
                   statistics.median(t / b for t, b in zip(ts, base, strict=True)))
            for name, ts in times.items()}


def inputs(images: int, views: int, m: int, device, gen):
    """Random control poses ``(images, m, 8)`` (about 0.1 rad and 0.1 apart: an exposure)
    and local parameters ``(images, views)`` spread over [0, 1]."""
    xi = 0.1 * torch.randn(images, m, 6, generator=gen)
    ctrl = dq.mul(dq.exp(torch.randn(images, 1, 6, generator=gen)), dq.exp(xi.cumsum(1)))
    u = (torch.arange(views) + torch.rand(images, views, generator=gen)) / views
    return ctrl.to(device), u.clamp(0.0, 1.0).to(device)


def ours(ctrl: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
    """torch_dq's split form on BAD-Gaussians' local parameters: degree 1 on knots
    ``(0, 0, 1, 1)``; the cubic on uniform knots ``0..7``, its one span ``[3, 4]``."""
    if ctrl.shape[-2] == 2:
        knots = torch.tensor([0.0, 0.0, 1.0, 1.0], device=u.device)
        return curves.bspline(ctrl, u, degree=1, knots=knots, form="split", check=False)
    knots = torch.arange(8.0, device=u.device)
    return curves.bspline(ctrl, 3.0 + u, degree=3, knots=knots, form="split", check=False)


def step(fn, leaf: torch.Tensor, *args):
    """One forward + backward of a weighted sum of ``fn(leaf, *args)``."""
    def run():
        leaf.grad = None
        out = fn(leaf, *args)
        (out * torch.linspace(-1.0, 1.0, out.shape[-1], device=out.device)).sum().backward()
    return run


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--images", type=int, default=1000)
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=1, help="CPU threads (default 1)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    gen = torch.Generator().manual_seed(0)
    print(f"torch {torch.__version__}, {device}, {torch.get_num_threads()} thread(s), "
          f"{args.images} images x {args.views} views, float32, forward + backward (ms)")
    for name, m in (("linear", 2), ("cubic", 4)):
        ctrl, u = inputs(args.images, args.views, m, device, gen)
        fns = {"torch_dq split": step(ours, ctrl.clone().requires_grad_(), u)}
        if pp is not None:
            functor = badgs_linear if m == 2 else badgs_cubic
            fns["BAD-Gaussians functor (rewrite)"] = step(functor,
                                                          to_pypose(ctrl).requires_grad_(), u)
            if m == 4:
                def pypose_bspline(c7, views=args.views):
                    return pp.bspline(pp.SE3(c7), interval=1.0 / views).tensor()
                fns[f"pypose.bspline ({args.views + 1} poses, SE(3))"] = step(
                    pypose_bspline, to_pypose(ctrl).requires_grad_())
        print(f"\n{name} ({m} control poses per image)")
        for label, (ms, ratio) in timed(fns, args.repeats, device).items():
            print(f"  {label:40s} {ms:9.2f} ms   {ratio:5.2f}x torch_dq's time (paired)")


if __name__ == "__main__":
    main()

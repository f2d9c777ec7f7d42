"""Elementary operations of torch_dq against pytransform3d, roma and pypose, side by side.

Standalone (not a ``run.py`` section): for every op, batch size, dtype and thread count it
times torch_dq and each peer that has the op, alternating ``ours, peer, ours, peer, ...``
(so a drift of a shared machine hits both), and prints ``ratio = ours / peer`` of the best
of ``--repeats`` (above 1: torch_dq is slower). The clock is the process CPU time
(``time.process_time``), robust on a loaded machine; each sample loops the call until it
lasts ``--min-ms``. Backward rows (``op bwd``): gradient of the output's sum w.r.t. the
inputs, for torch_dq and the torch peers (roma, pypose). pytransform3d (numpy, float64)
uses its single-item function at batch size 1 where it has one, its batch function
otherwise; at batch 1e6 it and pypose run on 1e5 items, scaled x10 (linear work).

    python benchmarks/bench_elementary.py --threads 1 --sizes 1,1000,1000000
    python benchmarks/bench_elementary.py --only q_mul,dq_mul --json out.json
"""

from __future__ import annotations

import argparse
import functools
import json
import time

import numpy as np
import torch

import torch_dq.dualquat as dq
from torch_dq import quat

XYZW, WXYZ = [1, 2, 3, 0], [3, 0, 1, 2]
PEER_CAP = 100_000  # numpy / pypose peers at most this many items, scaled linearly


def _imports():
    mods = {}
    for name in ("roma", "pypose", "pytransform3d"):
        try:
            mods[name] = __import__(name)
        except ImportError:
            pass
    if "pytransform3d" in mods:
        import pytransform3d.batch_rotations as pbr
        import pytransform3d.rotations as pr
        import pytransform3d.trajectories as ptr
        import pytransform3d.transformations as pt

        mods.update(pbr=pbr, pr=pr, ptr=ptr, pt=pt)
    return mods


M = _imports()


def _inputs(n, dtype, seed=0):
    g = torch.Generator().manual_seed(seed)
    q0 = quat.normalize(torch.randn(n, 4, generator=g, dtype=dtype))
    q1 = quat.normalize(torch.randn(n, 4, generator=g, dtype=dtype))
    t3 = torch.randn(n, 3, generator=g, dtype=dtype)
    x0, x1 = dq.from_rt(q0, t3), dq.from_rt(q1, torch.randn(n, 3, generator=g, dtype=dtype))
    return {
        "q0": q0,
        "q1": q1,
        "v": t3,
        "x0": x0,
        "x1": x1,
        "s": torch.rand(n, generator=g, dtype=dtype),
        "R": quat.to_matrix(q0),
        "T": dq.to_matrix(x0),
        "rv": quat.to_rotvec(q0),
        "xi": dq.log(x0),
        "w": torch.rand(n, 2, generator=g, dtype=dtype) + 0.1,
        "xs": torch.stack((x0, x1), -2),
    }


def _np(x):
    return x.detach().double().numpy()


def _pp(x, kind):
    pp = M["pypose"]
    if kind == "SO3":
        return pp.SO3(x[..., XYZW].contiguous())
    if kind == "SE3":
        return pp.SE3(dq.to_pose7(x).contiguous())
    if kind == "so3":
        return pp.so3(x.contiguous())
    return pp.se3(torch.cat((x[..., 3:], x[..., :3]), -1).contiguous())  # (v, omega)


class _Pick:
    """pytransform3d's single-item function at batch size 1 (if any), its batch one else."""

    def __init__(self, single, batch):
        self.single, self.batch = single, batch

    def at(self, n):
        return self.single if n == 1 and self.single is not None else self.batch


def _roma_rigid(d):
    """roma's rigid transform inputs: xyzw quaternion and translation of ``x0``."""
    return [d["x0"][..., XYZW].contiguous(), dq.to_rt(d["x0"])[1].contiguous()]


# Each op: name -> (our args, our fn, {peer: (prepare(inputs, n) -> args, fn(*args))}).
# Peer args are converted outside the timing; pytransform3d gets float64 numpy arrays.
def _ops():
    r, pp, pbr, pr, ptr, pt = (M.get(k) for k in ("roma", "pypose", "pbr", "pr", "ptr", "pt"))

    def xyzw(*names):
        return lambda d, n: [d[k][..., XYZW].contiguous() for k in names]

    def numpy(*names):
        return lambda d, n: [_np(d[k][0] if n == 1 else d[k]) for k in names]

    def one_or_batch(single, batch):
        return _Pick(single, batch)

    ops = {
        "q_mul": (
            ("q0", "q1"),
            quat.mul,
            {
                "roma": (xyzw("q0", "q1"), lambda a, b: r.quat_product(a, b)),
                "pypose": (
                    lambda d, n: [_pp(d["q0"], "SO3"), _pp(d["q1"], "SO3")],
                    lambda a, b: a * b,
                ),
                "pytransform3d": (
                    numpy("q0", "q1"),
                    one_or_batch(
                        pr and pr.concatenate_quaternions, pbr and pbr.batch_concatenate_quaternions
                    ),
                ),
            },
        ),
        "q_conj": (
            ("q0",),
            quat.conj,
            {
                "roma": (xyzw("q0"), lambda a: r.quat_conjugation(a)),
                "pypose": (lambda d, n: [_pp(d["q0"], "SO3")], lambda a: a.Inv()),
                "pytransform3d": (
                    numpy("q0"),
                    one_or_batch(pr and pr.q_conj, pbr and pbr.batch_q_conj),
                ),
            },
        ),
        "q_normalize": (
            ("q0",),
            quat.normalize,
            {
                "roma": (xyzw("q0"), lambda a: r.quat_normalize(a)),
                "pytransform3d": (
                    numpy("q0"),
                    one_or_batch(pr and pr.norm_vector, pbr and pbr.norm_vectors),
                ),
            },
        ),
        "q_rotate": (
            ("q0", "v"),
            quat.rotate,
            {
                "roma": (
                    lambda d, n: [*xyzw("q0")(d, n), d["v"]],
                    lambda a, v: r.quat_action(a, v, is_normalized=True),
                ),
                "pypose": (lambda d, n: [_pp(d["q0"], "SO3"), d["v"]], lambda a, v: a.Act(v)),
                "pytransform3d": (numpy("q0", "v"), one_or_batch(pr and pr.q_prod_vector, None)),
            },
        ),
        "q_to_matrix": (
            ("q0",),
            quat.to_matrix,
            {
                "roma": (xyzw("q0"), lambda a: r.unitquat_to_rotmat(a)),
                "pypose": (lambda d, n: [_pp(d["q0"], "SO3")], lambda a: a.matrix()),
                "pytransform3d": (
                    numpy("q0"),
                    one_or_batch(
                        pr and pr.matrix_from_quaternion, pbr and pbr.matrices_from_quaternions
                    ),
                ),
            },
        ),
        "q_from_matrix": (
            ("R",),
            quat.from_matrix,
            {
                "roma": (lambda d, n: [d["R"]], lambda a: r.rotmat_to_unitquat(a)),
                "pypose": (lambda d, n: [d["R"]], lambda a: pp.mat2SO3(a, check=False)),
                "pytransform3d": (
                    numpy("R"),
                    one_or_batch(
                        pr and pr.quaternion_from_matrix, pbr and pbr.quaternions_from_matrices
                    ),
                ),
            },
        ),
        "q_from_rotvec": (
            ("rv",),
            quat.from_rotvec,
            {
                "roma": (lambda d, n: [d["rv"]], lambda a: r.rotvec_to_unitquat(a)),
                "pypose": (lambda d, n: [_pp(d["rv"], "so3")], lambda a: a.Exp()),
                "pytransform3d": (
                    numpy("rv"),
                    one_or_batch(pr and pr.quaternion_from_compact_axis_angle, None),
                ),
            },
        ),
        "q_to_rotvec": (
            ("q0",),
            quat.to_rotvec,
            {
                "roma": (xyzw("q0"), lambda a: r.unitquat_to_rotvec(a)),
                "pypose": (lambda d, n: [_pp(d["q0"], "SO3")], lambda a: a.Log()),
                "pytransform3d": (
                    numpy("q0"),
                    one_or_batch(
                        pr and pr.compact_axis_angle_from_quaternion,
                        pbr and pbr.axis_angles_from_quaternions,
                    ),
                ),
            },
        ),
        "q_slerp": (
            ("q0", "q1", "s"),
            quat.slerp,
            {
                "roma": (
                    lambda d, n: [*xyzw("q0", "q1")(d, n), d["s"][0].clone()],
                    lambda a, b, s: r.unitquat_slerp(a, b, s, shortest_arc=True),
                ),
                "pytransform3d": (
                    lambda d, n: [_np(d["q0"][0]), _np(d["q1"][0]), float(d["s"][0])],
                    one_or_batch(pr and pr.quaternion_slerp, None),
                ),
            },
        ),
        "dq_mul": (
            ("x0", "x1"),
            dq.mul,
            {
                "pypose": (
                    lambda d, n: [_pp(d["x0"], "SE3"), _pp(d["x1"], "SE3")],
                    lambda a, b: a * b,
                ),
                "pytransform3d": (
                    numpy("x0", "x1"),
                    one_or_batch(
                        pt and pt.concatenate_dual_quaternions,
                        ptr and ptr.batch_concatenate_dual_quaternions,
                    ),
                ),
            },
        ),
        "dq_conj": (
            ("x0",),
            dq.conj,
            {
                "pypose": (lambda d, n: [_pp(d["x0"], "SE3")], lambda a: a.Inv()),
                "pytransform3d": (
                    numpy("x0"),
                    one_or_batch(pt and pt.dq_q_conj, ptr and ptr.batch_dq_q_conj),
                ),
            },
        ),
        "dq_normalize": (
            ("x0",),
            dq.normalize,
            {"pytransform3d": (numpy("x0"), one_or_batch(pt and pt.norm_dual_quaternion, None))},
        ),
        "dq_apply": (
            ("x0", "v"),
            dq.apply,
            {
                "roma": (
                    lambda d, n: [*_roma_rigid(d), d["v"]],
                    lambda q, t, v: r.RigidUnitQuat(q, t).apply(v),
                ),
                "pypose": (lambda d, n: [_pp(d["x0"], "SE3"), d["v"]], lambda a, v: a.Act(v)),
                "pytransform3d": (
                    numpy("x0", "v"),
                    one_or_batch(pt and pt.dq_prod_vector, ptr and ptr.batch_dq_prod_vector),
                ),
            },
        ),
        "dq_to_matrix": (
            ("x0",),
            dq.to_matrix,
            {
                "roma": (
                    lambda d, n: _roma_rigid(d),
                    lambda q, t: r.RigidUnitQuat(q, t).to_homogeneous(),
                ),
                "pypose": (lambda d, n: [_pp(d["x0"], "SE3")], lambda a: a.matrix()),
                "pytransform3d": (
                    numpy("x0"),
                    one_or_batch(
                        pt and pt.transform_from_dual_quaternion,
                        ptr and ptr.transforms_from_dual_quaternions,
                    ),
                ),
            },
        ),
        "dq_from_matrix": (
            ("T",),
            dq.from_matrix,
            {
                "pypose": (lambda d, n: [d["T"]], lambda a: pp.mat2SE3(a, check=False)),
                "pytransform3d": (
                    numpy("T"),
                    one_or_batch(
                        pt and pt.dual_quaternion_from_transform,
                        ptr and ptr.dual_quaternions_from_transforms,
                    ),
                ),
            },
        ),
        "dq_from_rt": (
            ("q0", "v"),
            dq.from_rt,
            {
                "pytransform3d": (
                    lambda d, n: [
                        np.concatenate((_np(d["v"]), _np(d["q0"])), -1)[
                            0 if n == 1 else slice(None)
                        ]
                    ],
                    one_or_batch(
                        pt and pt.dual_quaternion_from_pq, ptr and ptr.dual_quaternions_from_pqs
                    ),
                )
            },
        ),
        "dq_to_rt": (
            ("x0",),
            dq.to_rt,
            {
                "pytransform3d": (
                    numpy("x0"),
                    one_or_batch(
                        pt and pt.pq_from_dual_quaternion, ptr and ptr.pqs_from_dual_quaternions
                    ),
                )
            },
        ),
        "dq_exp": (
            ("xi",),
            dq.exp,
            {
                "pypose": (lambda d, n: [_pp(d["xi"], "se3")], lambda a: a.Exp()),
                "pytransform3d": (
                    numpy("xi"),
                    one_or_batch(
                        pt and pt.transform_from_exponential_coordinates,
                        ptr and ptr.transforms_from_exponential_coordinates,
                    ),
                ),
            },
        ),
        "dq_log": (
            ("x0",),
            dq.log,
            {
                "pypose": (lambda d, n: [_pp(d["x0"], "SE3")], lambda a: a.Log()),
                "pytransform3d": (
                    numpy("T"),
                    one_or_batch(
                        pt and pt.exponential_coordinates_from_transform,
                        ptr and ptr.exponential_coordinates_from_transforms,
                    ),
                ),
            },
        ),
        "dq_to_screw": (
            ("x0",),
            dq.to_screw,
            {
                "pytransform3d": (
                    numpy("x0"),
                    one_or_batch(
                        pt and pt.screw_parameters_from_dual_quaternion,
                        ptr and ptr.screw_parameters_from_dual_quaternions,
                    ),
                )
            },
        ),
        "dq_sclerp": (
            ("x0", "x1", "s"),
            dq.sclerp,
            {
                "pypose": (
                    lambda d, n: [_pp(d["x0"], "SE3"), _pp(d["x1"], "SE3"), d["s"][:, None]],
                    lambda a, b, s: a * (a.Inv() * b).Log().mul(s).Exp(),
                ),
                "pytransform3d": (
                    lambda d, n: (
                        [_np(d["x0"]), _np(d["x1"]), _np(d["s"])]
                        if n > 1
                        else [_np(d["x0"][0]), _np(d["x1"][0]), float(d["s"][0])]
                    ),
                    one_or_batch(
                        pt and pt.dual_quaternion_sclerp, ptr and ptr.dual_quaternions_sclerp
                    ),
                ),
            },
        ),
        "dq_dlb": (("w", "xs"), dq.dlb, {}),
    }
    return ops


def _cpu_ms(fn, min_ms):
    """CPU ms per call of ``fn``, looping until one sample lasts ``min_ms``."""
    k = 1
    while True:
        t0 = time.process_time()
        for _ in range(k):
            fn()
        dt = (time.process_time() - t0) * 1e3
        if dt >= min_ms or k >= 1 << 16:
            return dt / k, k
        k *= max(2, int(min_ms / max(dt, 1e-3)))


def _timed(fn, k):
    t0 = time.process_time()
    for _ in range(k):
        fn()
    return (time.process_time() - t0) * 1e3 / k


def _backward(fn, args):
    leaves = [a for a in args if isinstance(a, torch.Tensor) and a.requires_grad]

    def run():
        out = fn(*args)
        out = out if isinstance(out, (tuple, list)) else (out,)
        y = sum(o.tensor().sum() if hasattr(o, "tensor") else o.sum() for o in out)
        torch.autograd.grad(y, leaves)

    return run


def _grad_args(args):
    out = []
    for a in args:
        if isinstance(a, torch.Tensor) and a.is_floating_point():
            a = a.detach().clone().requires_grad_()
        out.append(a)
    return out


def bench_op(name, n, dtype, repeats, min_ms, backward):
    names, ours, peers = _ops()[name]
    d = _inputs(n, dtype)
    rows = []
    for peer, (prep, pfn) in peers.items():
        if isinstance(pfn, _Pick):
            pfn = pfn.at(n)
        if peer not in M or pfn is None or (backward and peer == "pytransform3d"):
            continue
        m = min(n, PEER_CAP) if peer in ("pytransform3d", "pypose") else n
        pd = _inputs(m, dtype) if m != n else d
        if peer == "pytransform3d" and dtype != torch.float64:
            pd = _inputs(m, torch.float64)
        pargs = prep(pd, m)
        our_args = [d[k] for k in names]
        if backward:
            pargs, our_args = _grad_args(pargs), _grad_args(our_args)
            fa, fb = _backward(ours, our_args), _backward(pfn, pargs)
        else:
            fa, fb = functools.partial(ours, *our_args), functools.partial(pfn, *pargs)
        _, ka = _cpu_ms(fa, min_ms)
        _, kb = _cpu_ms(fb, min_ms)
        best_a = best_b = float("inf")
        for _ in range(repeats):
            best_a = min(best_a, _timed(fa, ka))
            best_b = min(best_b, _timed(fb, kb) * n / m)
        rows.append(
            {
                "op": name + (" bwd" if backward else ""),
                "n": n,
                "dtype": str(dtype).split(".")[-1],
                "peer": peer,
                "ours_ms": best_a,
                "peer_ms": best_b,
                "ratio": best_a / best_b,
                "scaled": m != n,
            }
        )
    if not peers:
        our_args = _grad_args([d[k] for k in names]) if backward else [d[k] for k in names]
        fa = _backward(ours, our_args) if backward else functools.partial(ours, *our_args)
        _, ka = _cpu_ms(fa, min_ms)
        best = min(_timed(fa, ka) for _ in range(repeats))
        rows.append(
            {
                "op": name + (" bwd" if backward else ""),
                "n": n,
                "dtype": str(dtype).split(".")[-1],
                "peer": "-",
                "ours_ms": best,
                "peer_ms": float("nan"),
                "ratio": float("nan"),
                "scaled": False,
            }
        )
    return rows


NO_BWD = {"q_conj", "dq_conj", "dq_to_rt", "dq_from_rt"}  # linear ops: backward is a copy


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="1,1000,1000000")
    p.add_argument("--dtypes", default="float32,float64")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--min-ms", type=float, default=20.0)
    p.add_argument("--only", default="")
    p.add_argument("--no-backward", action="store_true")
    p.add_argument("--json", default="")
    a = p.parse_args()
    torch.set_num_threads(a.threads)
    names = [s for s in a.only.split(",") if s] or list(_ops())
    rows = []
    with open("/proc/loadavg") as f:
        load = f.read().split()[:3]
    print(
        f"# threads {a.threads}, load {' '.join(load)}, torch {torch.__version__}, "
        f"peers {', '.join(k for k in ('roma', 'pypose', 'pytransform3d') if k in M)}"
    )
    print(
        f"{'op':<20}{'n':>9} {'dtype':<8}{'peer':<14}{'ours ms':>11}{'peer ms':>11}"
        f"{'ours/peer':>10}"
    )
    for name in names:
        for dtype in (getattr(torch, s) for s in a.dtypes.split(",")):
            for n in (int(float(s)) for s in a.sizes.split(",")):
                for bwd in (False, True):
                    if bwd and (a.no_backward or n == 1 or name in NO_BWD):
                        continue
                    try:
                        new = bench_op(name, n, dtype, a.repeats, a.min_ms, bwd)
                    except Exception as exc:  # a peer's API mismatch: say so, go on
                        print(f"{name:<20}{n:>9} {dtype}: error {type(exc).__name__}: {exc}")
                        continue
                    for r in new:
                        print(
                            f"{r['op']:<20}{r['n']:>9} {r['dtype']:<8}{r['peer']:<14}"
                            f"{r['ours_ms']:>11.4g}{r['peer_ms']:>11.4g}{r['ratio']:>10.2f}"
                            + (" (peer scaled)" if r["scaled"] else ""),
                            flush=True,
                        )
                    rows += new
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"threads": a.threads, "load": load, "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()

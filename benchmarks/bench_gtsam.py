"""IMU + poses estimation side by side: torch_dq ``fitting.estimate`` against GTSAM's batch
Levenberg-Marquardt over preintegrated IMU factors, on the same synthetic job.

The job (``--duration`` seconds): a closed-form smooth motion (positions as sums of sines,
the rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` with sine Euler angles), poses at 20 Hz with
1 mrad / 1 mm noise, an IMU at 200 Hz (gyro ``R^T w + b_g``, 2e-3 rad/s noise; accelerometer
``R^T (a - g) + b_a``, 2e-2 m/s^2 noise; constant biases, gravity ``(0, 0, -9.81)``).

- torch_dq: a cumulative cubic ``BSpline`` with a knot about every 0.05 s (``n_ctrl`` = the
  number of poses, the most ``from_dualquats`` starts from), ``fitting.Poses``, ``Gyro`` and
  ``Accel`` with ``bias=True``, ``estimate(..., verbose=False)``, then ``std`` of both biases.
- GTSAM: ``PreintegratedCombinedMeasurements`` / ``CombinedImuFactor`` between the 20 Hz
  pose keys (bias random walk 1e-6 per sqrt(s), so near constant), a ``PriorFactorPose3`` per
  pose, a weak bias prior, started from the poses (velocities by finite differences, zero
  biases), ``LevenbergMarquardtOptimizer``, then ``Marginals`` for the middle key's bias.

``torch_dq+reuse``: the same with ``torch_dq.reuse_memory()`` called first (freed temporaries
kept in the heap, as the ``python -m torch_dq`` commands do; glibc only): the library's
default leaves glibc's, which returns each system's temporaries to the operating system and
faults them in again at the next.

Each side runs in a child process of its own (``--threads`` torch / OpenMP threads), warm
(an untimed 10 s job first), best of ``--repeats``; peak memory is the child's peak resident
set (``resource.getrusage``) and its increase over the resident set before the first run.
Bias errors are reported in standard deviations of the estimate (``|estimate - truth| /
std`` per axis, the largest of the three). ``--cpu`` reports process CPU seconds
(steadier on a shared machine). ``--scaling`` times one warm run per duration (10, 60, 300,
1200 s; ``--long`` adds 3600 s) and fits the time per LM step against the samples.
``--device cuda`` runs torch_dq's side on the GPU (the job's tensors and the spline moved
there; times after ``torch.cuda.synchronize``, peak memory the GPU allocator's peak;
GTSAM stays on the CPU).
``--real`` replaces the synthetic motion by a real one (:func:`make_real_job`: a hand-held
camera's motion capture, the repository's TUM freiburg1_xyz subsample by default); ``--knot``
sets torch_dq's knot spacing (at most one control point per pose).

    python benchmarks/bench_gtsam.py                       # 60 s, 1 and 2 threads
    python benchmarks/bench_gtsam.py --scaling --threads 1 # the scaling series
    python benchmarks/bench_gtsam.py --real                # real motion: TUM fr1_xyz poses,
                                                           # IMU from scipy's smoothing spline
    python benchmarks/bench_gtsam.py --profile --threads 1 # CPU time per solver phase,
                                                           # cProfile, torch.profiler

GTSAM (``pip install gtsam``, the ``bench`` extra) is optional: without it only torch_dq's
column is filled.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import resource
import subprocess
import sys
import time

import numpy as np

G = 9.81
CLOCK = 0  # 0: wall-clock times, 1: process CPU times (--cpu)
DEVICE = "cpu"  # torch_dq's device (--device)
POSE_HZ, IMU_HZ, KNOT = 20, 200, 0.05
SIGMA_ROT, SIGMA_POS, SIGMA_GYRO, SIGMA_ACC = 1e-3, 1e-3, 2e-3, 2e-2
B_GYRO = np.array([0.01, -0.02, 0.015])
B_ACC = np.array([0.05, -0.08, 0.1])


# ----------------------------------------------------------------------------- the job

def _euler(t: np.ndarray):
    """ZYX angles (yaw, pitch, roll) and their first derivatives."""
    yaw, dyaw = 0.5 * t + 0.3 * np.sin(0.7 * t), 0.5 + 0.21 * np.cos(0.7 * t)
    pitch, dpitch = 0.15 * np.sin(1.1 * t + 0.5), 0.165 * np.cos(1.1 * t + 0.5)
    roll, droll = 0.2 * np.sin(0.9 * t), 0.18 * np.cos(0.9 * t)
    return (yaw, pitch, roll), (dyaw, dpitch, droll)


def quaternion(t: np.ndarray) -> np.ndarray:
    """``(N, 4)`` (w, x, y, z) of ``Rz(yaw) Ry(pitch) Rx(roll)``."""
    (y, p, r), _ = _euler(t)
    cy, sy, cp, sp, cr, sr = (f(a / 2) for a in (y, p, r) for f in (np.cos, np.sin))
    return np.stack((cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
                     cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr), -1)


def rotation(t: np.ndarray) -> np.ndarray:
    """``(N, 3, 3)`` body to world."""
    w, x, y, z = quaternion(t).T
    return np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)),
                    -1).reshape(-1, 3, 3)


def body_rate(t: np.ndarray) -> np.ndarray:
    """``(N, 3)`` body angular velocity of the ZYX rotation (closed form)."""
    (_, p, r), (dy, dp, dr) = _euler(t)
    return np.stack((dr - dy * np.sin(p), dp * np.cos(r) + dy * np.cos(p) * np.sin(r),
                     -dp * np.sin(r) + dy * np.cos(p) * np.cos(r)), -1)


def position(t: np.ndarray, order: int = 0) -> np.ndarray:
    """``(N, 3)`` world position (``order`` 0) or its ``order``-th derivative."""
    amp = np.array([3.0, 2.0, 0.5])
    freq = np.array([0.4, 0.6, 0.8])
    phase = np.array([0.0, 0.3, 1.0])
    arg = t[:, None] * freq + phase + order * np.pi / 2
    return amp * freq**order * np.sin(arg)


def make_job(duration: float, seed: int = 0) -> dict:
    """Truth and noisy measurements of a ``duration`` s job (numpy float64)."""
    rng = np.random.default_rng(seed)
    tc = np.arange(round(duration * POSE_HZ) + 1) / POSE_HZ
    ti = np.arange(round(duration * IMU_HZ) + 1) / IMU_HZ
    Rc, Ri = rotation(tc), rotation(ti)
    g = np.array([0.0, 0.0, -G])
    gyro = body_rate(ti) + B_GYRO + SIGMA_GYRO * rng.standard_normal((len(ti), 3))
    acc = (np.einsum("nji,nj->ni", Ri, position(ti, 2) - g) + B_ACC
           + SIGMA_ACC * rng.standard_normal((len(ti), 3)))
    drot = SIGMA_ROT * rng.standard_normal((len(tc), 3))  # right-multiplied (body axes)
    meas_R = np.einsum("nij,njk->nik", Rc, _expm(drot))
    meas_p = position(tc) + SIGMA_POS * rng.standard_normal((len(tc), 3))
    return dict(tc=tc, ti=ti, R=meas_R, p=meas_p, gyro=gyro, acc=acc)


REAL_FILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "tests", "data",
                         "tum_fr1_xyz_sub.txt")
REAL: str | None = None  # --real: the job of make_real_job(REAL) instead of make_job


def make_real_job(path: str, seed: int = 0) -> dict:
    """The real-motion job (``--real``): TUM motion-capture poses of a hand-held camera
    (``path``, TUM format, UNIX seconds), every second line as a pose measurement, as they
    are (the capture's own noise), and a 200 Hz IMU on the same clock with the synthetic
    job's biases, noise and gravity. TUM has no IMU: its motion is scipy's smoothing spline
    of the capture (``make_smoothing_spline``, its own generalised cross-validation, per
    position axis and per component of the rotation vector ``phi`` of ``R_0^T R(t)``; an
    interpolant would turn the capture's millimetre noise into accelerations of metres per
    second squared that no rigid body has), gyro ``J_r(phi) dphi/dt``, accelerometer
    ``R^T (a - g)``: a model independent of both solvers."""
    from scipy.interpolate import make_smoothing_spline
    from scipy.spatial.transform import Rotation
    a = np.loadtxt(path, comments="#")
    t, rot = a[:, 0], Rotation.from_quat(a[:, 4:8])  # (qx, qy, qz, qw)
    phi = (rot[0].inv() * rot).as_rotvec()  # small on a hand-held sequence: no wrap
    fits = [make_smoothing_spline(t - t[0], x) for x in (*a[:, 1:4].T, *phi.T)]
    tc = t[::2]
    ti = tc[0] + np.arange(int((tc[-1] - tc[0]) * IMU_HZ) + 1) / IMU_HZ  # within the poses
    val = [np.stack([f(ti - t[0], nu) for f in fits], -1) for nu in (0, 1, 2)]
    ph, dph = val[0][:, 3:], val[1][:, 3:]
    th = np.linalg.norm(ph, axis=-1)[:, None, None]
    hat = np.zeros((len(ti), 3, 3))
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -ph[:, 2], ph[:, 1], -ph[:, 0]
    hat = hat - hat.transpose(0, 2, 1)
    A = np.where(th > 1e-8, (1 - np.cos(th)) / np.maximum(th, 1e-300) ** 2, 0.5)
    B = np.where(th > 1e-8, (th - np.sin(th)) / np.maximum(th, 1e-300) ** 3, 1 / 6)
    Jr = np.eye(3) - A * hat + B * hat @ hat  # the right Jacobian of SO(3)
    Ri = rot[0].as_matrix() @ _expm(ph)
    rng = np.random.default_rng(seed)
    g = np.array([0.0, 0.0, -G])
    gyro = (np.einsum("nij,nj->ni", Jr, dph) + B_GYRO
            + SIGMA_GYRO * rng.standard_normal((len(ti), 3)))
    acc = (np.einsum("nji,nj->ni", Ri, val[2][:, :3] - g) + B_ACC
           + SIGMA_ACC * rng.standard_normal((len(ti), 3)))
    return dict(tc=tc, ti=ti, R=rot[::2].as_matrix(), p=a[::2, 1:4], gyro=gyro, acc=acc)


def _job(duration: float) -> dict:
    """The job the run times: the real-motion one where ``--real`` is given."""
    return make_real_job(REAL) if REAL else make_job(duration)


def _expm(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for ``(N, 3)`` rotation vectors."""
    th = np.linalg.norm(w, axis=-1)[:, None, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K = K - K.transpose(0, 2, 1)
    s = np.where(th > 1e-12, np.sin(th) / np.where(th > 0, th, 1), 1.0)
    c = np.where(th > 1e-12, (1 - np.cos(th)) / np.where(th > 0, th, 1) ** 2, 0.5)
    return np.eye(3) + s * K + c * K @ K


def _now() -> np.ndarray:
    """Wall-clock and process CPU seconds (the CPU time is the steadier figure on a loaded
    machine; with 2 threads it counts both), after the GPU's queued work (``--device``)."""
    if DEVICE != "cpu":
        import torch
        torch.cuda.synchronize()
    return np.array([time.perf_counter(), time.process_time()])


def _sigmas(est: np.ndarray, std: np.ndarray, truth: np.ndarray) -> float:
    return float(np.max(np.abs(est - truth) / std))


# ----------------------------------------------------------------------------- torch_dq

def torch_dq_run(job: dict):
    """One torch_dq solve; returns (setup, solve, uncertainty seconds, steps, result)."""
    import torch

    import torch_dq.dualquat as dq
    from torch_dq import fitting, quat
    from torch_dq.nn import BSpline
    f64 = torch.float64
    t0 = _now()
    tc, ti, R, p, w, a = (torch.from_numpy(job[k]).to(DEVICE)
                          for k in ("tc", "ti", "R", "p", "gyro", "acc"))
    poses = dq.from_rt(quat.from_matrix(R), p)
    duration = float(tc[-1] - tc[0])
    n_ctrl = min(math.ceil(duration / KNOT - 1e-9) + 3, len(tc))  # the start needs <= N
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=n_ctrl, form="cumulative")
    cam = fitting.Poses(tc, poses, rot_sigma=SIGMA_ROT, trans_sigma=SIGMA_POS)
    gyro = fitting.Gyro(ti, w, sigma=SIGMA_GYRO, bias=True)
    acc = fitting.Accel(ti, a, sigma=SIGMA_ACC, bias=True,
                        gravity=torch.tensor([0.0, 0.0, -G], dtype=f64, device=DEVICE))
    t1 = _now()
    est = fitting.estimate(spline, [cam, gyro, acc], verbose=False)
    t2 = _now()
    sg, sa = est.std(gyro, "bias"), est.std(acc, "bias")
    t3 = _now()
    sg, sa, bg, ba = (x.cpu().numpy() for x in (sg, sa, gyro.bias, acc.bias))
    res = dict(gyro_sigmas=_sigmas(bg, sg, B_GYRO), acc_sigmas=_sigmas(ba, sa, B_ACC),
               gyro_std=float(sg.max()), acc_std=float(sa.max()), reason=est.reason)
    return t1 - t0, t2 - t1, t3 - t2, est.steps, res


# ----------------------------------------------------------------------------- GTSAM

def gtsam_run(job: dict):
    """One GTSAM solve; returns (setup, solve, uncertainty seconds, iterations, result)."""
    import gtsam
    from gtsam.symbol_shorthand import B, V, X
    t0 = _now()
    tc, ti = job["tc"], job["ti"]
    dt = 1.0 / IMU_HZ
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(G)
    params.setGyroscopeCovariance(SIGMA_GYRO**2 * dt * np.eye(3))  # density from the rate
    params.setAccelerometerCovariance(SIGMA_ACC**2 * dt * np.eye(3))
    params.setIntegrationCovariance(1e-10 * np.eye(3))
    params.setBiasOmegaCovariance(1e-12 * np.eye(3))
    params.setBiasAccCovariance(1e-12 * np.eye(3))
    graph, init = gtsam.NonlinearFactorGraph(), gtsam.Values()
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([SIGMA_ROT] * 3 + [SIGMA_POS] * 3))
    zero = gtsam.imuBias.ConstantBias()
    poses = [gtsam.Pose3(gtsam.Rot3(R), p) for R, p in zip(job["R"], job["p"], strict=True)]
    vel = np.gradient(job["p"], tc, axis=0)
    for i, pose in enumerate(poses):
        graph.add(gtsam.PriorFactorPose3(X(i), pose, pose_noise))
        init.insert(X(i), pose)
        init.insert(V(i), vel[i])
        init.insert(B(i), zero)
    graph.add(gtsam.PriorFactorConstantBias(B(0), zero, gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    k = np.searchsorted(ti, tc, side="left")  # IMU samples [k_i, k_{i+1}) between keys
    pim = gtsam.PreintegratedCombinedMeasurements(params, zero)
    for i in range(len(tc) - 1):
        pim.resetIntegrationAndSetBias(zero)
        for j in range(k[i], k[i + 1]):
            pim.integrateMeasurement(job["acc"][j], job["gyro"][j], dt)
        graph.add(gtsam.CombinedImuFactor(X(i), V(i), X(i + 1), V(i + 1), B(i), B(i + 1), pim))
    t1 = _now()
    lm = gtsam.LevenbergMarquardtParams()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, lm)
    result = opt.optimize()
    t2 = _now()
    mid = len(tc) // 2
    cov = gtsam.Marginals(graph, result).marginalCovariance(B(mid))
    t3 = _now()
    bias = result.atConstantBias(B(mid))
    std = np.sqrt(np.diag(cov))  # (acc, gyro)
    res = dict(gyro_sigmas=_sigmas(bias.gyroscope(), std[3:], B_GYRO),
               acc_sigmas=_sigmas(bias.accelerometer(), std[:3], B_ACC),
               gyro_std=float(std[3:].max()), acc_std=float(std[:3].max()),
               reason=f"error {opt.error():.4g}")
    return t1 - t0, t2 - t1, t3 - t2, opt.iterations(), res


# ----------------------------------------------------------------------------- children

def child(side: str, duration: float, repeats: int, threads: int) -> dict:
    """Runs in a fresh process: warm-up, then the best of ``repeats``."""
    import torch
    torch.set_num_threads(threads)
    job = _job(duration)
    if side == "torch_dq+reuse":  # freed temporaries kept in the heap (torch_dq.reuse_memory)
        import torch_dq
        torch_dq.reuse_memory()
    run = gtsam_run if side == "gtsam" else torch_dq_run
    run(make_job(10.0))  # warm-up on a 10 s job (imports, first calls)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    gpu = side != "gtsam" and DEVICE != "cpu"
    if gpu:
        torch.cuda.reset_peak_memory_stats()
    runs = [run(job) for _ in range(repeats)]
    best = min(runs, key=lambda r: r[1][CLOCK] + r[2][CLOCK])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    if gpu:  # the GPU allocator's peak, and its share above what the first run started from
        base, peak = 0, torch.cuda.max_memory_allocated() / 1024
    span = float(job["tc"][-1] - job["tc"][0])
    return dict(side=side + ("@" + DEVICE if gpu else ""), duration=span, threads=threads,
                setup=best[0][CLOCK], solve=best[1][CLOCK], unc=best[2][CLOCK],
                steps=best[3], peak_mb=peak / 1024,
                grew_mb=(peak - base) / 1024, imu=len(job["ti"]), poses=len(job["tc"]),
                wall=[float(r[1][0] + r[2][0]) for r in runs],
                cpu=[float(r[1][1] + r[2][1]) for r in runs], **best[4])


def spawn(side: str, duration: float, repeats: int, threads: int) -> dict | None:
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads))
    cmd = [sys.executable, __file__, "--child", side, "--duration", str(duration),
           "--repeats", str(repeats), "--threads", str(threads), "--knot", str(KNOT)]
    cmd += (["--cpu"] if CLOCK else []) + (["--real", REAL] if REAL else [])
    cmd += ["--device", DEVICE]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode:
        print(f"  {side} failed:\n{out.stderr[-2000:]}", file=sys.stderr)
        return None
    return json.loads(out.stdout.strip().splitlines()[-1])


def _row(r: dict) -> str:
    return (f"{r['side']:14s} {r['threads']}t {r['duration']:6.0f} s: setup {r['setup']:7.3f} s, "
            f"solve {r['solve']:7.3f} s ({r['steps']} steps), uncertainty {r['unc']:6.3f} s, "
            f"total {r['solve'] + r['unc']:7.3f} s; peak RSS {r['peak_mb']:6.0f} MB (+"
            f"{r['grew_mb']:.0f}); bias errors gyro {r['gyro_sigmas']:.2f} sd "
            f"(sd {r['gyro_std']:.2e}), accel {r['acc_sigmas']:.2f} sd "
            f"(sd {r['acc_std']:.2e})")


def side_by_side(duration: float, repeats: int, threads: list[int], sides: list[str]) -> None:
    job = _job(duration)
    what = f"real motion ({os.path.basename(REAL)})" if REAL else f"{duration:g} s"
    print(f"{what} job: {len(job['ti'])} IMU samples, {len(job['tc'])} poses over "
          f"{job['tc'][-1] - job['tc'][0]:.1f} s; warm, best of {repeats} "
          f"({'process CPU' if CLOCK else 'wall-clock'} seconds)")
    for th in threads:
        rows = {s: spawn(s, duration, repeats, th) for s in sides}
        for r in rows.values():
            if r is not None:
                print("  " + _row(r), flush=True)
        b = rows.get("gtsam")
        for name in ("torch_dq", "torch_dq+reuse"):
            a = rows.get(name)
            if a and b:
                print(f"  {th} thread(s): {a['side']} estimate + std / GTSAM solve + marginals = "
                      f"{(a['solve'] + a['unc']) / (b['solve'] + b['unc']):.2f}x")


def scaling(durations: list[float], threads: int, sides: list[str]) -> None:
    print(f"scaling, {threads} thread(s), one warm run each")
    for side in sides:
        pts = []
        for d in durations:
            r = spawn(side, d, 1, threads)
            if r is None:
                continue
            print("  " + _row(r), flush=True)
            samples = r["imu"] + r["poses"]
            pts.append((samples, r["solve"] / max(r["steps"], 1)))
        if len(pts) >= 2:
            x, y = np.array(pts).T
            slope, icpt = np.polyfit(x, y, 1)
            expo = np.polyfit(np.log(x), np.log(y), 1)[0]
            print(f"  {side}: {'CPU' if CLOCK else 'wall'} time per step = {1e6 * slope:.2f} "
                  f"us x samples + {icpt:.3f} s (log-log exponent {expo:.2f})")


_PHASES = [  # (module, attribute, label) of the solver's phases (private: skipped if renamed)
    ("_linearize", "Linearization.system", "Gauss-Newton system (Jacobians + assembly)"),
    ("_local", "SpanEvaluator.shared",
     "  span derivatives at the point (shared control points; costs too)"),
    ("_linearize", "Linearization._span_derivatives",
     "  span derivatives on per-sample copies (the reverse passes' forward)"),
    ("_linearize", "Linearization._through_spans", "  reverse passes through the spans"),
    ("_linearize", "sample_jacobians", "  residual Jacobians w.r.t. span derivatives"),
    ("_linearize", "_window_normal", "  assembly of the banded normal equations"),
    ("_normal", "_Normal.add_samples", "  assembly of the banded normal equations (compiled)"),
    ("_problem", "Problem.data_cost", "trial costs (span path)"),
    ("_solver", "DampedStep.step", "damped solves (banded Cholesky + Schur)"),
    ("_lm", "LevenbergMarquardt._prior_gradient", "prior gradients"),
    ("_uncertainty", "Estimate._factor", "uncertainty factorisation"),
]


def _instrument(totals: dict, counts: dict) -> None:
    """Wrap the phases of :data:`_PHASES` to add their process CPU time to ``totals``."""
    import functools
    import importlib
    for mod_name, attr, label in _PHASES:
        mod = importlib.import_module(f"torch_dq.fitting.{mod_name}")
        *owner_path, name = attr.split(".")
        owner = mod
        for part in owner_path:
            owner = getattr(owner, part, None)
        fn = getattr(owner, name, None) if owner is not None else None
        if fn is None:
            continue

        def wrapped(*a, _fn=fn, _label=label, **k):
            t = time.process_time()
            try:
                return _fn(*a, **k)
            finally:
                totals[_label] = totals.get(_label, 0.0) + time.process_time() - t
                counts[_label] = counts.get(_label, 0) + 1
        setattr(owner, name, functools.wraps(fn)(wrapped))


def profile(duration: float, threads: int) -> None:
    """Process CPU time per solver phase of one warm run, then cProfile's top functions and
    torch.profiler's top operators of one Gauss-Newton system."""
    import cProfile
    import pstats

    import torch
    torch.set_num_threads(threads)
    job = _job(duration)
    torch_dq_run(make_job(10.0))
    totals: dict = {}
    counts: dict = {}
    _instrument(totals, counts)
    _, solve, unc, steps, _ = torch_dq_run(job)
    print(f"{duration:g} s job, {threads} thread(s), process CPU s: estimate {solve[1]:.3f} "
          f"({steps} steps), std of both biases {unc[1]:.3f}")
    print("| phase | calls | CPU s |\n|---|---|---|")
    for _, _, label in _PHASES:
        if label in totals:
            print(f"| {label} | {counts[label]} | {totals[label]:.3f} |")
    prof = cProfile.Profile()
    prof.enable()
    torch_dq_run(job)
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(15)
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    import torch_dq.dualquat as dq
    from torch_dq import fitting, quat
    from torch_dq.fitting import _estimate, _problem
    from torch_dq.nn import BSpline
    tc, ti = (torch.from_numpy(job[k]) for k in ("tc", "ti"))
    poses = dq.from_rt(quat.from_matrix(torch.from_numpy(job["R"])), torch.from_numpy(job["p"]))
    spline = BSpline.from_dualquats(poses, tc, n_ctrl=len(tc), form="cumulative")
    terms = [fitting.Poses(tc, poses, rot_sigma=SIGMA_ROT, trans_sigma=SIGMA_POS),
             fitting.Gyro(ti, torch.from_numpy(job["gyro"]), sigma=SIGMA_GYRO, bias=True),
             fitting.Accel(ti, torch.from_numpy(job["acc"]), sigma=SIGMA_ACC, bias=True,
                           gravity=torch.tensor([0.0, 0.0, -G], dtype=torch.float64))]
    problem = _problem.Problem(spline, terms, torch.Size([]))
    ctrl = spline.control_points.detach().to(torch.float64)
    values = _estimate._starts("profile", problem, ctrl)
    width = problem.width(values)
    problem.system(ctrl, values, width)
    with torch_profile(activities=[ProfilerActivity.CPU]) as tp:
        problem.system(ctrl, values, width)
    print(tp.key_averages().table(sort_by="self_cpu_time_total", row_limit=12))


def main() -> None:
    global CLOCK, REAL, KNOT, DEVICE
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--scaling", action="store_true")
    ap.add_argument("--long", action="store_true", help="add 3600 s to the scaling series")
    ap.add_argument("--durations", help="comma list of the scaling series' durations (s)")
    ap.add_argument("--only", choices=["torch_dq", "torch_dq+reuse", "gtsam"])
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--knot", type=float, default=KNOT,
                    help="torch_dq's knot spacing in seconds (default %(default)s)")
    ap.add_argument("--real", nargs="?", const=REAL_FILE, metavar="TUM_FILE",
                    help="the real-motion job (make_real_job) on a TUM trajectory file "
                         "(default: the repository's tests/data/tum_fr1_xyz_sub.txt)")
    ap.add_argument("--device", default="cpu",
                    help="torch_dq's device: cpu (default) or cuda (GTSAM stays on the CPU)")
    ap.add_argument("--cpu", action="store_true",
                    help="report process CPU seconds instead of wall-clock (loaded machines)")
    ap.add_argument("--child", choices=["torch_dq", "torch_dq+reuse", "gtsam"],
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    threads = [int(x) for x in args.threads.split(",")]
    CLOCK, REAL, KNOT, DEVICE = (1 if args.cpu else 0), args.real, args.knot, args.device
    if args.child:
        print(json.dumps(child(args.child, args.duration, args.repeats, threads[0])))
        return
    if args.profile:
        profile(args.duration, threads[0])
        return
    import torch
    have = importlib.util.find_spec("gtsam") is not None
    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    reuse = glibc and args.device == "cpu"  # the heap's reuse is a CPU matter
    sides = ["torch_dq"] + (["torch_dq+reuse"] if reuse else []) + (["gtsam"] if have else [])
    if args.only:
        sides = [s for s in sides if s == args.only]
    if not have:
        print("gtsam not installed (pip install gtsam): torch_dq only")
    print(f"{platform.node()} {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs, torch {torch.__version__}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, load "
          f"{os.getloadavg()[0]:.1f}")
    if args.scaling:
        durations = [10.0, 60.0, 300.0, 1200.0] + ([3600.0] if args.long else [])
        if args.durations:
            durations = [float(x) for x in args.durations.split(",")]
        for th in threads:
            scaling(durations, th, sides)
    else:
        side_by_side(args.duration, args.repeats, threads, sides)


if __name__ == "__main__":
    main()

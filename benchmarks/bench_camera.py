"""Section ``camera``: ``camera.project`` / ``camera.unproject`` against OpenCV and plain torch.

Models: ``pinhole-radtan`` (EuRoC cam0), ``pinhole-equidistant`` (TUM VI cam0) and
``double-sphere`` (close to basalt's TUM VI calibration), on points up to 60 degrees off axis
and their pixels. Peers:

- OpenCV (float64 numpy, CPU): ``cv2.projectPoints`` with ``(k1, k2, p1, p2, 0)`` and
  ``cv2.fisheye.projectPoints``: their Python binding always computes the optional ``(2N,
  15)`` Jacobian w.r.t. pose and intrinsics (no way to skip it from Python), so OpenCV's
  projection time includes it (said in the note). ``cv2.undistortPoints`` /
  ``cv2.fisheye.undistortPoints`` with their default criteria (approximate for radtan: a
  few fixed-point iterations, 3e-4 in normalised coordinates at the image's corners, see
  the notes' max|diff|) and, for radtan, a second row with criteria ``(COUNT + EPS, 100,
  1e-14)`` that converge to rounding as ours do; OpenCV has no double sphere. Forward only.
- plain torch: the textbook formulas written here without masks or safe-where, autograd
  through them; for unprojection the same Newton iterations (10, then nothing), autograd
  through the loop.

The solver's cost per observation (float64 only, the solve's dtype): the per-sample
residuals and Jacobians that ``fitting.estimate`` computes at every step (the internal
``Linearization._chained``, exact Jacobians chained through the spans), and the whole
Gauss-Newton system accumulation (``Problem.system``) of one term, for a ``Reprojections``
term (radtan camera, 2 rows per observation) against a ``Poses`` term (6 rows), both with an
estimated extrinsic, the same spline and the same number of samples.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from _bench import Bench, err, grad, peer_time, seeded
from _peers import _need

import torch_dq.dualquat as dq
from torch_dq import camera, fitting, quat
from torch_dq.calibration import aprilgrid
from torch_dq.fitting._estimate import _starts
from torch_dq.fitting._problem import Problem
from torch_dq.nn import BSpline

PARAMS = {
    "pinhole-radtan": [458.654, 457.296, 367.215, 248.375, -0.28340811, 0.07395907,
                       0.00019359, 1.76187114e-05],
    "pinhole-equidistant": [190.978, 190.973, 254.932, 256.897, 0.0034824, 0.00071503,
                            -0.0020532, 0.00020294],
    "double-sphere": [158.28, 158.27, 254.94, 256.90, -0.1716, 0.5927],
}
ITERATIONS = 10


# ----------------------------------------------------------------------------- plain torch

def plain_project(model, p, x):
    """The textbook projection, no masks (NaN on the axis for the fisheye's theta / r)."""
    px, py, pz = x.unbind(-1)
    if model == "double-sphere":
        xi, alpha = p[4], p[5]
        d1 = torch.sqrt(px * px + py * py + pz * pz)
        w = xi * d1 + pz
        den = alpha * torch.sqrt(px * px + py * py + w * w) + (1 - alpha) * w
        a, b = px / den, py / den
    else:
        a, b = px / pz, py / pz
        r2 = a * a + b * b
        if model == "pinhole-radtan":
            k1, k2, p1, p2 = p[4:]
            rad = 1 + k1 * r2 + k2 * r2 * r2
            a, b = (a * rad + 2 * p1 * a * b + p2 * (r2 + 2 * a * a),
                    b * rad + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b)
        else:
            r = torch.sqrt(r2)
            th = torch.atan(r)
            t2 = th * th
            k1, k2, k3, k4 = p[4:]
            s = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) / r
            a, b = a * s, b * s
    return torch.stack([p[0] * a + p[2], p[1] * b + p[3]], -1)


def plain_unproject(model, p, pix):
    """Newton iterations differentiated through (radtan, equidistant); eqs. 47-50 (ds)."""
    a, b = (pix[..., 0] - p[2]) / p[0], (pix[..., 1] - p[3]) / p[1]
    if model == "double-sphere":
        xi, alpha = p[4], p[5]
        r2 = a * a + b * b
        mz = (1 - alpha**2 * r2) / (alpha * torch.sqrt(1 - (2 * alpha - 1) * r2) + 1 - alpha)
        k = (mz * xi + torch.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
        return torch.stack([k * a, k * b, k * mz - xi], -1)
    if model == "pinhole-radtan":
        k1, k2, p1, p2 = p[4:]
        x, y = a, b
        for _ in range(ITERATIONS):
            r2 = x * x + y * y
            rad = 1 + k1 * r2 + k2 * r2 * r2
            q = 2 * (k1 + 2 * k2 * r2)
            fx = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - a
            fy = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - b
            j00 = rad + q * x * x + 2 * p1 * y + 6 * p2 * x
            j01 = q * x * y + 2 * (p1 * x + p2 * y)
            j11 = rad + q * y * y + 6 * p1 * y + 2 * p2 * x
            det = j00 * j11 - j01 * j01
            x, y = x - (j11 * fx - j01 * fy) / det, y - (j00 * fy - j01 * fx) / det
        ray = torch.stack([x, y, torch.ones_like(x)], -1)
        return ray / ray.norm(dim=-1, keepdim=True)
    k1, k2, k3, k4 = p[4:]
    td = torch.sqrt(a * a + b * b)
    th = td
    for _ in range(ITERATIONS):
        t2 = th * th
        f = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))) - td
        df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        th = th - f / df
    s = torch.sin(th) / td
    return torch.stack([s * a, s * b, torch.cos(th)], -1)


# ----------------------------------------------------------------------------- OpenCV

def _cv_project(model, p, pts):
    cv2 = _need("cv2")
    K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    zero = np.zeros(3)
    if model == "pinhole-radtan":
        return lambda: cv2.projectPoints(pts, zero, zero, K, np.array([*p[4:], 0.0]))[0]
    return lambda: cv2.fisheye.projectPoints(pts[None], zero, zero, K, np.array(p[4:]))[0]


# undistortPoints' criteria that converge to rounding (radtan); None: OpenCV's default
CONVERGED = (3, 100, 1e-14)  # cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS


def _cv_unproject(model, p, pix, criteria=None):
    cv2 = _need("cv2")
    K = np.array([[p[0], 0, p[2]], [0, p[1], p[3]], [0, 0, 1.0]])
    if model == "pinhole-radtan":
        d = np.array([*p[4:], 0.0])
        if criteria is not None:
            return lambda: cv2.undistortPoints(pix[:, None], K, d, criteria=criteria)
        return lambda: cv2.undistortPoints(pix[:, None], K, d)
    return lambda: cv2.fisheye.undistortPoints(pix[:, None], K, np.array(p[4:]))


def _opencv_row(b: Bench, name, dtype, n, ours, nbytes, make, check, unit, what=""):
    """Time OpenCV on float64 numpy copies of the inputs; note the max |diff| to ours."""
    ms, note, made, _ = peer_time(b, "opencv", lambda m: (make(m),), n, cpu_only=True)
    if made is not None:
        try:
            diff = check(made[0]())
            note = "; ".join(x for x in (note, "peer in float64", f"max|diff| {diff:.1e} "
                                         f"{unit}", what) if x)
        except Exception as exc:
            note = f"{note}; check {err(exc)}"
    b.add(name, dtype, n, ours, nbytes, n, "OpenCV", ms, note)


# ----------------------------------------------------------------------------- rows

# Points up to this angle off axis: inside EuRoC cam0's image (radtan; its diagonal half
# field of view is ~45 degrees), and most of the fisheyes' (TUM VI: 95 degrees).
MAX_ANGLE = {"pinhole-radtan": 40.0, "pinhole-equidistant": 80.0, "double-sphere": 80.0}


def _inputs(model, n, dtype, dev):
    g = seeded(dev, 5)
    th = torch.rand(n, generator=g, device=dev, dtype=torch.float64) * math.radians(
        MAX_ANGLE[model])
    ph = torch.rand(n, generator=g, device=dev, dtype=torch.float64) * 2 * math.pi
    d = 0.5 + 5 * torch.rand(n, generator=g, device=dev, dtype=torch.float64)
    pts = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], -1) * d[:, None]
    p = torch.tensor(PARAMS[model], dtype=torch.float64, device=dev)
    pix = camera.project(model, p, pts)[0]
    return p.to(dtype), pts.to(dtype), pix.to(dtype)


def _opencv_rows(b: Bench, dtype, model, n, ours, nbytes, label, p, pts, pix):
    """The OpenCV row of project or unproject (radtan, equidistant)."""
    pts64, pix64 = pts.detach().cpu().double().numpy(), pix.detach().cpu().double().numpy()
    k = min(n, 2000)
    name = f"camera.{label} {model} fwd"
    if label == "project":
        def make(m):
            return _cv_project(model, PARAMS[model], pts64[:m])

        def check(out):
            return float(np.abs(out.reshape(-1, 2)[:k] - pix64[:k]).max())
        _opencv_row(b, name, dtype, n, ours, nbytes, make, check, "px",
                    "OpenCV's time includes the (2N, 15) Jacobian its binding always computes")
        return
    ray = camera.unproject(model, p.double(), pix[:k].double())[0].cpu().numpy()

    def check(out):
        return float(np.abs(out.reshape(-1, 2)[:k] - ray[:, :2] / ray[:, 2:]).max())
    for criteria in (None, CONVERGED) if model == "pinhole-radtan" else (None,):
        def make(m, criteria=criteria):
            return _cv_unproject(model, PARAMS[model], pix64[:m], criteria)
        what = "default criteria" if criteria is None else "criteria (COUNT+EPS, 100, 1e-14)"
        _opencv_row(b, name, dtype, n, ours, nbytes, make, check, "(normalised)", what)


def _model_rows(b: Bench, dtype, model, n):
    size = torch.finfo(dtype).bits // 8
    p, pts, pix = _inputs(model, n, dtype, b.device)
    cases = (("project", camera.project, plain_project, pts),
             ("unproject", camera.unproject, plain_unproject, pix))
    for label, ours_fn, plain_fn, x in cases:
        nbytes = 5 * n * size  # 3 + 2 numbers per item read and written

        def ours_call(p=p, x=x, f=ours_fn):
            return f(model, p, x)[0]

        def plain_call(p=p, x=x, f=plain_fn):
            return f(model, p, x)

        ours = b.time(ours_call)
        if model != "double-sphere":  # OpenCV has no double sphere
            _opencv_rows(b, dtype, model, n, ours, nbytes, label, p, pts, pix)
        b.add(f"camera.{label} {model} fwd", dtype, n, ours, nbytes, n, "plain torch",
              b.time(plain_call))
        pg, xg = p.clone().requires_grad_(), x.clone().requires_grad_()
        ours_fb = b.time(lambda pg=pg, xg=xg, f=ours_call: grad(f(pg, xg), (pg, xg)))
        plain_fb = b.time(lambda pg=pg, xg=xg, f=plain_call: grad(f(pg, xg), (pg, xg)))
        b.add(f"camera.{label} {model} fwd+bwd", dtype, n, ours_fb, 2 * nbytes, n,
              "plain torch", plain_fb, "", "grad of sum wrt params and input")


# ----------------------------------------------------------------------------- solver rows

def _observations(n: int, dev):
    """``n`` AprilGrid corners seen along a 5 s motion 1 m above the grid: the trajectory
    (cumulative, a knot every 0.1 s), times, target points, pixels and poses at the times."""
    f64 = torch.float64
    t = torch.linspace(0.0, 5.0, n, dtype=f64, device=dev)
    rotvec = torch.stack((math.pi + 0.2 * torch.sin(t), 0.2 * torch.cos(1.3 * t), 0.1 * t), -1)
    pos = torch.stack((0.3 + 0.1 * torch.sin(t), 0.3 + 0 * t, 1.0 + 0.1 * torch.cos(t)), -1)
    x = dq.from_rt(quat.from_rotvec(rotvec), pos)
    spline = BSpline.from_dualquats(x, t, n_ctrl=53, form="cumulative").to(dev)
    grid = aprilgrid(6, 6, 0.088, 0.3).to(dev)
    pts = grid[torch.arange(n, device=dev) % len(grid)]
    cam = camera.Camera("pinhole-radtan", torch.tensor(PARAMS["pinhole-radtan"], dtype=f64,
                                                       device=dev), (752, 480))
    pix = cam.project(dq.apply(dq.inv(x), pts))[0]
    return spline, t, pts, pix, cam, x


def _solver_costs(spline, term):
    """``(jacobians, system)``: closures over one term's problem at the spline's points."""
    ctrl = spline.control_points.detach().to(torch.float64)
    problem = Problem(spline, [term], ctrl.shape[:-2])
    values = _starts("bench", problem, ctrl)
    w = problem.width(values)
    return (lambda: problem.linearization._chained(0, problem.terms[0], ctrl, values, w),
            lambda: problem.system(ctrl, values, w))


def _solver_rows(b: Bench, n: int):
    spline, t, pts, pix, cam, x = _observations(n, b.device)
    reproj = fitting.Reprojections(t, pts, pix, camera=cam, sigma=0.3, extrinsic=True)
    poses = fitting.Poses(t, x, rot_sigma=0.01, trans_sigma=0.01, extrinsic=True)
    ours, peer = _solver_costs(spline, reproj), _solver_costs(spline, poses)
    for label, k in (("jacobians", 0), ("normal equations", 1)):
        ms, peer_ms = b.time(ours[k]), b.time(peer[k])
        b.add(f"fitting.Reprojections {label}", torch.float64, n, ms, 0, n, "Poses term",
              peer_ms, "", f"{1e3 * ms / n:.2f} us/observation (2 rows) vs Poses "
              f"{1e3 * peer_ms / n:.2f} us/sample (6 rows), Reprojections / Poses "
              f"{ms / peer_ms:.2f}; estimated extrinsic, per LM step")


def run(b: Bench, dtype):
    n = b.sizes["camera"]
    for model in PARAMS:
        _model_rows(b, dtype, model, n)
    if dtype == torch.float64:  # the solve runs in float64 whatever the data's dtype
        _solver_rows(b, max(n // 50, 2000))

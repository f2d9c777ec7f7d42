r"""Intrinsics of cameras and their relative poses from target observations alone.

:func:`cameras` is Kalibr's ``calibrate_cameras``: one or more cameras look at a planar
calibration target (an AprilGrid or a checkerboard, target points with ``Z = 0``); a frame
is one timestamp, and a frame seen by several cameras (equal timestamps) links them.

1. Start without user guesses (:mod:`torch_dq.calibration._start`): per camera, Zhang's
   closed form from normalised-DLT homographies for the pinhole part with distortion zero,
   or a line search over one focal length (principal point at the image centre; equidistant
   ``k = 0``, double sphere ``xi = 0, alpha = 0.5`` as basalt starts); per view the
   target's pose from the homography of the unprojected points; the cameras' relative
   poses averaged over the frames they share.
2. Bundle adjustment: Levenberg-Marquardt (Marquardt's diagonal damping) over the
   intrinsics ``params + delta``, the relative poses ``T exp(delta)`` and one target pose
   per frame in camera 0's frame (``T exp(delta)``), on the pixel errors
   :math:`e = \pi(\theta_c, T_{0c}^{-1} T_{0f} X) - u`, optionally robust (Huber, Cauchy on
   :math:`\|e\|` in pixels, iteratively reweighted). Exact Jacobians: reverse-mode
   autograd of the projection, one sample-wise pass per pixel axis
   (:func:`torch_dq.fitting._local.sample_jacobians`). The frame poses are eliminated per
   frame (6 x 6 blocks) through the Schur complement on the intrinsics and relative poses.
3. Standard deviations from the Gauss-Newton matrix at the optimum (robust weights as
   converged): the inverse of the Schur complement is the joint covariance of the
   intrinsics and relative poses with the frame poses marginalised, scaled by the
   residuals' variance factor :math:`\hat\sigma^2 = \chi^2 / (2 n - m)` (the corners' noise
   as the fit measures it).

The camera models are :mod:`torch_dq.camera`'s (``project``, ``unproject``, ``Camera``).
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

from .. import _checks, dualquat
from .._camera_values import outside
from ..camera import MODELS, Camera, project
from ..fitting._local import sample_jacobians, tangent_step
from ..fitting._robust import KERNELS, chi_quantile, inliers, rho, weight
from ..fitting._score import THRESHOLD, asking
from . import _start

__all__ = ["CameraCalibration", "cameras", "kalibr_entries"]

_FN = "calibration.cameras"
_SIZES = {model: len(names) for model, names in MODELS.items()}
_LARGEST_TARGET = 20.0  # metres: target points spread wider are in another unit (cm, mm)
_FLOOR = 0.01  # pixels: the smallest pixel error scale the score test of k1 assumes


@dataclass(frozen=True)
class CameraCalibration:
    r"""What :func:`cameras` returns.

    Attributes:
        cameras: one :class:`torch_dq.camera.Camera` per camera, the calibrated intrinsics.
        relative_poses: ``(C - 1, 8)`` camera ``i``'s pose in camera 0's frame
            (``p_cam0 = T p_cami``).
        reprojection_rms: ``(C,)`` root mean square of the pixel error's norm over each
            camera's observations used.
        std: ``"intrinsics"`` ``(C, P)`` (``P`` the largest parameter count; NaN past a
            camera's own), ``"relative_poses"`` ``(C - 1, 6)`` in the chart
            ``T exp(delta)``, ``delta = (omega, v)`` in camera ``i``'s axes. These are
            formal standard deviations: they assume independent white noise on every
            corner (of the fitted ``sigma``). Real corners have errors correlated within a
            frame (target flatness, blur, detector bias), which they do not see: on the
            real EuRoC corners a jackknife over frames scatters the focal lengths about 5
            times their ``std``. Read them as lower bounds; a jackknife or bootstrap over
            frames gives realistic ones.
        target_poses: ``(F, 8)`` the target's pose in camera 0's frame per frame
            (``p_cam0 = T p_target``).
        frame_times: ``(F,)`` the frames' timestamps.
        used: ``(C,)`` observations used per camera; ``excluded``: ``(C,)`` observations
            left out (in a view with too few points, or projecting invalid at the end).
        sigma: the residuals' standard deviation per pixel axis, :math:`\sqrt{\chi^2 /
            (2 n - m)}` (pixels), the scale of ``std``; with a robust kernel of the inliers
            alone (``chi2`` and ``n`` counted as :attr:`torch_dq.fitting.Estimate.chi2`
            counts them: gross outliers do not inflate it).
        iterations: Levenberg-Marquardt steps taken; ``converged``: whether the cost's
            relative decrease fell below ``tol``; ``cost``: the final (robust) cost.
        outliers: ``(C,)`` per camera the observations used beyond the robust kernel's
            inlier cutoff, left out of ``sigma`` (zeros without a kernel).
    """

    cameras: list
    relative_poses: Tensor
    reprojection_rms: Tensor
    std: dict = field(repr=False)
    target_poses: Tensor = field(repr=False)
    frame_times: Tensor = field(repr=False)
    used: Tensor = field(repr=False)
    excluded: Tensor = field(repr=False)
    sigma: float = 0.0
    iterations: int = 0
    converged: bool = False
    cost: float = 0.0
    outliers: Tensor | None = field(default=None, repr=False)

    def to_kalibr(self, rostopics: list[str] | None = None) -> dict:
        """Kalibr's ``camchain.yaml`` (what ``kalibr_calibrate_cameras`` writes) as a dict of
        plain lists and floats (``yaml.safe_dump`` writes it): per camera ``camN`` the model
        and intrinsics (:meth:`torch_dq.camera.Camera.to_kalibr`), ``cam_overlaps``,
        ``rostopic`` (``/camN/image_raw`` unless given) and, for ``N >= 1``, ``T_cn_cnm1``
        (4 x 4: ``p_camN = T p_camN-1``, from :attr:`relative_poses`)."""
        rel = self.relative_poses.detach().cpu().double()
        poses = torch.cat([dualquat.identity(dtype=torch.float64)[None], rel])
        out = kalibr_entries(self.cameras, rostopics, "calibration.CameraCalibration.to_kalibr")
        for i in range(1, len(self.cameras)):
            step = dualquat.mul(dualquat.inv(poses[i]), poses[i - 1])
            out[f"cam{i}"] = {"T_cn_cnm1": dualquat.to_matrix(step).tolist(), **out[f"cam{i}"]}
        return out


def kalibr_entries(cams: list, rostopics, fn: str) -> dict:
    """``{"camN": entry}`` of a Kalibr camchain without the transforms: ``cam_overlaps``
    (every other camera), the camera (:meth:`torch_dq.camera.Camera.to_kalibr`) and
    ``rostopic`` (``rostopics[N]``, a list of one str per camera, or ``/camN/image_raw``)."""
    if rostopics is not None and (not isinstance(rostopics, Sequence)
                                  or isinstance(rostopics, str) or len(rostopics) != len(cams)
                                  or not all(isinstance(r, str) for r in rostopics)):
        _checks.fail(fn, f"expected rostopics to be None or a list of {len(cams)} str (one per "
                         f"camera), got {rostopics!r}")
    return {f"cam{i}": {"cam_overlaps": [j for j in range(len(cams)) if j != i],
                        **cam.to_kalibr(),
                        "rostopic": rostopics[i] if rostopics else f"/cam{i}/image_raw"}
            for i, cam in enumerate(cams)}


@dataclass
class _Camera:
    """One camera's data: flat observations (frame ids, target points, pixels) and views."""

    model: str
    resolution: tuple[int, int]
    frame: Tensor  # (N,) frame index of each observation
    points: Tensor  # (N, 3)
    pixels: Tensor  # (N, 2)
    view_frames: Tensor  # (V,)
    views: tuple  # xy (V, n, 2), uv (V, n, 2), mask (V, n)
    excluded: int


def _observation(i: int, obs) -> tuple[Tensor, Tensor, Tensor]:
    if not isinstance(obs, (tuple, list)) or len(obs) != 3:
        _checks.fail(_FN, f"expected observations[{i}] to be a (times, points, pixels) "
                          f"tuple, got {type(obs).__name__}")
    names = (f"observations[{i}] times", f"observations[{i}] points",
             f"observations[{i}] pixels")
    t, p, u = (_checks.tensor(_FN, n, x) for n, x in zip(names, obs, strict=True))
    if t.dtype != torch.float64:
        _checks.fail(_FN, f"expected float64 {names[0]} (seconds), got {t.dtype}: float32 "
                          f"UNIX seconds are 128 s apart, which merges distinct frames into "
                          f"one timestamp", TypeError)
    _checks.tensor(_FN, names[1], p, 3)
    _checks.tensor(_FN, names[2], u, 2)
    if t.dim() != 1 or p.dim() != 2 or u.dim() != 2 or not (
            p.shape[0] == u.shape[0] == t.shape[0]):
        _checks.fail(_FN, f"expected observations[{i}] as times (N,), points (N, 3), pixels "
                          f"(N, 2), got {_checks.shape_str(t.shape)}, "
                          f"{_checks.shape_str(p.shape)}, {_checks.shape_str(u.shape)}")
    t, p, u = (x.detach().to("cpu", torch.float64) for x in (t, p, u))
    if not bool(torch.isfinite(t).all() & torch.isfinite(p).all() & torch.isfinite(u).all()):
        _checks.fail(_FN, f"observations[{i}] holds non-finite values")
    _planar(i, p)
    return t, p, u


def _distinct(obs: list, fn: str = _FN) -> None:
    """Fail where two cameras' ``(times, points, pixels)`` are one: equal times and pixels,
    which two cameras of a rig never see (one corners file given for both: their relative
    pose came out the identity, without a word)."""
    for j, (tj, _, uj) in enumerate(obs):
        for i, (ti, _, ui) in enumerate(obs[:j]):
            if ti.shape == tj.shape and torch.equal(ti, tj) and torch.equal(ui, uj):
                _checks.fail(fn, f"observations[{j}] repeat observations[{i}] (the same times "
                                 f"and pixels): one camera's corners given for two cameras?")


def _planar(i: int, points: Tensor, fn: str = _FN) -> None:
    """Check that camera ``i``'s ``(N, 3)`` target points lie on the plane ``Z = 0`` (the
    closed-form starts are homographies of that plane) and span at most
    ``_LARGEST_TARGET`` (metres: wider ones are centimetres or millimetres, which the
    intrinsics would not show but the poses' translations would carry)."""
    if points.numel() and bool(
            (points[:, 2].abs() > 1e-9 * points[:, :2].abs().max().clamp_min(1.0)).any()):
        _checks.fail(fn, f"expected a planar target (points with Z = 0) in observations[{i}]")
    span = float((points.amax(0) - points.amin(0)).norm()) if points.numel() else 0.0
    if span > _LARGEST_TARGET:
        # the units that make it a target of 5 cm to 5 m (millimetres where none does)
        units = [(u, f) for u, f in (("centimetres", "100"), ("millimetres", "1000"))
                 if 0.05 <= span / float(f) <= 5.0] or [("millimetres", "1000")]
        _checks.fail(fn, f"observations[{i}] points span {span:.4g} (metres expected): "
                         f"{' or '.join(u for u, _ in units)}? Kalibr's targets and "
                         f"read_corners' X_m, Y_m, Z_m are in metres; divide them by "
                         f"{' or '.join(f for _, f in units)}")


def _arguments(observations, models, resolution, robust, robust_k, max_iterations, tol,
               min_points):
    """Validate the arguments; the observations as float64 CPU tensors."""
    if not isinstance(observations, Sequence) or len(observations) == 0:
        _checks.fail(_FN, "expected observations to be a non-empty list of (times, points, "
                          "pixels), one per camera")
    C = len(observations)
    if isinstance(observations[0], torch.Tensor):
        _checks.fail(_FN, "expected observations to be a list of (times, points, pixels) "
                          "tuples, one per camera: observations[0] is a Tensor (one camera's "
                          "tuple goes in a list: [(times, points, pixels)])")
    for name, x in (("models", models), ("resolution", resolution)):
        if not isinstance(x, Sequence) or isinstance(x, str) or len(x) != C:
            n = len(x) if isinstance(x, Sequence) and not isinstance(x, str) else type(x).__name__
            _checks.fail(_FN, f"expected {name} to be a list with one entry per camera "
                              f"({C}, as observations), got {n}")
    for i, m in enumerate(models):
        if m not in _SIZES:
            _checks.fail(_FN, f"unknown model {m!r} in models[{i}]; expected one of "
                              f"{sorted(_SIZES)}")
    res = []
    for i, r in enumerate(resolution):
        if (not isinstance(r, Sequence) or len(r) != 2 or any(
                isinstance(v, bool) or not isinstance(v, numbers.Integral) or v <= 0 for v in r)):
            _checks.fail(_FN, f"expected resolution[{i}] to be (width, height), positive "
                              f"ints, got {r!r}")
        res.append((int(r[0]), int(r[1])))
    if robust not in KERNELS:
        _checks.fail(_FN, f"expected robust to be one of {KERNELS}, got {robust!r}")
    if robust_k is not None and not (isinstance(robust_k, numbers.Real) and float(robust_k) > 0):
        _checks.fail(_FN, f"expected robust_k > 0 (pixels) or None, got {robust_k!r}")
    if (isinstance(max_iterations, bool) or not isinstance(max_iterations, int)
            or max_iterations < 0):
        _checks.fail(_FN, f"expected max_iterations to be an int >= 0, got {max_iterations!r}")
    if not (isinstance(tol, numbers.Real) and float(tol) > 0):
        _checks.fail(_FN, f"expected tol > 0, got {tol!r}")
    if isinstance(min_points, bool) or not isinstance(min_points, int) or min_points < 4:
        _checks.fail(_FN, f"expected min_points to be an int >= 4, got {min_points!r}")
    obs = [_observation(i, o) for i, o in enumerate(observations)]
    _distinct(obs)
    for i, ((_, _, u), r) in enumerate(zip(obs, res, strict=True)):
        _inside(i, u, r)
    return obs, [str(m) for m in models], res


def _inside(i: int, pixels: Tensor, res: tuple[int, int], fn: str = _FN,
            where: str = "resolution[{i}]", slack: float = 0.0) -> None:
    """Check that camera ``i``'s pixels lie in its image: ``(0, 0)`` is the centre of the
    top-left pixel, so ``u`` in ``[-0.5, width - 0.5]`` and ``v`` in ``[-0.5, height - 0.5]``,
    widened by ``slack`` times the image's size (``fn`` and ``where``, the resolution's
    argument with ``{i}``, name the caller's)."""
    out = outside(pixels, res, slack)
    if out is not None:
        _checks.fail(fn, f"observations[{i}] pixels reach {out[0]} = {out[1]:.6g}, outside "
                         f"{where.format(i=i)} = {res} (expected {out[2]}; is the resolution "
                         f"(width, height) of that camera?)")


def _cameras_data(obs, models, res, min_points) -> tuple[list[_Camera], Tensor]:
    """Frames (the union of the timestamps) and each camera's views with enough points."""
    times = torch.unique(torch.cat([t for t, _, _ in obs]))
    out = []
    for i, ((t, p, u), model, r) in enumerate(zip(obs, models, res, strict=True)):
        frame = torch.searchsorted(times, t)
        ids, counts = torch.unique(frame, return_counts=True)
        ids = ids[counts >= min_points]
        keep = torch.isin(frame, ids)
        if ids.numel() < 3:
            n = ids.numel()
            _checks.fail(_FN, f"camera {i} has {n} view{'s' * (n != 1)} with >= {min_points} "
                              f"points (min_points); at least 3 are needed (frames of the "
                              f"target at distinct timestamps, in different poses)")
        frame, p, u = frame[keep], p[keep], u[keep]
        order = torch.argsort(frame, stable=True)
        frame, p, u = frame[order], p[order], u[order]
        view = torch.searchsorted(ids, frame)
        n = int(torch.bincount(view).max())
        slot = torch.arange(frame.numel()) - torch.searchsorted(view, view)
        xy = torch.zeros(ids.numel(), n, 2, dtype=torch.float64)
        uv = torch.zeros_like(xy)
        mask = torch.zeros(ids.numel(), n, dtype=torch.bool)
        xy[view, slot], uv[view, slot], mask[view, slot] = p[:, :2], u, True
        out.append(_Camera(model, r, frame, p, u, ids, (xy, uv, mask), int((~keep).sum())))
    return out, times


def _transform(cam: int, rel: Tensor, frames: Tensor, fid: Tensor) -> Tensor:
    """Target-to-camera poses ``(N, 8)``: :math:`T_{0c}^{-1} T_{0f}`."""
    T = frames[fid]
    return T if cam == 0 else dualquat.mul(dualquat.inv(rel[cam - 1]), T)


def _errors(cams: list[_Camera], intr: list[Tensor], rel: Tensor, frames: Tensor):
    """Pixel errors ``(N_c, 2)`` and validity ``(N_c,)`` per camera."""
    out = []
    for c, cam in enumerate(cams):
        pts = dualquat.apply(_transform(c, rel, frames, cam.frame), cam.points)
        pix, valid = project(cam.model, intr[c], pts)
        out.append((pix - cam.pixels, valid))
    return out


def _jacobians(c: int, cam: _Camera, intr: Tensor, rel: Tensor, frames: Tensor):
    """Errors ``(N, 2)`` and their exact Jacobians w.r.t. the frame pose ``(N, 2, 6)``, the
    intrinsics ``(N, 2, P)`` and the relative pose ``(N, 2, 6)`` (``None`` for camera 0)."""
    N = cam.frame.shape[0]
    T = frames[cam.frame]
    R = rel[c - 1].expand(N, 8) if c else T  # camera 0 has no relative pose
    leaves = [T.new_zeros(N, 6), intr.expand(N, -1).clone()]
    if c:
        leaves.append(T.new_zeros(N, 6))

    def residual(lv):
        pose = tangent_step(T, lv[0])
        if c:
            pose = dualquat.mul(dualquat.inv(tangent_step(R, lv[2])), pose)
        return project(cam.model, lv[1], dualquat.apply(pose, cam.points))[0] - cam.pixels

    r, J = sample_jacobians(residual, leaves, 2)
    return r, J[0], J[1], (J[2] if c else None)


@dataclass
class _Layout:
    """Columns of the global parameters: each camera's intrinsics, then relative poses."""

    sizes: list[int]

    @property
    def intr(self) -> list[int]:
        return [sum(self.sizes[:c]) for c in range(len(self.sizes))]

    def rel(self, c: int) -> int:
        return sum(self.sizes) + 6 * (c - 1)

    @property
    def G(self) -> int:
        return sum(self.sizes) + 6 * (len(self.sizes) - 1)


def _kernel(kind, k, e: Tensor, valid: Tensor) -> tuple[Tensor, Tensor]:
    """Robust cost and IRLS weights of pixel-error norms ``e``, zero where not ``valid``."""
    return (torch.where(valid, rho(kind, e, k), 0.0), torch.where(valid, weight(kind, e, k), 0.0))


def _linearize(cams, intr, rel, frames, layout: _Layout, kind, k, valid):
    """Gauss-Newton blocks: ``Hff (F, 6, 6)``, ``Hfg (F, 6, G)``, ``Hgg (G, G)``, gradients
    ``bf (F, 6)``, ``bg (G,)`` (of half the cost), and the cost."""
    F, G = frames.shape[0], layout.G
    Hff, Hfg = frames.new_zeros(F, 6, 6), frames.new_zeros(F, 6, G)
    Hgg, bf, bg = frames.new_zeros(G, G), frames.new_zeros(F, 6), frames.new_zeros(G)
    cost = 0.0
    for c, cam in enumerate(cams):
        r, Jf, Ji, Jr = _jacobians(c, cam, intr[c], rel, frames)
        Jg = r.new_zeros(r.shape[0], 2, G)
        o = layout.intr[c]
        Jg[..., o:o + Ji.shape[-1]] = Ji
        if Jr is not None:
            Jg[..., layout.rel(c):layout.rel(c) + 6] = Jr
        v = valid[c]
        r = torch.where(v[:, None], r, 0.0)
        rc, w = _kernel(kind, k, r.norm(dim=-1), v)
        cost += float(rc.sum())
        wJf, wJg = w[:, None, None] * Jf, w[:, None, None] * Jg
        Hff.index_add_(0, cam.frame, wJf.mT @ Jf)
        Hfg.index_add_(0, cam.frame, wJf.mT @ Jg)
        bf.index_add_(0, cam.frame, (wJf.mT @ r[..., None])[..., 0])
        Hgg += torch.einsum("nki,nkj->ij", wJg, Jg)
        bg += torch.einsum("nki,nk->i", wJg, r)
    return (Hff, Hfg, Hgg, bf, bg), cost


def _damped(H: Tensor, lam: float) -> Tensor:
    d = H.diagonal(dim1=-2, dim2=-1)
    d = d.clamp_min(1e-12 * d.amax(-1, keepdim=True))
    return H + lam * torch.diag_embed(d)


def _schur(Hff: Tensor, Hfg: Tensor, Hgg: Tensor) -> tuple[Tensor, Tensor]:
    r"""Cholesky factors of the frame blocks and the Schur complement
    :math:`S = H_{gg} - \sum_f H_{fg}^T H_{ff}^{-1} H_{fg}`."""
    L = torch.linalg.cholesky(Hff)
    X = torch.cholesky_solve(Hfg, L)
    return L, Hgg - torch.einsum("fai,faj->ij", Hfg, X)


def _solve(system, lam: float) -> tuple[Tensor, Tensor]:
    """Damped step ``(dg (G,), df (F, 6))`` of ``[Hff Hfg; Hgf Hgg] d = -b``."""
    Hff, Hfg, Hgg, bf, bg = system
    L, S = _schur(_damped(Hff, lam), Hfg, _damped(Hgg, lam))
    xb = torch.cholesky_solve(bf[..., None], L)[..., 0]
    dg = torch.linalg.solve(S, -bg + torch.einsum("fai,fa->i", Hfg, xb))
    df = -torch.cholesky_solve(bf[..., None] + Hfg @ dg[:, None], L)[..., 0]
    return dg, df


def _update(intr, rel, frames, dg, df, layout: _Layout):
    o = layout.intr
    intr = [p + dg[o[c]:o[c] + p.shape[0]] for c, p in enumerate(intr)]
    if rel.shape[0]:
        d = dg[layout.rel(1):].reshape(-1, 6)
        rel = dualquat.normalize(dualquat.mul(rel, dualquat.exp(d)))
    frames = dualquat.normalize(dualquat.mul(frames, dualquat.exp(df)))
    return intr, rel, frames


def _cost(cams, intr, rel, frames, kind, k):
    """Robust cost and the per-camera validity of a state."""
    total, valid = 0.0, []
    for e, v in _errors(cams, intr, rel, frames):
        total += float(_kernel(kind, k, e.norm(dim=-1), v)[0].sum())
        valid.append(v)
    return total, valid


def _lm(cams, intr, rel, frames, layout, kind, k, max_iterations, tol):
    """Levenberg-Marquardt; a step is accepted when it lowers the cost and keeps every
    valid observation valid. Returns the state, the iterations and convergence."""
    cost, valid = _cost(cams, intr, rel, frames, kind, k)
    lam, it, converged = 1e-4, 0, False
    while it < max_iterations and not converged:
        system, _ = _linearize(cams, intr, rel, frames, layout, kind, k, valid)
        while lam < 1e12:
            dg, df = _solve(system, lam)
            trial = _update(intr, rel, frames, dg, df, layout)
            new, nvalid = _cost(cams, trial[0], trial[1], trial[2], kind, k)
            kept = all(bool((n | ~v).all()) for n, v in zip(nvalid, valid, strict=True))
            if kept and new <= cost:
                converged = cost - new <= tol * cost
                intr, rel, frames = trial
                cost, lam = new, max(lam / 3.0, 1e-10)
                break
            lam *= 8.0
        else:
            converged = True  # no damped step lowers the cost: a minimum to rounding
        it += 1
    return (intr, rel, frames), it, converged, cost, valid


def _variances(S: Tensor) -> Tensor:
    r"""Diagonal of :math:`S^{-1}` for a symmetric positive semi-definite ``S``; ``inf``
    only for the parameters that a direction without information (an eigenvalue of the
    Jacobi-scaled ``S`` below ``1e-12`` of the largest) involves, as in
    :meth:`torch_dq.fitting.Estimate.std`."""
    d = S.diagonal().clamp_min(torch.finfo(S.dtype).tiny).rsqrt()
    e, V = torch.linalg.eigh(d[:, None] * S * d[None, :])
    null = e <= 1e-12 * e.amax()
    part = torch.where(null, 0.0, V ** 2 / torch.where(null, 1.0, e)).sum(-1)
    blind = ((V.abs() > 1e-8) & null).any(-1)
    return torch.where(blind, torch.inf, part * d ** 2)


def _std(system, layout: _Layout, sizes, chi2: float, dof: float):
    r"""Standard deviations of the intrinsics ``(C, P)`` and relative poses ``(C - 1, 6)``
    from the inverse Schur complement, scaled by :math:`\chi^2 / \text{dof}`."""
    Hff, Hfg, Hgg, _, _ = system
    _, S = _schur(Hff, Hfg, Hgg)
    s = (_variances(S) * (chi2 / max(dof, 1))).sqrt()
    P, o = max(sizes), layout.intr
    intr = torch.full((len(sizes), P), math.nan, dtype=S.dtype)
    for c, n in enumerate(sizes):
        intr[c, :n] = s[o[c]:o[c] + n]
    rel = s[layout.rel(1):].reshape(-1, 6) if len(sizes) > 1 else s.new_zeros(0, 6)
    return {"intrinsics": intr, "relative_poses": rel}


def _keep_views(cam: _Camera, ok: Tensor) -> _Camera:
    """``cam`` without the views whose start pose failed (their observations excluded)."""
    if bool(ok.all()):
        return cam
    keep = torch.isin(cam.frame, cam.view_frames[ok])
    xy, uv, mask = cam.views
    return _Camera(cam.model, cam.resolution, cam.frame[keep], cam.points[keep],
                   cam.pixels[keep], cam.view_frames[ok], (xy[ok], uv[ok], mask[ok]),
                   cam.excluded + int((~keep).sum()))


def _start_state(cams: list[_Camera]):
    """Start intrinsics, relative poses and frame poses; frames renumbered ``0..F-1``."""
    intr, poses = [], []
    for i, cam in enumerate(cams):
        p = _start.start_intrinsics(cam.model, cam.resolution, cam.views)
        T, _, ok = _start.view_poses(cam.model, p, *cam.views)
        if int(ok.sum()) < 3:
            _checks.fail(_FN, f"camera {i}: fewer than 3 views give the target a pose at "
                              f"the start (are the views degenerate?)")
        cams[i] = _keep_views(cam, ok)
        intr.append(p)
        poses.append(T[ok])
    rel = _start.relative_starts([cam.view_frames for cam in cams], poses)
    used = torch.unique(torch.cat([cam.view_frames for cam in cams]))
    frames = dualquat.identity((used.numel(),), dtype=torch.float64).clone()
    for c in reversed(range(len(cams))):  # camera 0's own view wins
        T = poses[c] if c == 0 else dualquat.mul(rel[c - 1], poses[c])
        frames[torch.searchsorted(used, cams[c].view_frames)] = T
    for cam in cams:
        cam.frame = torch.searchsorted(used, cam.frame)
    return intr, rel, frames, used


def cameras(observations, models, resolution, *, robust: str | None = None,
            robust_k: float | None = None, max_iterations: int = 100, tol: float = 1e-10,
            min_points: int = 6) -> CameraCalibration:
    r"""Intrinsics of one or more cameras and their poses relative to camera 0 from
    observations of a planar calibration target alone (Kalibr's ``calibrate_cameras``).

    Started without guesses (Zhang's homographies or a focal line search, distortion from
    zero), then a joint Levenberg-Marquardt bundle adjustment over the intrinsics, the
    relative poses and one target pose per frame (eliminated per frame by the Schur
    complement), exact Jacobians by autograd of :func:`torch_dq.camera.project`. See the
    module docstring for the method and its sources.

    Args:
        observations: one ``(times (N,), points (N, 3), pixels (N, 2))`` per camera, as
            ``torch_dq.calibration.read_corners`` returns them: float64 seconds (float32
            UNIX seconds are 128 s apart: frames would merge), target points (a planar
            target: ``Z = 0``), measured pixels. Observations with one timestamp are one
            view; equal timestamps in several cameras are one frame (the target did not
            move between them), which links those cameras.
        models: one model name per camera (``"pinhole"``, ``"pinhole-radtan"``,
            ``"pinhole-equidistant"``, ``"double-sphere"``).
        resolution: one ``(width, height)`` per camera (pixels); each camera's pixels
            must lie in its image, ``u`` in ``[-0.5, width - 0.5]``, ``v`` in
            ``[-0.5, height - 0.5]`` (``(0, 0)`` is the top-left pixel's centre).
        robust: ``None``, ``"huber"`` or ``"cauchy"`` on the pixel error's norm.
        robust_k: the kernel's scale in pixels (default 2.45, the 95 % quantile of the
            error norm for 1-pixel noise per axis).
        max_iterations: Levenberg-Marquardt steps at most.
        tol: convergence: the relative decrease of the cost in an accepted step.
        min_points: views with fewer points are left out (counted in ``excluded``).

    Returns:
        :class:`CameraCalibration`: ``cameras`` (a list of :class:`torch_dq.camera.Camera`),
        ``relative_poses (C - 1, 8)`` (``p_cam0 = T p_cami``), ``reprojection_rms (C,)``,
        ``std`` (``"intrinsics" (C, P)``, ``"relative_poses" (C - 1, 6)`` in the chart
        ``T exp(delta)``; formal white-noise standard deviations, optimistic for real
        corners, whose errors correlate within a frame: see :class:`CameraCalibration`),
        the frames' target poses, counts and convergence. Tensors in the
        dtype and device of ``observations[0]``'s pixels.

    Raises:
        ValueError: lists of different lengths, an unknown model, a bad resolution, a
            non-planar target or one spread over more than 20 m (millimetres, not
            metres: the relative poses' translations would carry them), a camera with
            fewer than 3 views of ``min_points`` points, a camera sharing no frame with
            camera 0 (directly or through others), pixels outside a camera's resolution.
        TypeError: observations that are not floating-point tensors, times that are not
            float64.

    Warns:
        RuntimeWarning: the bundle adjustment did not converge within ``max_iterations``
            (``converged`` False; not for ``max_iterations = 0``, the start alone), naming
            the camera with the largest reprojection error: the intrinsics may be far off
            (e.g. a ``"pinhole"`` model on a distorted lens). A ``"pinhole"`` camera whose
            pixel errors ask for radial distortion, converged or not: the score test of
            ``k1`` beyond 5 of its standard deviations (``_warn_distortion``; a model
            with distortion is named).
    """
    obs, models, res = _arguments(observations, models, resolution, robust, robust_k,
                                  max_iterations, tol, min_points)
    like = observations[0][2]
    k = float(robust_k) if robust_k is not None else chi_quantile(2)
    cams, times = _cameras_data(obs, models, res, min_points)
    intr, rel, frames, used = _start_state(cams)
    layout = _Layout([_SIZES[m] for m in models])
    state, it, converged, cost, valid = _lm(cams, intr, rel, frames, layout, robust, k,
                                            max_iterations, tol)
    system, _ = _linearize(cams, state[0], state[1], state[2], layout, robust, k, valid)
    out = _result(cams, state, system, layout, valid, robust, like, times[used],
                  (it, converged, cost))
    if not converged and max_iterations > 0:  # 0: the start alone was asked for
        _warn_unconverged(out, models)
    _warn_distortion(cams, state, robust, k, valid, max(out.sigma, _FLOOR))
    return out


def _warn_distortion(cams: list[_Camera], state, kind, k: float, valid, ratio: float) -> None:
    r"""The score test of ``k1`` for each ``"pinhole"`` camera (as
    ``torch_dq.fitting._score``'s of a :class:`~torch_dq.fitting.Reprojections` term): the
    problem linearised with that camera's model ``"pinhole-radtan"`` at
    ``(fu, fv, cu, cv, 0, 0, 0, 0)``, ``k2, p1, p2`` left out; ``z`` the Gauss-Newton step
    of ``k1``, every estimated parameter free, over its standard deviation (from the inverse
    Schur complement, times ``ratio``, the pixel errors' scale :math:`\sqrt{\chi^2/\nu}`:
    no sigma is given, as for the reported ``std``; the caller floors it at ``_FLOOR``, no
    corner is finer, else noise-free pixels would read roundoff). Beyond ``THRESHOLD`` a
    RuntimeWarning names the camera and the ``k1`` suggested; a singular system (k1 not
    determined apart from the rest) tests nothing."""
    for c, cam in enumerate(cams):
        if cam.model != "pinhole":
            continue
        intr = [torch.cat((p, p.new_zeros(4))) if i == c else p for i, p in enumerate(state[0])]
        wide = [replace(x, model="pinhole-radtan") if i == c else x for i, x in enumerate(cams)]
        layout = _Layout([_SIZES[x.model] for x in wide])
        Hff, Hfg, Hgg, bf, bg = _linearize(wide, intr, state[1], state[2], layout, kind, k,
                                           valid)[0]
        o = layout.intr[c] + 4  # k1's column; k2, p1, p2's (the next three) left out
        keep = torch.tensor([i for i in range(layout.G) if not o < i <= o + 3],
                            device=Hgg.device)
        Hfg, Hgg, bg = Hfg[..., keep], Hgg[keep][:, keep], bg[keep]
        try:
            step = float(_solve((Hff, Hfg, Hgg, bf, bg), 0.0)[0][o])
            z = step / float(_variances(_schur(Hff, Hfg, Hgg)[1])[o].sqrt()) / ratio
        except torch.linalg.LinAlgError:
            continue
        if abs(z) > THRESHOLD:
            warnings.warn(f"{_FN}: the pixel errors of camera {c} ('pinhole') "
                          f"{asking('k1', z, step)}", RuntimeWarning, stacklevel=3)


def _warn_unconverged(out: CameraCalibration, models: list[str]) -> None:
    """A RuntimeWarning naming the camera with the largest reprojection error."""
    rms = out.reprojection_rms.detach().cpu().double()
    c = int(rms.argmax())
    warnings.warn(f"{_FN}: the bundle adjustment did not converge in max_iterations = "
                  f"{out.iterations} steps: the cost still falls by more than tol per step; "
                  f"camera {c} ({models[c]!r}) has the largest reprojection rms, "
                  f"{float(rms[c]):.3g} px. Its intrinsics may be far off: does the model fit "
                  f"the lens (a model without distortion on a distorted lens?), or does it "
                  f"need more iterations?", RuntimeWarning, stacklevel=3)


def _chi2(e2: list[Tensor], kind, params: int) -> tuple[float, float, list[int]]:
    r"""Chi-square, degrees of freedom and outliers per camera of the squared pixel-error
    norms ``e2`` (one ``(n_c,)`` per camera, the observations used), ``params`` the
    parameters estimated. Without a kernel every observation counts: ``dof = 2 n - m``.
    With one only the inliers, as :attr:`torch_dq.fitting.Estimate.chi2` counts them
    (``torch_dq.fitting._robust.inliers``: a cutoff at the 99.9 % quantile scaled by the
    chi2/dof found, the sum over the truncated mean; ``dof`` the inliers' components less
    the parameters: one term takes them all)."""
    s2 = torch.cat(e2)
    taken = min(params, 2 * s2.numel())
    if kind is None:
        return float(s2.sum()), float(2 * s2.numel() - taken), [0] * len(e2)
    keep, kappa = inliers(s2, torch.ones_like(s2, dtype=torch.bool), 2, float(taken))
    chi2 = float(torch.where(keep, s2, 0.0).sum()) / kappa
    out = [int((~k).sum()) for k in keep.split([x.numel() for x in e2])]
    return chi2, max(2 * int(keep.sum()) - taken, 0), out


def _result(cams, state, system, layout, valid, kind, like, frame_times, run):
    intr, rel, frames = state
    e2 = [(e ** 2).sum(-1)[v] for (e, _), v in zip(_errors(cams, *state), valid, strict=True)]
    rms = [x.mean().sqrt() for x in e2]
    n_used = [x.numel() for x in e2]
    chi2, dof, outliers = _chi2(e2, kind, layout.G + 6 * frames.shape[0])
    std = _std(system, layout, layout.sizes, chi2, dof)
    out = {"device": like.device, "dtype": like.dtype}
    cams_out = [Camera(cam.model, p.to(**out), cam.resolution)
                for cam, p in zip(cams, intr, strict=True)]
    excluded = [cam.excluded + cam.frame.numel() - n for cam, n in zip(cams, n_used, strict=True)]
    it, converged, cost = run
    return CameraCalibration(
        cams_out, rel.to(**out), torch.stack(rms).to(**out),
        {key: v.to(**out) for key, v in std.items()}, frames.to(**out),
        frame_times.to(**out), torch.tensor(n_used, device=like.device),
        torch.tensor(excluded, device=like.device), math.sqrt(chi2 / max(dof, 1)), it,
        converged, cost, torch.tensor(outliers, device=like.device))

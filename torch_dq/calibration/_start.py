r"""Closed-form start of a camera calibration from views of a planar target (private).

Every view is one camera's observations of the target (``Z = 0``) at one timestamp, held
padded: target ``xy (V, n, 2)``, pixels ``uv (V, n, 2)``, ``mask (V, n)``.

- :func:`homographies`: plane-to-image homographies by the normalised direct linear
  transform (Hartley, "In defence of the eight-point algorithm", PAMI 1997; Hartley and
  Zisserman, *Multiple View Geometry*, 2nd ed., alg. 4.2), all views in one batched SVD.
- :func:`zhang`: pinhole intrinsics (zero skew) from three or more homographies (Zhang,
  "A flexible new technique for camera calibration", PAMI 2000, sec. 3.1 with
  :math:`B_{12} = 0`).
- :func:`pose_from_homography`: the target's pose in the camera from the homography of
  normalised image coordinates (Zhang 2000, sec. 3.1 and appendix C: the nearest rotation).
- :func:`start_intrinsics`: per model, Zhang's start (pinhole part; distortion zero) and a
  line search over one focal length with the principal point at the image centre and
  basalt's defaults for the other parameters (equidistant ``k = 0``; double sphere
  ``xi = 0, alpha = 0.5``), each candidate scored by the median over views of the RMS
  reprojection error after a per-view homography pose; the best-scoring start wins.
- :func:`relative_starts`: the cameras' poses in camera 0's frame from the views they
  share, averaged, chained breadth-first from camera 0.
"""

from __future__ import annotations

import math
from typing import NoReturn

import torch
from torch import Tensor

from .. import dualquat, quat
from ..camera import project, unproject

__all__ = ["focal_centred", "homographies", "pose_from_homography", "relative_starts",
           "start_intrinsics", "vanishing_distance", "view_poses", "zhang"]

_DEFAULTS = {  # parameters after (fu, fv, cu, cv) at the start: distortion zero, basalt's ds
    "pinhole": (), "pinhole-radtan": (0.0, 0.0, 0.0, 0.0),
    "pinhole-equidistant": (0.0, 0.0, 0.0, 0.0), "double-sphere": (0.0, 0.5)}
_MIN_Z = 0.1  # rays with z below this (beyond ~84 deg) stay out of the start's homographies


def _normaliser(p: Tensor, mask: Tensor) -> Tensor:
    """Similarity ``(V, 3, 3)`` taking the masked points to centroid 0, mean distance sqrt 2."""
    w = mask.to(p.dtype)[..., None]
    n = w.sum(-2).clamp_min(1.0)
    c = (p * w).sum(-2) / n
    d = ((p - c[..., None, :]).norm(dim=-1) * w[..., 0]).sum(-1) / n[..., 0]
    s = math.sqrt(2.0) / torch.where(d > 0, d, 1.0)  # a view without spread: not ok later
    T = torch.zeros(*p.shape[:-2], 3, 3, dtype=p.dtype, device=p.device)
    T[..., 0, 0] = T[..., 1, 1] = s
    T[..., :2, 2] = -s[..., None] * c
    T[..., 2, 2] = 1.0
    return T


def homographies(xy: Tensor, uv: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    r"""Homographies ``H (V, 3, 3)`` with :math:`(u, v, 1)^T \sim H (x, y, 1)^T`.

    Normalised DLT: both point sets moved to centroid 0 and mean distance :math:`\sqrt 2`,
    the null vector of the stacked :math:`2 n \times 9` system by SVD (masked rows zero),
    then denormalised; ``H`` scaled to unit Frobenius norm.

    Returns:
        ``H`` and ``ok (V,)``: at least 4 points and a one-dimensional null space (the
        points not collinear: the second-smallest singular value above ``1e-8`` of the
        largest).
    """
    Ta, Tb = _normaliser(xy, mask), _normaliser(uv, mask)
    one = torch.ones_like(xy[..., :1])
    a = torch.cat((xy, one), -1) @ Ta.mT
    b = torch.cat((uv, one), -1) @ Tb.mT
    zero = torch.zeros_like(a)
    r1 = torch.cat((a, zero, -b[..., :1] * a), -1)
    r2 = torch.cat((zero, a, -b[..., 1:2] * a), -1)
    A = torch.cat((r1, r2), -2) * torch.cat((mask, mask), -1).to(xy.dtype)[..., None]
    finite = torch.isfinite(A).flatten(-2).all(-1)
    A = torch.where(finite[..., None, None], A, 0.0)
    _, s, Vh = torch.linalg.svd(A, full_matrices=False)
    h = Vh[..., -1, :].reshape(*xy.shape[:-2], 3, 3)
    H = torch.linalg.solve(Tb, h @ Ta)
    H = H / H.flatten(-2).norm(dim=-1)[..., None, None]
    ok = finite & (mask.sum(-1) >= 4) & (s[..., -2] > 1e-8 * s[..., 0])
    ok = ok & torch.isfinite(H).flatten(-2).all(-1)
    eye = torch.eye(3, dtype=H.dtype, device=H.device) / math.sqrt(3.0)
    return torch.where(ok[..., None, None], H, eye), ok


def zhang(H: Tensor, resolution: tuple[int, int]) -> Tensor | None:
    r"""Pinhole ``(fu, fv, cu, cv)`` from pixel homographies ``H (V, 3, 3)``, zero skew.

    With :math:`B = K^{-T} K^{-1}` (up to scale) and :math:`B_{12} = 0`, every homography
    gives :math:`h_1^T B h_2 = 0` and :math:`h_1^T B h_1 = h_2^T B h_2` (Zhang 2000, eqs.
    3-4), linear in :math:`b = (B_{11}, B_{22}, B_{13}, B_{23}, B_{33})`; then
    :math:`c_u = -B_{13}/B_{11}`, :math:`c_v = -B_{23}/B_{22}`,
    :math:`\lambda = B_{33} - B_{13}^2/B_{11} - B_{23}^2/B_{22}`,
    :math:`f_u = \sqrt{\lambda / B_{11}}`, :math:`f_v = \sqrt{\lambda / B_{22}}`. The pixels
    are first scaled to about unit range (conditioning).

    Returns:
        ``(4,)``, or ``None`` when fewer than 3 views or no such ``K`` exists (``B`` not
        definite, the principal point outside the image).
    """
    if H.shape[0] < 3:
        return None
    w, h = resolution
    s = 0.5 * (w + h)
    N = H.new_tensor([[1 / s, 0.0, -0.5 * w / s], [0.0, 1 / s, -0.5 * h / s], [0.0, 0.0, 1.0]])
    Hn = N @ H

    def v(i: int, j: int) -> Tensor:
        hi, hj = Hn[:, :, i], Hn[:, :, j]
        return torch.stack((hi[:, 0] * hj[:, 0], hi[:, 1] * hj[:, 1],
                            hi[:, 2] * hj[:, 0] + hi[:, 0] * hj[:, 2],
                            hi[:, 2] * hj[:, 1] + hi[:, 1] * hj[:, 2], hi[:, 2] * hj[:, 2]), -1)

    A = torch.cat((v(0, 1), v(0, 0) - v(1, 1)), 0)
    b = torch.linalg.svd(A, full_matrices=False)[2][-1]
    b = b * torch.sign(b[0])
    B11, B22, B13, B23, B33 = b.unbind()
    lam = B33 - B13 ** 2 / B11 - B23 ** 2 / B22
    if not bool((B22 > 0) & (lam > 0)):
        return None
    k = torch.stack(((lam / B11).sqrt(), (lam / B22).sqrt(), -B13 / B11, -B23 / B22))
    out = torch.cat((k[:2] * s, k[2:] * s + H.new_tensor([0.5 * w, 0.5 * h])))
    inside = (out[2] > 0) & (out[2] < w) & (out[3] > 0) & (out[3] < h)
    return out if bool(torch.isfinite(out).all() & inside) else None


def pose_from_homography(H: Tensor) -> Tensor:
    r"""Target poses ``(V, 8)`` in the camera (``p_cam = T p_target``) from homographies of
    normalised image coordinates (:math:`H \sim [r_1\; r_2\; t]`): scale from the mean of
    :math:`\|h_1\|, \|h_2\|`, sign such that the target lies in front (:math:`t_z > 0`),
    the rotation the nearest to :math:`[r_1\; r_2\; r_1 \times r_2]` (SVD)."""
    scale = 2.0 / (H[..., :, 0].norm(dim=-1) + H[..., :, 1].norm(dim=-1))
    scale = scale * torch.where(H[..., 2, 2] < 0, -1.0, 1.0)
    r1, r2, t = (H[..., :, i] * scale[..., None] for i in range(3))
    M = torch.stack((r1, r2, torch.linalg.cross(r1, r2)), -1)
    U, _, Vh = torch.linalg.svd(M)
    d = torch.linalg.det(U @ Vh)
    R = U @ torch.diag_embed(torch.stack((torch.ones_like(d), torch.ones_like(d), d), -1)) @ Vh
    return dualquat.from_rt(quat.from_matrix(R), t)


def view_poses(model: str, params: Tensor, xy: Tensor, uv: Tensor, mask: Tensor,
               ) -> tuple[Tensor, Tensor, Tensor]:
    """Per-view target poses ``(V, 8)`` from the unprojected pixels under ``params``, the
    views' RMS reprojection errors ``(V,)`` (pixels; inf for a view without a pose) and
    ``ok (V,)``."""
    rays, valid = unproject(model, params, uv)
    z = rays[..., 2:]
    use = mask & valid & (z[..., 0] > _MIN_Z)
    xn = torch.where(use[..., None], rays[..., :2] / torch.where(use[..., None], z, 1.0), 0.0)
    H, ok = homographies(xy, xn, use)
    poses = pose_from_homography(H)
    points = torch.cat((xy, torch.zeros_like(xy[..., :1])), -1)
    pix, pvalid = project(model, params, dualquat.apply(poses[:, None, :], points))
    e2 = ((pix - uv) ** 2).sum(-1)
    m = mask & pvalid
    n = m.sum(-1)
    rms = torch.where(m, e2, 0.0).sum(-1).div(n.clamp_min(1)).sqrt()
    ok = ok & (n == mask.sum(-1)) & torch.isfinite(rms)
    return poses, torch.where(ok, rms, torch.inf), ok


def _candidate(model: str, f: float, resolution: tuple[int, int], like: Tensor) -> Tensor:
    w, h = resolution
    return like.new_tensor((f, f, 0.5 * (w - 1), 0.5 * (h - 1)) + _DEFAULTS[model])


def _score(model: str, params: Tensor, views) -> float:
    rms = view_poses(model, params, *views)[1]
    return float(rms.median()) if bool(torch.isfinite(rms).any()) else math.inf


def focal_centred(H: Tensor, resolution: tuple[int, int]) -> Tensor | None:
    r"""Pinhole ``(f, f, cu, cv)`` with the principal point at the image centre and one focal
    length, from pixel homographies ``H (V, 3, 3)``: with the centre moved to the origin,
    :math:`h_1^T B h_2 = 0` and :math:`h_1^T B h_1 = h_2^T B h_2` for
    :math:`B = \mathrm{diag}(1, 1, f^2)` are linear in :math:`f^2` (least squares over the
    views; OpenCV's ``initIntrinsicParams2D`` does likewise with two focal lengths).

    Returns:
        ``(4,)``, or ``None`` where no positive :math:`f^2` fits.
    """
    w, h = resolution
    c = H.new_tensor([0.5 * (w - 1), 0.5 * (h - 1)])
    Hc = H.clone()
    Hc[:, :2] = H[:, :2] - c[None, :, None] * H[:, 2:3]
    h1, h2 = Hc[:, :, 0], Hc[:, :, 1]
    a = torch.cat((h1[:, 2] * h2[:, 2], h1[:, 2] ** 2 - h2[:, 2] ** 2))
    b = -torch.cat(((h1[:, :2] * h2[:, :2]).sum(-1), (h1[:, :2] ** 2 - h2[:, :2] ** 2).sum(-1)))
    f2 = (a * b).sum() / (a * a).sum()
    if not bool(torch.isfinite(f2) & (f2 > 0)):
        return None
    f = f2.sqrt()
    return torch.stack((f, f, c[0], c[1]))


def _circles(p: Tensor, m: Tensor) -> Tensor:
    r"""Least-squares circles ``(L, 3)`` (centre, radius; Kasa's algebraic fit of
    :math:`x^2 + y^2 + a x + b y + c = 0`) of point sets ``p (L, n, 2)`` masked by ``m``."""
    A = torch.cat((p, torch.ones_like(p[..., :1])), -1) * m[..., None]
    y = -(p ** 2).sum(-1) * m
    sol = torch.linalg.lstsq(A, y[..., None]).solution[..., 0]
    centre = -0.5 * sol[..., :2]
    r2 = (centre ** 2).sum(-1) - sol[..., 2]
    return torch.cat((centre, r2.clamp_min(0.0).sqrt()[..., None]), -1)


def vanishing_distance(xy: Tensor, uv: Tensor, mask: Tensor) -> float | None:
    r"""Median distance (pixels) between the two vanishing points of parallel target lines.

    A straight line images as a circle under the unified model with :math:`\xi = 1` and,
    nearly, under the equidistant model; the images of two parallel lines meet in the two
    vanishing points of their direction (Hughes et al., "Equidistant fish-eye calibration
    and rectification by vanishing point extraction", PAMI 2010; Kalibr's focal start).
    The rows and columns of the target (equal ``y`` or ``x``, >= 4 points) are fitted by
    circles, and every pair of parallel ones in a view intersected.

    Returns:
        The median distance, or ``None`` without any pair.
    """
    dists = []
    for v in range(xy.shape[0]):
        for axis in (0, 1):
            key = xy[v, :, axis][mask[v]]
            pix = uv[v][mask[v]]
            _, inv, counts = torch.unique(torch.round(key * 1e6), return_inverse=True,
                                          return_counts=True)
            lines = torch.nonzero(counts >= 4)[:, 0]
            if lines.numel() < 2:
                continue
            n = int(counts.max())
            P = pix.new_zeros(lines.numel(), n, 2)
            M = torch.zeros(lines.numel(), n, dtype=torch.bool)
            for j, line in enumerate(lines.tolist()):
                q = pix[inv == line]
                P[j, :q.shape[0]], M[j, :q.shape[0]] = q, True
            c = _circles(P, M)
            i, j = torch.triu_indices(c.shape[0], c.shape[0], 1)
            d = (c[j, :2] - c[i, :2]).norm(dim=-1)
            r0, r1 = c[i, 2], c[j, 2]
            a = (r0 ** 2 - r1 ** 2 + d ** 2) / (2 * d)
            h2 = r0 ** 2 - a ** 2
            good = (h2 > 0) & (d > 0)
            dists.append(2 * h2[good].sqrt())  # the chord between the two intersections
    if not dists:
        return None
    d = torch.cat(dists)
    d = d[torch.isfinite(d)]
    return float(d.median()) if d.numel() else None


def _plausible(k: Tensor, resolution: tuple[int, int]) -> bool:
    """Focal lengths within [0.05, 20] image widths."""
    return bool((k[:2] > 0.05 * resolution[0]).all() & (k[:2] < 20.0 * resolution[0]).all())


def start_intrinsics(model: str, resolution: tuple[int, int], views) -> Tensor:
    r"""Start parameters ``(P,)`` of one camera from its views ``(xy, uv, mask)``.

    Pinhole models: Zhang's closed form, or where it fails (weak perspective, strong
    distortion: ``B`` indefinite) or gives a focal length outside ``[0.05, 20]`` image
    widths, the centred one-focal closed form (:func:`focal_centred`), or else the focal
    length of the vanishing points as for the equidistant model; distortion zero.
    Equidistant and double sphere: the vanishing-point focal length :math:`D / \pi`
    (equidistant: :math:`r = f \theta`) or :math:`D / 4` (double sphere at basalt's
    ``xi = 0, alpha = 0.5``, the unified model with :math:`\xi = 1` and twice the focal
    length), refined by a line search over ``[0.4, 2.5]`` times it (ratio ~1.04, then
    ~1.004 around the best), each candidate scored by the median over views of the RMS
    reprojection error after a per-view homography pose (:func:`view_poses`: with the wrong
    focal length the unprojected rays of a plane are not a homography of it).
    """
    xy, uv, mask = views
    D = vanishing_distance(xy, uv, mask)
    if model in ("pinhole", "pinhole-radtan"):
        H, ok = homographies(xy, uv, mask)
        ks = [zhang(H[ok], resolution), focal_centred(H[ok], resolution)]
        if D is not None:
            ks.append(_candidate("pinhole", D / math.pi, resolution, xy))
        for k in ks:
            if k is not None and _plausible(k, resolution):
                return torch.cat((k, k.new_tensor(_DEFAULTS[model])))
        _fail_start()
    if D is None:
        _fail_start()
    f0 = D / (math.pi if model == "pinhole-equidistant" else 4.0)

    def score(f: float) -> float:
        return _score(model, _candidate(model, f, resolution, xy), views)

    coarse = (f0 * torch.logspace(-0.4, 0.4, 48, dtype=torch.float64)).tolist()
    best = min(coarse, key=score)
    fine = (best * torch.logspace(-0.02, 0.02, 11, dtype=torch.float64)).tolist()
    return _candidate(model, min(fine, key=score), resolution, xy)


def _fail_start() -> NoReturn:
    raise ValueError("calibration.cameras: no start for a camera's focal length from its "
                     "views (are the points and pixels of one planar target, with rows "
                     "and columns of >= 4 points?)")


def _average(poses: Tensor) -> Tensor:
    """Mean of rigid poses ``(S, 8)``: sign-aligned quaternion mean, mean translation."""
    q, t = dualquat.to_rt(poses)
    q = q * torch.where((q * q[:1]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    return dualquat.from_rt(quat.normalize(q.mean(0)), t.mean(0))


def relative_starts(view_frames: list[Tensor], poses: list[Tensor]) -> Tensor:
    """Poses ``(C - 1, 8)`` of cameras ``1..`` in camera 0's frame, from the per-view target
    poses ``poses[c] (V_c, 8)`` of the frames ``view_frames[c] (V_c,)``: over the frames a
    known camera ``a`` shares with an unknown ``b``, ``T_0b = T_0a mean(T_af T_bf^-1)``,
    breadth-first from camera 0 (the pair sharing the most frames first).

    Raises:
        ValueError: a camera shares no frame with camera 0, directly or through others.
    """
    C = len(poses)
    known = {0: dualquat.identity((), dtype=poses[0].dtype)}
    while len(known) < C:
        links = []
        for a in known:
            for b in set(range(C)) - set(known):
                common = [int(f) for f in view_frames[a] if bool((view_frames[b] == f).any())]
                links.append((len(common), a, b, common))
        n, a, b, common = max(links, key=lambda x: x[0])
        if n == 0:
            missing = sorted(set(range(C)) - set(known))
            raise ValueError(f"calibration.cameras: cameras {missing} share no frame (equal "
                             f"timestamps) with camera 0, directly or through other cameras "
                             f"(cameras triggered together whose stamps differ by jitter: "
                             f"round their times to the common frame times first)")
        ia = torch.stack([torch.nonzero(view_frames[a] == f)[0, 0] for f in common])
        ib = torch.stack([torch.nonzero(view_frames[b] == f)[0, 0] for f in common])
        rel = _average(dualquat.mul(poses[a][ia], dualquat.inv(poses[b][ib])))
        known[b] = dualquat.mul(known[a], rel)
    return torch.stack([known[c] for c in range(1, C)]) if C > 1 else poses[0].new_zeros(0, 8)

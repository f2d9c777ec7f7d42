"""Our own rewrite of BAD-Gaussians' ``bad_gaussians/spline_functor.py`` (WU-CVGL/BAD-Gaussians:
``linear_interpolation`` and ``cubic_bspline_interpolation``, SO(3) x R^3 on pypose), written
from its description, not copied: the reference of the drop-in check (tests/test_split.py)
and the peer of ``benchmarks/bench_split.py``.

Their functor takes a batch of SE(3) control poses in pypose's layout ``(t, q_xyzw)`` and
local parameters ``u`` in ``[0, 1]`` (optionally clipped ``1e-6`` away from the ends,
``enable_eps``; not reproduced: the check is that torch_dq needs no such clipping).
"""

import pypose as pp
import torch

import torch_dq.dualquat as dq

__all__ = ["badgs_cubic", "badgs_linear", "to_pypose", "uniform_cubic_basis"]


def badgs_linear(ctrl7, u):
    """Our rewrite of BAD-Gaussians' ``linear_interpolation`` (spline_functor.py): SE(3)
    poses ``(B, 2, 7)`` in pypose's layout ``(t, q_xyzw)``, local parameters ``u (B, V)`` ->
    ``(B, V, 7)``: slerp ``R_0 Exp(u Log(R_0^-1 R_1))`` and ``(1 - u) t_0 + u t_1``."""
    T = pp.SE3(ctrl7)
    rot, trans = T.rotation(), T.translation()
    w = u[..., None]
    pos = (1.0 - w) * trans[:, None, 0] + w * trans[:, None, 1]
    delta = (rot[:, 0].Inv() @ rot[:, 1]).Log()  # (B, 3)
    q = rot[:, None, 0] @ pp.so3(w * delta[:, None]).Exp()
    return torch.cat((pos, q.tensor()), -1)


def uniform_cubic_basis(u):
    """The uniform cubic B-spline's four blending functions at local parameters ``u``."""
    v = 1.0 - u
    return torch.stack((v ** 3, 3 * u ** 3 - 6 * u ** 2 + 4, -3 * u ** 3 + 3 * u ** 2 + 3 * u + 1,
                        u ** 3), -1) / 6.0


def badgs_cubic(ctrl7, u):
    """Our rewrite of BAD-Gaussians' ``cubic_bspline_interpolation``: four poses
    ``(B, 4, 7)``, ``u (B, V)`` -> ``(B, V, 7)``: ``sum_j b_j(u) t_j`` and
    ``R_0 prod_{j=1}^3 Exp(c_j(u) Log(R_{j-1}^-1 R_j))``, ``c_j = sum_{l >= j} b_l``."""
    T = pp.SE3(ctrl7)
    rot, trans = T.rotation(), T.translation()
    b = uniform_cubic_basis(u)  # (B, V, 4)
    pos = b @ trans
    c = b.flip(-1).cumsum(-1).flip(-1)
    delta = (rot[:, :-1].Inv() @ rot[:, 1:]).Log()  # (B, 3, 3)
    q = rot[:, None, 0].expand(*u.shape, 4)
    for j in range(1, 4):
        q = pp.SO3(q) @ pp.so3(c[..., j, None] * delta[:, None, j - 1]).Exp()
    return torch.cat((pos, pp.SO3(q).tensor()), -1)


def to_pypose(x):
    """``(..., 8)`` dual quaternions -> pypose SE(3) ``(..., 7)``: ``(t, x, y, z, w)``."""
    q, t = dq.to_rt(x)
    return torch.cat((t, q[..., 1:], q[..., :1]), -1)


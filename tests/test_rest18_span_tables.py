"""rest18: ``BSpline.span_vjp_tables`` built from each neighbouring pair of control points
once: step ``j`` of span ``u`` holds the twist of the pair ``(u + j, u + j + 1)`` (against
pytransform3d's SE(3) logarithm of the relative transform) and the same 80 rows as the
span's own parts (``_cumulative_lie.span_parts`` of the span's points), batched or not."""

import numpy as np
import pytest
import pytransform3d.transformations as pt
import torch
from scipy.spatial.transform import Rotation

from torch_dq import _cumulative_lie
from torch_dq import dualquat as dq
from torch_dq._curve import aligned_chain
from torch_dq.nn import BSpline

F64 = torch.float64


def _transform(x: np.ndarray) -> np.ndarray:
    """4x4 of a unit dual quaternion ``(w, x, y, z | dual)`` (formula written here)."""
    r, d = x[:4], x[4:]
    t = 2.0 * np.array([  # 2 vec(d r^*)
        -d[0] * r[1] + d[1] * r[0] - d[2] * r[3] + d[3] * r[2],
        -d[0] * r[2] + d[1] * r[3] + d[2] * r[0] - d[3] * r[1],
        -d[0] * r[3] - d[1] * r[2] + d[2] * r[1] + d[3] * r[0]])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r[1], r[2], r[3], r[0]]).as_matrix()
    T[:3, 3] = t
    return T


@pytest.mark.parametrize("batch", [(), (2,)])
def test_tables_are_each_spans_parts(batch):
    p, n = 3, 9
    g = torch.Generator().manual_seed(len(batch))
    ctrl = dq.exp(0.6 * torch.randn(*batch, n, 6, dtype=F64, generator=g))
    curve = BSpline(ctrl, degree=p, form="cumulative")
    tables = curve.span_vjp_tables(ctrl)
    assert tables.shape == (80, p, *batch, n - p) and tables.is_contiguous()
    chain = aligned_chain(ctrl)
    for b in np.ndindex(*batch):
        pts = chain[b]
        for u in range(n - p):
            ref = _cumulative_lie.span_parts(pts[u:u + p + 1][None])[..., 0]  # (80, p)
            torch.testing.assert_close(tables[(slice(None), slice(None), *b, u)], ref,
                                       rtol=0, atol=1e-14)
            for j in range(p):
                rel = np.linalg.inv(_transform(pts[u + j].numpy())) @ _transform(
                    pts[u + j + 1].numpy())
                twist = pt.exponential_coordinates_from_transform(rel)
                np.testing.assert_allclose(tables[(slice(0, 6), j, *b, u)].numpy(), twist,
                                           rtol=0, atol=1e-12)

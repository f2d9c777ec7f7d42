"""RelativePoses refuses a valid pair whose two times are equal.

Found by outside testing (rig11): ``x(t)^-1 x(t)`` is the identity whatever the trajectory,
so such a pair (a copied time column, a keyframe paired with itself) carries no information
and its residual is the measurement itself: it was accepted silently, adding a constant to
the cost and to chi2 (times_from passed for both columns: accepted, the cost 4.6e8 with
nothing said). Pairs in any order stay legal (loop closures go back in time); masked pairs may
hold anything.
"""

import numpy as np
import pytest
import torch
from _rig11_rig import position, rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import RelativePoses

T = np.arange(0.0, 1.0, 0.1)


def _rel(a, b):
    """The relative poses ``x(a)^-1 x(b)`` of the closed-form motion (scipy)."""
    Ra, Rb = rotation(a), rotation(b)
    q = (Ra.inv() * Rb).as_quat(scalar_first=True)
    return dq.from_rt(torch.from_numpy(q), torch.from_numpy(Ra.inv().apply(position(b)
                                                                            - position(a))))


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def test_a_pair_at_one_instant_is_refused_naming_it():
    a, b = T[:-1], T[1:].copy()
    b[4] = a[4]
    with pytest.raises(ValueError, match=r"RelativePoses: times_from and times_to must "
                                         r"differ.*sample 4 is not"):
        RelativePoses(_t(a), _t(b), _rel(a, b), rot_sigma=1e-3, trans_sigma=1e-3)


def test_backward_and_masked_pairs_are_accepted():
    a, b = T[1:], T[:-1].copy()  # every pair back in time
    RelativePoses(_t(a), _t(b), _rel(a, b), rot_sigma=1e-3, trans_sigma=1e-3)
    b = b.copy()
    b[2] = a[2]
    mask = torch.ones(len(a), dtype=torch.bool)
    mask[2] = False
    term = RelativePoses(_t(a), _t(b), _rel(a, b), rot_sigma=1e-3, trans_sigma=1e-3,
                         mask=mask)
    assert int(term.mask.sum()) == len(a) - 1


def test_a_batch_row_is_named():
    a = np.stack([T[:-1], T[:-1]])
    b = np.stack([T[1:], T[1:]])
    b[1, 6] = a[1, 6]
    x = torch.stack([_rel(a[0], b[0]), _rel(a[0], b[0])])
    with pytest.raises(ValueError, match=r"sample 6 of batch element \[1\]"):
        RelativePoses(_t(a), _t(b), x, rot_sigma=1e-3, trans_sigma=1e-3)

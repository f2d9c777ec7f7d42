"""numpy / scipy truth to torch_dq inputs, for the rig tests: float64 tensors and dual
quaternions from a scipy ``Rotation`` and positions (through ``dualquat.from_rt`` only)."""

import numpy as np
import torch

import torch_dq.dualquat as dq


def t64(a):
    """A contiguous float64 tensor of ``a``."""
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def pose(R, p):
    """``(N, 8)`` poses from a scipy ``Rotation`` ``R`` and positions ``p (N, 3)``."""
    return dq.from_rt(t64(R.as_quat(scalar_first=True)), t64(p))

"""torch_dq: differentiable unit dual quaternions for PyTorch.

Modules: :mod:`torch_dq.dual` (dual numbers), :mod:`torch_dq.quat` (quaternions),
:mod:`torch_dq.dualquat` (dual quaternions, dual angle, screw interpolation),
:mod:`torch_dq.curves` (De Casteljau and De Boor on dual quaternions),
:mod:`torch_dq.nn` (curve layers, unit-dual-quaternion parametrization, fitting),
:mod:`torch_dq.losses` (sign-invariant pose losses).
"""

from . import curves, dual, dualquat, losses, nn, quat
from .dual import Dual
from .dualquat import angle as dual_angle
from .dualquat import sclerp
from .object import DualQuaternion

__all__ = [
    "Dual", "DualQuaternion", "curves", "dual", "dual_angle", "dualquat", "losses", "nn",
    "quat", "sclerp",
]
__version__ = "0.2.0"

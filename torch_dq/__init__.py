"""torch_dq: differentiable unit dual quaternions for PyTorch.

Modules: :mod:`torch_dq.dual` (dual numbers), :mod:`torch_dq.quat` (quaternions),
:mod:`torch_dq.dualquat` (dual quaternions, dual angle, screw interpolation),
:mod:`torch_dq.curves` (De Casteljau and De Boor on dual quaternions).
"""

from . import curves, dual, dualquat, quat
from .dual import Dual
from .dualquat import angle as dual_angle
from .dualquat import sclerp

__all__ = ["Dual", "curves", "dual", "dual_angle", "dualquat", "quat", "sclerp"]
__version__ = "0.1.0"

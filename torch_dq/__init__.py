"""torch_dq: differentiable unit dual quaternions for PyTorch.

Modules: :mod:`torch_dq.dual` (dual numbers), :mod:`torch_dq.quat` (quaternions),
:mod:`torch_dq.dualquat` (dual quaternions, dual angle, screw interpolation),
:mod:`torch_dq.camera` (camera models: project, unproject),
:mod:`torch_dq.curves` (De Casteljau and De Boor on dual quaternions),
:mod:`torch_dq.nn` (curve layers in the caller's time, unit-dual-quaternion parametrization),
:mod:`torch_dq.fitting` (least-squares start and fit loop, re-exported by ``nn``),
:mod:`torch_dq.losses` (sign-invariant pose losses),
:mod:`torch_dq.io` (TUM, KITTI and EuRoC trajectory files),
:mod:`torch_dq.calibration` (calibration targets, corner files and corner detection).
"""

from . import calibration, camera, curves, dual, dualquat, fitting, io, losses, nn, quat
from ._memory import reuse_memory
from ._version import __version__ as __version__
from .dual import Dual
from .dualquat import angle as dual_angle
from .dualquat import sclerp
from .object import DualQuaternion

__all__ = [
    "Dual", "DualQuaternion", "calibration", "camera", "curves", "dual", "dual_angle", "dualquat",
    "fitting", "io", "losses", "nn", "quat", "reuse_memory", "sclerp",
]

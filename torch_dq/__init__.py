"""torch_dq: differentiable unit dual quaternions for PyTorch."""

from . import quat

__all__ = ["quat"]
__version__ = "0.1.0"

"""Applications built on the library (not its core): the knee demo behind
``python -m torch_dq demo``.

- :mod:`.knee`: a synthetic knee-flexion model (tibia relative to femur), embedded, no data.
- :mod:`.runner`: the demo itself: fits, figures and a JSON summary.
"""

from .runner import FIGURES, PLOT_HINT, run_demo

__all__ = ["FIGURES", "PLOT_HINT", "run_demo"]

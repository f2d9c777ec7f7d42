"""Applications built on the library (not its core): the knee demo behind
``python -m torch_dq demo`` and the trajectory-file fit behind ``python -m torch_dq fit``.

- :mod:`.knee`: a synthetic knee-flexion model (tibia relative to femur), embedded, no data.
- :mod:`.runner`: the demo itself: fits, a JSON summary and the printed table.
- :mod:`.plots`: the demo's figures (matplotlib, optional).
- :mod:`.fit_file`: ``python -m torch_dq fit FILE`` (a TUM, KITTI or EuRoC trajectory).
"""

from .runner import FIGURES, PLOT_HINT, run_demo

__all__ = ["FIGURES", "PLOT_HINT", "run_demo"]

"""The knee demo behind ``python -m torch_dq demo``, an application built on the library (not
its core; the command line itself is :mod:`torch_dq.cli`).

- :mod:`.knee`: a synthetic knee-flexion model (tibia relative to femur), embedded, no data.
- :mod:`.runner`: the demo itself: fits, a JSON summary and the printed table.
- :mod:`.plots`: the demo's figures (matplotlib, optional).
"""

from .runner import FIGURES, PLOT_HINT, run_demo

__all__ = ["FIGURES", "PLOT_HINT", "run_demo"]

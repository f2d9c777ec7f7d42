"""``python -m torch_dq demo``, ``python -m torch_dq fit FILE`` and ``python -m torch_dq
calibrate ...`` (also the ``torch-dq`` console script): see :mod:`torch_dq.cli`.

Run ``python -m torch_dq demo --help`` or ``python -m torch_dq fit --help`` for the options.
The process is the command's own: it keeps freed memory for reuse
(:func:`~torch_dq.reuse_memory`), which a library call never does by itself.
"""

from __future__ import annotations

import sys

from ._memory import reuse_memory
from .cli import main

__all__ = ["main", "run"]


def run() -> int:
    """The command line in a process of its own: :func:`~torch_dq.reuse_memory`, then
    :func:`~torch_dq.cli.main`; the exit status."""
    reuse_memory()
    return main()


if __name__ == "__main__":
    sys.exit(run())

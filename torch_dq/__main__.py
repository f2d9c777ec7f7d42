"""``python -m torch_dq demo``, ``python -m torch_dq fit FILE`` and ``python -m torch_dq
calibrate ...`` (also the ``torch-dq`` console script): see :mod:`torch_dq.cli`.

Run ``python -m torch_dq demo --help`` or ``python -m torch_dq fit --help`` for the options.
"""

from __future__ import annotations

import sys

from .cli import main

__all__ = ["main"]

if __name__ == "__main__":
    sys.exit(main())

"""The command line: ``python -m torch_dq fit``, ``calibrate`` and ``demo`` (also the
``torch-dq`` console script); run ``python -m torch_dq COMMAND --help`` for the options.

- :mod:`.fit_file`: ``fit FILE``, a B-spline fitted to a trajectory file (TUM, KITTI,
  EuRoC), measured on held-out poses, resampled and written;
- :mod:`.fit_imu`: ``fit FILE --imu IMU_FILE``, the poses and an IMU fitted together;
- :mod:`.fit_plots`: ``fit``'s figures;
- ``calibrate``: camera-IMU calibration from Kalibr's files (:mod:`torch_dq.calibration`);
- ``demo``: the knee demo of :mod:`torch_dq.demo`.

The commands are applications of the library: nothing in :mod:`torch_dq` imports this
package but ``python -m torch_dq`` (``torch_dq/__main__.py``).
"""

from ._main import main

__all__ = ["main"]

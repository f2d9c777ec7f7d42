"""Target-based calibration of cameras (and, later, cameras and IMUs).

:func:`cameras`: intrinsics of one or more cameras and the poses of cameras ``1..``
relative to camera 0 from target observations alone (Kalibr's ``calibrate_cameras``).
"""

from ._cameras import CameraCalibration, cameras

__all__ = ["CameraCalibration", "cameras"]

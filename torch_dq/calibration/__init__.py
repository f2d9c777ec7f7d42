r"""Target-based calibration of cameras and IMUs: targets, corner files, corner detection,
camera intrinsics and camera-IMU calibration.

* :class:`Target`, :func:`aprilgrid`, :func:`checkerboard`, :func:`read_target`: Kalibr's
  calibration targets (AprilGrid, checkerboard), their points in Kalibr's order and
  Kalibr's target yaml.
* :func:`read_corners`: corner detections from a CSV (``t_ns, tag_id, corner_idx, u_px,
  v_px, X_m, Y_m, Z_m``), as ``(times, points, pixels)``.
* :func:`detect`, :func:`detect_folder`: AprilGrid and checkerboard corners of grey images
  (OpenCV's ArUco module and chessboard detector, sub-pixel refined).
* :func:`cameras`: intrinsics of one or more cameras and the poses of cameras ``1..``
  relative to camera 0 from target observations alone (Kalibr's ``calibrate_cameras``).
* :func:`camera_imu`: the cameras' poses on an IMU, clock offsets, rolling-shutter line
  delays, IMU biases and gravity from target observations and IMU readings (Kalibr's
  ``calibrate_imu_camera``); ``python -m torch_dq calibrate`` runs it from Kalibr's files.
* :func:`read_camchain`: Kalibr's ``camchain.yaml`` / ``camchain-imucam.yaml`` (what the
  results' ``to_kalibr()`` and the command write) read back as cameras, relative poses,
  extrinsics and clock offsets (a :class:`Camchain`).

The target's frame is Kalibr's (``Z = 0`` on the board, ``X`` right and ``Y`` up seen from
the front). OpenCV and PyYAML are optional: ``pip install torch_dq[calib]``; they are
imported when a function needs them.
"""

from ._camchain import Camchain, read_camchain
from ._camera_imu import CameraImuCalibration, camera_imu
from ._cameras import CameraCalibration, cameras
from ._corners import CornersFileError, read_corners
from ._detect import detect, detect_folder
from ._targets import Target, aprilgrid, checkerboard, read_target

for _obj in (Camchain, CameraCalibration, CameraImuCalibration, CornersFileError, Target,
             aprilgrid, camera_imu, cameras, checkerboard, detect, detect_folder,
             read_camchain, read_corners, read_target):
    _obj.__module__ = __name__  # the public home of the names (and of their documentation)
del _obj

__all__ = [
    "Camchain", "CameraCalibration", "CameraImuCalibration", "CornersFileError", "Target",
    "aprilgrid", "camera_imu", "cameras", "checkerboard", "detect", "detect_folder",
    "read_camchain", "read_corners", "read_target",
]

r"""Read and write trajectory files (TUM, KITTI, EuRoC ground truth, a resampled CSV) and IMU files.

A trajectory file holds timestamped rigid poses (body to world). Three common formats:

============  ==================================================================  ============
``format``    one pose per line                                                   times
============  ==================================================================  ============
``"tum"``     ``t x y z qx qy qz qw`` (whitespace or commas; ``#`` comments),     seconds
              the TUM RGB-D benchmark's ``groundtruth.txt``
``"kitti"``   ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``: the 3x4 matrix    a separate
              ``[R | t]`` row by row (KITTI odometry ``poses/NN.txt``)            file (s)
``"euroc"``   ``#timestamp [ns], p_RS_R_x [m], p_RS_R_y, p_RS_R_z, q_RS_w,        nanoseconds
              q_RS_x, q_RS_y, q_RS_z`` and optionally velocity and biases
              (``state_groundtruth_estimate0/data.csv``; columns after the 8th
              are ignored)
============  ==================================================================  ============

:func:`read_trajectory` returns a :class:`Trajectory`: ``float64`` times in seconds as
written (absolute UNIX seconds stay absolute: ``float64`` keeps them to ~0.2 µs), rotations
as unit quaternions ``(w, x, y, z)`` and translations, on the CPU; ``trajectory.poses()``
gives the unit dual quaternions. Malformed files raise :class:`TrajectoryFileError` (a
``ValueError``) naming the file and the line: wrong column count, a value that is not a
finite number, timestamps that are not strictly increasing, a quaternion whose norm is not 1
within ``atol`` (a KITTI rotation matrix that is not orthonormal), an empty file.
:func:`write_trajectory` writes the three formats back, exactly (every float64 time and value
reads back bit for bit); :func:`write_csv` writes a resampled trajectory with its velocities
and accelerations (what ``python -m torch_dq fit`` writes). :func:`read_imu` reads gyroscope
and accelerometer samples (EuRoC ``imu0/data.csv`` or plain ``t gx gy gz ax ay az``).

Numbers are read strictly as files write them: ASCII decimals (``1_0``, which Python's
``float`` takes for 10, is an error); a UTF-8 byte-order mark is skipped.

Example:
    >>> import torch, tempfile, os
    >>> from torch_dq import io
    >>> path = os.path.join(tempfile.mkdtemp(), "traj.txt")
    >>> with open(path, "w") as f:
    ...     _ = f.write("# timestamp tx ty tz qx qy qz qw\n"
    ...                 "1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\n"
    ...                 "1305031098.6758 1.3543 0.6306 1.6360 0.6129 0.5966 -0.3316 -0.3980\n")
    >>> traj = io.read_trajectory(path)
    >>> len(traj), traj.times.dtype, traj.poses().shape
    (2, torch.float64, torch.Size([2, 8]))
    >>> round(float(traj.times[1] - traj.times[0]), 4)
    0.0099
"""

from ._imu import read_imu
from ._text import TrajectoryFileError
from ._trajectory import FORMATS, Trajectory, read_trajectory
from ._write import CSV_COLUMNS, write_csv, write_trajectory

for _obj in (Trajectory, TrajectoryFileError, read_imu, read_trajectory, write_csv,
             write_trajectory):
    _obj.__module__ = __name__  # the public home of the names (and of their documentation)
del _obj
__test__ = {"Trajectory.select": Trajectory.select}  # its example, defined in ._trajectory

__all__ = [
    "CSV_COLUMNS",
    "FORMATS",
    "Trajectory",
    "TrajectoryFileError",
    "read_imu",
    "read_trajectory",
    "write_csv",
    "write_trajectory",
]

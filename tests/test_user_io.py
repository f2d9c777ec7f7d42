"""An outside tester's uses of ``torch_dq.io`` (0.5.0 trial): a ``Trajectory`` built by hand
with mismatched or non-tensor fields, its printed form, and IMU files whose gyroscope reads
deg/s. Each test failed before its fix (the Trajectory was accepted, and failed later or
not at all; the deg/s file was read without a word)."""

from __future__ import annotations

import os
import sys
import warnings

import numpy as np
import pytest
import torch

from torch_dq import io, quat

sys.path.insert(0, os.path.dirname(__file__))
import _camera_imu_sim as sim

F64 = torch.float64


def test_trajectory_checks_its_fields():
    t = torch.arange(5, dtype=F64)
    q, p = quat.identity((5,), F64), torch.zeros(5, 3, dtype=F64)
    cases = [((t, q[:3], p), ValueError, r"io\.Trajectory: expected times \(N,\), rotations "
                                         r"\(N, 4\) .* got \(5,\), \(3, 4\) and \(5, 3\)"),
             ((t, p, p), ValueError, r"got \(5,\), \(5, 3\) and \(5, 3\)"),
             ((t[:, None], q, p), ValueError, r"got \(5, 1\)"),
             (([0.0, 1.0], q[:2], p[:2]), TypeError, r"io\.Trajectory: expected a torch\.Tensor "
                                                     r"for times, got list"),
             ((t.long(), q, p), TypeError, r"floating-point tensor for times")]
    for args, kind, message in cases:
        with pytest.raises(kind, match=message):
            io.Trajectory(*args)
    traj = io.Trajectory(t, q, p)
    assert len(traj.select(slice(1, 3))) == 2
    assert repr(traj) == "Trajectory(5 poses, times 0.0 to 4.0, dtype=torch.float64)"
    assert repr(traj.select(slice(0, 0))) == "Trajectory(0 poses, dtype=torch.float64)"


def _imu_file(tmp_path, scale, name="imu.txt"):
    """The simulated rig's IMU (rad/s times ``scale``) as a ``t gx gy gz ax ay az`` file."""
    (t, g, a), _ = sim.rig(duration=4.0, seed=3)
    path = tmp_path / name
    np.savetxt(path, np.column_stack((t + 100.0, scale * g, a)), fmt="%.12g",
               header="t gx gy gz ax ay az")
    return path


def test_read_imu_names_a_gyroscope_in_degrees_per_second(tmp_path):
    with pytest.warns(UserWarning, match=r"io\.read_imu: .*imu\.txt: the gyroscope readings "
                                         r"look like deg/s, not rad/s: .*torch\.deg2rad"):
        _, gyro, _ = io.read_imu(_imu_file(tmp_path, 180.0 / np.pi))
    assert gyro.abs().max() > 30.0  # read as written: the warning names the fix
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        io.read_imu(_imu_file(tmp_path, 1.0, "ok.txt"))


def test_kitti_reads_back_with_the_writers_keyword(tmp_path):
    """write_trajectory(..., "kitti", times_path=T) wrote a file that read_trajectory(...,
    "kitti", times_path=T) refused with a bare Python TypeError (the reader's name is
    ``times``): the reader takes ``times_path`` too."""
    t = 1305031098.6659 + 0.01 * torch.arange(6, dtype=F64)
    axis = torch.tensor([0.0, 0.0, 1.0], dtype=F64)
    traj = io.Trajectory(t, quat.from_axis_angle(axis, 0.1 * torch.arange(6, dtype=F64)),
                         torch.rand(6, 3, dtype=F64))
    io.write_trajectory(tmp_path / "p.txt", traj, "kitti", times_path=tmp_path / "t.txt")
    back = io.read_trajectory(tmp_path / "p.txt", "kitti", times_path=tmp_path / "t.txt")
    assert torch.equal(back.times, t)
    torch.testing.assert_close(back.translations, traj.translations, rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"io\.read_trajectory: times and times_path name "
                                         r"the same argument"):
        io.read_trajectory(tmp_path / "p.txt", "kitti", tmp_path / "t.txt",
                           times_path=tmp_path / "t.txt")
    with pytest.raises(ValueError, match=r"times= applies to KITTI files only"):
        io.read_trajectory(tmp_path / "p.txt", "tum", times_path=tmp_path / "t.txt")


def test_read_imu_names_seconds_under_a_nanosecond_header(tmp_path):
    """A EuRoC header (``#timestamp [ns]``) over times written in seconds was read as
    nanoseconds with fractions: samples 5e-12 s apart, without a word."""
    head = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
            "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
    rows = "".join(f"{1403715273.262 + 0.005 * k:.3f},0.1,0.2,0.3,0.1,0.2,9.8\n"
                   for k in range(50))
    path = tmp_path / "data.csv"
    path.write_text(head + rows)
    with pytest.warns(UserWarning, match=r"io\.read_imu: .*data\.csv: the times look like "
                                         r"seconds, not nanoseconds: .*5e-12 s apart .* "
                                         r"time_unit='s'"):
        io.read_imu(path)
    t, _, _ = io.read_imu(path, time_unit="s")
    assert abs(float(t[1] - t[0]) - 0.005) < 1e-6
    ns = "".join(f"{1403715273262000000 + 5000000 * k},0.1,0.2,0.3,0.1,0.2,9.8\n"
                 for k in range(50))
    path.write_text(head + ns)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert abs(float(io.read_imu(path)[0][1] - 1403715273.267)) < 1e-6


def test_read_trajectory_names_seconds_under_a_nanosecond_header(tmp_path):
    """The same for EuRoC ground truth: decimal seconds under ``#timestamp [ns]`` were read
    as poses 5e-12 s apart (a 1.4 s long 'UNIX time'), without a word."""
    head = ("#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
            "q_RS_y [], q_RS_z []\n")
    path = tmp_path / "gt.csv"
    path.write_text(head + "".join(f"{1403636579.758 + 0.005 * k:.3f},{0.01 * k},0,0,1,0,0,0\n"
                                   for k in range(50)))
    with pytest.warns(UserWarning, match=r"io\.read_trajectory: .*gt\.csv: the times look "
                                         r"like seconds, not nanoseconds"):
        io.read_trajectory(path)

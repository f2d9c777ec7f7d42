"""A new user's wrong inputs (user11): files of another kind given as a trajectory, and a
folder given to ``fit``, end in errors that name what the file is and what reads it.

Before: a corners CSV read as a EuRoC trajectory stopped on "duplicate timestamp ... pass
duplicates='first'" (and then on a quaternion's norm); EuRoC's ``imu0/data.csv`` on a column
count; a 7-column IMU text file on "pass format="; ``fit`` on a folder said "No such file or
directory" about a folder that exists.
"""

import pytest

from torch_dq import io
from torch_dq.cli import main

CORNERS = ("# t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m\n"
           "1403709385487836928,6,0,274.6642,57.4390,0.000000,0.114400,0.000000\n"
           "1403709385487836928,6,1,235.9239,51.5984,0.088000,0.114400,0.000000\n")
EUROC_IMU = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
             "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n"
             "1403636579758555392,-0.0991,0.1473,0.0272,8.1477,-0.3759,-2.4026\n"
             "1403636579763555584,-0.0991,0.1403,0.0293,8.0333,-0.4086,-2.4026\n")
PLAIN_IMU = ("1305031098.665 0.01 0.02 0.03 0.1 0.2 9.81\n"
             "1305031098.670 0.01 0.02 0.03 0.1 0.2 9.81\n")


@pytest.mark.parametrize("text, reader", [(CORNERS, "torch_dq.calibration.read_corners"),
                                          (EUROC_IMU, "torch_dq.io.read_imu"),
                                          (PLAIN_IMU, "torch_dq.io.read_imu")])
def test_a_file_of_another_kind_names_its_reader(tmp_path, text, reader):
    path = tmp_path / "data.csv"
    path.write_text(text)
    with pytest.raises(io.TrajectoryFileError, match=reader) as info:
        io.read_trajectory(path)
    assert str(path) in str(info.value) and "duplicate" not in str(info.value)


def test_the_files_read_by_their_own_readers(tmp_path):
    """The same texts are what those readers take (the error pointed the right way)."""
    from torch_dq import calibration

    (tmp_path / "c.csv").write_text(CORNERS)
    assert calibration.read_corners(tmp_path / "c.csv")[2].shape == (2, 2)
    for name, text in (("i.csv", EUROC_IMU), ("i.txt", PLAIN_IMU)):
        (tmp_path / name).write_text(text)
        assert io.read_imu(tmp_path / name)[1].shape == (2, 3)


def test_fit_on_a_folder_says_it_is_a_folder(tmp_path, capsys):
    (tmp_path / "poses").mkdir()
    assert main(["fit", str(tmp_path / "poses"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a folder, not a file" in err[0] and "No such" not in err[0]
    assert not (tmp_path / "out").exists()

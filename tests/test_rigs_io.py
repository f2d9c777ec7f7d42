"""Outside-tester regressions for the corner and IMU readers (rigs7); each failed before its
fix: a EuRoC IMU file whose header states deg/s (or an accelerometer in g) was read as rad/s
(m/s^2) without a word; a corners file listing one tag corner twice in one frame at two
pixels was read as two observations of one point."""

import pytest

from torch_dq import calibration, io

_EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                 "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
_ROWS = "".join(f"{1403715273262142976 + 5000000 * i},-0.0991,0.1382,0.0307,8.1,-0.37,-2.4\n"
                for i in range(5))


def test_read_imu_euroc_header_in_rad_s_reads(tmp_path):
    path = tmp_path / "data.csv"
    path.write_text(_EUROC_HEADER + _ROWS)
    t, g, a = io.read_imu(path)
    assert t.shape == (5,) and float(g[0, 0]) == -0.0991 and float(a[0, 0]) == 8.1


@pytest.mark.parametrize("header, word", [
    (_EUROC_HEADER.replace("rad s^-1", "deg s^-1"), "degrees per second"),
    ("# t [s], gx [deg/s], gy [deg/s], gz [deg/s], ax, ay, az\n", "degrees per second"),
    (_EUROC_HEADER.replace("[m s^-2]", "[g]"), "accelerometer in g"),
])
def test_read_imu_refuses_a_header_stating_other_units(tmp_path, header, word):
    path = tmp_path / "data.csv"
    rows = _ROWS if "[ns]" in header else "".join(
        f"{0.005 * i} 0.1 0.2 0.3 0 0 9.81\n" for i in range(5))
    path.write_text(header + rows)
    with pytest.raises(io.TrajectoryFileError, match=rf"data\.csv: the header gives .*{word}"):
        io.read_imu(path)


_CORNERS = ("#t_ns,tag_id,corner_idx,u_px,v_px,X_m,Y_m,Z_m\n"
            "1403709395937837056,0,0,100.5,200.25,0.0,0.0,0.0\n"
            "1403709395937837056,0,1,110.5,200.25,0.088,0.0,0.0\n"
            "1403709396037837056,0,0,101.5,201.25,0.0,0.0,0.0\n")


def test_read_corners_refuses_one_corner_twice_in_a_frame(tmp_path):
    path = tmp_path / "corners.csv"
    path.write_text(_CORNERS + "1403709395937837056,0,0,300.5,400.25,0.0,0.0,0.0\n")
    with pytest.raises(calibration.CornersFileError,
                       match=r"line 5: tag_id 0 corner_idx 0 again in the frame "
                             r"1403709395937837056 \(first on line 2\)"):
        calibration.read_corners(path)


def test_read_corners_coinciding_corners_of_two_tags_stay(tmp_path):
    # an AprilGrid of spacing 0: tag 0's corner 1 is tag 1's corner 0
    path = tmp_path / "corners.csv"
    path.write_text(_CORNERS + "1403709395937837056,1,0,110.5,200.25,0.088,0.0,0.0\n")
    t, p, _ = calibration.read_corners(path)
    assert t.shape == (4,) and p[1].tolist() == p[3].tolist()

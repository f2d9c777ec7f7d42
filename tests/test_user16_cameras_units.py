"""``calibration.cameras`` refuses target points in millimetres, as ``camera_imu`` does
(user16).

Intrinsics do not depend on the target's scale, so corners whose ``X_m, Y_m, Z_m`` hold
millimetres calibrated "fine", and the relative poses came out in millimetres:
``to_kalibr()``'s ``T_cn_cnm1`` for EuRoC's stereo rig held a baseline of 111.7 where Kalibr
writes metres (0.1117), silently. ``camera_imu`` already refused points spread over more
than 20 m; ``cameras`` now does too, with the same advice. Reference: the EuRoC corner file
(metres, its README) scaled by 1000 in the test.
"""

from pathlib import Path

import pytest

from torch_dq import calibration

DATA = Path(__file__).resolve().parent / "data" / "calibration"


def test_millimetre_points_refused():
    t, p, u = calibration.read_corners(DATA / "euroc_cam_april_cam0_corners.csv")
    with pytest.raises(ValueError, match=r"observations\[0\].*millimetres.*1000"):
        calibration.cameras([(t, 1000.0 * p, u)], ["pinhole-radtan"], [(752, 480)])


def test_metre_points_pass_the_check():
    t, p, u = calibration.read_corners(DATA / "euroc_cam_april_cam0_corners.csv")
    res = calibration.cameras([(t, p, u)], ["pinhole-radtan"], [(752, 480)],
                              max_iterations=0)  # the start alone: the check is before it
    assert res.cameras[0].params.shape == (8,)

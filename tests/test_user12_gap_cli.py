"""A new user's recording with a 10 s gap (user12): ``python -m torch_dq fit`` says that the
gap, not the poses' noise, limits the knot spacing (uniform knots put control points in the
gap too, and the fitted poses bound their number), and how to get finer knots."""

import pathlib

import numpy as np

from torch_dq.__main__ import main

SHIPPED = pathlib.Path(__file__).parent / "data" / "tum_fr1_xyz_sub.txt"


def _write(path, rows):
    np.savetxt(path, rows, fmt=["%.4f"] + ["%.4f"] * 7)


def test_a_long_gap_is_named_as_what_limits_the_spacing(tmp_path, capsys):
    rows = np.loadtxt(SHIPPED)[:300]
    rows[100:, 0] += 10.0  # 2 s of poses, 10 s without, 4 s of poses: 63 % gap
    _write(tmp_path / "gap.txt", rows)
    assert main(["fit", str(tmp_path / "gap.txt"), "--out", str(tmp_path / "o"),
                 "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "it takes 63 % of the span" in out and "fit the parts between the gaps" in out
    # the same poses without the gap, checked with numpy: the note is not there
    _write(tmp_path / "nogap.txt", np.loadtxt(SHIPPED)[:300])
    assert main(["fit", str(tmp_path / "nogap.txt"), "--out", str(tmp_path / "p"),
                 "--no-plots"]) == 0
    assert "of the span" not in capsys.readouterr().out

"""The ``fit`` command's knot-spacing search (``torch_dq.fitting._knots``): which candidate
spacings it scores, and that scoring fewer of them chooses what the whole grid chooses."""

import pathlib
import warnings

import pytest

from torch_dq import io
from torch_dq.cli import fit_file
from torch_dq.fitting import _knots

DATA = pathlib.Path(__file__).resolve().parent / "data"


def test_first_pass_stops_once_either_error_has_risen():
    """Rotation errors rising past 1 + 10 tol of their lowest at grid point 4 while the
    translation errors stay flat: no coarser point can be within tol of both lowest errors,
    so the every-other pass stops there (it went on to the end of the grid while the flat
    error had not risen too), then scores only the points between near the best."""
    rot = [1.0, 1.0, 1.0, 1.05, 1.3, 1.5, 1.7, 1.9, 2.1, 2.3, 2.5, 2.7]
    seen = []

    def score(i):
        seen.append(i)
        return rot[i], 1.0

    scores = _knots._coarse_to_fine(score, len(rot), 0.02)
    assert sorted(scores) == [0, 1, 2, 3, 4] and sorted(seen) == [0, 1, 2, 3, 4]


def _choice(scores, tol=0.02):
    """The grid index the search's rule chooses among ``{index: (rot, trans)}``."""
    index = sorted(scores)
    rot, trans = [scores[i][0] for i in index], [scores[i][1] for i in index]
    ok = [i for i, (r, p) in enumerate(zip(rot, trans, strict=True))
          if r <= (1 + tol) * min(rot) + 1e-15 and p <= (1 + tol) * min(trans) + 1e-15]
    ratio = [max(r / min(rot), p / min(trans)) for r, p in zip(rot, trans, strict=True)]
    return index[max(ok) if ok else min(range(len(ratio)), key=ratio.__getitem__)]


@pytest.mark.parametrize("name", ["tum_fr1_xyz_sub.txt", "tum_fr2_desk_sub.txt"])
@pytest.mark.parametrize("holdout", [1, 2])
def test_search_chooses_what_the_whole_grid_chooses(name, holdout):
    """On real hand-held motion the coarse-to-fine search scores part of the grid and
    chooses the candidate that scoring every grid point chooses."""
    traj = io.read_trajectory(DATA / name, duplicates="first")
    train = traj.select(fit_file._split(len(traj), holdout, 3)[0])
    times, poses = train.times, train.poses()
    fit, check = _knots.inner_split(times.shape[0])
    grid = _knots._grid(float(times[fit][-1] - times[fit][0]), fit.shape[0], 3)
    inner = (times[fit], _knots._unit64(poses[fit]), times[check], poses[check])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = {i: _knots._scores(*inner, g, 3, "de_boor") for i, g in enumerate(grid)}
    search = _knots.knot_spacing_search(times, poses, 3)
    assert len(search.candidates) < len(grid)
    assert search.candidates[search.chosen] == grid[_choice(full)]

"""Section ``cumulative``: the cumulative cubic B-spline (``form="cumulative"``) beside
``pypose.bspline``, which computes the same curve on uniform knots (pypose's time ``s`` is
our ``t = s + 3`` on knots ``0, 1, ..., n + 3``): eager and compiled, forward and
forward+backward, with the largest difference between the two curves in the note."""

from __future__ import annotations

import _peers
from _bench import Bench, curves, max_diff_up_to_sign
from _peers import PeerMissing
from bench_bspline import form_inputs, rows

def _agreement(ctrl, knots) -> str:
    """``max|diff|`` of our cumulative curve and pypose's at pypose's own grid."""
    try:
        s, theirs = _peers.pypose_bspline_curve(ctrl, interval=0.25)
    except PeerMissing:
        return ""
    ours = curves.bspline(ctrl, s + 3.0, degree=3, knots=knots, form="cumulative")
    return f"max|diff| {max_diff_up_to_sign(ours, theirs):.1e} at {len(s)} times"


def run(b: Bench, dtype):
    note = ""
    if curves is not None:
        ctrl, _, knots = form_inputs(2, dtype, b.device, "cumulative")
        note = _agreement(ctrl, knots)
    rows(b, dtype, "cumulative", note)

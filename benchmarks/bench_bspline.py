"""Section ``bspline``: the cubic De Boor B-spline against ``pypose.bspline``, eager and
compiled; the rows of both B-spline forms (``rows``), which ``bench_cumulative`` shares."""

from __future__ import annotations

import functools

import torch

import _peers
from _bench import (
    Bench, CURVES_ERROR, N_CTRL, bspline_inputs, compiled_rows, curves, err, fit_size, grad,
    peer_time, skip_compile,
)



# The two forms: row label, the knots and times of the timed curve, and how the work is
# matched with pypose's (the uniform cumulative SE3 spline, Hug et al. 2020).
FORMS = {
    "de_boor": ("bspline cubic", "pypose's uniform cumulative SE3 spline vs our clamped De "
                "Boor sclerp"),
    "cumulative": ("bspline cumulative cubic", "the same curve as pypose's: uniform knots "
                   "0..n+3, our t = s + 3"),
}


def form_inputs(T: int, dtype, device, form: str):
    """Control poses, ``T`` times over the domain and the knots (None: clamped uniform on
    [0, 1]) of the cubic B-spline of ``form``."""
    ctrl, t = bspline_inputs(T, dtype, device)
    if form == "de_boor":
        return ctrl, t, None
    knots = torch.arange(N_CTRL + 4, dtype=dtype, device=device)  # domain [3, N_CTRL]
    return ctrl, 3.0 + t * (N_CTRL - 3), knots


def rows(b: Bench, dtype, form: str, note: str = ""):
    """Eager and compiled rows, forward and forward+backward, of the cubic B-spline of
    ``form`` beside ``pypose.bspline`` on the same number of output poses."""
    label, matched = FORMS[form]
    if curves is None:
        b.add(f"{label} fwd", dtype, b.sizes["bspline"], "not available", 0, 0,
              note=CURVES_ERROR)
        return
    dev = b.device
    spline = functools.partial(curves.bspline, degree=3, form=form)

    def fwdbwd_probe(m):
        ctrl, t, knots = form_inputs(m, dtype, dev, form)
        ctrl.requires_grad_()
        grad(spline(ctrl, t, knots=knots), (ctrl,))

    T = fit_size(b, b.sizes["bspline"], 100_000, fwdbwd_probe)
    ctrl, t, knots = form_inputs(T, dtype, dev, form)
    size = torch.finfo(dtype).bits // 8
    cbytes = N_CTRL * 8 * size
    fwd_bytes = cbytes + T * size + 8 * T * size
    fb_bytes = fwd_bytes + 8 * T * size + cbytes
    match = f"matched: {N_CTRL} control poses, cubic, same number of output poses ({matched})"
    try:
        ours = b.time(lambda: spline(ctrl, t, knots=knots))
        cg = ctrl.clone().requires_grad_()
        ours_fb = b.time(lambda: grad(spline(cg, t, knots=knots), (cg,)))
    except Exception as exc:
        b.add(label, dtype, T, err(exc), 0, T)
        return
    pp_times = {}
    for row, ms, bytes_, bwd in ((f"{label} fwd", ours, fwd_bytes, False),
                                 (f"{label} fwd+bwd", ours_fb, fb_bytes, True)):
        pp_ms, pp_note = _pypose(b, ctrl, T, bwd)
        pp_note = "; ".join(x for x in (pp_note, match, note) if x)
        b.add(row, dtype, T, ms, bytes_, T, "pypose bspline", pp_ms, pp_note,
              "grad wrt control points" if bwd else "")
        pp_times[bwd] = pp_ms

    # torch.compile of the public function (check=False: no value check at all)
    if skip_compile(b, dtype, f"{label} [compiled]", T):
        return
    compiled = torch.compile(functools.partial(spline, knots=knots, check=False))
    compiled_rows(b, dtype, T, "pypose bspline", (
        (f"{label} fwd [compiled]", lambda: compiled(ctrl, t), ours, pp_times[False],
         fwd_bytes),
        (f"{label} fwd+bwd [compiled]", lambda: grad(compiled(cg, t), (cg,)), ours_fb,
         pp_times[True], fb_bytes)))


def _pypose(b: Bench, ctrl, T: int, bwd: bool):
    """pypose's time for ``T`` output poses (scaled per pose returned) and its note."""
    counts = {}

    def make(m):
        fn, check, count = _peers.pypose_bspline(ctrl, m, bwd)
        counts["m"] = count
        return fn, check

    pp_ms, note, made, m_req = peer_time(b, "pypose", make, T)
    if made is not None:
        # peer_time scaled by T / m_req, m_req the count asked for; rescale to the
        # count pypose returned ((N - 3) / interval + 1 >= m_req).
        pp_ms *= m_req / counts["m"]
        note = "; ".join(x for x in (note, f"pypose returned {counts['m']} poses for "
                                     f"{m_req} asked, time scaled per pose") if x)
    return pp_ms, note


def run(b: Bench, dtype):
    rows(b, dtype, "de_boor")

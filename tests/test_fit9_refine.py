"""The ``fit`` command refines the least-squares start only where it pays (``refine="auto"``,
``torch_dq.cli._refine.predicted_gain``): the predicted gain of one Gauss-Newton step
against a finite-difference Gauss-Newton reference in numpy/scipy, LM skipped on slow
smooth motion (the start already optimal to within the noise) and run on fast tumbling
motion sampled sparsely (where the charts' linearisation biases the start), with the
held-out errors recomputed by scipy."""

import json
import math

import numpy as np
import pytest
import torch

from torch_dq import dualquat
from torch_dq import nn as dqnn
from torch_dq.cli import fit_file
from torch_dq.cli._refine import predicted_gain

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


def _motion(t, rate):
    """Rotations (scipy) and positions (m) of a smooth motion turning at about ``rate``
    rad/s about slowly varying axes."""
    rotvec = np.stack((rate / 0.7 * np.sin(0.7 * t), rate / 0.45 * np.sin(0.45 * t),
                       0.5 * rate * t), -1)
    p = np.stack((np.sin(0.5 * t), np.cos(0.3 * t), 0.3 * np.sin(0.9 * t)), -1)
    return Rotation.from_rotvec(rotvec), p


def _tum_file(path, hz, seconds, rate, rot_noise, trans_noise, seed=0):
    """A TUM file of the motion at ``hz`` with Gaussian noise (rad, m); its array."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / hz)
    rot, p = _motion(t, rate)
    rot = rot * Rotation.from_rotvec(rot_noise * rng.standard_normal((len(t), 3)))
    p = p + trans_noise * rng.standard_normal(p.shape)
    xyzw = rot.as_quat()
    data = np.column_stack((t, p, xyzw))
    np.savetxt(path, data, fmt="%.9f")
    return data


def _heldout_scipy(out, data):
    """Held-out (every odd pose but the last) mean translation (mm) and rotation (deg)
    errors of the written ``spline.pt``, evaluated here and measured with numpy/scipy."""
    spline = dqnn.BSpline.from_state_dict(torch.load(out / "spline.pt"))
    held = np.arange(1, len(data) - 1, 2)
    with torch.no_grad():
        q, p = dualquat.to_rt(spline(torch.tensor(data[held, 0])).double())
    q, p = q.numpy(), p.numpy()
    trans = 1e3 * np.linalg.norm(p - data[held, 1:4], axis=1)
    rel = Rotation.from_quat(q[:, [1, 2, 3, 0]]).inv() * Rotation.from_quat(data[held, 4:])
    return trans.mean(), np.rad2deg(rel.magnitude()).mean()


def _run(path, out, **kw):
    summary = fit_file.run_fit(path, out=str(out), plots=False, verbose=False, **kw)
    return summary, json.loads((out / "summary.json").read_text())


def test_slow_smooth_motion_keeps_the_start(tmp_path):
    """100 Hz poses of a motion turning at 0.3 rad/s with 2 mrad and 1 mm of noise: one
    Gauss-Newton step would gain under 1 % of either part of the cost, so LM is skipped;
    the refined curve (``refine="always"``) is no better on the held-out poses by more
    than 1 %, and the gains predicted match what its LM run achieved."""
    path = tmp_path / "slow.txt"
    data = _tum_file(path, 100.0, 20.0, 0.3, 2e-3, 1e-3)
    auto, written = _run(path, tmp_path / "auto")
    assert written["fit"] == auto["fit"]
    gain = auto["fit"]["predicted_gain"]
    assert not auto["fit"]["refined"] and auto["fit"]["steps"] == 0
    assert max(gain.values()) <= fit_file.REFINE_GAIN, gain
    assert "Gauss-Newton" in auto["fit"]["reason"]
    always, _ = _run(path, tmp_path / "always", refine="always")
    assert always["fit"]["refined"] and always["fit"]["steps"] >= 1
    assert "predicted_gain" not in always["fit"]
    mm_auto, deg_auto = _heldout_scipy(tmp_path / "auto", data)
    mm_lm, deg_lm = _heldout_scipy(tmp_path / "always", data)
    assert mm_auto <= 1.01 * mm_lm and deg_auto <= 1.01 * deg_lm, (mm_auto, mm_lm, deg_auto,
                                                                   deg_lm)
    assert abs(auto["heldout_errors"]["translation_mm"]["mean"] - mm_auto) < 1e-6 * mm_auto
    achieved = 1 - always["fit"]["loss_final"] / always["fit"]["loss_start"]
    assert achieved <= fit_file.REFINE_GAIN  # LM, run anyway, gained what was predicted


def test_fast_tumbling_motion_is_refined(tmp_path):
    """30 Hz poses of a motion turning at 4 rad/s (a knot span turns by ~0.7 rad, where
    the start's linearisation in local charts is off): the predicted gain passes
    ``REFINE_GAIN``, LM runs and lowers the held-out errors (scipy) below the start's
    (``steps=0``) by more than 2 %, which skipping it would have lost."""
    path = tmp_path / "fast.txt"
    data = _tum_file(path, 30.0, 60.0, 4.0, 1e-2, 1e-3)
    auto, _ = _run(path, tmp_path / "auto")
    gain = auto["fit"]["predicted_gain"]
    assert max(gain.values()) > fit_file.REFINE_GAIN, gain
    assert auto["fit"]["refined"] and auto["fit"]["steps"] >= 1
    _run(path, tmp_path / "start", steps=0)
    mm_lm, _ = _heldout_scipy(tmp_path / "auto", data)
    mm_start, _ = _heldout_scipy(tmp_path / "start", data)
    assert mm_lm < 0.98 * mm_start, (mm_lm, mm_start)


def _fd_reference(spline, times, poses):
    """Gauss-Newton decrement ``g^T (J^T J)^-1 g`` of the fitted poses' cost at the
    spline's control points, ``J`` by central differences in the body-frame charts
    ``c_k exp(delta_k)`` and residuals (rotation vectors of ``R_m^T R``, translation
    differences) by scipy and numpy; and the cost's two parts."""
    ctrl = spline.control_points.detach().double()
    n = ctrl.shape[0]
    tq, tp = dualquat.to_rt(poses)
    target = Rotation.from_quat(tq.numpy()[:, [1, 2, 3, 0]])

    def residual(delta):
        moved = dualquat.mul(ctrl, dualquat.exp(torch.tensor(delta).reshape(n, 6)))
        with torch.no_grad():
            q, p = dualquat.to_rt(spline(times, ctrl=moved).double())
        rot = (target.inv() * Rotation.from_quat(q.numpy()[:, [1, 2, 3, 0]])).as_rotvec()
        return np.concatenate((rot, p.numpy() - tp.numpy()), 1).reshape(-1)

    r0 = residual(np.zeros(6 * n))
    eps = 1e-6
    J = np.stack([(residual(e) - residual(-e)) / (2 * eps) for e in eps * np.eye(6 * n)], 1)
    g = J.T @ r0
    dec = g @ np.linalg.solve(J.T @ J, g)
    r = r0.reshape(-1, 6)
    return dec, (r[:, :3] ** 2).sum(), (r[:, 3:] ** 2).sum()


@pytest.mark.parametrize("rate", [0.5, 3.0])
def test_predicted_gain_matches_finite_difference_gauss_newton(rate):
    """On 120 poses and 14 control points, the predicted decrease (each part's gain times
    its cost, summed) is the finite-difference Gauss-Newton decrement to within 2 % for a
    slow motion and 25 % for one turning ~0.6 rad per knot span, and each part's cost is
    scipy's."""
    t = np.linspace(0.0, 3.0, 120)
    rot, p = _motion(t, rate)
    rng = np.random.default_rng(1)
    rot = rot * Rotation.from_rotvec(5e-3 * rng.standard_normal((len(t), 3)))
    p = p + 2e-3 * rng.standard_normal(p.shape)
    q = torch.tensor(rot.as_quat()[:, [3, 0, 1, 2]])
    times = torch.tensor(t)
    spline = dqnn.BSpline.from_poses(q, torch.tensor(p), times, n_ctrl=14, degree=3)
    poses = dualquat.from_rt(q, torch.tensor(p))
    g_rot, g_trans = predicted_gain(spline, times, poses)
    dec, c_rot, c_trans = _fd_reference(spline, times, poses)
    assert g_rot >= 0 and g_trans >= 0 and math.isfinite(g_rot + g_trans)
    predicted = g_rot * c_rot + g_trans * c_trans
    assert abs(predicted - dec) <= (0.02 if rate < 1 else 0.25) * dec, (predicted, dec)


def test_refine_argument_is_checked(tmp_path):
    path = tmp_path / "slow.txt"
    _tum_file(path, 50.0, 2.0, 0.3, 2e-3, 1e-3)
    with pytest.raises(ValueError, match="refine must be 'auto' or 'always'"):
        fit_file.run_fit(path, out=str(tmp_path / "o"), refine="never", plots=False,
                         verbose=False)


def test_command_line_refine_option(tmp_path):
    """``--refine always`` reaches run_fit: the slow motion, whose start the default keeps,
    is refined; ``--refine never`` is refused by the parser (exit status 2)."""
    from torch_dq.cli._main import main

    path = tmp_path / "slow.txt"
    _tum_file(path, 100.0, 10.0, 0.3, 2e-3, 1e-3)
    for mode, refined in (("auto", False), ("always", True)):
        out = tmp_path / mode
        assert main(["fit", str(path), "--out", str(out), "--no-plots", "--quiet",
                     "--refine", mode]) == 0
        assert json.loads((out / "summary.json").read_text())["fit"]["refined"] is refined
    with pytest.raises(SystemExit) as info:
        main(["fit", str(path), "--out", str(tmp_path / "x"), "--refine", "never"])
    assert info.value.code == 2

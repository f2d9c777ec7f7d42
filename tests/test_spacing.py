"""The knot spacing chosen from the data (issue 20): torch_dq.fitting._knots."""

import math

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq.fitting import _knots as _spacing
from torch_dq.fitting._knots import choose_knot_spacing, knot_spacing_search

Rotation = pytest.importorskip("scipy.spatial.transform").Rotation


def _motion(freq: float, n: int = 301, duration: float = 10.0, noise: float = 0.0, seed=0):
    """Poses of a smooth motion with content at ``freq`` Hz (numpy/scipy, then dq)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, n)
    w = 2 * np.pi * freq
    rotvec = np.stack((0.4 * np.sin(w * t), 0.3 * np.cos(0.7 * w * t), 0.1 * t), -1)
    p = np.stack((np.sin(w * t), 0.5 * np.cos(w * t), 0.2 * t), -1)
    rotvec = rotvec + noise * rng.normal(size=rotvec.shape)
    p = p + noise * rng.normal(size=p.shape)
    q = np.roll(Rotation.from_rotvec(rotvec).as_quat(), 1, axis=-1)
    x = dq.from_rt(torch.from_numpy(q), torch.from_numpy(p))
    return torch.from_numpy(t), x


def test_faster_motion_gets_finer_knots():
    spacings = [choose_knot_spacing(*_motion(f, noise=0.01)) for f in (0.05, 0.2, 0.8)]
    assert spacings[0] > spacings[1] > spacings[2], spacings


def test_never_more_control_points_than_poses():
    for n in (12, 40, 301):
        t, x = _motion(1.5, n=n)  # fast: the data limit the spacing
        h = choose_knot_spacing(t, x)
        assert _spacing.n_ctrl(float(t[-1] - t[0]), h, 3) <= n
        assert h == float(f"{h:.4g}")  # printed with 4 digits, it is the same number


def test_noise_gives_coarser_knots_than_none():
    t, clean = _motion(0.2)
    _, noisy = _motion(0.2, noise=0.02)
    assert choose_knot_spacing(t, noisy) > choose_knot_spacing(t, clean)


def test_search_reports_what_it_tried():
    t, x = _motion(0.2, noise=0.005)
    s = knot_spacing_search(t, x)
    assert list(s.candidates) == sorted(s.candidates) and len(s.candidates) >= 3
    ratios = np.diff(np.log(s.candidates)) / math.log(_spacing.GRID_RATIO)
    # points of the geometric grid (4-digit values), coarse to fine: one or two steps apart
    np.testing.assert_allclose(ratios, np.round(ratios), atol=0.01)
    assert set(np.round(ratios).tolist()) <= {1.0, 2.0}
    i = s.chosen
    # the chosen candidate is within 2 % of the best of both errors, no larger one is
    assert s.rot_mean[i] <= 1.02 * min(s.rot_mean) + 1e-15
    assert s.trans_mean[i] <= 1.02 * min(s.trans_mean) + 1e-15
    for j in range(i + 1, len(s.candidates)):
        assert (s.rot_mean[j] > 1.02 * min(s.rot_mean)
                or s.trans_mean[j] > 1.02 * min(s.trans_mean))
    assert (s.n_fit, s.n_check, s.n) == (241, 60, 301)  # every 5th pose (from index 2) checks
    assert s.scale == pytest.approx(240 / 300)
    assert s.reason().startswith(f"tried {len(s.candidates)} spacings from "
                                 f"{s.candidates[0]:.4g} s to {s.candidates[-1]:.4g} s")
    assert s.reason().endswith(f"{s.spacing:.4g} s")  # ends with the spacing chosen


def test_noise_limited_spacing_is_not_halved():
    """Where noise limits the spacing (slow motion, noisy poses), the candidate chosen on
    80 % of the poses is scaled only by that density ratio, not halved."""
    t, x = _motion(0.1, n=401, noise=0.01)
    s = knot_spacing_search(t, x)
    assert not s.data_limited and s.chosen > _spacing.DATA_LIMIT_STEPS
    assert s.spacing == _spacing.round_up(s.candidates[s.chosen] * s.scale)
    assert 0.78 < s.spacing / s.candidates[s.chosen] < 0.82
    assert "within 2 % of the lowest" in s.reason() and "density ratio 0.8" in s.reason()


def test_data_limited_spacing_is_the_finest():
    """Where the errors still fall at the finest spacing the inner fit allows (fast motion,
    clean poses), the spacing is the finest all the poses determine."""
    t, x = _motion(1.5, n=101, noise=1e-4)
    s = knot_spacing_search(t, x)
    assert s.data_limited and s.chosen <= _spacing.DATA_LIMIT_STEPS
    assert s.spacing == _spacing.finest_spacing(10.0, 101, 3)
    assert "the data, not their noise, limit the spacing" in s.reason()


def test_inner_split_every_fifth():
    fit, check = _spacing.inner_split(13)
    assert check.tolist() == [2, 7]  # never the first or the last
    assert fit.tolist() == [0, 1, 3, 4, 5, 6, 8, 9, 10, 11, 12]
    fit, check = _spacing.inner_split(8)
    assert check.tolist() == [2] and fit[-1] == 7


def test_inner_check_errors_against_numpy():
    """The scores are the mean rotation angle and translation error of the start fitted to
    every other pose, at the others (recomputed here with scipy and numpy)."""
    from torch_dq import nn

    t, x = _motion(0.3, n=81, noise=0.003)
    s = knot_spacing_search(t, x)
    h = s.candidates[0]
    check = np.arange(2, 80, 5)
    fit = np.setdiff1d(np.arange(81), check)
    q, p = dq.to_rt(x)
    spline = nn.BSpline.from_poses(q[fit], p[fit], t[fit],
                                   n_ctrl=math.ceil(10.0 / h - 1e-9) + 3)
    assert s.n_fit == len(fit) and s.n_check == len(check)
    with torch.no_grad():
        qs, ps = dq.to_rt(spline(t[check]))
    r = Rotation.from_quat(qs.numpy()[:, [1, 2, 3, 0]])
    r_true = Rotation.from_quat(q[check].numpy()[:, [1, 2, 3, 0]])
    assert s.rot_mean[0] == pytest.approx((r.inv() * r_true).magnitude().mean(), rel=1e-9)
    assert s.trans_mean[0] == pytest.approx(
        np.linalg.norm(ps.numpy() - p[check].numpy(), axis=1).mean(), rel=1e-9)


@pytest.mark.parametrize("value", [0.20718, 1.0, 3.3333e-5, 123456.7, 0.1])
def test_rounding_for_hints(value):
    up, down = _spacing.round_up(value), _spacing.round_down(value)
    assert down <= value <= up
    assert float(f"{up:g}") == up and float(f"{down:g}") == down  # printed as is
    assert up - value < 1e-3 * value and value - down < 1e-3 * value


@pytest.mark.parametrize("kwargs,error,match", [
    ({"degree": 0}, ValueError, "degree must be an int >= 1"),
    ({"tolerance": 1.5}, ValueError, r"tolerance must be a number in \[0, 1\)"),
    ({"form": "bezier"}, ValueError, "form must be 'de_boor', 'cumulative' or 'split'"),
])
def test_argument_errors(kwargs, error, match):
    t, x = _motion(0.2, n=41)
    with pytest.raises(error, match=match):
        choose_knot_spacing(t, x, **kwargs)


def test_bad_data_errors():
    t, x = _motion(0.2, n=41)
    with pytest.raises(ValueError, match="strictly increasing"):
        choose_knot_spacing(t.flip(0), x)
    bad = x.clone()
    bad[3, 0] = float("nan")
    with pytest.raises(ValueError, match="poses must be finite"):
        choose_knot_spacing(t, bad)
    with pytest.raises(ValueError, match=r"times \(N,\) and poses \(N, 8\)"):
        choose_knot_spacing(t[:-1], x)
    with pytest.raises(ValueError, match="needs at least 10 poses"):
        choose_knot_spacing(t[:9], x[:9])
    with pytest.raises(TypeError):
        choose_knot_spacing(t, x.long())
    before = x.clone()
    choose_knot_spacing(t, x)
    assert torch.equal(x, before)  # input untouched

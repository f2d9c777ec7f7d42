"""fitting.estimate on a batch of two rigs of unequal lengths, padded and masked, against
each rig solved alone.

Each rig: camera poses at 20 Hz on a mount 0.9 rad and 10 cm from the body (estimated from
the identity), a gyroscope and an accelerometer at 100 Hz with their own biases (from zero)
and one clock 20 ms late (one ``Free`` shared by both, from 0), gravity's magnitude only;
the truth is ``_rig11_rig``'s closed form, the second rig 1 s later into the motion and 0.6
s shorter. The padding holds what a user's arrays might: times outside the domain, NaN
readings, a zero pose. Each problem must come out as its solo solve (the same optimum,
standard deviations, chi2 and degrees of freedom): the padding changes nothing.
"""

import numpy as np
import pytest
import torch
from _rig11_rig import accel, gyro, position, rotation
from scipy.spatial.transform import Rotation

import torch_dq.dualquat as dq
from torch_dq.fitting import Accel, Free, Gyro, Poses, estimate
from torch_dq.nn import BSpline

SP, SG, SA = 2e-3, 2e-3, 2e-2
ROT_E, T_E = Rotation.from_rotvec([0.5, -0.7, 0.3]), np.array([0.05, 0.08, -0.04])
RIGS = ((0, 3.0, 0.0), (1, 2.4, 1.0))  # seed, duration, where in the motion it starts
N_CTRL = 24


def _t(a):
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))


def _data(seed, duration, shift):
    rng = np.random.default_rng(seed)
    n = lambda k: rng.standard_normal((len(k), 3))  # noqa: E731
    tc = np.arange(0.0, duration + 1e-9, 1 / 20)
    R = rotation(tc + shift)
    Rc = R * ROT_E * Rotation.from_rotvec(SP * n(tc))
    pc = position(tc + shift) + R.apply(T_E) + SP * n(tc)
    ti = np.arange(0.15, duration - 0.15, 1 / 100)
    bg, ba = rng.normal(0, 0.03, 3), rng.normal(0, 0.2, 3)
    g = gyro(ti + shift + 0.02) + bg + SG * n(ti)
    a = accel(ti + shift + 0.02) + ba + SA * n(ti)
    return tc, Rc.as_quat(scalar_first=True), pc, ti, g, a


def _terms(tc, cam, ti, g, a, mask_c=None, mask_i=None):
    clock = Free(start=0.0)
    return [Poses(tc, cam, rot_sigma=SP, trans_sigma=SP, extrinsic=True, mask=mask_c),
            Gyro(ti, g, sigma=SG, bias=True, time_offset=clock, mask=mask_i),
            Accel(ti, a, sigma=SA, bias=True, gravity=9.81, time_offset=clock, mask=mask_i)]


def _start(tc, q, pc):
    return BSpline.from_poses(_t(q), _t(pc), _t(tc), form="cumulative", degree=4,
                              margin=0.1, n_ctrl=N_CTRL)


def _pad(rows, fill):
    n = max(len(r) for r in rows)
    out = np.stack([np.concatenate([r, np.full((n - len(r), *r.shape[1:]), fill)])
                    for r in rows])
    mask = np.stack([np.arange(n) < len(r) for r in rows])
    return _t(out), torch.from_numpy(mask)


@pytest.fixture(scope="module")
def solved():
    data = [_data(*r) for r in RIGS]
    solo = []
    for tc, q, pc, ti, g, a in data:
        spline = _start(tc, q, pc)
        terms = _terms(_t(tc), dq.from_rt(_t(q), _t(pc)), _t(ti), _t(g), _t(a))
        solo.append((spline, terms, estimate(spline, terms, verbose=False)))
    starts = [_start(d[0], d[1], d[2]) for d in data]
    spline = BSpline(torch.stack([s.control_points.detach() for s in starts]), degree=4,
                     knots=torch.stack([s.knots for s in starts]), form="cumulative")
    tc, mask_c = _pad([d[0] for d in data], 99.0)  # beyond the domain: masked
    q = _pad([d[1] for d in data], 0.0)[0]  # a zero quaternion: masked
    pc = _pad([d[2] for d in data], 0.0)[0]
    ti, mask_i = _pad([d[3] for d in data], -5.0)
    g, a = _pad([d[4] for d in data], np.nan)[0], _pad([d[5] for d in data], 0.0)[0]
    terms = _terms(tc, dq.from_rt(q, pc), ti, g, a, mask_c, mask_i)
    return solo, (spline, terms, estimate(spline, terms, verbose=False))


@pytest.mark.parametrize("b", [0, 1])
def test_each_problem_is_its_solo_solve(solved, b):
    solo, (spline, terms, est) = solved
    s_spline, s_terms, s_est = solo[b]
    assert bool(s_est.converged) and bool(est.converged[b]), (s_est.reason, est.reason)
    for name, k in (("extrinsic", 0), ("bias", 1), ("bias", 2), ("time_offset", 1),
                    ("gravity", 2)):
        std = s_est.std(s_terms[k], name)
        np.testing.assert_allclose(est.std(terms[k], name)[b], std, rtol=1e-6)
        value, mine = getattr(s_terms[k], name), getattr(terms[k], name)[b]
        if name == "extrinsic":
            diff = dq.log(dq.mul(dq.conj(value), mine))
        else:
            diff = mine - value
        assert float((diff.abs() / std).max()) < 1e-3, (name, diff)
    for k in range(3):
        assert float(est.dof[terms[k]][b]) == pytest.approx(float(s_est.dof[s_terms[k]]))
        assert float(est.chi2[terms[k]][b]) == pytest.approx(float(s_est.chi2[s_terms[k]]),
                                                             rel=1e-6)
    t = _t(np.linspace(0.2, 2.2, 4))  # inside both domains
    rows = torch.stack([t, t])
    np.testing.assert_allclose(est.pose_std(rows)[b], s_est.pose_std(t), rtol=1e-6)
    np.testing.assert_allclose(spline(rows)[b].detach(), s_spline(t).detach(), atol=1e-8)

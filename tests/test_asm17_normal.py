"""The compiled assembly of the normal equations (``_Normal.add_samples``, ``csrc/normal.c``)
against an independent dense numpy sum :math:`\\sum_s w_s J_s^T J_s`, :math:`\\sum_s w_s J_s^T
r_s` and against the PyTorch path (``_window_normal`` then ``_Normal.add``), over random
rows: batches, widths, row counts (the kernel's groups of three rows and their rests),
selected and missing nuisance columns, unsorted and shared windows, strided rows; then whole
Gauss-Newton systems with the compiled path on and off."""

import numpy as np
import pytest
import torch
from test_shared_spans import FIELDS, _job

from torch_dq._kernels import native
from torch_dq.fitting._normal import _Normal, _window_normal

F64 = torch.float64
pytestmark = pytest.mark.skipif(native.library() is None,
                                reason="the compiled kernels are not built (or TORCH_DQ_NATIVE=0)")

# (batch rows, control points n, width w, rows k, problem's nuisance m, term's columns Mt,
#  a window's columns M, samples, sorted by window)
CASES = [(1, 12, 4, 3, 6, 3, 3, 200, True),    # an IMU term: a bias, every window all of it
         (2, 9, 4, 6, 0, 0, 0, 50, False),     # poses: no nuisance, two batch rows
         (1, 15, 5, 1, 10, 7, 4, 300, False),  # one row; windows select (and miss) columns
         (3, 8, 3, 2, 4, 4, 2, 100, False),
         (1, 10, 4, 4, 5, 5, 5, 120, True),    # three rows and one
         (2, 11, 6, 7, 3, 2, 2, 90, False)]


def _case(seed, Bf, n, w, k, m, Mt, M, S, ordered):
    """Random rows of ``S`` samples per batch row (float64 numpy), their windows (shared,
    unsorted unless ``ordered``) and each window's nuisance columns."""
    g = np.random.default_rng(seed)
    f = g.integers(0, n - w + 1, (Bf, S))
    if ordered:
        f = np.sort(f, -1)
    keys = (f + np.arange(Bf)[:, None] * (n + w)).reshape(-1)
    lo, hi = int(keys.min()), int(keys.max())
    cols = g.permutation(m)[:Mt]  # the term's columns in the problem's
    local = np.stack([g.permutation(Mt)[:M] for _ in range(hi - lo + 1)]).reshape(
        hi - lo + 1, M)
    valid = g.random(local.shape) < (1.0 if M == Mt else 0.8)
    return dict(keys=keys, lo=lo, Jc=g.standard_normal((Bf * S, k, w, 6)),
                Jn=g.standard_normal((Bf * S, k, Mt)), r=g.standard_normal((Bf * S, k)),
                wt=g.random(Bf * S) * (g.random(Bf * S) > 0.1),  # some weights zero
                local=local, gcols=cols[local].reshape(local.shape), valid=valid)


def _dense(c, Bf, n, w, m):
    """Per batch row the dense normal matrix of the ``n`` control points' steps and the
    ``m`` nuisance columns, and its gradient, by numpy sums over the samples."""
    D = 6 * n + m
    H, g = np.zeros((Bf, D, D)), np.zeros((Bf, D))
    for s, key in enumerate(c["keys"]):
        b, f = divmod(int(key), n + w)
        u = int(key) - c["lo"]
        J = np.zeros((c["r"].shape[1], D))
        J[:, 6 * f:6 * (f + w)] = c["Jc"][s].reshape(-1, 6 * w)
        for j, (loc, col) in enumerate(zip(c["local"][u], c["gcols"][u], strict=True)):
            if c["valid"][u, j]:
                J[:, 6 * n + col] += c["Jn"][s][:, loc]
        H[b] += c["wt"][s] * J.T @ J
        g[b] += c["wt"][s] * J.T @ c["r"][s]
    return H, g


def _compiled(c, Bf, n, w, m, terms=1, term=-1, strided=False):
    acc = _Normal(torch.zeros((), dtype=F64), Bf, n, w, m, terms)
    t = {x: torch.from_numpy(c[x]) for x in ("keys", "Jc", "Jn", "r", "wt", "local", "gcols")}
    Jc, Jn, r = t["Jc"], t["Jn"], t["r"]
    if strided:  # component-major rows, as the span products give them; a slice, a transpose
        Jc = Jc.permute(1, 2, 3, 0).contiguous().permute(3, 0, 1, 2)
        Jn = torch.cat((Jn, Jn), -1)[..., :Jn.shape[-1]]
        r = r.T.contiguous().T
    assert native.enabled(Jc, Jn, r, t["wt"])
    acc.add_samples(t["keys"] - c["lo"], c["lo"], Jc, Jn, r, t["wt"], t["local"],
                    t["gcols"].masked_fill(~torch.from_numpy(c["valid"]), -1), term)
    return acc


def _torch(c, Bf, n, w, m, terms=1, term=-1):
    """The PyTorch path: the whitened rows, ``_window_normal``, ``_Normal.add``."""
    acc = _Normal(torch.zeros((), dtype=F64), Bf, n, w, m, terms)
    rel = torch.from_numpy(c["keys"] - c["lo"])
    local, valid = torch.from_numpy(c["local"])[rel], torch.from_numpy(c["valid"])[rel]
    Jn = torch.from_numpy(c["Jn"]).gather(-1, local[:, None, :].expand(
        -1, c["r"].shape[1], -1)) * valid[:, None, :]
    Y = torch.cat((torch.from_numpy(c["Jc"]).flatten(-2), Jn, torch.from_numpy(c["r"])[..., None]),
                  -1) * torch.from_numpy(c["wt"]).sqrt()[:, None, None]
    win, block = _window_normal(rel, Y)
    acc.add(win + c["lo"], block, torch.from_numpy(c["gcols"])[win], term)
    return acc


def _parts(acc):
    band, cn, nn = acc.blocks()
    return dict(band=band, cn=cn, nn=nn, gc=acc.gc.reshape(acc.Bf, -1, 6)[:, :acc.n],
                gn=acc.gn.reshape(acc.Bf, acc.m))


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("strided", [False, True])
def test_compiled_sums_equal_a_dense_numpy_sum(case, strided):
    Bf, n, w, _, m, *_ = case
    c = _case(1, *case)
    got = _parts(_compiled(c, Bf, n, w, m, strided=strided))
    H, g = _dense(c, Bf, n, w, m)
    scale = np.abs(H).max()
    for b in range(Bf):
        for i in range(n):
            rows = slice(6 * i, 6 * i + 6)
            for d in range(w):
                ref = (H[b, rows, 6 * (i + d):6 * (i + d + 1)] if i + d < n
                       else np.zeros((6, 6)))
                np.testing.assert_allclose(got["band"][b, i, d], ref, rtol=0, atol=1e-12 * scale)
            np.testing.assert_allclose(got["cn"][b, i], H[b, rows, 6 * n:], rtol=0,
                                       atol=1e-12 * scale)
        np.testing.assert_allclose(got["nn"][b], H[b, 6 * n:, 6 * n:], rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(got["gc"][b].reshape(-1), g[b, :6 * n], rtol=0,
                                   atol=1e-12 * np.abs(g).max())
        np.testing.assert_allclose(got["gn"][b], g[b, 6 * n:], rtol=0, atol=1e-12 * np.abs(g).max())


@pytest.mark.parametrize("case", CASES)
def test_compiled_equals_the_torch_path_and_fills_a_terms_own_blocks(case):
    """A term with its own blocks (``System.own``): both accumulators get the same sums;
    the compiled ones equal the PyTorch path's to 1e-12 relative (the order of the sums
    differs)."""
    Bf, n, w, _, m, *_ = case
    c = _case(2, *case)
    got, ref = _compiled(c, Bf, n, w, m, 3, 1), _torch(c, Bf, n, w, m, 3, 1)
    for acc_got, acc_ref in ((got, ref), (got.own[1], ref.own[1])):
        a, b = _parts(acc_got), _parts(acc_ref)
        for name in FIELDS:
            assert a[name].shape == b[name].shape, name
            if b[name].numel():
                scale = float(b[name].abs().max())
                assert float((a[name] - b[name]).abs().max()) <= 1e-12 * scale, name
    assert not got.own[0].band.any() and not got.own[0].gc.any()


def test_compiled_adds_to_what_is_there():
    """Two calls sum (a part after the other), and no samples add nothing."""
    case = CASES[0]
    Bf, n, w, _, m, *_ = case
    c = _case(3, *case)
    acc = _compiled(c, Bf, n, w, m)
    once = {k: v.clone() for k, v in _parts(acc).items()}
    z = torch.zeros(0, dtype=torch.int64)
    acc.add_samples(z, 0, torch.zeros(0, 3, w, 6, dtype=F64), torch.zeros(0, 3, 3, dtype=F64),
                    torch.zeros(0, 3, dtype=F64), torch.zeros(0, dtype=F64),
                    torch.zeros(1, 3, dtype=torch.int64), torch.zeros(1, 3, dtype=torch.int64))
    assert all(torch.equal(once[k], v) for k, v in _parts(acc).items())
    t = {x: torch.from_numpy(c[x]) for x in ("keys", "Jc", "Jn", "r", "wt", "local", "gcols")}
    acc.add_samples(t["keys"] - c["lo"], c["lo"], t["Jc"], t["Jn"], t["r"], t["wt"], t["local"],
                    t["gcols"])
    for k, v in _parts(acc).items():
        torch.testing.assert_close(v, 2 * once[k], rtol=1e-13, atol=1e-13)


def test_compiled_rejects_mismatched_rows():
    acc = _Normal(torch.zeros((), dtype=F64), 1, 8, 4, 0)
    with pytest.raises(ValueError, match="add_samples"):
        acc.add_samples(torch.zeros(5, dtype=torch.int64), 0, torch.zeros(5, 3, 3, 6, dtype=F64),
                        torch.zeros(5, 3, 0, dtype=F64), torch.zeros(5, 3, dtype=F64),
                        torch.ones(5, dtype=F64), torch.zeros(1, 0, dtype=torch.int64),
                        torch.zeros(1, 0, dtype=torch.int64))


def test_not_compiled_where_a_gradient_is_needed_or_not_float64():
    x = torch.zeros(3, dtype=F64)
    assert native.enabled(x, torch.zeros(2, dtype=torch.int64))
    assert not native.enabled(x.requires_grad_())
    with torch.no_grad():
        assert native.enabled(x)
    assert not native.enabled(torch.zeros(3, dtype=torch.float32))


@pytest.mark.parametrize("robust", [True, False])
def test_systems_with_and_without_the_compiled_path(monkeypatch, robust):
    """The 3 s poses + IMU job's Gauss-Newton system (its terms' own blocks too) with the
    compiled assembly equals the PyTorch path's to 1e-12 relative."""
    problem, ctrl, values = _job()
    w = problem.width(values)
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    ref = problem.system(ctrl, values, w, robust=robust)
    monkeypatch.setenv("TORCH_DQ_NATIVE", "1")
    got = problem.system(ctrl, values, w, robust=robust)
    pairs = [(getattr(got, f), getattr(ref, f)) for f in FIELDS]
    pairs += [(a, b) for o1, o0 in zip(got.own, ref.own, strict=True)
              for a, b in zip(o1, o0, strict=True)]
    assert len(got.own) == (len(problem.terms) - 1 if robust else 0)
    for a, b in pairs:
        assert float((a - b).abs().max()) <= 1e-12 * float(b.abs().max())

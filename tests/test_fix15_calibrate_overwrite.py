"""``python -m torch_dq calibrate`` refuses an ``--out`` holding an earlier run's results
unless ``--overwrite``, as ``fit`` does (it replaced ``camchain.yaml`` / ``summary.json`` of an
earlier, possibly long, run without a word: user15 finding 3). The corners are a pinhole
camera's view of an AprilGrid, projected in numpy here."""

import json

import numpy as np
import pytest

from torch_dq.cli import main

pytest.importorskip("yaml")


def _rot(rv):
    th = np.linalg.norm(rv)
    k = np.asarray(rv) / th
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * kx + (1 - np.cos(th)) * kx @ kx


def _inputs(tmp_path):
    s, pitch = 0.088, 0.088 * 1.3
    P = np.array([(c * pitch + a * s, r * pitch + b * s, 0.0) for r in range(6)
                  for c in range(6) for a, b in ((0, 0), (1, 0), (1, 1), (0, 1))])
    rng, rows = np.random.default_rng(5), []
    for f in range(8):
        R = _rot(rng.uniform(-0.4, 0.4, 3) + np.array([np.pi, 0.0, 0.0]))
        X = (P - P.mean(0)) @ R.T + [rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 1.2]
        uv = X[:, :2] / X[:, 2:] * 460.0 + [376.0, 240.0]
        rows += [f"{1_403_709_385_000_000_000 + f * 50_000_000},{u:.17g},{v:.17g},"
                 f"{p[0]:.17g},{p[1]:.17g},0" for (u, v), p in zip(uv, P, strict=True)]
    (tmp_path / "cam0.csv").write_text("# t_ns,u_px,v_px,X_m,Y_m,Z_m\n" + "\n".join(rows) + "\n")
    (tmp_path / "target.yaml").write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\n"
                                          "tagSize: 0.088\ntagSpacing: 0.3\n")
    (tmp_path / "camchain.yaml").write_text("cam0:\n  camera_model: pinhole\n  distortion_model:"
                                            " none\n  resolution: [752, 480]\n")
    return ["calibrate", "--target", str(tmp_path / "target.yaml"), "--cameras",
            str(tmp_path / "camchain.yaml"), "--corners", str(tmp_path / "cam0.csv"),
            "--out", str(tmp_path / "out"), "--quiet", "--no-plots"]


def test_earlier_results_need_overwrite(tmp_path, capsys):
    argv = _inputs(tmp_path)
    assert main(argv) == 0
    summary = tmp_path / "out" / "summary.json"
    assert "cam0" in (tmp_path / "out" / "camchain.yaml").read_text()
    summary.write_text('{"earlier": true}')  # a mark: refused runs leave it
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "already holds results of an earlier run (camchain.yaml, " \
        "summary.json)" in err and "pass --overwrite" in err, err
    assert summary.read_text() == '{"earlier": true}'
    assert main([*argv, "--overwrite"]) == 0
    assert "earlier" not in json.loads(summary.read_text())  # replaced


def test_help_names_overwrite(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    out = capsys.readouterr().out
    assert "--overwrite" in out and "refused without --overwrite" in " ".join(out.split())

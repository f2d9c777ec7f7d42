"""README's statements that a new user checks against the repository (user15): the
notebooks it counts and lists are the ones in ``notebooks/``."""

import re
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
WORDS = {"seven": 7, "eight": 8, "nine": 9, "ten": 10, "eleven": 11, "twelve": 12}


def _section(title: str) -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    return text.split(f"\n## {title}\n", 1)[1].split("\n## ", 1)[0]


def test_the_notebooks_section_counts_and_lists_every_notebook():
    files = sorted(p.name for p in (ROOT / "notebooks").glob("*.ipynb"))
    section = " ".join(_section("Notebooks").split())
    count = re.search(r"holds (\w+) short notebooks", section).group(1)
    assert WORDS.get(count, count) == len(files), (count, files)
    for name in files:
        assert f"({name[:2]})" in section, name


def _paragraph(text: str, start: str) -> str:
    return " ".join(text.split(start, 1)[1].split("\n\n", 1)[0].split())


def test_trajectory_poses_is_documented_as_a_method():
    from torch_dq import io

    doc = " ".join(io.Trajectory.__doc__.split())
    assert "times" in doc and "rotations" in doc and "translations" in doc
    assert "traj.poses()" in doc and "method" in doc, doc
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    para = _paragraph(readme, "`torch_dq.io.read_trajectory` reads TUM")
    assert "io.Trajectory" in para and "traj.poses()" in para and "method" in para, para
    # what the docs say: attributes are tensors, poses() computes the (N, 8) dual quaternions
    t = torch.tensor([0.0, 1.0], dtype=torch.float64)
    traj = io.Trajectory(t, torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64),
                         torch.tensor([[1.0, 2.0, 3.0]] * 2, dtype=torch.float64))
    assert callable(traj.poses) and traj.poses().shape == (2, 8)
    # dual part 0.5 (0, p) r with r the identity: (0, 0.5, 1, 1.5)
    assert traj.poses()[0, 4:].tolist() == [0.0, 0.5, 1.0, 1.5]


def test_nanosecond_files_read_by_the_api_and_the_cli_as_documented(tmp_path):
    """``io.read_trajectory`` keeps a TUM file's nanoseconds (with a warning naming the
    division), ``fit`` converts them to seconds (with a note); both docstrings and README
    say so."""
    from torch_dq import io
    from torch_dq.cli import fit_file, main

    ns = [1_700_000_000_000_000_000 + 50_000_000 * k for k in range(41)]
    rows = [f"{s} {0.1 * k:.6f} {0.05 * k * k:.6f} 0.0 0.0 0.0 {np.sin(0.02 * k):.9f} "
            f"{np.cos(0.02 * k):.9f}" for k, s in enumerate(ns)]
    path = tmp_path / "ns.txt"
    path.write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(rows) + "\n")
    with pytest.warns(UserWarning, match=r"divide the times by 1e\+0?9"):
        traj = io.read_trajectory(path)
    assert traj.times.tolist() == [float(s) for s in ns]  # kept as written
    out = tmp_path / "out"
    assert main(["fit", str(path), "--out", str(out), "--no-plots", "--quiet"]) == 0
    first = next(line for line in (out / "trajectory.csv").read_text().splitlines()
                 if line[:1].isdigit()).split(",")[0]
    assert float(first) == ns[0] / 1e9
    words = " ".join(io.read_trajectory.__doc__.split())
    assert "kept as written" in words and "python -m torch_dq fit`` converts" in words, words
    assert "converted to seconds here" in " ".join(fit_file.__doc__.split())
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    para = _paragraph(readme, "`torch_dq.io.read_trajectory` reads TUM")
    assert "keeps such times as written" in para and "converts them" in para, para

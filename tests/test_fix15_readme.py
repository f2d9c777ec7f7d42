"""README's statements that a new user checks against the repository (user15): the
notebooks it counts and lists are the ones in ``notebooks/``."""

import re
from pathlib import Path

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

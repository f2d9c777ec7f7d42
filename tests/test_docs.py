"""The reference documentation builds with warnings as errors, covers every public name, and
its examples run.

The build is ``sphinx-build -W --keep-going -n -b html docs <tmp>`` (Sphinx, autodoc,
napoleon, myst-nb) with ``nitpicky = True``: a malformed docstring, a cross-reference that
does not resolve (to torch_dq, or to an outside name missing from ``docs/conf.py``'s
``EXTERNAL`` table), a page missing from a toctree or a notebook that does not execute fails
it. The notebooks are executed by the build and their pages show their outputs and figures:
here with ``TORCH_DQ_NOTEBOOK_QUICK=1`` (the smaller sizes of ``tests/test_notebooks.py``) and
one thread per kernel, cached apart from the real docs' outputs (in
``docs/_build/.jupyter_cache_tests``, so a clean clone runs them once at the small sizes and
a real build never shows them). Skipped, with the reason, when the ``docs`` extra is not
installed.
"""

import doctest
import importlib
import os
import pathlib
import pkgutil
import re
import subprocess
import sys

import pytest

import torch_dq

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(p.relative_to(DOCS).with_suffix("").as_posix()
               for p in DOCS.glob("*.md"))


def _public_modules() -> list[str]:
    """Every importable torch_dq module without a private (``_``) component."""
    names = ["torch_dq"]
    for info in pkgutil.walk_packages(torch_dq.__path__, "torch_dq."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)
    return sorted(names)


def _documented_modules() -> set[str]:
    text = "\n".join(p.read_text(encoding="utf-8") for p in (DOCS / "api").glob("*.rst"))
    return set(re.findall(r"^\.\. automodule:: (\S+)", text, flags=re.M))


def test_every_public_module_has_an_api_page():
    missing = sorted(set(_public_modules()) - _documented_modules())
    assert not missing, f"add an automodule for {missing} to docs/api/ (and its toctree)"


@pytest.fixture(scope="module")
def html(tmp_path_factory) -> pathlib.Path:
    pytest.importorskip("sphinx", reason="the docs build needs the docs extra: "
                                         "pip install -e '.[docs]'")
    pytest.importorskip("myst_nb", reason="the docs build needs myst-nb (the docs extra)")
    out = tmp_path_factory.mktemp("docs")
    cache = DOCS / "_build" / ".jupyter_cache_tests"
    cmd = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-n", "-q", "-b", "html",
           "-D", f"nb_execution_cache_path={cache}",
           "-d", str(out / "doctrees"), str(DOCS), str(out / "html")]
    env = {**os.environ, "TORCH_DQ_NOTEBOOK_QUICK": "1", "OMP_NUM_THREADS": "1",
           "TORCH_DQ_FIGURES": str(out / "figures")}
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=600, env=env)
    assert res.returncode == 0, f"sphinx-build failed:\n{res.stdout}\n{res.stderr}"
    return out / "html"


def test_docs_build_writes_every_page(html):
    for page in [*PAGES, "api/index", "genindex"]:
        assert (html / f"{page}.html").is_file(), page
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        assert (html / "notebooks" / f"{nb.stem}.html").is_file(), nb.name


def test_notebook_pages_show_their_figures(html):
    """Each notebook page carries the figures the notebook draws (rendered outputs)."""
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        page = (html / "notebooks" / f"{nb.stem}.html").read_text(encoding="utf-8")
        assert re.search(r'<img[^>]+src="[^"]+\.png"', page), f"{nb.name}: no figure rendered"


def test_architecture_page_says_which_path_runs_where(html):
    page = (html / "architecture.html").read_text(encoding="utf-8")
    for text in ("plain-op path", "torch.func", "check=False", "KnotDomain"):
        assert text in page, text
    for target in ("torch_dq.dualquat._eq11", "torch_dq.curves._de_boor",
                   "torch_dq._time.KnotDomain"):
        assert f'id="{target}"' in page, target


# Files the docs, the docstrings and the changelog may cite by name.
_CITED = re.compile(r"\b([A-Za-z_][\w/]*\.(?:md|rst|ipynb|toml|cfg))\b")


def test_no_reference_to_missing_files():
    """Every ``name.md`` (``.rst``, ``.ipynb``, ...) cited in the docs, the library's
    docstrings and the changelog exists in the repository (e.g. the contract is
    ``docs/api_contract.md``, not an ``API.md`` the repository does not have)."""
    sources = [*DOCS.glob("*.md"), *(DOCS / "api").glob("*.rst"), ROOT / "CHANGELOG.md",
               *(ROOT / "torch_dq").rglob("*.py")]
    names = {p.name for p in ROOT.rglob("*") if ".git" not in p.parts}
    missing = sorted({f"{src.relative_to(ROOT)}: {m}" for src in sources
                      for m in _CITED.findall(src.read_text(encoding="utf-8"))
                      if m.rsplit("/", 1)[-1] not in names})
    assert not missing, missing


@pytest.mark.parametrize("module", [m for m in _public_modules() if m != "torch_dq"])
def test_every_public_name_is_documented(html, module):
    """Each name of the module's ``__all__`` has an entry (an anchor) in the reference."""
    mod = importlib.import_module(module)
    names = getattr(mod, "__all__", [])
    if module == "torch_dq.demo":  # re-exports from torch_dq.demo.runner, documented there
        mod, module = importlib.import_module("torch_dq.demo.runner"), "torch_dq.demo.runner"
    text = "\n".join(p.read_text(encoding="utf-8") for p in (html / "api").glob("*.html"))
    missing = [n for n in names if f'id="{module}.{n}"' not in text]
    assert not missing, f"{module}: {missing} have no entry in the API reference"


def test_layers_show_torch_dq_members_not_nn_module(html):
    page = (html / "api" / "nn.html").read_text(encoding="utf-8")
    for cls in ("BSpline", "Bezier"):
        for member in ("from_poses", "forward", "control_points"):
            assert f'id="torch_dq.nn.{cls}.{member}"' in page, (cls, member)
    for inherited in ("register_forward_hook", "state_dict", "zero_grad", "parameters",
                      "training"):
        assert f".{inherited}\"" not in page, inherited


def test_paper_reference_and_equations(html):
    page = (html / "paper.html").read_text(encoding="utf-8")
    for text in ("Guillard", "Hamitouche", "Roux", "Modélisation de courbes de quaternions",
                 "LaTIM INSERM U650", "GET-ENST Bretagne"):
        assert text in page, text
    for target in ("torch_dq.dualquat.dot", "torch_dq.dualquat.angle",
                   "torch_dq.dualquat.sclerp", "torch_dq.curves.bezier",
                   "torch_dq.curves.bspline"):
        assert f'href="api/{target.rsplit(".", 2)[1]}.html#{target}"' in page, target


def _python_blocks(page: str) -> list[str]:
    text = (DOCS / f"{page}.md").read_text(encoding="utf-8")
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


EXAMPLES = [(page, i) for page in PAGES for i in range(len(_python_blocks(page)))]


def test_pages_have_examples():
    assert {page for page, _ in EXAMPLES} >= {"getting_started", "interop"}


@pytest.mark.parametrize("page, index", EXAMPLES)
def test_docs_example_runs(page, index, capsys):
    code = _python_blocks(page)[index]
    for peer in re.findall(r"^(?:import|from) (scipy|pytransform3d|pypose|roma)\b", code,
                           flags=re.M):
        pytest.importorskip(peer)
    exec(compile(code, f"docs/{page}.md block {index}", "exec"), {})
    assert capsys.readouterr().out.strip(), "each example prints its result"


@pytest.mark.parametrize("module", _public_modules())
def test_docstring_examples_run(module, tmp_path, monkeypatch):
    """Every ``Example:`` in the reference runs and prints what it shows (doctest)."""
    pytest.importorskip("scipy")  # a few examples compare with scipy
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    mod = importlib.import_module(module)
    flags = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
    result = doctest.testmod(mod, optionflags=flags, report=True, verbose=False)
    assert result.failed == 0, f"{module}: {result.failed} of {result.attempted} examples fail"

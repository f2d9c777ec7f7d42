"""Sphinx configuration of the torch_dq reference documentation.

Build (from the repository root, with ``pip install -e ".[docs]"``)::

    sphinx-build -W --keep-going -b html docs docs/_build/html

``tests/test_docs.py`` runs the same build with warnings as errors, so a broken reference,
a malformed docstring or a missing page fails the test suite.
"""

import os
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)  # document the working tree even without an editable install

import torch_dq  # noqa: E402

project = "torch_dq"
author = "the torch_dq contributors"
copyright = "torch_dq contributors, BSD-3-Clause"
release = torch_dq.__version__
version = ".".join(release.split(".")[:2])

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_nb",  # MyST markdown pages and .ipynb notebooks (includes myst_parser)
]

# Notebooks are stored without outputs and are executed by tests/test_notebooks.py; the
# docs render their text and code as stored and never start a kernel (offline, fast).
nb_execution_mode = "off"
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}
exclude_patterns = ["_build", "notebooks/figures", "notebooks/.ipynb_checkpoints"]

# Google-style docstrings (the library's style).
napoleon_google_docstring = True
napoleon_numpy_docstring = False
napoleon_use_rtype = False
# "Attributes:" sections as :ivar: fields: autodoc documents dataclass fields itself, and
# napoleon's attribute directives would describe them twice.
napoleon_use_ivar = True
# Only torch_dq's own members: never nn.Module's hundred methods (see api/nn.rst).
autodoc_default_options = {"members": True, "undoc-members": False}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
autodoc_preserve_defaults = True

html_theme = "alabaster"
html_title = f"torch_dq {release}"
html_theme_options = {"description": "Differentiable unit dual quaternions for PyTorch",
                      "fixed_sidebar": True}

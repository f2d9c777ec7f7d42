"""Sphinx configuration of the torch_dq reference documentation.

Build (from the repository root, with ``pip install -e ".[docs]"``)::

    sphinx-build -W --keep-going -b html docs docs/_build/html

``tests/test_docs.py`` runs the same build with warnings as errors and ``nitpicky`` on, so
a broken reference (to torch_dq, to Python, torch or numpy), a malformed docstring or a
missing page fails the test suite.
"""

import os
import re
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

# Notebooks are stored without outputs (tests/test_notebooks.py executes them and checks
# their figures). The docs execute them once and render their outputs and figures; the
# executed notebooks are cached in docs/_build/.jupyter_cache (keyed by the code cells),
# so later builds, the test suite's included, reuse them while the code is unchanged.
nb_execution_mode = "cache"
nb_execution_cache_path = os.path.join(ROOT, "docs", "_build", ".jupyter_cache")
nb_execution_timeout = 600
nb_execution_raise_on_error = True
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

# Every cross-reference must resolve: torch_dq's own against the reference pages, outside
# names against EXTERNAL below (the build is offline, so no intersphinx inventories).
nitpicky = True

_PY = "https://docs.python.org/3/library/"
_TORCH = "https://docs.pytorch.org/docs/stable/"
# Names outside torch_dq that signatures and docstrings use -> their documentation.
EXTERNAL = {
    "torch.Tensor": _TORCH + "tensors.html#torch.Tensor",
    "Tensor": _TORCH + "tensors.html#torch.Tensor",
    "torch.Size": _TORCH + "size.html#torch.Size",
    "torch.dtype": _TORCH + "tensor_attributes.html#torch.dtype",
    "torch.device": _TORCH + "tensor_attributes.html#torch.device",
    "torch.Generator": _TORCH + "generated/torch.Generator.html",
    "torch._C.Generator": _TORCH + "generated/torch.Generator.html",
    "torch.nn.Module": _TORCH + "generated/torch.nn.Module.html",
    "torch.nn.modules.module.Module": _TORCH + "generated/torch.nn.Module.html",
    "Module": _TORCH + "generated/torch.nn.Module.html",
    "torch.optim.Optimizer": _TORCH + "optim.html#torch.optim.Optimizer",
    "torch.optim.optimizer.Optimizer": _TORCH + "optim.html#torch.optim.Optimizer",
    "torch.nn.utils.parametrize.register_parametrization":
        _TORCH + "generated/torch.nn.utils.parametrize.register_parametrization.html",
    "numpy.ndarray": "https://numpy.org/doc/stable/reference/generated/numpy.ndarray.html",
    "numpy.dtype": "https://numpy.org/doc/stable/reference/generated/numpy.dtype.html",
    "numpy.typing.ArrayLike": "https://numpy.org/doc/stable/reference/typing.html"
                              "#numpy.typing.ArrayLike",
    "collections.abc.Sequence": _PY + "collections.abc.html#collections.abc.Sequence",
    "collections.abc.Callable": _PY + "collections.abc.html#collections.abc.Callable",
    "collections.abc.Iterable": _PY + "collections.abc.html#collections.abc.Iterable",
    "collections.abc.Mapping": _PY + "collections.abc.html#collections.abc.Mapping",
    "os.PathLike": _PY + "os.html#os.PathLike",
    "pathlib.Path": _PY + "pathlib.html#pathlib.Path",
    "typing.NamedTuple": _PY + "typing.html#typing.NamedTuple",
}


def _external(app, env, node, contnode):
    """Resolve a Python reference to a name of ``EXTERNAL``; others stay broken (an error)."""
    from docutils import nodes

    if node.get("refdomain") != "py" or node.get("reftarget") not in EXTERNAL:
        return None
    ref = nodes.reference("", "", internal=False, refuri=EXTERNAL[node["reftarget"]])
    ref.append(contnode)
    return ref


# numpy.typing.ArrayLike as autodoc expands it (a union of numpy's private protocols).
_ARRAY_LIKE = re.compile(
    r"~numpy\._typing\._array_like\._Buffer \| .*?"
    r"~numpy\._typing\._nested_sequence\._NestedSequence\[complex \| bytes \| str\]")


def _signature(app, what, name, obj, options, signature, return_annotation):
    """Signatures show ``numpy.typing.ArrayLike`` by its public name."""
    if signature and "numpy._typing" in signature:
        signature = _ARRAY_LIKE.sub("~numpy.typing.ArrayLike", signature)
    return signature, return_annotation


def setup(app):
    app.connect("missing-reference", _external)
    app.connect("autodoc-process-signature", _signature)


html_theme = "alabaster"
html_title = f"torch_dq {release}"
html_theme_options = {"description": "Differentiable unit dual quaternions for PyTorch",
                      "fixed_sidebar": True}

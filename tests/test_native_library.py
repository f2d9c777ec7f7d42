"""The optional compiled library (``torch_dq._kernels.native``): built where a C compiler is,
turned off by ``TORCH_DQ_NATIVE=0``, taken only on float64 CPU tensors. The kernels it holds
are checked against their PyTorch references in their own test files."""

import shutil
import sysconfig
from pathlib import Path

import pytest
import torch

from torch_dq._kernels import native


def test_built_where_a_compiler_is():
    """``pip install`` (setup.py's optional Extension) builds the library wherever a C
    compiler and Python's headers are; a silent fallback there would lose issue 34's speed."""
    headers = sysconfig.get_paths()["include"]
    if shutil.which(sysconfig.get_config_var("CC").split()[0]) is None:
        pytest.skip("no C compiler: the PyTorch kernels run")
    if not (Path(headers) / "Python.h").exists():
        pytest.skip("no Python headers: the PyTorch kernels run")
    assert native.library() is not None, (
        "the compiled kernels are not built: `python setup.py build_ext --inplace` or "
        "`pip install -e .`")


def test_environment_turns_it_off(monkeypatch):
    monkeypatch.setenv("TORCH_DQ_NATIVE", "0")
    assert native.library() is None
    assert not native.enabled(torch.zeros(3, dtype=torch.float64))


def test_taken_on_float64_cpu_only():
    if native.library() is None:
        pytest.skip("the compiled kernels are not built")
    index = torch.arange(3)
    assert native.enabled(torch.zeros(3, dtype=torch.float64), index)
    assert not native.enabled(torch.zeros(3, dtype=torch.float32), index)


def test_address_reads_contiguous_tensors_only():
    x = torch.zeros(4, 3, dtype=torch.float64)
    assert native.address(x).value == x.data_ptr()
    with pytest.raises(ValueError, match="contiguous"):
        native.address(x.T)

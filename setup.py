"""Build of the optional compiled kernels (everything else is in setup.cfg).

``torch_dq._kernels._native`` is a shared library of plain C loops over float64 arrays,
called through :mod:`ctypes` (``torch_dq._kernels.native``): no torch headers, so building it
never needs a torch build. It is optional: where no C compiler is found the install goes on
and the same mathematics runs in PyTorch ops.
"""

from glob import glob

from setuptools import Extension, setup

setup(ext_modules=[Extension(
    "torch_dq._kernels._native",
    sources=sorted(glob("torch_dq/_kernels/csrc/*.c")),
    extra_compile_args=["-O3", "-std=c11", "-fno-math-errno"],
    optional=True,
)])

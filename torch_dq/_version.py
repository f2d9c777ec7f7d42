"""The package's version (private): read by :mod:`torch_dq` and the command line's
``--version`` without importing the package root."""

__version__ = "0.4.3"

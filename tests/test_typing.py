"""Static typing: ``mypy`` (configured in setup.cfg, ``[mypy]``) is clean on the package.

torch_dq ships ``py.typed``, so its annotations are part of its interface: this test fails on
any mypy error in ``torch_dq/``, and checks that a user's code type-checks against the
installed package (the public signatures are seen, not ``Any``).
"""

import importlib.util
import os
import re
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

pytestmark = pytest.mark.skipif(importlib.util.find_spec("mypy") is None,
                                reason="mypy is not installed (pip install -e .[test])")


def _mypy(*args: str, cwd: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mypy", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def test_package_is_mypy_clean_and_user_code_sees_the_public_signatures(tmp_path):
    # One test, so both mypy runs share one cache outside the repository (no .mypy_cache
    # left behind) in one process whatever the xdist scheduling: the first is a full check
    # from an empty cache, the second (same options: the project's config) reuses its
    # analysis of torch instead of redoing it.
    cache = str(tmp_path / "cache")
    result = _mypy("--cache-dir", cache, "torch_dq", cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Success: no issues found" in result.stdout, result.stdout
    # From outside the repository: mypy must find the installed (editable) package and its
    # py.typed marker, so a wrong argument type is an error and the return types are known.
    user = tmp_path / "user" / "user.py"
    user.parent.mkdir()
    user.write_text(textwrap.dedent("""
        import torch
        import torch_dq
        from torch_dq.nn import BSpline

        a = torch_dq.dualquat.identity()
        reveal_type(torch_dq.dualquat.sclerp(a, a, torch.tensor([0.5])))
        reveal_type(BSpline(torch_dq.dualquat.identity((6,))).domain)
        torch_dq.dualquat.sclerp("a", a, 0.5)
    """))
    result = _mypy("--config-file", os.path.join(ROOT, "setup.cfg"), "--cache-dir", cache,
                   "--python-version", "3.10", str(user), cwd=user.parent)
    out = result.stdout
    assert 'Revealed type is "torch._tensor.Tensor"' in out, out
    # mypy < 2 prints builtins.float, mypy >= 2 float; a module with a row of knots per
    # trajectory reports its domain as two (B,) tensors
    pair = (r'Revealed type is "tuple\[(builtins\.)?float, (builtins\.)?float\] \| '
            r'tuple\[torch\._tensor\.Tensor, torch\._tensor\.Tensor\]"')
    assert re.search(pair, out), out
    assert 'Argument 1 to "sclerp" has incompatible type "str"' in out, out
    assert "Found 1 error" in out, out

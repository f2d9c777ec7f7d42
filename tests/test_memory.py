"""``torch_dq.reuse_memory``: freed temporaries stay in the heap (no page faults when the
next iteration allocates them again), only where the C library is glibc; run in child
processes (it is process-wide and irreversible)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

import torch_dq

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"

# two rounds of five 16 MiB tensors allocated together, then freed together (an iteration's
# temporaries); the minor page faults of the second round
_ROUNDS = """
import resource, sys, torch, torch_dq
applied = torch_dq.reuse_memory() if sys.argv[1] == "reuse" else None
def round_():
    xs = [torch.ones(1 << 21, dtype=torch.float64) for _ in range(5)]
    return float(sum(float(x[-1]) for x in xs))
round_()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
round_()
print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple[str, int]:
    out = subprocess.run([sys.executable, "-c", _ROUNDS, mode], capture_output=True,
                         text=True, check=True).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not GLIBC, reason="glibc's mallopt only")
def test_reuse_memory_keeps_freed_temporaries_in_the_heap():
    """Without it the second round faults in its 80 MiB again (20,480 pages of 4 KiB, the
    heap top trimmed after the first); with it, at most one of its five tensors (0 pages
    here, 4,096 in a CI run: where the heap's free blocks lie depends on the process)."""
    applied, kept = _faults("reuse")
    _, default = _faults("default")
    assert applied == "True"
    assert default > 15_000, default
    assert kept <= 0.25 * default, (kept, default)


def test_reuse_memory_is_exported_and_reports_where_it_cannot_apply(monkeypatch):
    """A top-level name; False (nothing changed) where the C library is not glibc."""
    assert "reuse_memory" in torch_dq.__all__
    monkeypatch.setattr(platform, "libc_ver", lambda: ("musl", "1.2"))
    assert torch_dq.reuse_memory() is False

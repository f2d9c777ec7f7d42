r"""The process's heap: :func:`reuse_memory`, an opt-in for large batched work on the CPU.

PyTorch's CPU tensors come from the C library's ``malloc``. glibc returns freed memory at
the top of its heap to the operating system once more than its trim threshold is free
(``2 x`` the largest block freed so far, at most 64 MiB), and serves blocks above its mmap
threshold (at most 32 MiB) by fresh mappings: an iteration that allocates and frees a few
hundred megabytes of temporaries (the Gauss-Newton systems of
:func:`~torch_dq.fitting.estimate` on a minute of 200 Hz IMU data) then faults every page of
them in again, zero-filled, at every iteration. Kept in the heap they are reused instead:
:func:`reuse_memory` fixes the mmap threshold at 32 MiB and the trim threshold at 2 GiB
(``mallopt``, as the environment variables ``MALLOC_MMAP_THRESHOLD_=33554432
MALLOC_TRIM_THRESHOLD_=2147483647`` do at start-up; PyTorch's CPU performance guide
recommends jemalloc or tcmalloc for the same reason). It is process-wide and irreversible:
the resident memory stays at its peak instead of shrinking after the work, so the library
never calls it by itself; the ``python -m torch_dq`` commands do.
"""

from __future__ import annotations

import ctypes
import platform
import sys

__all__ = ["reuse_memory"]

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's malloc.h
MMAP_THRESHOLD = 32 << 20  # glibc's largest (HEAP_MAX_SIZE / 2 on 64-bit systems)
TRIM_THRESHOLD = (1 << 31) - 1  # mallopt takes an int


def reuse_memory() -> bool:
    """Keep freed memory in the process's heap for reuse (module docstring): large
    temporaries of repeated batched work are not returned to the operating system and
    faulted in again. The 60 s IMU + poses job of ``benchmarks/bench_gtsam.py`` faulted
    65,000-100,000 pages in per run without it (0.1-0.3 s of kernel time), about 20 with it,
    and took about 10 % less time (one thread, 2026-11-29), at the same peak memory.

    Process-wide and irreversible (the resident memory no longer shrinks after a peak);
    only where the C library is glibc (Linux): elsewhere nothing changes.

    Returns:
        True where both settings were applied, False where the C library is not glibc or
        refused them.
    """
    if not sys.platform.startswith("linux") or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own C library
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return (mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1
            and mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1)

"""Eager kernels run large batches in chunks: cache-sized on the CPU, ``DEVICE_SCALE`` times
larger on a GPU, where a CPU-sized chunk leaves every op launch-bound (1e8 float32 sclerp
pairs took 1.8 s on an H200 in 1526 chunks, where moving their bytes takes 2.4 ms)."""

import math

import torch

from torch_dq._kernels import layout


def _covers(parts, n):
    seen = torch.zeros(n, dtype=torch.int64)
    for s in parts:
        seen[s] += 1
    return bool((seen == 1).all())


def test_chunks_are_larger_off_the_cpu():
    n = 10**7
    cpu = layout.chunks(n)
    gpu = layout.chunks(n, device=torch.device("cuda"))
    assert len(cpu) == math.ceil(n / layout.CHUNK)
    assert len(gpu) == math.ceil(n / (layout.CHUNK * layout.DEVICE_SCALE))
    assert _covers(cpu, n) and _covers(gpu, n)
    small = layout.chunks(n, layout.PYRAMID_CHUNK, torch.device("cpu"))
    assert len(small) == math.ceil(n / layout.PYRAMID_CHUNK) and _covers(small, n)
    assert len(layout.chunks(n, layout.PYRAMID_CHUNK, torch.device("cuda", 0))) == math.ceil(
        n / (layout.PYRAMID_CHUNK * layout.DEVICE_SCALE))

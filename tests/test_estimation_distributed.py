"""A large batch of independent problems sharded across processes (torch.distributed, gloo).

Each process estimates its shard of the batch (its rows of the control points and of the
terms' data) with ``torch_dq.fitting.estimate``; the shards' results are gathered with
``all_gather``. Independent problems need no communication during the solve, so the sharded
result equals the single-process batched one. Two CPU processes here; the same code runs one
process per GPU with the "nccl" backend.
"""

import socket

import pytest
import torch
import torch.distributed as dist
import torch.multiprocessing as mp

import torch_dq.dualquat as dq
from torch_dq import fitting
from torch_dq.nn import BSpline

F64 = torch.float64
B, WORLD = 6, 2


def problems():
    """B trajectories (screw motions with noise) sampled at shared times."""
    gen = torch.Generator().manual_seed(3)
    t = torch.linspace(0.0, 2.0, 41, dtype=F64)
    xi = 0.5 * torch.randn(B, 1, 6, generator=gen, dtype=F64)
    x = dq.mul(dq.exp(t[:, None] * xi), dq.exp(0.01 * torch.randn(B, 41, 6, generator=gen,
                                                                   dtype=F64)))
    gyro = xi[:, :, :3].expand(B, 41, 3) + 0.02  # a constant bias of 0.02 rad/s
    return t, x, gyro


def solve(t, x, gyro):
    """Estimate a batch of problems; returns the control points and the gyro biases."""
    spline = BSpline.from_dualquats(x, t, n_ctrl=8)
    bias = fitting.Gyro(t[5:-5], gyro[:, 5:-5], sigma=0.01, bias=True)
    fitting.estimate(spline, [fitting.Poses(t, x, rot_sigma=0.01, trans_sigma=0.01), bias],
                     verbose=False)
    return spline.control_points.detach(), bias.bias


def worker(rank, port, out):
    torch.set_num_threads(1)
    dist.init_process_group("gloo", init_method=f"tcp://127.0.0.1:{port}", rank=rank,
                            world_size=WORLD)
    t, x, gyro = problems()
    shard = slice(rank * B // WORLD, (rank + 1) * B // WORLD)  # this process's problems
    ctrl, bias = solve(t, x[shard], gyro[shard])
    parts = [torch.empty_like(ctrl) for _ in range(WORLD)]
    dist.all_gather(parts, ctrl)
    biases = [torch.empty_like(bias) for _ in range(WORLD)]
    dist.all_gather(biases, bias)
    if rank == 0:
        torch.save((torch.cat(parts), torch.cat(biases)), out)
    dist.destroy_process_group()


@pytest.mark.skipif(not dist.is_available(), reason="torch.distributed is not available")
def test_sharded_batch_equals_one_process(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    out = str(tmp_path / "gathered.pt")
    mp.start_processes(worker, args=(port, out), nprocs=WORLD, start_method="spawn")
    ctrl, bias = torch.load(out)
    ref_ctrl, ref_bias = solve(*problems())
    torch.testing.assert_close(ctrl, ref_ctrl, rtol=0, atol=1e-10)
    torch.testing.assert_close(bias, ref_bias, rtol=0, atol=1e-10)
    torch.testing.assert_close(bias, torch.full_like(bias, 0.02), rtol=0, atol=0.015)

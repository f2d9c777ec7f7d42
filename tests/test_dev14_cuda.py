"""Public functions outside ``tests/test_cuda_pipelines.py`` on a GPU give what they give on
the CPU (skipped without CUDA): each audited with a CPU simulation of the device rules
(tensors made without ``device=`` are host tensors; mixing one with a device tensor fails),
then fixed where a host tensor met the data's device."""

import dataclasses

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import fitting, quat
from torch_dq.fitting import _knots

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
F64 = torch.float64
CUDA = torch.device("cuda")


def _motion(t: np.ndarray):
    """Poses of a smooth motion (rotation vectors and positions written out here)."""
    rv = np.stack([0.4 * np.sin(0.7 * t), 0.3 * np.cos(0.5 * t), 0.5 * t], -1)
    p = np.stack([np.sin(0.6 * t), 0.5 * np.cos(0.4 * t), 0.1 * t], -1)
    return dq.from_rt(quat.from_rotvec(torch.as_tensor(rv)), torch.as_tensor(p))


@pytest.mark.parametrize("form", ["de_boor", "cumulative", "split"])
def test_knot_spacing_search_on_cuda_matches_cpu(form):
    """``fitting.choose_knot_spacing`` built its candidate knots on the CPU and met the
    poses' times on their device (``searchsorted`` of CPU knots and CUDA times); the search
    now runs on the CPU whatever the inputs' device: the same floats, bit for bit."""
    tp = np.arange(0.0, 6.0, 0.05)
    rng = np.random.default_rng(3)
    x = dq.mul(_motion(tp), dq.exp(torch.as_tensor(1e-3 * rng.standard_normal((tp.size, 6)))))
    t = torch.as_tensor(tp)
    cpu = _knots.knot_spacing_search(t, x, form=form)
    gpu = _knots.knot_spacing_search(t.to(CUDA), x.to(CUDA), form=form)
    assert dataclasses.asdict(gpu) == dataclasses.asdict(cpu)
    assert fitting.choose_knot_spacing(t.to(CUDA), x.float().to(CUDA), form=form) == \
        fitting.choose_knot_spacing(t, x.float(), form=form)


def _close(gpu: torch.Tensor, cpu: torch.Tensor, rel: float = 1e-9) -> None:
    assert gpu.device.type == CUDA.type
    err = (gpu.cpu() - cpu).abs().max()
    assert err <= rel * cpu.abs().max().clamp(min=1e-300), (err, cpu.abs().max())


def test_from_poses_with_chosen_knots_on_cuda_matches_cpu():
    """``BSpline.from_dualquats(n_ctrl=None)``: the knot spacing chosen from the data."""
    from torch_dq.nn import BSpline
    tp = np.arange(0.0, 4.0, 0.04)
    x, t = _motion(tp), torch.as_tensor(tp)
    out = [BSpline.from_dualquats(x.to(d), t.to(d), form="cumulative") for d in ("cpu", CUDA)]
    assert out[1].n_ctrl == out[0].n_ctrl
    _close(out[1].control_points.detach(), out[0].control_points.detach(), 1e-10)
    _close(out[1](t.to(CUDA)).detach(), out[0](t).detach(), 1e-10)

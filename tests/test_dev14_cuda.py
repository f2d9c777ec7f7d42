"""Public functions outside ``tests/test_cuda_pipelines.py`` on a GPU give what they give on
the CPU (skipped without CUDA): each audited with a CPU simulation of the device rules
(tensors made without ``device=`` are host tensors; mixing one with a device tensor fails),
then fixed where a host tensor met the data's device."""

import dataclasses

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import calibration, camera, fitting, quat
from torch_dq.fitting import _knots
from torch_dq.nn import BSpline

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
    tp = np.arange(0.0, 4.0, 0.04)
    x, t = _motion(tp), torch.as_tensor(tp)
    out = [BSpline.from_dualquats(x.to(d), t.to(d), form="cumulative") for d in ("cpu", CUDA)]
    assert out[1].n_ctrl == out[0].n_ctrl
    _close(out[1].control_points.detach(), out[0].control_points.detach(), 1e-10)
    _close(out[1](t.to(CUDA)).detach(), out[0](t).detach(), 1e-10)


def _estimate_on_cpu():
    """A CPU estimate: poses of a constant screw motion at 20 Hz and a gyroscope at 200 Hz."""
    xi = torch.tensor([0.1, 0.3, 0.5, 0.5, 0.0, 0.1], dtype=F64)  # rad/s, m/s
    tp, ti = torch.arange(0.0, 4.0 + 1e-9, 0.05, dtype=F64), torch.arange(0.1, 3.9, 0.005,
                                                                          dtype=F64)
    rng = np.random.default_rng(6)
    x = dq.mul(dq.exp(tp[:, None] * xi), dq.exp(torch.as_tensor(
        1e-3 * rng.standard_normal((tp.numel(), 6)))))
    gyro = xi[:3] + 1e-3 * torch.as_tensor(rng.standard_normal((ti.numel(), 3)))
    spline = BSpline.from_dualquats(x, tp, knot_spacing=0.2, form="cumulative")
    terms = [fitting.Poses(tp, x, rot_sigma=1e-3, trans_sigma=1e-3),
             fitting.Gyro(ti, gyro, sigma=1e-3, bias=True)]
    return fitting.estimate(spline, terms, verbose=False)


def test_estimate_std_along_answers_cuda_times():
    """``Estimate.pose_std`` / ``kinematics_std`` compute where the estimate lives and answer
    on the times' device: a CPU estimate (as ``calibration.camera_imu``'s) takes CUDA times."""
    est = _estimate_on_cpu()
    t = torch.linspace(0.5, 3.5, 13, dtype=F64)
    for name in ("pose_std", "kinematics_std"):
        cpu = getattr(est, name)(t)
        gpu = getattr(est, name)(t.to(CUDA))
        assert gpu.device.type == CUDA.type and torch.equal(gpu.cpu(), cpu)
        assert bool(torch.isfinite(cpu).all()) and bool((cpu > 0).all())


def test_camera_imu_estimate_usable_on_cuda():
    """``calibration.camera_imu`` on CUDA inputs computes on the CPU and moved its trajectory
    onto the IMU's device in place: the trajectory of its ``estimate`` with it, whose
    ``pose_std`` then met CPU factors with CUDA knots. The result's trajectory is a moved
    copy now; the estimate's stays where it was computed and answers times on any device."""
    import _camera_imu_sim as sim
    imu, cams = sim.rig(duration=5.0, offset=0.004, seed=2)

    def dev(x):
        return torch.as_tensor(np.asarray(x)).to(CUDA)
    cam = camera.Camera("pinhole-radtan", torch.tensor(sim.intrinsics(0)), sim.RESOLUTION)
    res = calibration.camera_imu([cam, cam], [tuple(dev(x) for x in c) for c in cams],
                                 tuple(dev(x) for x in imu), gyro_noise=sim.GYRO_DENSITY,
                                 accel_noise=sim.ACCEL_DENSITY, pixel_sigma=0.3,
                                 knot_spacing=0.05)
    assert res.trajectory.control_points.device.type == CUDA.type
    assert res.gyro_bias.device.type == CUDA.type
    t = torch.linspace(1.0, 4.0, 7, dtype=F64)
    cpu = res.estimate.pose_std(t)
    gpu = res.estimate.pose_std(t.to(CUDA))
    assert gpu.device.type == CUDA.type and torch.equal(gpu.cpu(), cpu)
    assert bool(torch.isfinite(cpu).all())
    # the trajectory returned is the estimated one, on the IMU's device
    est_traj = res.estimate._problem.trajectory
    assert torch.equal(res.trajectory.control_points.detach().cpu(),
                       est_traj.control_points.detach().cpu())


def test_estimate_with_undetermined_combinations_on_cuda_matches_cpu():
    """A knot at every pose leaves combinations of control points that no sample determines;
    the numerical prior finds them by subspace iteration from pseudo-random columns
    (``fitting._prior``), which a CUDA generator drew differently from the CPU's. They are
    drawn on the CPU for every device now: the same prior, the same estimate."""
    tp, td = np.arange(0.0, 4.0 + 1e-9, 0.1), np.arange(0.0, 4.0 + 1e-9, 0.025)
    x, t = _motion(tp), torch.as_tensor(tp)
    rng = np.random.default_rng(8)
    x = dq.mul(x, dq.exp(torch.as_tensor(2e-3 * rng.standard_normal((tp.size, 6)))))
    ti = torch.arange(0.2, 3.8, 0.01, dtype=F64)
    with torch.no_grad():  # a gyroscope whose clock offset is estimated
        w = BSpline.from_dualquats(_motion(td), torch.as_tensor(td), n_ctrl=80).imu(ti)[0]
    w = w + 2e-3 * torch.as_tensor(rng.standard_normal(w.shape))
    out = []
    for device in ("cpu", CUDA):
        spline = BSpline.from_dualquats(_motion(td), torch.as_tensor(td), n_ctrl=43,
                                        form="cumulative").to(device)
        terms = [fitting.Poses(t.to(device), x.to(device), rot_sigma=2e-3, trans_sigma=2e-3),
                 fitting.Gyro(ti.to(device), w.to(device), sigma=2e-3,
                              time_offset=fitting.Free(0.0))]
        est = fitting.estimate(spline, terms, verbose=False)
        out.append((spline.control_points.detach(), spline(t.to(device)).detach(),
                    torch.as_tensor(est.final_loss)))
    for g_, c in zip(out[1][:2], out[0][:2], strict=True):
        _close(g_, c, 1e-8)
    assert abs(float(out[1][2]) - float(out[0][2])) <= 1e-8 * abs(float(out[0][2])) + 1e-20

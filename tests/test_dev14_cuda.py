"""Public functions outside ``tests/test_cuda_pipelines.py`` on a GPU give what they give on
the CPU (skipped without CUDA): each audited with a CPU simulation of the device rules
(tensors made without ``device=`` are host tensors; mixing one with a device tensor fails),
then fixed where a host tensor met the data's device."""

import dataclasses

import numpy as np
import pytest
import torch
from test_cuda_pipelines import CUDA, F64, _close
from test_cuda_pipelines import _motion as motion

import torch_dq.dualquat as dq
from torch_dq import calibration, camera, fitting, quat
from torch_dq.fitting import _knots
from torch_dq.nn import BSpline

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _motion(t: np.ndarray):
    """Poses ``(N, 8)`` of ``test_cuda_pipelines``' smooth motion."""
    rv, p = motion(t)
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


def _flat(x) -> list[torch.Tensor]:
    """The tensors of nested tuples / lists / named tuples / Dual numbers, in order."""
    if isinstance(x, torch.Tensor):
        return [x]
    if hasattr(x, "real") and hasattr(x, "dual") and not isinstance(x, (tuple, list)):
        return [x.real, x.dual]
    return [t for y in x if y is not None for t in _flat(y)]


def _same(run, rel: float = 1e-9) -> None:
    """``run(device)`` on the CPU and on CUDA: every tensor on CUDA, equal to rounding."""
    cpu, gpu = _flat(run(torch.device("cpu"))), _flat(run(CUDA))
    assert len(cpu) == len(gpu)
    for g_, c in zip(gpu, cpu, strict=True):
        if g_.dtype == torch.bool or not g_.is_floating_point():
            assert g_.device.type == CUDA.type and torch.equal(g_.cpu(), c)
        else:
            _close(g_.detach(), c.detach(), rel)


@pytest.mark.parametrize("form", ["de_boor", "cumulative", "split"])
def test_curves_and_layers_on_cuda_match_cpu(form):
    """Per-trajectory knots, extrapolation, kinematics, twists and screw axes, the layers'
    batched constructors and their evaluations with ``ctrl=`` from a net, a reloaded
    state dict, losses and the ``DualQuaternion`` object (audited, no defect found)."""
    from torch_dq import DualQuaternion, curves, losses
    tp = np.linspace(0.0, 2.0, 41)
    xb = torch.stack([_motion(tp), _motion(1.5 * tp)])  # (2, N, 8)
    tb = torch.stack([torch.as_tensor(tp), torch.as_tensor(tp) + 3.0])  # own times per row
    g = torch.Generator().manual_seed(2)
    ctrl = dq.normalize(torch.randn(2, 7, 8, generator=g, dtype=F64))
    knots = torch.stack([curves.clamped_uniform_knots(7, 3, dtype=F64) * s for s in (1., 2.)])
    tq = torch.rand(2, 9, generator=g, dtype=F64) * torch.tensor([[1.0], [2.0]], dtype=F64)

    def run(d):
        out = list(curves.bspline_derivatives(ctrl.to(d), tq.to(d), order=3,
                                              knots=knots.to(d), form=form))
        out.append(curves.bspline(ctrl.to(d), tq.to(d) - 0.1, knots=knots.to(d), form=form,
                                  extrapolate=True))
        x, dx, ddx = out[:3]
        tw = curves.twists(x, dx)
        out += [curves.kinematics(x, dx, ddx, frame="body"), curves.imu(x, dx, ddx),
                tw, curves.screw_axis(tw[..., :3], tw[..., 3:])]
        m = BSpline.from_dualquats(xb.to(d), tb.to(d), n_ctrl=9, form=form)
        c = m.control_points.detach().clone().requires_grad_(True)
        tm = tb[:, 3:38:5].to(d)
        w, a = m.imu(tm, ctrl=c)
        out += [m.derivatives(tm, order=3, ctrl=c), m.kinematics(tm, ctrl=c), w, a,
                torch.autograd.grad(w.square().sum() + a.square().sum(), c)[0],
                BSpline.from_state_dict(m.state_dict())(tm).detach(),
                m(tb[:, :2].to(d) - 0.2, extrapolate=True).detach()]
        p, q = xb[0].to(d), xb[1].to(d)
        out += [losses.rotation_angle(p, q), losses.translation_error(p, q),
                losses.pose_loss(p, q, rot_weight=2.0)]
        A, B = DualQuaternion(p), DualQuaternion(q)
        out += [(A * B.inverse()).tensor, A.apply(q[:, 4:7]), A.to_matrix(),
                A.sclerp(B, 0.3).tensor, A.angle(B), A.log()]
        return out
    _same(run, 1e-8)


@pytest.mark.filterwarnings("ignore:fitting.Estimate:RuntimeWarning")  # noiseless poses
def test_estimate_options_on_cuda_match_cpu():
    """An extrinsic with a prior, a lever arm, priors on a bias and a clock offset, robust
    kernels and a mask, read back through ``std`` (scaled too), ``cov``, ``pose_std``,
    ``kinematics_std``, ``outliers`` and ``chi2``; and a batch of two trajectories with
    their own times and masks (audited, no defect found)."""
    tp, ti = np.arange(0.0, 4.0 + 1e-9, 0.05), np.arange(0.2, 3.8, 0.01)
    x, t = _motion(tp), torch.as_tensor(tp)
    rng = np.random.default_rng(9)
    with torch.no_grad():
        w, a = BSpline.from_dualquats(x, t, knot_spacing=0.2, form="cumulative").imu(
            torch.as_tensor(ti), gravity=torch.tensor([0.0, 0.0, -9.81], dtype=F64))
    w = w + 1e-3 * torch.as_tensor(rng.standard_normal(w.shape)) + 0.01
    a = a + 1e-2 * torch.as_tensor(rng.standard_normal(a.shape)) - 0.05
    ext = dq.exp(torch.tensor([0.1, 0.0, 0.2, 0.1, 0.0, 0.0], dtype=F64))
    arm = torch.tensor([0.1, -0.05, 0.02], dtype=F64)
    mask = torch.ones(t.shape, dtype=torch.bool)
    mask[3] = False
    te = torch.linspace(0.5, 3.5, 5, dtype=F64)

    def run(d):
        spline = BSpline.from_dualquats(x, t, knot_spacing=0.2, form="cumulative").to(d)
        ti_, tp_ = torch.as_tensor(ti).to(d), t.to(d)
        T = [fitting.Poses(tp_, dq.mul(x, ext).to(d), rot_sigma=1e-3, trans_sigma=1e-3,
                           extrinsic=fitting.Free(ext, prior_std=0.1), mask=mask.to(d)),
             fitting.Positions(tp_, dq.apply(x, arm).to(d), sigma=1e-3,
                               lever_arm=fitting.Free(prior_std=1.0), robust="huber"),
             fitting.Gyro(ti_, w.to(d), sigma=1e-3, bias=fitting.Free(prior_std=0.1),
                          time_offset=fitting.Free(0.0, prior_std=0.01)),
             fitting.Accel(ti_, a.to(d), sigma=1e-2, bias=True, robust="cauchy")]
        est = fitting.estimate(spline, T, verbose=False)
        return [spline.control_points, est.std(T[0], "extrinsic"),
                est.std(T[1], "lever_arm", scaled=True), est.std(T[2], "time_offset"),
                est.cov((T[2], "bias"), (T[3], "bias")), est.pose_std(te.to(d)),
                est.kinematics_std(te.to(d), scaled=True), T[0].extrinsic, T[1].lever_arm,
                [est.outliers[u] for u in T], [est.chi2[u] for u in T]]
    _same(run, 1e-7)

    xb = torch.stack([x, dq.mul(x, ext)])
    tb, tib = torch.stack([t, t + 0.5]), torch.stack([torch.as_tensor(ti)] * 2)
    tib[1] += 0.5
    mb = torch.ones(tib.shape, dtype=torch.bool)
    mb[1, -20:] = False

    def run_batch(d):
        spline = BSpline.from_dualquats(xb, tb, knot_spacing=0.2, form="cumulative").to(d)
        T = [fitting.Poses(tb.to(d), xb.to(d), rot_sigma=1e-3, trans_sigma=1e-3),
             fitting.Gyro(tib.to(d), torch.stack([w, w]).to(d), sigma=1e-3, bias=True,
                          mask=mb.to(d)),
             fitting.Accel(tib.to(d), torch.stack([a, a]).to(d), sigma=1e-2, bias=True,
                           gravity=9.81, mask=mb.to(d), robust="huber")]
        est = fitting.estimate(spline, T, verbose=False)
        return [spline.control_points, est.std(T[1], "bias"), T[2].gravity,
                est.std(T[2], "gravity", scaled=True),
                est.pose_std(torch.stack([te, te + 0.5]).to(d)), est.outliers[T[2]]]
    _same(run_batch, 1e-7)


@pytest.mark.filterwarnings("ignore:fitting.Estimate:RuntimeWarning")  # noiseless poses
@pytest.mark.parametrize("options", ["line_delay", "intrinsics", "target"])
def test_reprojections_options_on_cuda_match_cpu(options):
    """A rolling shutter's line delay, estimated intrinsics, an estimated target pose, and
    the float32 camera models (audited, no defect found)."""
    from torch_dq import camera
    tp = np.arange(0.0, 4.0 + 1e-9, 0.05)
    rv = np.stack([0.12 * np.sin(0.7 * tp), 0.09 * np.cos(0.5 * tp), 0.5 * tp], -1)
    p = np.stack([np.sin(0.6 * tp), 0.5 * np.cos(0.4 * tp), 0.1 * tp], -1)
    body = dq.from_rt(quat.from_rotvec(torch.as_tensor(rv)), torch.as_tensor(p))
    side = np.linspace(-1.5, 1.5, 4)
    grid = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    target = torch.as_tensor(np.concatenate([grid, np.full((16, 1), -6.0)], -1))
    ext = dq.from_rt(quat.from_rotvec(torch.tensor([np.pi, 0.0, 0.0], dtype=F64)),
                     torch.tensor([0.02, -0.01, 0.0], dtype=F64))
    params = torch.tensor([458.7, 457.3, 367.2, 248.4, -0.283, 0.074, 1.9e-4, 1.8e-5],
                          dtype=F64)
    pc = dq.apply(dq.inv(dq.mul(body, ext))[:, None], target[None])
    pix, valid = camera.project("pinhole-radtan", params, pc)
    assert bool(valid.all())
    rng = np.random.default_rng(10)
    pixels = pix.reshape(-1, 2) + 0.3 * torch.as_tensor(rng.standard_normal((pix.numel() // 2,
                                                                              2)))
    times, points = torch.as_tensor(np.repeat(tp, 16)), target.repeat(tp.size, 1)
    cam = camera.Camera("pinhole-radtan", params, (740, 500))

    def run(d):
        kw = {"line_delay": {"line_delay": fitting.Free(1e-5, prior_std=1e-4)},
              "intrinsics": {"intrinsics": True},  # a Free is one parameter: one per run
              "target": {"target": fitting.Free(dq.identity(dtype=F64))}}[options]
        spline = BSpline.from_dualquats(body, torch.as_tensor(tp), knot_spacing=0.2,
                                        margin=0.2).to(d)
        term = fitting.Reprojections(times.to(d), points.to(d), pixels.to(d), camera=cam,
                                     sigma=0.3, extrinsic=fitting.Free(ext), **kw)
        poses = fitting.Poses(torch.as_tensor(tp).to(d), body.to(d), rot_sigma=1e-2,
                              trans_sigma=1e-2)
        est = fitting.estimate(spline, [term, poses], verbose=False)
        c32 = camera.Camera("pinhole-radtan", params.float().to(d), (740, 500))
        px32, ok32 = c32.project(pc[:5].float().to(d))
        return [spline.control_points, term.extrinsic, est.std(term, options),
                est.std(term, "extrinsic"), px32, ok32, c32.unproject(px32)]
    _same(run, 1e-6)

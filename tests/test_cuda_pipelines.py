"""The user pipelines on a GPU give what they give on the CPU (skipped without CUDA).

``tests/test_modes.py`` runs every registry op on CUDA; this file runs what a user runs end
to end with CUDA tensors: `fitting.estimate` with IMU biases, a clock offset and a robust
kernel (values, standard deviations, ``pose_std``), `fit`, the camera models (pixels, rays,
gradients), a `Reprojections` term, a training step of each B-spline form, and
`calibration.camera_imu`. Each result must live on the GPU and equal the CPU's to rounding
(the float64 algebra is the same; reductions may sum in another order)."""

import numpy as np
import pytest
import torch

import torch_dq.dualquat as dq
from torch_dq import calibration, camera, fitting, quat
from torch_dq.nn import BSpline, fit

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
F64 = torch.float64
CUDA = torch.device("cuda")


def _motion(t: np.ndarray):
    """Rotation vectors, positions and body rates of a smooth motion, written out here."""
    rv = np.stack([0.4 * np.sin(0.7 * t), 0.3 * np.cos(0.5 * t), 0.5 * t], -1)
    p = np.stack([np.sin(0.6 * t), 0.5 * np.cos(0.4 * t), 0.1 * t], -1)
    return rv, p


GRAVITY = torch.tensor([0.0, 0.0, -9.81], dtype=F64)


def _recording(duration: float, seed: int):
    """Poses at 20 Hz over ``duration`` s and an IMU at 200 Hz 0.2 s inside them, its
    readings (1e-3 rad/s, 1e-2 m/s^2 noise) from the spline through the poses (the data
    consistent): times, rotation vectors, positions, rotations, that spline, IMU times, gyro,
    accel and the generator."""
    rng = np.random.default_rng(seed)
    tp = np.arange(0.0, duration + 1e-9, 0.05)
    rv, p = _motion(tp)
    q = quat.from_rotvec(torch.as_tensor(rv))
    truth = BSpline.from_poses(q, torch.as_tensor(p), torch.as_tensor(tp), knot_spacing=0.1,
                               form="cumulative")
    ti = torch.as_tensor(np.arange(0.2, duration - 0.2, 0.005))
    with torch.no_grad():
        w, a = truth.imu(ti, gravity=GRAVITY)
    w = w + 1e-3 * torch.as_tensor(rng.standard_normal(w.shape))
    a = a + 1e-2 * torch.as_tensor(rng.standard_normal(a.shape))
    return tp, rv, p, q, truth, ti, w, a, rng


def _problem(device, robust=None):
    """8 s of :func:`_recording` with biases on the IMU, its clock offset estimated."""
    tp, rv, p, q, _, ti, w, a, rng = _recording(8.0, 0)
    w, a = w + 0.01, a - 0.05
    noisy = quat.mul(q, quat.from_rotvec(torch.as_tensor(1e-3 * rng.standard_normal(rv.shape))))
    poses = dq.from_rt(noisy, torch.as_tensor(p + 1e-3 * rng.standard_normal(p.shape)))
    spline = BSpline.from_poses(noisy, torch.as_tensor(p), torch.as_tensor(tp),
                                knot_spacing=0.1, form="cumulative").to(device)
    mv = {"device": device}
    terms = [fitting.Poses(torch.as_tensor(tp).to(**mv), poses.to(**mv), rot_sigma=1e-3,
                           trans_sigma=1e-3, robust=robust),
             fitting.Gyro(ti.to(**mv), w.to(**mv), sigma=1e-3, bias=True,
                          time_offset=fitting.Free(0.0)),
             fitting.Accel(ti.to(**mv), a.to(**mv), sigma=1e-2, bias=True,
                           gravity=GRAVITY.to(**mv))]
    return spline, terms


def _close(gpu: torch.Tensor, cpu: torch.Tensor, rel: float = 1e-9) -> None:
    assert gpu.device.type == "cuda"
    err = (gpu.cpu() - cpu).abs().max()
    assert err <= rel * cpu.abs().max().clamp(min=1e-300), (err, cpu.abs().max())


@pytest.mark.parametrize("robust", [None, "cauchy"])
def test_estimate_on_cuda_matches_cpu(robust):
    out = []
    for device in ("cpu", CUDA):
        spline, terms = _problem(device, robust)
        est = fitting.estimate(spline, terms, verbose=False)
        assert bool(est.converged), est.reason
        t = torch.linspace(1.0, 7.0, 9, dtype=F64, device=device)
        out.append((spline.control_points.detach(), terms[1].bias, terms[2].bias,
                            terms[1].time_offset.reshape(()), est.std(terms[1], "bias"),
                            est.std(terms[2], "bias"), est.std(terms[1], "time_offset"),
                            est.pose_std(t), est.kinematics_std(t),
                            torch.stack([c for c in est.chi2.values()])))
    for g, c in zip(out[1], out[0], strict=True):
        _close(g, c, 1e-7)
    assert abs(float(out[0][3])) < 5 * float(out[0][6])  # no offset in the data


def test_other_terms_on_cuda_match_cpu():
    """Positions with an estimated lever arm, odometry, and gravity of known magnitude whose
    direction is estimated (its start from the mean reading)."""
    tp, _, p, q, truth, ti, w, a, rng = _recording(6.0, 4)
    arm = torch.tensor([0.1, -0.05, 0.02], dtype=F64)
    with torch.no_grad():
        x = truth(torch.as_tensor(tp))
        pos = dq.apply(x, arm) + 1e-3 * torch.as_tensor(rng.standard_normal((tp.size, 3)))
        odo = dq.mul(dq.mul(dq.inv(x[:-1]), x[1:]),
                     dq.exp(1e-3 * torch.as_tensor(rng.standard_normal((tp.size - 1, 6)))))
    t = torch.as_tensor(tp)
    out = []
    for device in ("cpu", CUDA):
        spline = BSpline.from_poses(q, torch.as_tensor(p), t, knot_spacing=0.1,
                                    form="cumulative").to(device)
        terms = [fitting.Positions(t.to(device), pos.to(device), sigma=1e-3, lever_arm=True),
                 fitting.RelativePoses(t[:-1].to(device), t[1:].to(device), odo.to(device),
                                       rot_sigma=1e-3, trans_sigma=1e-3),
                 fitting.Gyro(ti.to(device), w.to(device), sigma=1e-3),
                 fitting.Accel(ti.to(device), a.to(device), sigma=1e-2, gravity=9.81)]
        est = fitting.estimate(spline, terms, verbose=False)
        out.append((terms[0].lever_arm, terms[3].gravity, est.std(terms[0], "lever_arm"),
                    est.std(terms[3], "gravity"), spline.control_points.detach()))
    for g_, c in zip(out[1], out[0], strict=True):
        _close(g_, c, 1e-7)
    assert (out[0][0] - arm).abs().max() < 5 * out[0][2].max()


def test_positions_and_imu_from_identity_on_cuda_match_cpu():
    """Positions, a gyroscope and an accelerometer from a start without rotation: the
    IMU-aligned start (``fitting._align``) runs on the GPU too."""
    tp, _, p, _, truth, ti, w, a, rng = _recording(6.0, 5)
    pos = torch.as_tensor(p + 1e-3 * rng.standard_normal(p.shape))
    t = torch.as_tensor(tp)
    out = []
    for device in ("cpu", CUDA):
        spline = BSpline.from_poses(quat.identity((tp.size,), dtype=F64), pos, t,
                                    knot_spacing=0.1, form="cumulative").to(device)
        terms = [fitting.Positions(t.to(device), pos.to(device), sigma=1e-3),
                 fitting.Gyro(ti.to(device), w.to(device), sigma=1e-3),
                 fitting.Accel(ti.to(device), a.to(device), sigma=1e-2)]
        est = fitting.estimate(spline, terms, verbose=False)
        assert bool(est.converged), est.reason
        with torch.no_grad():
            inner = t[10:-10].to(device)
            turn = quat.to_rotvec(quat.mul(quat.conj(truth.to(device)(inner)[..., :4]),
                                           spline(inner)[..., :4]))
        out.append((spline.control_points.detach(), turn.norm(dim=-1).max()))
    _close(out[1][0], out[0][0], 1e-7)
    assert float(out[0][1]) < 0.01  # radians: the rotation found from no rotation at all


def test_from_poses_on_cuda_matches_cpu():
    """Knots finer than the poses (the start sampled densely from a coarse fit) and the
    module's own times on the GPU."""
    tp = np.arange(0.0, 3.0, 0.05)
    rv, p = _motion(tp)
    q, pp, t = quat.from_rotvec(torch.as_tensor(rv)), torch.as_tensor(p), torch.as_tensor(tp)
    out = []
    for device in ("cpu", CUDA):
        m = BSpline.from_poses(q.to(device), pp.to(device), t.to(device), knot_spacing=0.01,
                               form="cumulative")
        out.append((m.control_points.detach(), m(t.to(device)).detach()))
    for g_, c in zip(out[1], out[0], strict=True):
        _close(g_, c, 1e-10)


def test_fit_on_cuda_matches_cpu():
    tp = np.arange(0.0, 4.0, 0.02)
    rv, p = _motion(tp)
    poses = dq.from_rt(quat.from_rotvec(torch.as_tensor(rv)), torch.as_tensor(p))
    out = []
    for device in ("cpu", CUDA):
        times = torch.as_tensor(tp).to(device)
        m = BSpline.from_dualquats(poses.to(device), times, n_ctrl=30, form="cumulative")
        hist = fit(m, times, poses.to(device), "lm", verbose=False)
        out.append((m.control_points.detach(), torch.as_tensor(hist.final_loss)))
    _close(out[1][0], out[0][0], 1e-8)
    assert abs(float(out[1][1]) - float(out[0][1])) <= 1e-8 * abs(float(out[0][1])) + 1e-20


MODELS = {"pinhole": [450.0, 455.0, 370.0, 250.0],
          "pinhole-radtan": [458.7, 457.3, 367.2, 248.4, -0.283, 0.074, 1.9e-4, 1.8e-5],
          "pinhole-equidistant": [380.0, 381.0, 370.0, 250.0, -0.01, 0.02, -0.005, 0.001],
          "double-sphere": [310.0, 311.0, 370.0, 250.0, -0.2, 0.58]}


@pytest.mark.parametrize("model", list(MODELS))
def test_camera_on_cuda_matches_cpu(model):
    g = torch.Generator().manual_seed(1)
    pts = torch.cat([torch.rand(64, 2, generator=g, dtype=F64) - 0.5,
                     torch.ones(64, 1, dtype=F64)], -1)
    params = torch.tensor(MODELS[model], dtype=F64)
    out = []
    for device in ("cpu", CUDA):
        x = pts.to(device).requires_grad_(True)
        k = params.to(device).requires_grad_(True)
        pix, valid = camera.project(model, k, x)
        gx, gk = torch.autograd.grad(pix.square().sum(), (x, k))
        rays, ok = camera.unproject(model, k.detach(), pix.detach())
        out.append((pix.detach(), gx, gk, rays, valid, ok))
    for g_, c in zip(out[1], out[0], strict=True):
        if g_.dtype == torch.bool:
            assert g_.device.type == "cuda" and torch.equal(g_.cpu(), c)
        else:
            _close(g_, c, 1e-10)
    assert bool(out[0][4].all()) and bool(out[0][5].all())


def test_reprojections_on_cuda_matches_cpu():
    tp = np.arange(0.0, 4.0 + 1e-9, 0.05)
    rv, p = _motion(tp)
    q = quat.from_rotvec(torch.as_tensor(rv * [0.3, 0.3, 1.0]))  # tilts of at most 0.12 rad
    # the camera looks down at a 4 x 4 grid 6 m below the body's path
    side = np.linspace(-1.5, 1.5, 4)
    grid = np.stack(np.meshgrid(side, side), -1).reshape(-1, 2)
    target = np.concatenate([grid, np.full((16, 1), -6.0)], -1)
    ext = dq.from_rt(quat.from_rotvec(torch.tensor([np.pi, 0.0, 0.0], dtype=F64)),
                     torch.tensor([0.02, -0.01, 0.0], dtype=F64))
    body = dq.from_rt(q, torch.as_tensor(p))
    cam_pose = dq.mul(body, ext)  # (T, 8) camera in world
    pc = dq.apply(dq.inv(cam_pose)[:, None], torch.as_tensor(target)[None])
    params = torch.tensor(MODELS["pinhole"], dtype=F64)
    pix, valid = camera.project("pinhole", params, pc)
    assert bool(valid.all())
    rng = np.random.default_rng(2)
    times = torch.as_tensor(np.repeat(tp, 16))
    points = torch.as_tensor(np.tile(target, (tp.size, 1)))
    pixels = pix.reshape(-1, 2) + 0.3 * torch.as_tensor(rng.standard_normal((times.numel(), 2)))
    cam = camera.Camera("pinhole", params, (740, 500))
    noisy = dq.from_rt(quat.mul(q, quat.from_rotvec(torch.as_tensor(
        1e-2 * rng.standard_normal((tp.size, 3))))), torch.as_tensor(
        p + 1e-2 * rng.standard_normal((tp.size, 3))))
    out = []
    for device in ("cpu", CUDA):
        spline = BSpline.from_poses(q, torch.as_tensor(p), torch.as_tensor(tp),
                                    knot_spacing=0.2).to(device)
        term = fitting.Reprojections(times.to(device), points.to(device), pixels.to(device),
                                     camera=cam, sigma=0.3, extrinsic=fitting.Free(ext))
        poses = fitting.Poses(torch.as_tensor(tp).to(device), noisy.to(device), rot_sigma=1e-2,
                              trans_sigma=1e-2)
        est = fitting.estimate(spline, [term, poses], verbose=False)
        assert bool(est.converged), est.reason
        out.append((term.extrinsic, est.std(term, "extrinsic")))
    for g_, c in zip(out[1], out[0], strict=True):
        _close(g_, c, 1e-7)


@pytest.mark.parametrize("form", ["de_boor", "cumulative", "split"])
def test_training_step_on_cuda_matches_cpu(form):
    tp = np.linspace(0.0, 2.0, 41)
    rv, p = _motion(tp)
    q = quat.from_rotvec(torch.as_tensor(rv))
    out = []
    for device in ("cpu", CUDA):
        m = BSpline.from_poses(q, torch.as_tensor(p), torch.as_tensor(tp), n_ctrl=8,
                               form=form).to(device)
        t = torch.as_tensor(tp).to(device)
        w, a = m.imu(t, gravity=GRAVITY.to(device))
        loss = w.square().sum() + 1e-2 * a.square().sum()
        grads = torch.autograd.grad(loss, [x for x in m.parameters() if x.requires_grad])
        out.append((w.detach(), a.detach(), *grads))
    for g_, c in zip(out[1], out[0], strict=True):
        _close(g_, c, 1e-10)


def test_camera_imu_on_cuda_matches_cpu():
    import _camera_imu_sim as sim
    imu, cams = sim.rig(duration=6.0, offset=0.004, seed=1)
    out = []
    for device in ("cpu", CUDA):
        def t(x, device=device):
            return torch.as_tensor(np.asarray(x)).to(device)
        obs = [tuple(t(x) for x in c) for c in cams]
        cam = camera.Camera("pinhole-radtan", torch.tensor(sim.intrinsics(0)), sim.RESOLUTION)
        res = calibration.camera_imu([cam, cam], obs, tuple(t(x) for x in imu),
                                     gyro_noise=sim.GYRO_DENSITY, accel_noise=sim.ACCEL_DENSITY,
                                     pixel_sigma=0.3, knot_spacing=0.05)
        out.append((res.extrinsics, res.time_offsets, res.gyro_bias, res.accel_bias,
                    res.std["extrinsics"], res.trajectory.control_points.detach()))
    for g_, c in zip(out[1], out[0], strict=True):
        _close(g_, c, 1e-6)

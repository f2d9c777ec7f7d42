"""calibration.camera_imu and ``python -m torch_dq calibrate`` on a simulated rig.

The rig (``tests/_camera_imu_sim.py``): closed-form motion (sums of sines in a rotation
vector and a position), two EuRoC-like pinhole-radtan cameras (EuRoC's ``T_imu_cam``, 11 cm
baseline) at 20 Hz seeing an aprilgrid(6, 6, 0.088, 0.3), corners projected by OpenCV's
``projectPoints`` with 0.3 px noise, an IMU at 200 Hz from the analytic derivatives with
biases and EuRoC's noise densities, a 4 ms clock offset and, in one recording, a rolling
shutter (30 us per row). No start is given: every value must lie within 4 standard
deviations of the truth (the errors measured with numpy/scipy, independent of torch_dq).
"""

import json
import math
import os
import sys
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from torch_dq import calibration, dualquat
from torch_dq.__main__ import main
from torch_dq.calibration import _knot_spacing
from torch_dq.camera import Camera

pytest.importorskip("cv2")
yaml = pytest.importorskip("yaml")
sys.path.insert(0, os.path.dirname(__file__))
import _camera_imu_sim as sim  # noqa: E402

OFFSET = 0.004
LINE_DELAY = 3e-5
DURATION = 3.0


def _t(x):
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def _camera():
    k = sim.K
    return Camera("pinhole-radtan", _t([k[0, 0], k[1, 1], k[0, 2], k[1, 2], *sim.DIST]),
                  sim.RESOLUTION)


def _inputs(line_delay):
    imu, cams = sim.rig(duration=DURATION, offset=OFFSET, line_delay=line_delay, seed=1)
    return [tuple(_t(x) for x in c) for c in cams], tuple(_t(x) for x in imu)


def _fit(obs, imu, rolling):
    return calibration.camera_imu([_camera(), _camera()], obs, imu,
                                  gyro_noise=sim.GYRO_DENSITY, accel_noise=sim.ACCEL_DENSITY,
                                  pixel_sigma=0.3, rolling_shutter=rolling)


@pytest.fixture(scope="module")
def global_fit():
    obs, imu = _inputs(0.0)
    return _fit(obs, imu, False)


@pytest.fixture(scope="module")
def rolling_data():
    return _inputs(LINE_DELAY)


def _errors_over_std(res, line_delay):
    """Each estimated value's error over its standard deviation (numpy/scipy errors)."""
    out = {}
    for i in range(2):
        E = dualquat.to_matrix(res.extrinsics[i]).numpy()
        T = sim.extrinsic_matrix(i)
        rot = Rotation.from_matrix(E[:3, :3].T @ T[:3, :3]).as_rotvec()  # camera axes
        trans = E[:3, :3].T @ (T[:3, 3] - E[:3, 3])
        out[f"extrinsic{i}"] = np.concatenate([rot, trans]) / res.std["extrinsics"][i].numpy()
    out["time_offsets"] = (res.time_offsets.numpy() - OFFSET) / res.std["time_offsets"].numpy()
    if line_delay:
        out["line_delays"] = (res.line_delays.numpy() - line_delay) / res.std[
            "line_delays"].numpy()
    out["gyro_bias"] = (res.gyro_bias.numpy() - sim.GYRO_BIAS) / res.std["gyro_bias"].numpy()
    out["accel_bias"] = (res.accel_bias.numpy() - sim.ACCEL_BIAS) / res.std[
        "accel_bias"].numpy()
    g_err = res.gravity.numpy() - sim.GRAVITY
    out["gravity"] = g_err / np.maximum(res.std["gravity"].numpy(), 1e-12)
    return out


def _assert_within(res, line_delay, k=4.0):
    for name, z in _errors_over_std(res, line_delay).items():
        assert np.all(np.isfinite(z)), name
        assert np.all(np.abs(z) < k), (name, z)


def test_global_shutter_within_4_std(global_fit):
    res = global_fit
    _assert_within(res, 0.0)
    assert res.extrinsics.shape == (2, 8) and res.std["extrinsics"].shape == (2, 6)
    assert res.time_offsets.shape == res.line_delays.shape == (2,)
    assert torch.all(res.line_delays == 0)
    # 0.3 px per axis: the error norm's RMS is 0.3 sqrt(2) = 0.42 px
    assert torch.all((res.reprojection_rms > 0.38) & (res.reprojection_rms < 0.47))
    # the baseline of the rig, from the two extrinsics: 11 cm within a millimetre
    base = np.linalg.norm(sim.T_IMU_CAM[1] - sim.T_IMU_CAM[0])
    t = dualquat.to_rt(res.extrinsics)[1].numpy()
    assert abs(np.linalg.norm(t[1] - t[0]) - base) < 1e-3
    for key, v in res.std.items():
        assert torch.all(torch.isfinite(v) & (v >= 0)), key


def test_rolling_shutter_within_4_std_and_global_fit_worse(rolling_data):
    obs, imu = rolling_data
    rs = _fit(obs, imu, True)
    _assert_within(rs, LINE_DELAY)
    assert torch.all((rs.reprojection_rms > 0.38) & (rs.reprojection_rms < 0.47))
    with warnings.catch_warnings():  # a wrong model: the estimate may say chi2/dof > 1
        warnings.simplefilter("ignore", RuntimeWarning)
        gs = _fit(obs, imu, False)
    assert torch.all(gs.reprojection_rms > 1.5 * rs.reprojection_rms), (
        gs.reprojection_rms, rs.reprojection_rms)


def test_to_kalibr(global_fit, tmp_path):
    res = global_fit
    chain = res.to_kalibr()
    assert sorted(chain) == ["cam0", "cam1"]
    keys = {"T_cam_imu", "cam_overlaps", "camera_model", "distortion_coeffs",
            "distortion_model", "intrinsics", "resolution", "rostopic", "timeshift_cam_imu"}
    assert set(chain["cam0"]) == keys and set(chain["cam1"]) == keys | {"T_cn_cnm1"}
    T0, T1 = (np.array(chain[c]["T_cam_imu"]) for c in ("cam0", "cam1"))
    E0 = dualquat.to_matrix(res.extrinsics[0]).numpy()
    np.testing.assert_allclose(T0 @ E0, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(np.array(chain["cam1"]["T_cn_cnm1"]), T1 @ np.linalg.inv(T0),
                               atol=1e-12)
    assert chain["cam0"]["timeshift_cam_imu"] == pytest.approx(float(res.time_offsets[0]))
    path = tmp_path / "camchain-imucam.yaml"
    path.write_text(yaml.safe_dump(chain))
    back = yaml.safe_load(path.read_text())
    cam = Camera.from_kalibr(back["cam1"])
    assert cam.model == "pinhole-radtan" and cam.resolution == sim.RESOLUTION
    torch.testing.assert_close(cam.params, _camera().params)


def test_motion_warnings_name_the_parameters():
    from torch_dq.calibration._camera_imu import _motion_warnings

    t = torch.linspace(0, 10, 2001, dtype=torch.float64)
    small = 0.01 * torch.sin(3 * t)
    one_axis = torch.stack([small, small.roll(7), torch.sin(t)], -1)  # about z only
    accel = torch.tensor([0.0, 0.0, 9.81], dtype=torch.float64).expand(2001, 3)
    notes = _motion_warnings(one_axis, accel)
    assert len(notes) == 2
    assert "rotation about one IMU axis only (0.00, 0.00, 1.00)" in notes[0].replace("-0.", "0.")
    assert "extrinsics' rotation about that axis and their translation along it" in notes[0]
    assert "accel_bias is undetermined" in notes[1]
    none = _motion_warnings(torch.stack([small] * 3, -1), accel + torch.sin(t)[:, None])
    assert len(none) == 1 and "time_offsets are undetermined" in none[0]
    two_axes = torch.stack([torch.cos(2 * t), small, torch.sin(t)], -1)
    assert _motion_warnings(two_axes, accel + torch.sin(t)[:, None]) == []


def test_arguments(rolling_data):
    obs, imu = rolling_data
    kw = {"gyro_noise": 1e-4, "accel_noise": 1e-3}
    with pytest.raises(TypeError, match="camera_imu: expected cameras"):
        calibration.camera_imu(["pinhole"], obs[:1], imu, **kw)
    with pytest.raises(ValueError, match="camera_imu: expected one"):
        calibration.camera_imu([_camera()], obs, imu, **kw)
    with pytest.raises(ValueError, match="gyro_noise"):
        calibration.camera_imu([_camera()], obs[:1], imu, gyro_noise=-1.0, accel_noise=1e-3)
    with pytest.raises(ValueError, match="imu as times"):
        calibration.camera_imu([_camera()], obs[:1], (imu[0], imu[1][:, :2], imu[2]), **kw)
    with pytest.raises(ValueError, match="strictly increasing"):
        calibration.camera_imu([_camera()], obs[:1], (imu[0].flip(0), imu[1], imu[2]), **kw)
    late = (obs[0][0] + 1000.0, obs[0][1], obs[0][2])
    with pytest.raises(ValueError, match="overlap"):
        calibration.camera_imu([_camera()], [late], imu, **kw)
    noise = torch.randn(imu[1].shape, generator=torch.Generator().manual_seed(3),
                        dtype=imu[1].dtype)  # a log of another recording: unrelated rates
    with pytest.raises(ValueError, match=r"camera 0: the gyroscope's angular speeds do not "
                                         r"follow the camera's \(best correlation 0\.[0-2]"):
        calibration.camera_imu([_camera()], obs[:1], (imu[0], noise, imu[2]), **kw)


def _write_inputs(tmp_path, obs, imu, intrinsics=True):
    """Kalibr-format files of the simulated rig (times shifted by 100 s)."""
    t, g, a = (x.numpy() for x in imu)
    np.savetxt(tmp_path / "imu.txt", np.column_stack([t + 100.0, g, a]), fmt="%.9f",
               header="t gx gy gz ax ay az")
    (tmp_path / "imu.yaml").write_text(yaml.safe_dump({
        "gyroscope_noise_density": sim.GYRO_DENSITY, "gyroscope_random_walk": 1.9393e-05,
        "accelerometer_noise_density": sim.ACCEL_DENSITY,
        "accelerometer_random_walk": 3.0e-3, "update_rate": 200.0, "rostopic": "/imu0"}))
    (tmp_path / "target.yaml").write_text(
        "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n")
    chain = {}
    for i, (ti, p, u) in enumerate(obs):
        rows = np.column_stack([np.round((ti.numpy() + 100.0) * 1e9).astype(np.int64),
                                u.numpy(), p.numpy()])
        with open(tmp_path / f"cam{i}.csv", "w") as f:
            f.write("t_ns,u_px,v_px,X_m,Y_m,Z_m\n")
            for r in rows:
                f.write(f"{int(r[0])},{r[1]:.6f},{r[2]:.6f},{r[3]:.6f},{r[4]:.6f},{r[5]:.6f}\n")
        entry = _camera().to_kalibr()
        if not intrinsics:
            entry.pop("intrinsics")
            entry.pop("distortion_coeffs")
        chain[f"cam{i}"] = entry | {"rostopic": f"/cam{i}/image_raw"}
    (tmp_path / "camchain.yaml").write_text(yaml.safe_dump(chain))


def _argv(tmp_path, out, n=2):
    argv = ["calibrate", "--target", str(tmp_path / "target.yaml"), "--imu",
            str(tmp_path / "imu.txt"), "--imu-noise", str(tmp_path / "imu.yaml"),
            "--cameras", str(tmp_path / "camchain.yaml"), "--out", str(out),
            "--pixel-sigma", "0.3", "--quiet"]
    for i in range(n):
        argv += ["--corners", str(tmp_path / f"cam{i}.csv")]
    return argv


def test_cli_end_to_end(tmp_path, rolling_data, capsys):
    obs, imu = rolling_data
    _write_inputs(tmp_path, obs, imu)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    out = tmp_path / "out"
    assert main([*_argv(tmp_path, out), "--rolling-shutter", "--shared-time-offset",
                 "--bias", "constant"]) == 0
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    chain = yaml.safe_load((out / "camchain-imucam.yaml").read_text())
    assert sorted(chain) == ["cam0", "cam1"] and "T_cn_cnm1" in chain["cam1"]
    for i in range(2):
        cam = Camera.from_kalibr(chain[f"cam{i}"])
        torch.testing.assert_close(cam.params, _camera().params)
        T = np.array(chain[f"cam{i}"]["T_cam_imu"])
        truth = np.linalg.inv(sim.extrinsic_matrix(i))
        assert np.abs(T[:3, 3] - truth[:3, 3]).max() < 3e-3
        assert abs(chain[f"cam{i}"]["timeshift_cam_imu"] - OFFSET) < 2e-4
        assert chain[f"cam{i}"]["rostopic"] == f"/cam{i}/image_raw"
    assert chain["cam0"]["timeshift_cam_imu"] == chain["cam1"]["timeshift_cam_imu"]
    summary = json.loads((out / "summary.json").read_text())
    for key in ("extrinsics", "time_offsets", "line_delays", "gyro_bias", "accel_bias",
                "gravity"):
        assert set(summary["values"][key]) >= {"value", "std"}
    assert summary["bias"] == {"model": "constant", "interval_s": None, "edges_s": None,
                               "segments": 1}
    assert np.shape(summary["values"]["gyro_bias"]["std"]) == (3,)
    assert math.isclose(summary["values"]["line_delays"]["value"][0], LINE_DELAY,
                        rel_tol=0.05)
    assert set(summary["chi2"]) == {"reprojections_cam0", "reprojections_cam1", "gyro",
                                    "accel"}
    # each term's exact dof (its leverages): chi2/dof 1 within 3 standard deviations
    # sqrt(2 / dof), the IMU's plus the spline's model error (at most
    # _knot_spacing.EXCESS; chi15: the accelerometer read 1.28 with knots every 0.05 s)
    for k, v in summary["chi2"].items():
        spread = 3 * math.sqrt(2 / v["dof"])
        excess = 0.0 if k.startswith("reprojections") else _knot_spacing.EXCESS
        assert 1 - spread < v["chi2_per_dof"] < 1 + excess + spread, (k, v)
    assert len(summary["reprojection_rms_px"]) == 2
    pytest.importorskip("matplotlib")
    assert (out / "reprojection.png").stat().st_size > 10000
    assert (out / "imu.png").stat().st_size > 10000


def test_cli_calibrates_intrinsics_when_the_camchain_has_none(global_fit):
    from torch_dq.cli._calibrate import _cameras

    _, cams = sim.rig(duration=DURATION, offset=OFFSET, seed=2)
    obs = [tuple(_t(x) for x in cams[0])]
    entry = {"camera_model": "pinhole", "distortion_model": "radtan",
             "resolution": list(sim.RESOLUTION)}
    said = []
    cam, = _cameras([entry], obs, "camchain.yaml", said.append)
    assert said and "intrinsics" in said[0]
    assert cam.model == "pinhole-radtan" and cam.resolution == sim.RESOLUTION
    truth = _camera().params.numpy()
    assert np.abs(cam.params.numpy()[:4] - truth[:4]).max() < 2.0  # pixels
    assert np.abs(cam.params.numpy()[4:6] - truth[4:6]).max() < 0.02


def test_cli_user_errors(tmp_path, rolling_data, capsys):
    obs, imu = rolling_data
    _write_inputs(tmp_path, obs, imu)
    out = tmp_path / "out"
    assert main(_argv(tmp_path, out, n=1)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "one --corners or --images per camera" in err
    # an output that would overwrite an input (a camchain named like an output)
    (tmp_path / "summary.json").write_text("{}")
    argv = _argv(tmp_path, tmp_path)
    argv[argv.index("--cameras") + 1] = str(tmp_path / "summary.json")
    assert main(argv) == 2
    assert "would overwrite the input" in capsys.readouterr().err
    assert (tmp_path / "summary.json").read_text() == "{}"
    argv = _argv(tmp_path, out)
    argv[argv.index("--imu") + 1] = str(tmp_path / "missing.txt")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("torch-dq calibrate: error:") and err.count("\n") == 1
    (tmp_path / "bad.yaml").write_text("gyroscope_noise_density: -1\n")
    argv = _argv(tmp_path, out)
    argv[argv.index("--imu-noise") + 1] = str(tmp_path / "bad.yaml")
    assert main(argv) == 2
    assert "gyroscope_noise_density" in capsys.readouterr().err
    (tmp_path / "small.yaml").write_text(  # another grid: the corners are not its points
        "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.06\ntagSpacing: 0.3\n")
    argv = _argv(tmp_path, out)
    argv[argv.index("--target") + 1] = str(tmp_path / "small.yaml")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a corner of the target" in err, err
    for option, value in (("--bias", "linear"), ("--bias-interval", "0"),
                          ("--bias-interval", "abc"), ("--bias-interval", "inf")):
        assert main([*_argv(tmp_path, out), option, value]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"error: {option} must" in err, err
    (tmp_path / "nowalk.yaml").write_text(yaml.safe_dump({
        "gyroscope_noise_density": 1e-4, "accelerometer_noise_density": 1e-3}))
    argv = _argv(tmp_path, out)
    argv[argv.index("--imu-noise") + 1] = str(tmp_path / "nowalk.yaml")
    assert main(argv) == 2  # the default --bias random-walk needs the walks
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "gyroscope_random_walk" in err and "--bias" in err
    assert not out.exists()


WALK = (1e-3, 0.02)  # rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz): a drift visible in 3 s


def _segment_means(t, b, edges):
    seg = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    inside = (t >= edges[0]) & (t <= edges[-1])
    return np.stack([b[inside & (seg == k)].mean(0) for k in range(len(edges) - 1)])


def _drifting_rig():
    """The global-shutter rig (seed 1) whose biases drift as Wiener processes of intensity
    ``WALK`` (numpy): observations, IMU readings and the drifts ``(N, 3)``."""
    (t, g, a), cams = sim.rig(duration=DURATION, offset=OFFSET, seed=1)
    rng = np.random.default_rng(5)
    step = np.sqrt(np.diff(t, prepend=t[0]))[:, None]
    drift_g = np.cumsum(WALK[0] * step * rng.standard_normal(g.shape), 0)
    drift_a = np.cumsum(WALK[1] * step * rng.standard_normal(a.shape), 0)
    return [tuple(_t(x) for x in c) for c in cams], (t, g, a), (drift_g, drift_a)


def test_random_walk_biases_follow_a_drifting_bias():
    """Biases that drift as Wiener processes (numpy): with ``bias_walk`` the per-segment
    biases, the extrinsics and the offsets are within 4 standard deviations of the truth
    (the biases': each segment's mean of the simulated walk)."""
    obs, (t, g, a), (drift_g, drift_a) = _drifting_rig()
    res = calibration.camera_imu([_camera(), _camera()], obs,
                                 (_t(t), _t(g + drift_g), _t(a + drift_a)),
                                 gyro_noise=sim.GYRO_DENSITY, accel_noise=sim.ACCEL_DENSITY,
                                 pixel_sigma=0.3, bias_walk=WALK, bias_interval=0.25)
    edges = res.bias_edges.numpy()
    K = len(edges) - 1
    assert K == 13 and np.allclose(np.diff(edges), np.diff(edges)[0])
    assert res.gyro_bias.shape == res.accel_bias.shape == res.std["gyro_bias"].shape == (K, 3)
    z = _errors_over_std(res, 0.0)
    for key, truth in (("gyro_bias", sim.GYRO_BIAS + drift_g),
                       ("accel_bias", sim.ACCEL_BIAS + drift_a)):
        mean = _segment_means(t, truth, edges)
        z[key] = (getattr(res, key).numpy() - mean) / res.std[key].numpy()
        # the drift is resolved: it spans more than 4 standard deviations of a segment
        assert np.abs((mean - mean[0]) / res.std[key].numpy()).max() > 4, key
    for name, v in z.items():  # measured: 2.8 at most (accel_bias)
        assert np.all(np.isfinite(v)) and np.all(np.abs(v) < 4.0), (name, v)
    # each term's exact dof: chi2/dof 1 within 3 of its standard deviations sqrt(2 / dof),
    # plus the spline's model error (at most _knot_spacing.EXCESS with the default knots)
    # and the walk within a segment (walk^2 h / 6 over the per-sample variance: accel
    # 0.021, gyro 0.007). chi15: the accelerometer read 1.27 with knots every 0.05 s
    for term, walk, density in zip(res.terms[-2:], WALK, (sim.GYRO_DENSITY,
                                                         sim.ACCEL_DENSITY), strict=True):
        dof = float(res.estimate.dof[term])
        ratio = float(res.estimate.chi2[term]) / dof
        drift = walk ** 2 * 0.25 / 6 / (density ** 2 * 200.0)
        spread = 3 * math.sqrt(2 / dof)
        assert 1 - spread < ratio < 1 + _knot_spacing.EXCESS + drift + spread, (term, ratio)
    # the ties: the gyroscope term's rows at the inner edges read (b_k+1 - b_k) over the
    # walk's sigma over adjacent segment means, walk sqrt(2 h / 3)
    gyro = res.terms[-2]
    with torch.no_grad():
        r = gyro(res.trajectory).numpy()
    h = edges[1] - edges[0]
    ties = np.diff(res.gyro_bias.numpy(), axis=0) / (WALK[0] * np.sqrt(2 * h / 3))
    np.testing.assert_allclose(r[gyro.link.numpy()], ties, rtol=1e-9, atol=1e-12)


def test_random_walk_arguments(rolling_data):
    obs, imu = rolling_data
    kw = {"gyro_noise": 1e-4, "accel_noise": 1e-3}
    with pytest.raises(ValueError, match="camera_imu: expected bias_walk"):
        calibration.camera_imu([_camera()], obs[:1], imu, bias_walk=1e-3, **kw)
    with pytest.raises(ValueError, match=r"bias_walk\[1\]"):
        calibration.camera_imu([_camera()], obs[:1], imu, bias_walk=(1e-3, -1.0), **kw)
    with pytest.raises(ValueError, match="bias_interval"):
        calibration.camera_imu([_camera()], obs[:1], imu, bias_walk=(1e-3, 1e-2),
                               bias_interval=0.0, **kw)


def test_cli_random_walk_biases(tmp_path):
    """``calibrate`` with the default ``--bias random-walk`` on the drifting rig: the walks
    come from imu.yaml, summary.json holds K segments (edges on the IMU clock), each bias
    within 4 standard deviations of the simulated walk's mean over its segment."""
    obs, (t, g, a), (drift_g, drift_a) = _drifting_rig()
    _write_inputs(tmp_path, obs, tuple(_t(x) for x in (t, g + drift_g, a + drift_a)))
    (tmp_path / "imu.yaml").write_text(yaml.safe_dump({
        "gyroscope_noise_density": sim.GYRO_DENSITY, "gyroscope_random_walk": WALK[0],
        "accelerometer_noise_density": sim.ACCEL_DENSITY,
        "accelerometer_random_walk": WALK[1], "update_rate": 200.0}))
    out = tmp_path / "out"
    assert main([*_argv(tmp_path, out), "--bias-interval", "0.25"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    bias = summary["bias"]
    edges = np.array(bias["edges_s"]) - 100.0  # the CSVs' clock is shifted by 100 s
    K = bias["segments"]
    assert bias["model"] == "random-walk" and bias["interval_s"] == 0.25
    assert K == len(edges) - 1 == round((edges[-1] - edges[0]) / 0.25) and K >= 10
    for key, truth in (("gyro_bias", sim.GYRO_BIAS + drift_g),
                       ("accel_bias", sim.ACCEL_BIAS + drift_a)):
        value = np.array(summary["values"][key]["value"])
        std = np.array(summary["values"][key]["std"])
        assert value.shape == std.shape == (K, 3) and np.all(std > 0)
        z = (value - _segment_means(t, truth, edges)) / std
        assert np.all(np.abs(z) < 4.0), (key, z)  # measured: 2.8 at most (accel_bias)
    assert set(summary["chi2"]) == {"reprojections_cam0", "reprojections_cam1", "gyro",
                                    "accel"}
    assert "one row per segment" in summary["notes"][0]
    pytest.importorskip("matplotlib")
    assert (out / "imu.png").stat().st_size > 10000

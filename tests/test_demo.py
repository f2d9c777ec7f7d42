"""The demo (``python -m torch_dq demo``), its command line, and the synthetic knee model."""

import argparse
import inspect
import json
import math
import os
import re
import subprocess
import sys
import textwrap

import pytest
import torch

import torch_dq.curves as curves
import torch_dq.dualquat as dq
import torch_dq.losses as losses
import torch_dq.quat as quat
from torch_dq import nn
from torch_dq.__main__ import main
from torch_dq.cli._parsers import build_parser as _parser
from torch_dq.demo import FIGURES, PLOT_HINT, run_demo
from torch_dq.demo.knee import KneeModel, sample_poses

# Small, fast settings: the errors must still beat these bounds (noise: 1 deg, 1 mm per axis).
FAST = ["--steps", "20", "--samples", "50", "--quiet"]
MAX_ROT_MEAN_DEG, MAX_ROT_DEG = 1.0, 3.0
MAX_TRANS_MEAN_MM, MAX_TRANS_MM = 1.0, 3.0

ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
    + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else []))}


def _demo_parser() -> argparse.ArgumentParser:
    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["demo"]


def _summary(out) -> dict:
    with open(os.path.join(out, "summary.json"), encoding="utf-8") as fh:
        return json.load(fh)


def _check_errors(summary: dict) -> None:
    noise = summary["noise_errors"]
    assert set(summary["curves"]) == {"bspline", "bezier"}
    for name, curve in summary["curves"].items():
        e = curve["errors"]
        assert e["rot_deg_mean"] < MAX_ROT_MEAN_DEG, (name, e)
        assert e["rot_deg_max"] < MAX_ROT_DEG, (name, e)
        assert e["trans_mm_mean"] < MAX_TRANS_MEAN_MM, (name, e)
        assert e["trans_mm_max"] < MAX_TRANS_MM, (name, e)
        # the fitted curve is closer to the truth than the noisy samples are
        assert e["rot_deg_mean"] < 0.7 * noise["rot_deg_mean"], (name, e, noise)
        assert e["trans_mm_mean"] < 0.7 * noise["trans_mm_mean"], (name, e, noise)
        assert 1 <= curve["steps"] <= 20
        assert math.isfinite(curve["final_loss"])
        assert curve["final_loss"] <= 1.01 * curve["initial_loss"]  # init is near the optimum


# ----------------------------------------------------------------------------- demo

# No deprecated API and no warning from our own code; torch's own jit deprecation (emitted when
# forward-mode AD first loads its decompositions) is filtered as in setup.cfg.
@pytest.mark.filterwarnings("ignore:`torch.jit.script` is deprecated:DeprecationWarning")
@pytest.mark.filterwarnings("error")
def test_demo_writes_figures_and_summary(tmp_path):
    pytest.importorskip("matplotlib")
    assert main(["demo", "--out", str(tmp_path), *FAST]) == 0
    for name in FIGURES:
        path = tmp_path / name
        assert path.is_file() and path.stat().st_size > 10_000, name
    summary = _summary(tmp_path)
    assert summary["figures"] == list(FIGURES)
    assert summary["warnings"] == []
    assert summary["settings"]["n_samples"] == 50
    _check_errors(summary)


def test_demo_prints_table(tmp_path, capsys):
    args = ["demo", "--out", str(tmp_path), "--steps", "3", "--samples", "30", "--n-ctrl", "5",
            "--no-plots"]
    assert main(args) == 0
    text = capsys.readouterr().out
    for word in ("rotation (deg)", "translation (mm)", "B-spline", "Bézier", "noisy samples",
                 "summary.json", "total time"):
        assert word in text
    assert not any((tmp_path / name).exists() for name in FIGURES)
    summary = _summary(tmp_path)
    assert summary["figures"] == []
    assert summary["curves"]["bezier"]["degree"] == 4


def test_demo_options_reach_the_fit(tmp_path):
    args = ["demo", "--out", str(tmp_path), "--steps", "2", "--samples", "30", "--n-ctrl", "6",
            "--degree", "2", "--seed", "5", "--dtype", "float64", "--no-plots", "--quiet"]
    assert main(args) == 0
    s = _summary(tmp_path)
    assert s["settings"]["seed"] == 5 and s["settings"]["dtype"] == "float64"
    assert s["curves"]["bspline"]["degree"] == 2 and s["curves"]["bspline"]["n_ctrl"] == 6
    assert s["curves"]["bspline"]["steps"] <= 2


@pytest.mark.parametrize("args", [
    ["--degree", "8", "--n-ctrl", "8"],
    ["--steps", "0"],
    ["--samples", "4", "--n-ctrl", "6"],
    ["--rot-noise", "-1"],
    ["--optimizer", "newton"],
    ["--lr", "0"],
])
def test_demo_rejects_bad_arguments(args, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(tmp_path), *args])
    assert exc.value.code == 2
    assert "error" in capsys.readouterr().err


def test_demo_defaults_are_fits():
    """One source of truth: the demo and its command line take fit's defaults."""
    fit_defaults = {k: p.default for k, p in inspect.signature(nn.fit).parameters.items()}
    demo_defaults = {k: p.default for k, p in inspect.signature(run_demo).parameters.items()}
    for name in ("optimizer", "steps", "lr"):
        assert demo_defaults[name] == fit_defaults[name], name
    args = _demo_parser().parse_args(["--out", "x"])
    assert args.optimizer == fit_defaults["optimizer"] and args.steps == fit_defaults["steps"]
    assert args.lr is None


def test_demo_help_states_each_default_once():
    text = " ".join(_demo_parser().format_help().split())
    assert "(default: None)" not in text
    assert f"(default: {inspect.signature(nn.fit).parameters['steps'].default})" in text
    for entry in re.split(r"\s(?=--)", text):
        assert entry.count("(default:") <= 1, entry
    assert "1e-3" not in text and "0.001" not in text


def test_main_without_command_prints_help(capsys):
    assert main([]) == 2
    assert "demo" in capsys.readouterr().out


def test_cli_help_subprocess():
    res = subprocess.run([sys.executable, "-m", "torch_dq", "demo", "--help"],
                         capture_output=True, text=True, env=ENV, timeout=120)
    assert res.returncode == 0, res.stderr
    for option in ("--out", "--n-ctrl", "--degree", "--steps", "--seed", "--device",
                   "--no-plots"):
        assert option in res.stdout
    assert "torch_dq[plot]" in res.stdout


def test_console_script_entry_point():
    from importlib.metadata import entry_points

    eps = [ep for ep in entry_points(group="console_scripts") if ep.name == "torch-dq"]
    if not eps:
        pytest.skip("torch_dq is not installed with its entry points (pip install -e .)")
    assert eps[0].value == "torch_dq.__main__:run"  # reuse_memory, then main
    from torch_dq.__main__ import run
    assert eps[0].load() is run


def test_missing_matplotlib_prints_install_hint(tmp_path):
    """Without matplotlib: a clear hint, no figures, but the JSON and the table, exit 0."""
    code = textwrap.dedent(f"""
        import sys
        sys.modules["matplotlib"] = None  # any `import matplotlib...` now raises ImportError
        from torch_dq.__main__ import main
        sys.exit(main(["demo", "--out", {str(tmp_path)!r}, "--steps", "2", "--samples", "30",
                       "--n-ctrl", "5"]))
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=ENV,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert PLOT_HINT in res.stderr and "matplotlib" in res.stderr
    assert (res.stdout + res.stderr).count(PLOT_HINT) == 1  # said once (0.2 said it twice)
    assert res.stderr.strip().splitlines()[-1].startswith("torch-dq demo: warning: matplotlib")
    assert "rotation (deg)" in res.stdout
    summary = _summary(tmp_path)
    assert summary["figures"] == [] and PLOT_HINT in summary["warnings"][0]
    assert not any((tmp_path / name).exists() for name in FIGURES)


# ----------------------------------------------------------------------------- knee model

@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_knee_poses_are_unit(dtype):
    knee = KneeModel()
    t = torch.linspace(0.0, knee.duration_s, 101, dtype=dtype)
    x = knee.poses(t)
    assert x.shape == (101, 8) and x.dtype == dtype
    assert bool(dq.is_unit(x).all())


def test_knee_angles_in_plausible_ranges():
    knee = KneeModel()
    t = torch.linspace(0.0, knee.duration_s, 201, dtype=torch.float64)
    flexion, internal, varus = knee.angles(t)
    assert float(flexion[0]) == 0.0 and abs(float(flexion[-1]) - 120.0) < 1e-9
    assert bool((flexion[1:] > flexion[:-1]).all())  # flexes all the way, never at rest
    assert 0.0 <= float(internal.min()) and float(internal.max()) <= 20.0
    assert 15.0 <= float(internal[-1]) <= 20.0  # screw-home coupling, 15-20 deg
    assert float(internal[flexion <= 30.0].max()) > 0.6 * float(internal[-1])  # mostly early
    assert 0.0 <= float(varus.min()) and float(varus.max()) <= 5.0
    # the angles are those of the rotation: R = Rx(-flexion) Ry(varus) Rz(internal)
    euler = torch.rad2deg(quat.to_euler(knee.poses(t)[..., :4], "XYZ"))
    torch.testing.assert_close(euler, torch.stack((-flexion, varus, internal), -1))


def test_knee_translations_in_mm_and_rollback():
    knee = KneeModel()
    t = torch.linspace(0.0, knee.duration_s, 101, dtype=torch.float64)
    x = knee.poses(t)
    _, p = dq.to_rt(x)
    torch.testing.assert_close(p[0], torch.tensor([0.0, 0.0, -knee.axis_height_mm],
                                                  dtype=torch.float64))
    assert float(p.norm(dim=-1).max()) < 40.0  # the tibial plateau stays near the condyles
    # femoral rollback: the flexion axis (femoral origin) moves posteriorly on the tibia
    femur_in_tibia = dq.apply(dq.inv(x), torch.zeros(3, dtype=torch.float64))
    back = femur_in_tibia[:, 1]
    assert float(back[0]) == pytest.approx(0.0, abs=1e-9)
    assert -15.0 < float(back[-1]) < -5.0
    torch.testing.assert_close(knee.rollback(t[-1:]), torch.tensor([knee.rollback_mm],
                                                                   dtype=torch.float64))


def test_knee_screw_axis_is_medial_lateral_in_mid_flexion():
    knee = KneeModel()
    t = torch.linspace(0.5, 1.5, 11, dtype=torch.float64)
    x, dx = curves.velocity(knee.poses, t)  # forward-mode AD through the model
    xi = curves.twists(x, dx, frame="spatial")
    direction, moment, pitch = curves.screw_axis(xi[..., :3], xi[..., 3:])
    assert bool(torch.isfinite(direction).all() & torch.isfinite(pitch).all())
    tilt = torch.rad2deg(torch.acos(direction[:, 0].abs()))
    assert float(tilt.max()) < 20.0
    point = torch.linalg.cross(direction, moment, dim=-1)  # axis point nearest the origin
    assert float(point.norm(dim=-1).max()) < 15.0  # passes near the epicondylar midpoint


def test_sample_poses_seeded_and_noise_levels():
    knee = KneeModel()
    a = sample_poses(knee, n=2000, rot_noise_deg=1.0, trans_noise_mm=0.5,
                     generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    b = sample_poses(knee, n=2000, rot_noise_deg=1.0, trans_noise_mm=0.5,
                     generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    torch.testing.assert_close(a.poses, b.poses, rtol=0, atol=0)
    assert a.poses.shape == (2000, 8) and a.times.shape == (2000,)
    assert bool(dq.is_unit(a.poses).all())
    torch.testing.assert_close(a.truth, knee.poses(a.times))
    torch.testing.assert_close(a.poses, dq.from_rt(a.rotations, a.translations))
    # |N(0, s^2 I_3)| has mean 2 sqrt(2 / pi) s
    k = 2.0 * math.sqrt(2.0 / math.pi)
    rot = torch.rad2deg(losses.rotation_angle(a.poses, a.truth)).mean()
    trans = losses.translation_error(a.poses, a.truth).mean()
    assert float(rot) == pytest.approx(k * 1.0, rel=0.05)
    assert float(trans) == pytest.approx(k * 0.5, rel=0.05)
    c = sample_poses(knee, n=10, rot_noise_deg=0.0, trans_noise_mm=0.0, dtype=torch.float32)
    torch.testing.assert_close(c.poses, c.truth)


@pytest.mark.parametrize("kwargs, error", [
    ({"n": 1}, ValueError),
    ({"rot_noise_deg": -1.0}, ValueError),
    ({"trans_noise_mm": float("nan")}, ValueError),
    ({"dtype": torch.int64}, TypeError),
])
def test_sample_poses_rejects_bad_input(kwargs, error):
    with pytest.raises(error, match="sample_poses"):
        sample_poses(**kwargs)


def test_knee_model_rejects_bad_parameters():
    with pytest.raises(ValueError, match="flexion_deg"):
        KneeModel(flexion_deg=0.0)
    with pytest.raises(ValueError, match="duration_s"):
        KneeModel(duration_s=-1.0)

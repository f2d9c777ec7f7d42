"""Shared fixtures: dtypes, devices, batch shapes and the per-dtype tolerance table."""

import os

import pytest
import torch
from hypothesis import HealthCheck, settings

# Hypothesis profiles. "ci" (the default) is fixed and derandomized: 40 examples per
# property, the same ones on every run, so CI stays fast and reproducible. "long" explores
# 2000 fresh random examples per property; run it before a release or after touching the
# numerics:  HYPOTHESIS_PROFILE=long pytest tests/test_reliability.py tests/test_dualquat.py
settings.register_profile(
    "ci", max_examples=40, deadline=None, derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("long", max_examples=2000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

# One intra-op thread per test process: the README runs `pytest -n 2` on 2-core machines, and
# a second thread per worker only oversubscribes the cores (about 10x slower optimisation loops).
torch.set_num_threads(1)

DTYPES = (torch.float32, torch.float64)
DEVICES = ("cpu", "cuda") if torch.cuda.is_available() else ("cpu",)
BATCH_SHAPES = ((), (1,), (3, 1, 2))

# One tolerance table for the whole suite: absolute tolerances for quantities of unit scale.
TOL = {
    torch.float32: 2e-6,
    torch.float64: 1e-12,
}


@pytest.fixture(params=DTYPES, ids=lambda d: str(d).replace("torch.", ""))
def dtype(request):
    return request.param


@pytest.fixture(params=DEVICES)
def device(request):
    """The CPU, or the current GPU with its index (a tensor's device is ``cuda:0``, and
    ``torch.device("cuda")`` does not compare equal to it)."""
    if request.param == "cuda":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device(request.param)


@pytest.fixture(params=BATCH_SHAPES, ids=lambda s: "x".join(map(str, s)) or "scalar")
def batch_shape(request):
    return request.param


@pytest.fixture
def gen():
    """A seeded generator so every test draws the same samples run to run."""
    return torch.Generator().manual_seed(20261121)


# The files whose tests take ~12 s or more together (compilation, notebooks, mypy, the
# solves, the registry's second-order checks), longest first (whole-file process CPU times,
# one process, 2026-11-29; test_compile ~80 s down to test_split ~12 s; test_fitting 28 s;
# 2026-11-30, tests16: test_calib12_camera_imu 24 s on 4 s records, test_demo 20 s,
# test_calib12_cli 18 s, test_calib12_cameras 15 s, test_fit13_every_term 14 s,
# test_calib13_cli and test_mend14_cli_partial_intrinsics 12 s). They run first, so
# that `pytest -n 2` deals them to both workers at the start (xdist hands out tests in
# collection order) instead of one of them running alone at the end.
# Not test_docs.py: its build renders the notebooks that test_notebooks.py executed and
# cached, so it comes well after them (alphabetically, among the rest).
SLOW_FILES_FIRST = (
    "test_compile.py", "test_compile_float32_pyramid.py", "test_notebooks.py",
    "test_reliability.py", "test_modes.py",
    "test_second_order.py", "test_cumulative.py", "test_typing.py", "test_interp.py",
    "test_learner8_module.py", "test_fitting.py", "test_calib12_camera_imu.py",
    "test_term_jacobians.py",
    "test_learner8_pipeline.py", "test_calibration_cameras.py", "test_learner8_second_order.py",
    "test_float32.py", "test_outside8_stereo.py", "test_estimation_prior.py", "test_fit_cli.py",
    "test_demo.py", "test_camera_imu.py", "test_calib12_cli.py", "test_calib12_cameras.py",
    "test_fit13_every_term.py", "test_estimation_montecarlo.py", "test_honest_imu_poses.py",
    "test_span_jacobians.py", "test_kernels.py", "test_nn.py", "test_reprojections.py",
    "test_calib13_cli.py", "test_mend14_cli_partial_intrinsics.py",
    "test_continuous_time.py", "test_split.py", "test_estimation.py",
)


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(SLOW_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: files stay whole

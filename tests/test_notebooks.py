"""Execute every notebook in notebooks/ and check the figures each one writes.

The notebooks read ``TORCH_DQ_FIGURES`` (default ``figures``) for their output folder, so the
figures land in ``tmp_path`` and the repository stays clean, and ``TORCH_DQ_NOTEBOOK_QUICK=1``
for smaller sizes (fewer optimiser steps, a shorter recording: every cell still runs).
Skipped cleanly when nbclient, nbformat, ipykernel or matplotlib is missing.

Each executed notebook also goes into the jupyter cache of ``tests/test_docs.py``'s build
(``docs/_build/.jupyter_cache_tests``, keyed by the code cells), which then renders it
instead of executing it a second time (``tests/conftest.py`` runs this file among the
first, the docs well after it).
"""

import contextlib
import importlib.util
import pathlib

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("matplotlib")

NB_DIR = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
DOCS_CACHE = NB_DIR.parent / "docs" / "_build" / ".jupyter_cache_tests"

# The figures each notebook must write into $TORCH_DQ_FIGURES.
EXPECTED = {
    "01_dual_numbers_and_quaternions": ["01_dual_functions.png", "01_euler_vs_slerp.png"],
    "02_interpolation": ["02_norm_error.png", "02_screw_path.png"],
    "03_bezier_vs_bspline": ["03_fig1_components.png", "03_local_control.png"],
    "04_fitting_and_learning": ["04_fit_losses.png", "04_mlp_predictions.png"],
    "05_knee_axode": ["05_knee_angles.png", "05_axode.png"],
    "06_real_trajectory": ["06_heldout_errors.png", "06_kinematics.png", "06_imu.png"],
    "07_estimation": ["07_trajectory.png", "07_kinematics.png"],
    "08_camera_rig": ["08_extrinsics.png", "08_residuals.png"],
    "09_deblurring": ["09_deblur_images.png", "09_deblur_loss.png"],
    "10_calibration": ["10_detection.png", "10_errors.png", "10_reprojection.png", "10_imu.png"],
}


def test_every_notebook_is_listed():
    found = sorted(p.stem for p in NB_DIR.glob("*.ipynb"))
    assert found == sorted(EXPECTED), "add new notebooks (and their figures) to EXPECTED"


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_stored_without_outputs(name):
    nb = nbformat.read(NB_DIR / f"{name}.ipynb", as_version=4)
    nbformat.validate(nb)
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, (
                f"{name}: clear the outputs before committing")


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_notebook_executes_and_writes_figures(name, tmp_path, monkeypatch):
    figures = tmp_path / "figures"
    monkeypatch.setenv("TORCH_DQ_FIGURES", str(figures))
    monkeypatch.setenv("TORCH_DQ_NOTEBOOK_QUICK", "1")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # the kernel shares the cores with pytest -n
    nb = nbformat.read(NB_DIR / f"{name}.ipynb", as_version=4)
    # "immediate": kill the kernel once the last cell ran, instead of a graceful shutdown
    # request that waits ~3 s per notebook for nothing (every cell's output is in already)
    client = nbclient.NotebookClient(nb, timeout=180, kernel_name="python3",
                                     shutdown_kernel="immediate",
                                     resources={"metadata": {"path": str(NB_DIR)}})
    client.execute()  # raises CellExecutionError on the first failing cell
    errors = [out for cell in nb.cells if cell.cell_type == "code"
              for out in cell.get("outputs", []) if out.get("output_type") == "error"]
    assert not errors
    for fig in EXPECTED[name]:
        path = figures / fig
        assert path.is_file() and path.stat().st_size > 10_000, f"{name} did not write {fig}"
    _share_with_the_docs_build(nb, NB_DIR / f"{name}.ipynb")


def _share_with_the_docs_build(nb, path):
    """Store the executed notebook where the docs test's build looks it up (myst-nb's
    ``cache`` mode); without the docs extra, or while that build holds the cache's database,
    the build executes the notebook itself."""
    if importlib.util.find_spec("jupyter_cache") is None:
        return
    from jupyter_cache import get_cache
    from jupyter_cache.base import CacheBundleIn
    from sqlalchemy.exc import OperationalError
    stored = nbformat.read(path, as_version=4)  # the cache's key: the file's cells, metadata
    for cell, run in zip(stored.cells, nb.cells, strict=True):
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = run.outputs, run.execution_count
    with contextlib.suppress(OperationalError):
        get_cache(str(DOCS_CACHE)).cache_notebook_bundle(
            CacheBundleIn(stored, str(path)), check_validity=False, overwrite=True)

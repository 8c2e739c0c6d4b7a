"""notebooks/analysis.ipynb runs top to bottom on a short simulation, so it cannot rot; and it is
committed without outputs."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

import nbclient
import nbformat

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "analysis.ipynb"
#: Steps of the simulated drive the notebook benchmarks in the test (its default is 600).
TEST_FRAMES = 80
#: Figures the notebook draws on one sequence: accuracy, EKF vs smoother trajectory, map
#: differences, NEES over time, speed.
MIN_FIGURES = 5


def _outputs(nb, kind: str) -> list:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
            if kind in o.get("data", {})]


def test_notebook_is_committed_without_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    dirty = [i for i, c in enumerate(nb.cells)
             if c.cell_type == "code" and (c.outputs or c.execution_count is not None)]
    assert not dirty, f"cells {dirty} carry outputs: run python tools/strip_notebook.py {NOTEBOOK}"


def test_notebook_parameter_cell_comes_first():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    first = next(c for c in nb.cells if c.cell_type == "code")
    assert "parameters" in first.metadata.get("tags", []), "first code cell must be tagged 'parameters'"
    for name in ("RESULTS_DIR", "FRAMES", "ESTIMATORS"):
        assert name in first.source


@pytest.mark.regression
@pytest.mark.slow
def test_notebook_executes_on_the_quick_benchmark(monkeypatch, tmp_path):
    monkeypatch.setenv("VISLAM_NB_FRAMES", str(TEST_FRAMES))
    monkeypatch.setenv("VISLAM_NB_JOBS", "2")
    monkeypatch.delenv("VISLAM_NB_RESULTS_DIR", raising=False)
    monkeypatch.delenv("VISLAM_NB_ESTIMATORS", raising=False)
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the notebook's benchmark folder lands here
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOK.parent)}}
    )
    t0 = time.perf_counter()
    client.execute()  # raises CellExecutionError naming the cell on any error
    wall = time.perf_counter() - t0
    print(f"notebook executed on {TEST_FRAMES} frames in {wall:.1f} s")

    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors, f"error outputs: {[e.get('ename') for e in errors]}"
    figures = _outputs(nb, "image/png")
    assert len(figures) >= MIN_FIGURES, f"{len(figures)} figures drawn, expected at least {MIN_FIGURES}"
    tables = "\n".join(o["data"]["text/markdown"] for o in _outputs(nb, "text/markdown"))
    for estimator in ("dead-reckoning", "ekf-joint", "smoother"):
        assert estimator in tables, f"{estimator} missing from the notebook's tables"
    assert "failed:" not in tables, "an estimator failed in the notebook's benchmark"
    assert "inside ±3σ" in tables and "frames/s" in tables
    assert list(tmp_path.glob("vislam-analysis-*/bench/results.json")), "benchmark folder not written"
    assert "re-ran" not in _streams(nb), "the notebook re-ran estimators the benchmark saved"


def _streams(nb) -> str:
    return "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.outputs
                   if o.output_type == "stream")


@pytest.mark.regression
@pytest.mark.slow
def test_notebook_executes_on_a_folder_without_ground_truth(monkeypatch, tmp_path):
    """A results folder of a drive file without ground truth (as 0034 is): the notebook loads
    the saved estimates, says that accuracy needs ground truth, and draws the rest."""
    from vislam.ekf.config import FilterConfig
    from vislam.eval.bench_output import run_benchmark
    from vislam.eval.drives import collect_sequences
    from vislam.eval.sim_files import write_simulation
    from vislam.eval.simulate import SimConfig, simulate

    paths = write_simulation(simulate(SimConfig(seed=2, n_frames=TEST_FRAMES)), tmp_path / "data", "nogt")
    for f in (tmp_path / "data" / "groundtruth").glob("*"):
        f.unlink()
    seqs = collect_sequences([str(paths["data"])])
    assert seqs[0].gt is None
    out = run_benchmark(seqs, ["dead-reckoning", "ekf-joint", "ekf-invariant", "smoother"], FilterConfig(),
                        tmp_path / "bench", jobs=2, show_progress=False).out_dir
    assert sorted(p.name for p in (out / "nogt").glob("*.estimate.npz")) == [
        "dead-reckoning.estimate.npz", "ekf-invariant.estimate.npz", "ekf-joint.estimate.npz",
        "smoother.estimate.npz"]
    monkeypatch.setenv("VISLAM_NB_RESULTS_DIR", str(out))
    monkeypatch.setenv("MPLBACKEND", "module://matplotlib_inline.backend_inline")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    streams = _streams(nb)
    assert "re-ran" not in streams
    assert "no drive in this folder has ground truth" in streams
    assert len(_outputs(nb, "image/png")) >= 3
    tables = "\n".join(o["data"]["text/markdown"] for o in _outputs(nb, "text/markdown"))
    assert "ekf-invariant" in tables and "inside ±3σ" in tables

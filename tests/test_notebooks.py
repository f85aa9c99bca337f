"""The notebooks: stored without outputs, import only kfusion, and run from a clean kernel on
small data (KFUSION_NOTEBOOK_QUICK=1)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOK_DIRECTORY = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIRECTORY.glob("*.ipynb"))
CELL_TIMEOUT_S = 300
FULL_BROAD_NOTEBOOKS = {"03_broad_real_data"}
"""Notebooks that read the BROAD ``.mat`` trials: they skip without the full set."""
RUN_CASES = [pytest.param(path, id=path.stem,
                          marks=[pytest.mark.broad] if path.stem in FULL_BROAD_NOTEBOOKS else [])
             for path in NOTEBOOKS]


def code_cells(path: Path) -> list:
    notebook = nbformat.read(path, as_version=4)
    return [cell for cell in notebook.cells if cell.cell_type == "code"]


def test_the_four_notebooks_exist():
    assert [path.name for path in NOTEBOOKS] == [
        "01_paper_experiments.ipynb", "02_sweep_analysis.ipynb", "03_broad_real_data.ipynb",
        "04_calibrate_a_recording.ipynb"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_is_stored_with_outputs_stripped(path):
    notebook = nbformat.read(path, as_version=4)
    nbformat.validate(notebook)
    for cell in code_cells(path):
        assert cell.outputs == [] and cell.execution_count is None, cell.source[:60]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_imports_only_kfusion(path):
    for cell in code_cells(path):
        for node in ast.walk(ast.parse(cell.source)):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                modules = [node.module or ""]
            else:
                continue
            assert all(module.split(".")[0] == "kfusion" for module in modules), modules


@pytest.mark.parametrize("path", RUN_CASES)
def test_notebook_runs_from_a_clean_kernel(path, tmp_path, monkeypatch):
    monkeypatch.setenv("KFUSION_NOTEBOOK_QUICK", "1")
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the sweeps' temporary folders
    notebook = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(notebook, timeout=CELL_TIMEOUT_S, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError on any error
    outputs = [output for cell in notebook.cells if cell.cell_type == "code"
               for output in cell.outputs]
    assert not [output for output in outputs if output.output_type == "error"]
    images = [output for output in outputs if "image/png" in output.get("data", {})]
    assert images, "expected the notebook to show figures"
    assert "quick" in "".join(output.get("text", "") for output in outputs) or \
        path.stem != "01_paper_experiments"

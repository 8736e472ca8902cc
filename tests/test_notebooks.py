"""The analysis notebooks run top to bottom on the bundled sample."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))
#: Figures each notebook shows: each must reach the page as a PNG, once.
IMAGES = {"01_dataset_exploration": 2, "02_results_analysis": 2, "03_llm_backends": 0}


def test_there_are_notebooks() -> None:
    assert [p.name for p in NOTEBOOKS] == [
        "01_dataset_exploration.ipynb",
        "02_results_analysis.ipynb",
        "03_llm_backends.ipynb",
    ]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.stem)
def test_notebook_runs(path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import nbformat
    from nbclient import NotebookClient

    # The kernel is this interpreter's (its folder first on PATH), run from the checkout, with
    # the session's cache (SKYVLN_EVAL_CACHE is set by the test session). Agg, not the
    # inline backend Jupyter picks: the toolkit's figures must show without it.
    monkeypatch.setenv("PATH", str(Path(sys.executable).parent) + os.pathsep + os.environ["PATH"])
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("SKYVLN_EVAL_NOTEBOOK_OUTPUT", str(tmp_path))
    notebook = nbformat.read(path, as_version=4)
    client = NotebookClient(
        notebook, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(REPO)}}
    )
    client.execute()
    errors = [
        output
        for cell in notebook.cells
        if cell.cell_type == "code"
        for output in cell.get("outputs", [])
        if output.get("output_type") == "error"
    ]
    assert not errors
    assert any(cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code")
    # A figure without a PNG representation shows as text ('<Figure size ... with 13 Axes>').
    images = [
        output
        for cell in notebook.cells
        if cell.cell_type == "code"
        for output in cell.get("outputs", [])
        if "image/png" in output.get("data", {})
    ]
    assert len(images) == IMAGES[path.stem]
    # Its files are in its own output folder (they were in temporary folders, left behind).
    assert any((tmp_path / path.stem).iterdir())


def test_notebooks_read_runs_checked() -> None:
    # An audit found notebook 03 reading results.jsonl with read_results: a run stopped by
    # refused credentials (HTTP 401) gave its stop row as an 'error' episode and hid the
    # episodes that never ran. run_results checks the run covers its episodes.
    import nbformat

    for path in NOTEBOOKS:
        code = "\n".join(
            cell.source for cell in nbformat.read(path, as_version=4).cells
            if cell.cell_type == "code"
        )  # fmt: skip
        assert "read_results(" not in code, path.name

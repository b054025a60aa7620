"""Every notebook executes top to bottom in SMALL mode (nbclient) and shows at least one picture."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((Path(__file__).resolve().parents[2] / "notebooks").glob("*.ipynb"))
# Run by default: about 8-15 s each on 2 busy cores. 04 trains four small runs (~25 s): slow.
DEFAULT = {"01_quickstart.ipynb", "02_predictions.ipynb", "03_disentanglement.ipynb"}


def test_notebooks_are_stored_without_outputs():
    assert NOTEBOOKS, "no notebooks found"
    for path in NOTEBOOKS:
        notebook = nbformat.read(path, as_version=4)
        nbformat.validate(notebook)
        assert not any(cell.get("outputs") for cell in notebook.cells if cell.cell_type == "code"), path.name
        parameters = [cell for cell in notebook.cells if "parameters" in cell.metadata.get("tags", [])]
        assert len(parameters) == 1 and "SMALL" in parameters[0].source, path.name


@pytest.mark.parametrize(
    "path",
    [pytest.param(path, id=path.stem, marks=[] if path.name in DEFAULT else [pytest.mark.slow]) for path in NOTEBOOKS],
)
def test_notebook_executes_in_small_mode(path, tmp_path, monkeypatch):
    monkeypatch.setenv("SB3_EF_SMALL", "1")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    monkeypatch.setenv("MUJOCO_GL", "egl")
    notebook = nbformat.read(path, as_version=4)
    resources = {"metadata": {"path": str(tmp_path)}}  # the kernel's working directory: saved files go there
    NotebookClient(notebook, timeout=600, kernel_name="python3", resources=resources).execute()
    images = [
        output
        for cell in notebook.cells
        for output in cell.get("outputs", [])
        if "image/png" in output.get("data", {})
    ]
    assert images, f"{path.name} showed no picture"

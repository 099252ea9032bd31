"""The notebooks run top to bottom (nbclient), with budgets shrunk by WRL_NOTEBOOK_QUICK=1,
so a notebook broken by a change elsewhere fails the test suite. The kernels inherit the session's
``XLA_FLAGS`` (LLVM level 0, tests/conftest.py): quick mode checks that every cell runs, not what it
measures, and is mostly compiling."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"


@pytest.mark.parametrize("name", ["quickstart.ipynb", "failure_modes.ipynb", "generalization.ipynb", "fleet.ipynb",
                                  "continuous.ipynb"])
def test_notebook_runs(name, tmp_path, monkeypatch):
    monkeypatch.setenv("WRL_NOTEBOOK_QUICK", "1")  # the kernel inherits this process's environment
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # the notebooks' output folders (tempfile) go with the test's
    # The kernel runs in tmp_path: make the checkout importable whether or not it is pip-installed.
    root = str(NOTEBOOKS.parent)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p))
    book = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = nbclient.NotebookClient(book, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    errors = [out for cell in book.cells if cell.cell_type == "code" for out in cell.get("outputs", [])
              if out.get("output_type") == "error"]
    assert not errors
    outputs = [out for cell in book.cells if cell.cell_type == "code" for out in cell.get("outputs", [])]
    text = "".join(out.get("text", "") for out in outputs)
    assert "quick mode" in text or name not in ("quickstart.ipynb", "generalization.ipynb", "fleet.ipynb", "continuous.ipynb")


def test_committed_notebooks_have_no_outputs():
    # Outputs (images, GIFs) would bloat the repository and go stale: commit notebooks cleared.
    for path in NOTEBOOKS.glob("*.ipynb"):
        book = nbformat.read(path, as_version=4)
        assert all(not cell.get("outputs") for cell in book.cells if cell.cell_type == "code"), path.name

"""The notebooks run top to bottom (nbclient), with budgets shrunk by WRL_NOTEBOOK_QUICK=1,
so a notebook broken by a change elsewhere fails the test suite. The kernel inherits the session's
``XLA_FLAGS`` (LLVM level 0, tests/conftest.py): quick mode checks that every cell runs, not what it
measures, and is mostly compiling.

The five notebooks share one kernel (``kernel``), its namespace cleared between them (``%reset -f``), so
each still starts from no names of its own and fails on a name it forgot to define or import. What they
share is what a Python process keeps anyway: imported modules and JAX's caches of compiled programs. A
kernel and its imports of JAX, wrl_jax and matplotlib cost about 3.5 s of CPU, paid once instead of five
times."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
jupyter_client = pytest.importorskip("jupyter_client")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
QUICK_BANNER = ("quickstart.ipynb", "generalization.ipynb", "fleet.ipynb", "continuous.ipynb")
"""Notebooks that print "quick mode" when WRL_NOTEBOOK_QUICK=1 (their budgets depend on it)."""


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    """One Python kernel for the module, started in a folder of its own with quick mode on; its temporary files
    (the notebooks' output folders, made with tempfile) go to that folder."""
    folder = tmp_path_factory.mktemp("notebooks")
    root = str(NOTEBOOKS.parent)  # the checkout importable whether or not it is pip-installed
    env = {**os.environ, "WRL_NOTEBOOK_QUICK": "1", "MPLBACKEND": "Agg", "TMPDIR": str(folder),
           "PYTHONPATH": os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)}
    manager = jupyter_client.KernelManager(kernel_name="python3")
    manager.start_kernel(cwd=str(folder), env=env)
    try:
        yield manager
    finally:
        manager.shutdown_kernel(now=True)


def run_notebook(book, manager):
    """Executes ``book`` in place on the shared kernel, after clearing the previous notebook's names and figures."""
    reset = nbformat.v4.new_code_cell("%reset -f\nimport matplotlib.pyplot\nmatplotlib.pyplot.close('all')")
    cleared = nbformat.v4.new_notebook(cells=[reset], metadata=book.metadata)
    for notebook in (cleared, book):
        nbclient.NotebookClient(notebook, km=manager, timeout=300, kernel_name="python3").execute()
    return [out for cell in book.cells if cell.cell_type == "code" for out in cell.get("outputs", [])]


@pytest.mark.parametrize("name", ["quickstart.ipynb", "failure_modes.ipynb", "generalization.ipynb", "fleet.ipynb",
                                  "continuous.ipynb"])
def test_notebook_runs(name, kernel):
    book = nbformat.read(NOTEBOOKS / name, as_version=4)
    outputs = run_notebook(book, kernel)
    assert not [out for out in outputs if out.get("output_type") == "error"]
    text = "".join(out.get("text", "") for out in outputs)
    assert "quick mode" in text or name not in QUICK_BANNER


def test_a_name_left_by_an_earlier_notebook_is_not_there(kernel):
    """The reset between notebooks: a notebook that used a name it never defined would fail here as it fails a
    user in a fresh kernel."""
    first = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("left_behind = 1")])
    run_notebook(first, kernel)
    second = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("left_behind")])
    with pytest.raises(nbclient.exceptions.CellExecutionError, match="NameError"):
        run_notebook(second, kernel)


def test_committed_notebooks_have_no_outputs():
    # Outputs (images, GIFs) would bloat the repository and go stale: commit notebooks cleared.
    for path in NOTEBOOKS.glob("*.ipynb"):
        book = nbformat.read(path, as_version=4)
        assert all(not cell.get("outputs") for cell in book.cells if cell.cell_type == "code"), path.name

"""Execute every notebook in notebooks/ on small grids, and check they are stored clean.

Each notebook asserts the numbers it reproduces (the paper's estimates, the printed
polynomial's failure, the layers' sharpness, the kinematic mean flow), so running it is
a test. The notebooks read ``SPOTPDE_NOTEBOOK_SMALL=1`` and switch to coarse grids and
short runs; the whole set takes about a minute on two cores.
"""

from __future__ import annotations

import os
from pathlib import Path

import nbclient
import nbformat
import pytest

NOTEBOOKS_DIR = Path(__file__).resolve().parent.parent / "notebooks"
NOTEBOOKS = sorted(NOTEBOOKS_DIR.glob("*.ipynb"))
#: seconds allowed per cell (the slowest cell takes a few seconds on the small grids)
CELL_TIMEOUT = 300


def _ids(paths):
    return [p.stem for p in paths]


def test_notebooks_exist():
    names = {p.name for p in NOTEBOOKS}
    for expected in ("paper_estimates.ipynb", "velocity_correlations.ipynb",
                     "layered_silo.ipynb", "kinematic_rule.ipynb", "density_waves.ipynb",
                     "cage_breaking.ipynb"):
        assert expected in names, f"notebooks/{expected} is missing"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_stored_without_outputs(path):
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    dirty = [i for i, c in enumerate(nb.cells) if c.cell_type == "code"
             and (c.get("outputs") or c.get("execution_count") is not None)]
    assert not dirty, f"{path.name}: cells {dirty} have outputs or execution counts; clear them"
    assert nb.metadata.get("kernelspec", {}).get("name") == "python3"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_runs(path, monkeypatch):
    # the kernel inherits the environment of this process
    monkeypatch.setenv("SPOTPDE_NOTEBOOK_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    # one numerical thread per kernel: the suite runs in parallel on two cores
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
        monkeypatch.setenv(var, os.environ.get(var, "1"))
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb, timeout=CELL_TIMEOUT, kernel_name="python3", allow_errors=False,
        resources={"metadata": {"path": str(NOTEBOOKS_DIR)}})
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as exc:
        # the message holds the failing cell's source and traceback
        pytest.fail(f"{path.name} failed:\n{exc}", pytrace=False)

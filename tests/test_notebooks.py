"""The notebooks in notebooks/: stored without outputs, and each runs top to bottom.

Each notebook is executed with nbclient on a kernel of the interpreter running
the tests, at ``RFMITSUBA_NOTEBOOK_SIZE=tiny``, writing its files under a
temporary ``RFMITSUBA_NOTEBOOK_OUT``; any cell error fails the test.
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import nbformat
import pytest

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
EXPECTED = ["01_author_a_scene.ipynb", "02_ground_truth.ipynb", "03_two_stage_fit.ipynb",
            "04_compare_methods.ipynb"]
#: seconds allowed per cell at tiny size (the whole notebook run should stay under ~4 minutes)
CELL_TIMEOUT = 300


def _present() -> list[str]:
    return sorted(p.name for p in NOTEBOOKS.glob("*.ipynb"))


def test_the_notebooks_are_there():
    present = _present()
    missing = [n for n in EXPECTED if n not in present]
    assert not missing, f"missing notebooks: {missing}"


@pytest.mark.parametrize("name", _present())
def test_stored_without_outputs(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    nbformat.validate(nb)
    dirty = [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and (c.outputs or c.execution_count)]
    assert not dirty, f"{name}: cells {dirty} carry outputs; clear them before committing"


@pytest.mark.parametrize("name", _present())
def test_first_cell_reads_the_size_switch(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    first_code = next(c for c in nb.cells if c.cell_type == "code")
    assert "RFMITSUBA_NOTEBOOK_SIZE" in first_code.source


@pytest.fixture(scope="module")
def kernel_name(tmp_path_factory) -> str:
    """A kernelspec that runs this interpreter (whatever is installed as 'python3')."""
    root = tmp_path_factory.mktemp("jupyter")
    spec = root / "kernels" / "rfmitsuba-test"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "rfmitsuba test", "language": "python"}))
    old = os.environ.get("JUPYTER_PATH")
    os.environ["JUPYTER_PATH"] = str(root) + (os.pathsep + old if old else "")
    yield "rfmitsuba-test"
    if old is None:
        os.environ.pop("JUPYTER_PATH", None)
    else:
        os.environ["JUPYTER_PATH"] = old


@pytest.mark.slow
@pytest.mark.parametrize("name", _present())
def test_runs_top_to_bottom_at_tiny_size(name, kernel_name, tmp_path, monkeypatch):
    from nbclient import NotebookClient

    monkeypatch.setenv("RFMITSUBA_NOTEBOOK_SIZE", "tiny")
    monkeypatch.setenv("RFMITSUBA_NOTEBOOK_OUT", str(tmp_path / "out"))
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend draws headless
    monkeypatch.setenv("RFMITSUBA_QUIET", "1")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = NotebookClient(nb, kernel_name=kernel_name, timeout=CELL_TIMEOUT,
                            resources={"metadata": {"path": str(tmp_path)}})
    t0 = time.perf_counter()
    client.execute()  # raises CellExecutionError naming the cell on any error
    print(f"{name}: {time.perf_counter() - t0:.1f} s at tiny size")
    images = sum(1 for c in nb.cells if c.cell_type == "code" for o in c.outputs
                 if o.get("output_type") in ("display_data", "execute_result") and "image/png" in o.get("data", {}))
    assert images >= 1, f"{name}: no figure was shown"

"""The example notebook (examples/notebook/identify.ipynb), executed as a user would run it.

The notebook identifies examples/paper-sample, displays the result (its ``_repr_html_``),
exports it to pandas and python-control, and plots the identified plant's step response. The
test executes the committed notebook's cells again in a fresh kernel (nbclient, the well-kept
runner Jupyter itself uses) and checks what they display against an identification made here.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

for _name in ("nbclient", "nbformat", "ipykernel", "control", "pandas"):
    pytest.importorskip(_name, reason=f"the notebook test needs {_name} (the test extra)")

import nbformat  # noqa: E402
from nbclient import NotebookClient  # noqa: E402

import phoid  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOK = ROOT / "examples" / "notebook" / "identify.ipynb"
NUMBER = re.compile(r"[-+]?\d+\.\d+(?:e[-+]?\d+)?")

pytestmark = pytest.mark.slow


def _outputs(cell, kind: str) -> list[str]:
    return [o["data"][kind] for o in cell.get("outputs", [])
            if o.get("output_type") in ("execute_result", "display_data") and kind in o["data"]]


@pytest.fixture(scope="module")
def executed():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:  # run from the sources alone: nothing of the committed outputs kept
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    NotebookClient(nb, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    return nb


@pytest.fixture(scope="module")
def reference():
    return phoid.identify(phoid.read_experiment(ROOT / "examples" / "paper-sample"))


def _cell(nb, source_start: str):
    cells = [c for c in nb.cells if c.cell_type == "code" and c.source.startswith(source_start)]
    assert len(cells) == 1, source_start
    return cells[0]


def test_the_notebook_runs_without_errors(executed):
    errors = [o for c in executed.cells if c.cell_type == "code" for o in c.outputs
              if o.get("output_type") == "error"]
    assert errors == []


def test_the_displayed_result_shows_the_estimates(executed, reference):
    """The ``result`` cell's HTML holds m, c, k to the precision of their stderr (the display
    rounds an estimate to its stderr's leading digits, so within stderr/2 of the value)."""
    html = _outputs(_cell(executed, "result = phoid.identify"), "text/html")
    assert len(html) == 1
    numbers = [float(x) for x in NUMBER.findall(html[0])]
    for est in (reference.m, reference.c, reference.k):
        assert any(abs(x - est.value) <= est.stderr / 2 for x in numbers), est
        assert any(abs(x - est.stderr) <= est.stderr / 10 for x in numbers), est
    # and the plain text a terminal shows is the short repr, not the dataclass dump
    text = _outputs(_cell(executed, "result = phoid.identify"), "text/plain")[0]
    assert len(text) < 400 and text.startswith("Identification(")


def test_the_experiment_set_and_the_tables_display(executed, reference):
    assert _outputs(_cell(executed, "%matplotlib inline"), "text/html")
    estimates = _outputs(_cell(executed, "frames = result.to_pandas()"), "text/html")[0]
    assert f"{reference.k.value:.4f}"[:5] in estimates  # 63.98…: pandas' own float rendering
    assert _outputs(_cell(executed, "frames.runs.head()"), "text/html")


def test_the_step_response_is_plotted(executed, reference):
    cell = _cell(executed, "import control")
    assert len(_outputs(cell, "image/png")) == 1
    stream = "".join(o.get("text", "") for o in cell.outputs if o["output_type"] == "stream")
    # python-control prints the transfer function's denominator m s^2 + c s + k to 4
    # significant digits (so within a relative 5e-4 of each coefficient)
    coeffs = [float(x) for x in re.findall(r"\d+(?:\.\d+)?(?:e[-+]?\d+)?", stream)]
    for est in (reference.m, reference.c, reference.k):
        assert any(abs(x - est.value) <= 5e-4 * est.value for x in coeffs), (est, stream)


def test_the_committed_notebook_is_the_generators_executed_output():
    """examples/notebook/make_notebook.py writes the notebook: the committed file has its cells
    (same sources) and their outputs (executed), so the page a user opens is not stale."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_notebook", ROOT / "examples" / "notebook" / "make_notebook.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    committed = nbformat.read(NOTEBOOK, as_version=4)
    assert [c.source for c in committed.cells] == [c.source for c in module.CELLS]
    assert all(c.outputs for c in committed.cells if c.cell_type == "code")

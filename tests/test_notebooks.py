"""The notebooks are part of the product: each one is executed (nbclient, kernel
python3) and must run without error. They check their own numbers with asserts
against closed forms and the joint-based reference. Notebooks that take more than
about 40 s, and the joint-friction notebook (~25 s), are marked slow (run with ``pytest -m slow``)."""

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
SLOW = {
    "02_watt_sixbar_dynamics.ipynb",
    "03_class4_kinetostatics.ipynb",
    "04_synthesis_and_sensitivities.ipynb",
    "05_vmapped_sweeps.ipynb",
    "08_joint_friction.ipynb",  # ~25 s; the friction itself is checked in test_friction.py
}


def _params():
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        marks = [pytest.mark.slow] if path.name in SLOW else []
        yield pytest.param(path, id=path.stem, marks=marks)


@pytest.mark.parametrize("path", list(_params()))
def test_notebook_runs(path):
    nb = nbformat.read(path, as_version=4)
    assert all(not cell.get("outputs") for cell in nb.cells if cell.cell_type == "code"), "store notebooks without outputs"
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()


def test_runtime_notebook_runs_without_benchmark_results(tmp_path):
    """06 reads benchmarks/results/*.json; with none there it must still run and say so."""
    (tmp_path / "benchmarks").mkdir()
    (tmp_path / "notebooks").mkdir()
    nb = nbformat.read(NOTEBOOKS / "06_runtime_vs_error.ipynb", as_version=4)
    client = nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path / "notebooks")}})
    client.execute()
    text = "".join(o.get("text", "") for cell in nb.cells for o in cell.get("outputs", []))
    assert "work_precision.json is missing" in text


def test_every_notebook_is_tested():
    names = {p.name for p in NOTEBOOKS.glob("*.ipynb")}
    expected = {"01_roberts_straight_line", "02_watt_sixbar_dynamics", "03_class4_kinetostatics",
                "04_synthesis_and_sensitivities", "05_vmapped_sweeps", "06_runtime_vs_error", "07_jansen_leg",
                "08_joint_friction"}
    assert {n + ".ipynb" for n in expected} <= names

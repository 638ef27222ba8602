"""The example notebook runs from top to bottom (nbclient), and what it
prints is what the recording holds."""

import re
from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "plr.ipynb"


def test_example_notebook_executes(data_dir, monkeypatch):
    monkeypatch.setenv("GAZELIGHT_DATA_DIR", str(data_dir))
    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3",
                   resources={"metadata": {"path": str(NOTEBOOK.parent)}}).execute()
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    rows = sum(1 for _ in open(data_dir / "eye/piprkit-plr/pupil_trace.csv")) - 1
    assert f"csv {rows} samples per eye" in text, text
    assert "rms residual after the fit block" in text
    # The reflex latency fitted on the first two flashes is a human one:
    # 0.2-0.5 s from light onset to constriction (e.g. Ellis 1981; Bergamin &
    # Kardon 2003 report ~0.2-0.3 s for bright flashes).
    latency = float(re.search(r"latency_secs=([0-9.]+)", text).group(1))
    assert 0.15 <= latency <= 0.6, latency

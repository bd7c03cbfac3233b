"""The notebooks run top to bottom (each has its own assertions on the numbers it shows)."""
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

MIN_IMAGES = {"calibrate_puma": 2, "online_convergence": 1, "paper_figures": 4}
NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    # the figures are shown as images, not as "<Figure size 640x420 with 1 Axes>"
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert len(images) >= MIN_IMAGES[path.stem]
    assert not any("<Figure size" in o.get("data", {}).get("text/plain", "") and "image/png" not in o.get("data", {})
                   for o in outputs)
    if path.stem == "calibrate_puma":  # and the report itself
        assert any("Is this calibration good enough?" in o.get("data", {}).get("text/html", "") for o in outputs)


def test_there_are_notebooks():
    assert {p.stem for p in NOTEBOOKS} >= {"calibrate_puma", "online_convergence", "paper_figures"}

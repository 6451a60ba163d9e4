"""The example notebook (examples/notebooks/device_to_certified_controller.ipynb) runs: its code cells are
executed in order in one namespace, from the notebook's folder, as a kernel would (no Jupyter needed: the
notebook is JSON, nbformat 4)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "notebooks" / "device_to_certified_controller.ipynb"


@pytest.mark.slow                        # an FMU build of the solenoid and a certificate: about 30 s
def test_the_notebook_runs_from_description_to_certificate(monkeypatch):
    monkeypatch.chdir(NOTEBOOK.parent)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = json.loads(NOTEBOOK.read_text())
    assert notebook["nbformat"] == 4
    cells = [("".join(c["source"]), i) for i, c in enumerate(notebook["cells"]) if c["cell_type"] == "code"]
    assert len(cells) >= 5
    namespace: dict = {"__name__": "__main__"}
    for source, i in cells:
        exec(compile(source, f"{NOTEBOOK.name}, cell {i}", "exec"), namespace)        # noqa: S102 - our own file
    assert sorted(namespace["fmus"]) == ["Reference", "Solenoid", "Solenoid_Proposition1", "Solenoid_Theorem2"]
    df = namespace["df"]
    assert df.attrs["units"]["plant.q"] == "m" and len(df) == 1001
    # issue 41: the 1e-4 s run is not accepted (the command line exits 5), its rows kept and its figure marked;
    # the step the loop needs is accepted
    assert namespace["result"].accepted is False and namespace["fine"].accepted is True
    assert (namespace["WORK"] / "run_not_accepted.png").stat().st_size > 0
    assert (namespace["WORK"] / "run.png").stat().st_size > 0
    assert "Certificate for Solenoid_Proposition1" in namespace["certificate"].report()

"""Issue 41, item 1: a results file of every kind is a CSV that common readers take as it is. A fixed-step run's
file and every partial file used to open with a comment line (`# emcosim: estimated coupling error ...`,
`# emcosim: PARTIAL result ...`): pandas.read_csv made a two-column frame of it, fmpy.util.read_csv raised.
Now the header is the first line, `time` first, and what the comments said is in the sidecar NAME.json.

Independent truths: three readers that are not emcosim's (pandas, fmpy, numpy) with no arguments, against the
rows the Python API returns for the same run (the same master, so equal to the CSV's 17 digits), and the
estimate the command line prints."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from fmpy.util import read_csv as fmpy_read_csv

import emcosim
from emcosim.cli import main
from emcosim.engine.outputs import read_sidecar

SCENARIO = "maglev_regulation_prop2"
KINDS = {
    "fixed step": ([], {}),
    "ModelExchange": (["--interface-type", "ModelExchange"], {"interface_type": "ModelExchange"}),
    "tolerance": (["--tolerance", "1e-3"], {"tolerance": 1e-3}),
    "partial": (["--error-threshold", "1e-9"], {}),             # every estimate is above it: exit 5, partial
}


def read_by_everyone(path) -> dict[str, np.ndarray]:
    """The columns as pandas, fmpy and numpy read the file with no arguments (checked to agree)."""
    frame = pd.read_csv(path)
    fmpy_rows = fmpy_read_csv(path)
    numpy_rows = np.genfromtxt(path, delimiter=",", names=True)
    names = list(frame.columns)
    assert names[0] == "time" and list(fmpy_rows.dtype.names) == names
    assert len(numpy_rows.dtype.names) == len(names) and numpy_rows.dtype.names[0] == "time"   # numpy drops the '.'
    for i, name in enumerate(names):
        column = frame[name].to_numpy(dtype=float)
        np.testing.assert_array_equal(column, fmpy_rows[name])
        np.testing.assert_array_equal(column, numpy_rows[numpy_rows.dtype.names[i]])
    return {name: frame[name].to_numpy(dtype=float) for name in names}


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_of_results_file_is_read_as_it_is(kind, fmu_dir, tmp_path, capsys):
    flags, options = KINDS[kind]
    out = tmp_path / "r.csv"
    status = main(["run", SCENARIO, "--stop-time", "0.5", "-o", str(out), "--no-progress", "--fmu-dir", str(fmu_dir),
                   *flags])
    printed = capsys.readouterr()
    assert status == (5 if kind == "partial" else 0), printed.err
    path = tmp_path / ("r.partial.csv" if kind == "partial" else "r.csv")
    assert path.read_text().startswith("time,controller.u,plant.q")
    columns = read_by_everyone(path)
    threshold = 1e-9 if kind == "partial" else None
    expected = emcosim.run(emcosim.load_scenario(SCENARIO, fmu_dir), emcosim.RunOptions(stop_time=0.5, **options),
                           error_threshold=threshold, accept="warn" if kind == "partial" else "raise")
    np.testing.assert_array_equal(columns["time"], expected.time)
    for name in expected.columns:
        np.testing.assert_allclose(columns[name], expected[name], rtol=1e-15, atol=0)

    side = read_sidecar(path)
    assert side == json.loads(path.with_suffix(".json").read_text())       # strict JSON, NAME.json beside
    assert side["csv"] == path.name and side["columns"] == ["time", *expected.columns]
    assert side["rows"] == len(expected) and side["last_time"] == pytest.approx(0.5)
    assert side["units"]["plant.q"] == "m" and side["units"]["time"] == "s"
    assert side["scenario"]["name"] == SCENARIO and side["versions"]["emcosim"]
    assert side["options"]["stop_time"] == 0.5
    if kind == "partial":
        assert side["status"] == "partial" and side["partial"] is True
        assert "above the accepted 1e-09 of its range" in side["why"]
        assert side["verdict"]["accepted"] is False
        assert not out.exists()
    else:
        assert side["status"] == "complete" and side["why"] is None and side["verdict"]["accepted"] is True
    if kind in ("fixed step", "partial"):                     # the estimate the command line prints
        summary = side["coupling_error"]["summary"]
        assert summary.startswith("estimated coupling error") and (kind == "partial" or summary in printed.out)
    else:
        assert "coupling_error" not in side


def test_a_users_json_beside_the_results_is_never_replaced(fmu_dir, tmp_path, capsys):
    """NAME.json is the sidecar's name: a file of the user's there is refused before the run, not replaced."""
    mine = tmp_path / "r.json"
    mine.write_text('{"my": "settings"}\n')
    assert main(["run", SCENARIO, "--stop-time", "0.1", "-o", str(tmp_path / "r.csv"), "--no-progress",
                 "--fmu-dir", str(fmu_dir)]) == 1
    assert "r.json: exists and is not emcosim's sidecar of r.csv (not replaced)" in capsys.readouterr().err
    assert mine.read_text() == '{"my": "settings"}\n' and {p.name for p in tmp_path.iterdir()} == {"r.json"}


def test_from_csv_reads_the_sidecar_back(fmu_dir, tmp_path):
    out = tmp_path / "r.csv"
    assert main(["run", SCENARIO, "--stop-time", "0.5", "-o", str(out), "--no-progress", "--fmu-dir", str(fmu_dir),
                 "--error-threshold", "1e-9"]) == 5
    back = emcosim.Result.from_csv(tmp_path / "r.partial.csv")
    assert back.units["plant.q"] == "m" and back.partial.startswith("emcosim: PARTIAL result of maglev_regulation_prop2")
    assert "26 rows up to t = 0.5 s" in back.partial

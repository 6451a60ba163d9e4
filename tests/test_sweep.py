"""`emcosim sweep` (emcosim.paper.sweep): a sweep gives the same numbers as the same runs made one by one
with `emcosim run`; a failing grid point is a row with its error; a real dask scheduler + workers on
loopback gives the same table as the local cluster; malformed specifications are one-line errors.

Horizons are short (MEMS regulation, 1 ms = 100 communication steps) so the file runs in well under a
minute; most of the time is dask start-up."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from emcosim import cli
from emcosim.engine.outputs import read_sidecar
from emcosim.engine.results import Result, read_csv
from emcosim.engine.ssd import read_scenario
from emcosim.paper.sweep import metrics_of, parse_grid, parse_sample, points
from emcosim.paper.sweep_output import METRICS, read_table

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = "mems_regulation_Dd0"
STOP = "1e-3"
STEP = "4e-6"         # the scenario's default (1e-4 s, exact at D_d = 0 and rbar_e = r_e) is unstable elsewhere
GRID = "controller.D_d=-1:0:3"
MODELS = ["MEMS", "MEMS_Theorem2", "Reference"]


@pytest.fixture(scope="module")
def fmu_dir() -> Path:
    """build/fmus (or $EMCOSIM_FMU_DIR); built with build.py if missing (as in test_scenarios)."""
    d = Path(os.environ.get("EMCOSIM_FMU_DIR", ROOT / "build" / "fmus"))
    if any(not (d / f"{m}.fmu").is_file() for m in MODELS) and "EMCOSIM_FMU_DIR" not in os.environ:
        subprocess.run([sys.executable, str(ROOT / "build.py")], cwd=ROOT, check=True, capture_output=True)
    if any(not (d / f"{m}.fmu").is_file() for m in MODELS):
        pytest.skip(f"FMUs not built in {d}")
    return d


def sweep_cli(out: Path, fmu_dir: Path, *extra: str, status: int = 0) -> list[dict]:
    code = cli.main(["sweep", SCENARIO, "--stop-time", STOP, "--step-size", STEP, "--fmu-dir", str(fmu_dir), "--out", str(out),
                     "--no-progress", *extra])
    assert code == status
    return read_table(out / "sweep.csv")


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory, fmu_dir) -> Path:
    """The folder of a sweep on a local cluster. At D_d = -1 and -0.5 explicit coupling at 4 us is near its
    limit: their estimates exceed 1e-2 (exit 5)."""
    out = tmp_path_factory.mktemp("local")
    sweep_cli(out, fmu_dir, "--grid", GRID, "--workers", "2", status=5)
    return out


@pytest.fixture(scope="module")
def local_table(local_sweep) -> list[dict]:
    return read_table(local_sweep / "sweep.csv")


def result_of_csv(path: Path) -> Result:
    cols = read_csv(path)
    names = [c for c in cols if c != "time"]
    r = Result(names)
    for i, t in enumerate(cols["time"]):
        r.append(float(t), [float(cols[n][i]) for n in names])
    return r


def test_sweep_equals_runs_one_by_one(local_table, fmu_dir, tmp_path):
    assert [r["controller.D_d"] for r in local_table] == [-1.0, -0.5, 0.0]
    scenario = read_scenario(ROOT / "scenarios" / SCENARIO, fmu_dir=fmu_dir)
    for row in local_table:
        value = row["controller.D_d"]
        csv = tmp_path / f"run_{value}.csv"
        # --error-threshold: at D_d = -1 explicit coupling at 4 us is near its limit (the run's estimate says
        # so, exit 5); the sweep's numbers are compared here, not their accuracy
        assert cli.main(["run", SCENARIO, "--stop-time", STOP, "--step-size", STEP, "--fmu-dir", str(fmu_dir), "--no-progress",
                         "--set", f"controller.D_d={value!r}", "--output", str(csv), "--error-threshold", "1e9"]) == 0
        expected = metrics_of(scenario, {"controller.D_d": value}, result_of_csv(csv))
        for m in METRICS + ["initial_error"]:
            assert row[m] == expected[m], (value, m)          # bit for bit: same master, same FMUs
        # the run's estimate, as `run` writes it in its file's sidecar (issue 41: no comment line in the CSV)
        assert row["coupling_error"] == max(read_sidecar(csv)["coupling_error"]["relative"].values())
    # the study is meaningful: coupled damping changes the response
    assert len({r["ise"] for r in local_table}) == 3


def test_a_run_above_the_error_threshold_is_marked_and_the_sweep_exits_5(local_sweep, local_table, tmp_path):
    """Issue 35: a sweep did not look at its runs' error estimates (a run exits 5 where its estimated coupling
    error exceeds --error-threshold; a sweep used the same run's metrics silently and exited 0). Each row now has
    its estimate; a run above the threshold has status "not accepted: ..." (its metrics kept in the table, left
    out of the plots), sweep.md and sweep.json count them, and the sweep exits 5 (the local table's fixture)."""
    import json

    statuses = [r["status"] for r in local_table]
    assert [s.startswith("not accepted: estimated coupling error") for s in statuses] == [True, True, False]
    assert statuses[2] == "ok"
    assert [r["coupling_error"] > 1e-2 for r in local_table] == [True, True, False]
    assert all(r["ise"] is not None for r in local_table)          # the numbers stay, marked
    info = json.loads((local_sweep / "sweep.json").read_text())["info"]
    assert info["not_accepted"] == 2 and info["failed"] == 0 and info["error_threshold"] == 1e-2
    assert "0 failed, 2 not accepted" in (local_sweep / "sweep.md").read_text()
    panels = _png_description(local_sweep / "sweep_metrics.png")["panels"]
    assert all(panel["failed_at"] == [-1.0, -0.5] for panel in panels.values()), panels


def test_invalid_point_is_a_row_with_its_error(fmu_dir, tmp_path):
    # rbar_e = 50 (K_e != 0: a stiff loop) is near explicit coupling's limit at 4 us: not accepted, exit 5
    rows = sweep_cli(tmp_path, fmu_dir, "--grid", "controller.rbar_e=-50,50,100", "--workers", "1", status=5)
    assert [r["controller.rbar_e"] for r in rows] == [-50.0, 50.0, 100.0]
    assert "rbar_e" in rows[0]["status"] and "violates" in rows[0]["status"]
    assert rows[0]["ise"] is None and rows[0]["coupling_error"] is None       # no metrics for a failed run
    assert rows[1]["status"].startswith("not accepted: ") and rows[2]["status"] == "ok"
    assert all(np.isfinite(r["ise"]) for r in rows[1:])
    assert (tmp_path / "sweep.md").is_file() and (tmp_path / "sweep_metrics.png").is_file()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(port: int, timeout: float = 30.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise TimeoutError(f"dask scheduler did not open port {port}")


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_loopback_cluster_gives_the_same_table(local_table, fmu_dir, tmp_path):
    dask = Path(sys.executable).parent / "dask"
    if not dask.is_file():
        pytest.skip("the dask command is not installed")
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path)]
    try:
        _wait_for(port)
        for _ in range(2):
            procs.append(subprocess.Popen([str(dask), "worker", address, "--nthreads", "1", "--no-dashboard"],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path))
        from dask.distributed import Client
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        remote = sweep_cli(tmp_path, fmu_dir, "--grid", GRID, "--scheduler", address, status=5)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    assert remote == local_table


# ---- specifications (no cluster) -----------------------------------------------------------------

def test_grid_and_sample_parsing():
    assert parse_grid("controller.D_d=-1:0:3") == ("controller.D_d", [-1.0, -0.5, 0.0])
    assert parse_grid("controller.R_e_bar=0.82,2.82") == ("controller.R_e_bar", [0.82, 2.82])
    assert parse_sample("plant.m=0.08:0.09") == ("plant.m", 0.08, 0.09)
    runs = points([("a.x", [1.0, 2.0]), ("b.y", [3.0, 4.0, 5.0])], [("plant.m", 1.0, 2.0)], 2, seed=1)
    assert len(runs) == 12 and runs[0]["a.x"] == 1.0 and runs[-1]["b.y"] == 5.0
    assert runs[0]["plant.m"] == runs[2]["plant.m"] != runs[1]["plant.m"]      # same draws at every point


@pytest.mark.parametrize("args, message", [
    (["--grid", "controller.D_d=0:1"], "START:STOP:N"),
    (["--grid", "controller.D_d=0:1:x"], "not a whole number"),
    (["--grid", "D_d=0:1:3"], "COMPONENT.PARAMETER"),
    (["--grid", "controller.D_d=0:nan:3"], "not finite"),
    (["--grid", "ctrl.D_d=0:1:3"], "no component 'ctrl'"),
    (["--grid", "controller.nope=0:1:3"], "unknown variable 'nope'"),
    (["--grid", "controller.D_d=0:1:2", "--grid", "controller.D_d=0:1:2"], "appears twice"),
    (["--sample", "plant.m=2:1", "--samples", "3"], "LOW must not exceed HIGH"),
    (["--sample", "plant.m=1:2"], "needs --samples"),
    ([], "nothing to sweep"),
    (["--grid", "controller.D_d=0:1:2", "--coupling", "implicit", "--coupling-order", "1"],
     "--coupling implicit passes none"),
])
def test_malformed_specifications_are_one_line_errors(args, message, fmu_dir, tmp_path, capsys):
    code = cli.main(["sweep", SCENARIO, "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), *args])
    err = capsys.readouterr().err.strip()
    assert code == 1
    assert len(err.splitlines()) == 1 and err.startswith("emcosim: error:") and message in err, err


# ---- bounds (issue 26, item 6) -----------------------------------------------------------------------

def test_a_grid_beyond_the_limit_is_refused_before_anything_runs(fmu_dir, tmp_path):
    """1000 x 1000 used to start a cluster and submit 10^6 tasks (1.1 GB) before collecting one row. Now a
    one-line error naming the count, the limit and the option, in well under the 60 s this test allows it
    (the process group is killed after that), and nothing written."""
    out = tmp_path / "big"
    argv = [sys.executable, "-m", "emcosim.cli", "sweep", SCENARIO, "--grid", "controller.D_d=-1:0:1000",
            "--grid", "controller.rbar_e=90:110:1000", "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"]
    tic = time.monotonic()
    proc = subprocess.Popen(argv, cwd=str(ROOT), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        _, err = proc.communicate(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        proc.communicate()
        pytest.fail("a 10^6-run sweep was started instead of refused")
    assert proc.returncode == 1 and time.monotonic() - tic < 30, err
    assert err.strip() == ("emcosim: error: --grid/--sample (1000 x 1000) makes 1000000 runs, more than the limit of "
                           "100000 runs of a sweep; give --max-runs 1000000 to run them anyway"), err
    assert list(tmp_path.iterdir()) == []


def test_the_limit_is_overridable_and_counts_every_run():
    from emcosim.engine.errors import LimitError
    from emcosim.paper.sweep import MAX_RUNS

    assert MAX_RUNS == 100_000
    axes = [("a.x", [float(i) for i in range(400)]), ("b.y", [float(i) for i in range(300)])]
    with pytest.raises(LimitError, match="400 x 300.* makes 120000 runs") as caught:
        points(axes)
    assert caught.value.option == "max_runs" and "--max-runs 120000" in caught.value.describe(cli.FLAGS)
    assert len(points(axes, max_runs=120_000)) == 120_000
    with pytest.raises(LimitError, match=r"\(10 x 20000 samples\) makes 200000 runs"):
        points([("a.x", [0.0] * 10)], [("plant.m", 1.0, 2.0)], 20_000)    # the draws count too
    with pytest.raises(LimitError, match="controller.D_d=0:1:100001 makes 100001 runs"):
        parse_grid("controller.D_d=0:1:100001")                # refused before its values are made
    assert len(parse_grid("controller.D_d=0:1:100001", max_runs=100_001)[1]) == 100_001


def test_max_runs_on_the_command_line(fmu_dir, tmp_path, capsys):
    assert cli.main(["sweep", SCENARIO, "--grid", "controller.D_d=-1:0:3", "--max-runs", "2", "--out",
                     str(tmp_path / "x"), "--fmu-dir", str(fmu_dir)]) == 1
    assert "makes 3 runs, more than the limit of 2 runs of a sweep; give --max-runs 3" in capsys.readouterr().err
    assert cli.main(["sweep", SCENARIO, "--grid", "controller.D_d=-1:0:3", "--max-runs", "0"]) == 1
    assert capsys.readouterr().err.strip() == "emcosim: error: --max-runs 0: must be >= 1"


class CountingClient:
    """A dask client that counts the runs submitted but not yet handed back to `on_row`."""

    def __init__(self, client):
        self.client, self.submitted, self.returned, self.most = client, 0, 0, 0

    def submit(self, *args, **kwargs):
        self.most = max(self.most, self.submitted - self.returned)
        self.submitted += 1
        return self.client.submit(*args, **kwargs)

    def on_row(self, i: int, row: dict) -> None:
        self.returned += 1

    def __getattr__(self, name):
        return getattr(self.client, name)


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_runs_are_submitted_in_bounded_batches(fmu_dir):
    """All runs used to be submitted before the first result was collected (10^6 futures and task graphs
    for a 1000 x 1000 grid). Now IN_FLIGHT_PER_THREAD per worker thread are in flight, the next one
    submitted as each finishes; the rows come back complete and in run order."""
    from emcosim.paper.sweep import dask_client, run_all

    runs = points([("controller.D_d", list(np.linspace(-1, 0, 24)))])
    ssd = str((ROOT / "scenarios" / SCENARIO / "SystemStructure.ssd").resolve())
    with dask_client(workers=1) as client:
        spy = CountingClient(client)
        rows = run_all(spy, ssd, str(fmu_dir), runs, stop_time=2e-4, step_size=4e-6, stream=None, on_row=spy.on_row)
    assert spy.submitted == spy.returned == 24
    assert 1 <= spy.most <= 2, spy.most                        # IN_FLIGHT_PER_THREAD x 1 worker thread
    assert [r["controller.D_d"] for r in rows] == [r["controller.D_d"] for r in runs]
    assert all(r["status"] == "ok" or r["status"].startswith("not accepted: ") for r in rows)


# ---- plots: what each figure shows (its data, also stored in the PNG's metadata) ------------------

def _rows(values: dict[tuple[float, float], float], metric: str) -> list[dict]:
    rows = []
    for (a, b), v in values.items():
        row = {"controller.D_d": a, "controller.R_e_bar": b, "status": "ok", **{m: 1.0 for m in METRICS}}
        row[metric] = v
        rows.append(row)
    return rows


def _png_description(path: Path) -> dict:
    import json

    from PIL import Image
    return json.loads(Image.open(path).text["Description"])


def test_heatmap_log_scale_not_settled_and_grid_ticks(tmp_path):
    from emcosim.paper.sweep_output import heatmap_data, plot
    grid = {"controller.D_d": [-1.0, 0.0], "controller.R_e_bar": [0.82, 2.82]}
    units = {"controller.D_d": "Wb/m", "controller.R_e_bar": "Ohm"}
    settle = {(-1.0, 0.82): 4.5, (0.0, 0.82): float("inf"), (-1.0, 2.82): 12.0, (0.0, 2.82): 40.0}
    data = heatmap_data(_rows(settle, "settling_time_2pct"), list(grid), grid, units, "settling_time_2pct", 40.0)
    assert data["x"]["ticks"] == [-1.0, 0.0] and data["y"]["ticks"] == [0.82, 2.82]
    assert data["x"]["label"] == "controller.D_d [Wb/m]"
    assert data["text"] == [["4.5", "not reached"], ["12", "not reached"]]   # inf, and equal to the horizon
    assert data["scale"] == "linear"                                          # 4.5 .. 12: within a decade
    ise = {(-1.0, 0.82): 5e-7, (0.0, 0.82): 1e-5, (-1.0, 2.82): 1.2e-6, (0.0, 2.82): 3e-7}
    files = plot(_rows(ise, "ise"), grid, units, tmp_path, horizon=40.0)
    assert len(files) == len(METRICS)
    shown = _png_description(tmp_path / "sweep_ise.png")
    assert shown["scale"] == "log" and shown["values"] == [[5e-7, 1e-5], [1.2e-6, 3e-7]]
    assert shown["label"] == "ISE = integral of e^2 [m^2 s]"
    assert _png_description(tmp_path / "sweep_overshoot.png")["label"] == "overshoot (% of |e(0)|) [%]"
    (tmp_path / "s").mkdir()
    plot(_rows(settle, "settling_time_2pct"), grid, units, tmp_path / "s", horizon=40.0)
    unsettled = _png_description(tmp_path / "s" / "sweep_settling_time_2pct.png")
    assert unsettled["values"] == [[4.5, None], [12.0, None]] and unsettled["text"][1][1] == "not reached"


def test_line_plot_marks_not_settled_and_ticks_the_grid(tmp_path):
    from emcosim.paper.sweep_output import plot
    rows = [{"controller.D_d": d, "status": "ok", **{m: 1.0 for m in METRICS}, "settling_time_2pct": st}
            for d, st in [(-1.0, 0.8e-3), (-0.5, 1.2e-3), (0.0, float("inf"))]]
    path, = plot(rows, {"controller.D_d": [-1.0, -0.5, 0.0]}, {"controller.D_d": "C/m"}, tmp_path, horizon=0.02)
    shown = _png_description(path)
    assert shown["x"] == {"name": "controller.D_d", "unit": "C/m", "values": [-1.0, -0.5, 0.0]}
    panel = shown["panels"]["settling_time_2pct"]
    assert panel["mean"] == [0.8e-3, 1.2e-3, None] and panel["not_settled_at"] == [0.0] and panel["failed_at"] == []


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_tolerance_lets_a_sweep_leave_the_scenarios_gains(local_table, fmu_dir):
    """The scenario's default step (chosen for D_d = 0) does not bear D_d = -1: that run is a row with its
    error. With `tolerance` the same point runs and its metrics agree with the fixed 4 us run of the
    sweep above."""
    from emcosim.paper.sweep import run_point

    ssd = str(ROOT / "scenarios" / SCENARIO / "SystemStructure.ssd")
    values = {"controller.D_d": -1.0}
    at_default_step = run_point(ssd, str(fmu_dir), values, stop_time=float(STOP))
    assert at_default_step["status"] != "ok"
    controlled = run_point(ssd, str(fmu_dir), values, stop_time=float(STOP), tolerance=1e-4)
    assert controlled["status"] == "ok", controlled["status"]
    fixed = next(r for r in local_table if r["controller.D_d"] == -1.0)
    assert controlled["ise"] == pytest.approx(fixed["ise"], rel=1e-2)
    assert controlled["max_abs_u"] == pytest.approx(fixed["max_abs_u"], rel=1e-2)


def test_implicit_coupling_lets_a_sweep_keep_the_scenarios_step(local_table, fmu_dir, tmp_path):
    """At the scenario's step (1e-4 s, chosen for D_d = 0) explicit coupling fails at D_d = -1 (the loop is
    stiff there: the test below). `--coupling implicit` runs every point of the grid at that step, and
    agrees with the explicit sweep at 4 us (another coupling at a 25 times shorter step): final errors
    within 1 % of the initial error, ISE within 15 % (both from the runs' own communication points, 11
    against 251). sweep.json and sweep.md say how the runs ran."""
    import json

    out = tmp_path / "implicit"
    # --error-threshold: at D_d = -1 the run's estimate is 0.056 of p's range (its 11 points), at -0.5 0.022
    code = cli.main(["sweep", SCENARIO, "--stop-time", STOP, "--fmu-dir", str(fmu_dir), "--out", str(out),
                     "--no-progress", "--no-plots", "--workers", "1", "--grid", GRID, "--coupling", "implicit",
                     "--error-threshold", "0.1"])
    assert code == 0
    rows = read_table(out / "sweep.csv")
    assert [r["status"] for r in rows] == ["ok"] * 3
    for r, fixed in zip(rows, local_table):
        assert r["controller.D_d"] == fixed["controller.D_d"]
        assert abs(r["final_error"] - fixed["final_error"]) <= 0.01 * abs(fixed["initial_error"]), (r, fixed)
        assert r["ise"] == pytest.approx(fixed["ise"], rel=0.15)
    info = json.loads((out / "sweep.json").read_text())["info"]
    assert info["coupling"] == "implicit" and info["step_size"] is None
    assert "Every run: implicit coupling, the scenario's step, stop time 0.001 s." in (out / "sweep.md").read_text()


@pytest.mark.slow      # 8-21 s: in the full set, out of the quick one (issue 33)
def test_failed_runs_at_the_default_step_get_a_note(fmu_dir, tmp_path, capsys):
    code = cli.main(["sweep", SCENARIO, "--stop-time", STOP, "--grid", "controller.D_d=-1,0", "--fmu-dir", str(fmu_dir),
                     "--out", str(tmp_path / "s"), "--no-progress", "--no-plots", "--workers", "1"])
    assert code == 0
    captured = capsys.readouterr()
    assert "2 runs (1 failed)" in captured.out
    err = captured.err
    rows = read_table(tmp_path / "s" / "sweep.csv")
    assert [r["status"] == "ok" for r in rows] == [False, True]
    assert "failed runs may need --step-size or --tolerance, or --coupling implicit" in err, err


def test_the_sweep_table_says_what_the_reproduce_report_says_for_a_band_not_reached(tmp_path):
    """Issue 41, item 7: sweep.md said `inf` where reproduce's metrics.md says 'not reached' for a time into the
    band that the horizon does not reach. Both now say the same words; sweep.csv keeps the number (inf) that
    every CSV reader reads as one."""
    import csv

    from emcosim.paper.sweep_output import write_table

    rows = [{"controller.D_d": d, **{m: 1.0 for m in METRICS}, "settling_time_2pct": st, "coupling_error": None,
             "status": "ok"} for d, st in [(-1.0, 0.5), (0.0, float("inf"))]]
    write_table(rows, tmp_path, {"scenario": "s", "runs": 2, "failed": 0, "workers": 1, "runs_per_s": 1.0,
                                 "coupling": "explicit", "step_size": 1e-3})
    table = [line for line in (tmp_path / "sweep.md").read_text().splitlines() if line.startswith("| 1 |")]
    assert len(table) == 1 and "| not reached |" in table[0] and "inf" not in table[0], table
    with open(tmp_path / "sweep.csv", newline="") as f:
        assert [r["settling_time_2pct"] for r in csv.DictReader(f)] == ["0.5", "inf"]

"""Issue 31, items 3-6: `emcosim run --interface-type ModelExchange` as hardened as the co-simulation path.
Every run is a subprocess of the command line on the suite's FMUs.

What must hold (docs/reliability.md, "Model Exchange"): one Ctrl-C (SIGINT to the process group, as a
terminal sends it) or SIGTERM stops a Model Exchange run within a couple of seconds, also where the solver
records no row for a long time, with exit 130 / 143 and the rows so far in NAME.partial.csv; a second
Ctrl-C is not reported as an FMU's failure; a run's rows stream to the disk with flat memory on any
horizon (a precomputed grid of 1e8 points does not fit the address-space limit the runs get here, 2 GiB);
a tolerance the solvers cannot keep ends the run non-zero with the rows kept; a plant that fails in a run
with --tolerance leaves the rows before the failure."""
from __future__ import annotations

import os
import resource
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.results import read_csv
from emcosim.engine.ssd import read_scenario

from ..integrity_helpers import emcosim, partial_note, partial_of, popen

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.reliability

ME = ["--interface-type", "ModelExchange", "--no-progress"]
# a solve that records no row for half an hour: rows at 0, 5e4 s and 1e5 s, ~3000 solver steps a second
SLOW = ["maglev_tracking_D0_R2.82", "--stop-time", "1e5", "--step-size", "5e4", "--rtol", "1e-12"]
# 1e8 rows on the grid, about 10000 a second: a precomputed grid would need 3 GB
LONG = ["maglev_regulation_prop2", "--step-size", "1e-6", "--stop-time", "100", "--max-steps", "2e8"]
ADDRESS_SPACE = 2 << 30
ENV = {"OPENBLAS_NUM_THREADS": "1"}              # a fixed address space, whatever the machine's cores


def _limit_address_space() -> None:
    os.setsid()                                  # its own process group (a terminal's Ctrl-C reaches all of it)
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))


def _start(args: list[str]) -> subprocess.Popen:
    return popen(["run", *args, *ME], env=ENV, preexec_fn=_limit_address_space)


def _wait_for(folder: Path, pattern: str, timeout: float = 60) -> Path:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = sorted(folder.glob(pattern))
        if found:
            return found[0]
        time.sleep(0.02)
    raise AssertionError(f"no {pattern} in {folder} after {timeout} s")


def _stop(proc: subprocess.Popen, signals: list[int], gap: float = 0.0) -> tuple[str, float]:
    """Send the signals to the run's process group; stderr and the seconds from the first to the exit."""
    tic = time.monotonic()
    for s in signals:
        os.killpg(proc.pid, s)
        time.sleep(gap)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise AssertionError(f"no exit 30 s after {[signal.Signals(s).name for s in signals]}") from None
    return err, time.monotonic() - tic


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_one_signal_stops_a_solve_between_its_rows(fmu_dir, tmp_path, tally, signum, status):
    """The maglev loop at rtol 1e-12 with a row every 5e4 s: the signal 3 s into the solve (the row at t = 0
    recorded, the next one ~30 min away) ends the run within 2 s, exit 128 + signal, one error line, the row
    in NAME.partial.csv. Before issue 31 the integrator looked for a stop only when it recorded a row."""
    out = tmp_path / "r.csv"
    proc = _start([*SLOW, "--fmu-dir", str(fmu_dir), "-o", str(out)])
    _wait_for(tmp_path, "r.incomplete-*.csv")
    time.sleep(3.0)                                               # initialized, deep in the first solve
    assert proc.poll() is None, proc.communicate()
    err, elapsed = _stop(proc, [signum])
    name = signal.Signals(signum).name
    assert proc.returncode == status, (proc.returncode, err)
    assert elapsed < 2.0, f"exit {elapsed:.2f} s after {name}"
    lines = [x for x in err.splitlines() if x.strip()]
    partial = partial_of(out)
    assert len(lines) == 1 and lines[0].startswith(f"emcosim: error: interrupted by {name};"), err
    assert f"saved to {partial}" in lines[0] and not out.exists()
    assert f"interrupted by {name}" in partial_note(partial)
    assert read_csv(partial)["time"].tolist() == [0.0]
    tally.add("model_exchange", f"{name} during a solve", "clean_error")
    tally.measurements["model_exchange"][f"{name}_exit_seconds"] = round(elapsed, 3)


def test_a_second_ctrl_c_is_not_an_fmu_failure(fmu_dir, tmp_path, tally):
    """Two SIGINTs 1 ms apart: the second may land inside a Python FMU's call before the first is looked
    at. The run ends as interrupted (exit 130), never as the controller's failure (exit 1), and keeps its
    row. Five runs."""
    for k in range(5):
        out = tmp_path / f"r{k}.csv"
        proc = _start([*SLOW, "--fmu-dir", str(fmu_dir), "-o", str(out)])
        _wait_for(tmp_path, f"r{k}.incomplete-*.csv")
        time.sleep(2.0)
        err, elapsed = _stop(proc, [signal.SIGINT, signal.SIGINT], gap=0.001)
        assert proc.returncode == 130 and elapsed < 2.0, (proc.returncode, elapsed, err)
        assert "failed" not in err and "Traceback" not in err, err
        assert "interrupted by SIGINT" in err.splitlines()[-1], err
        assert partial_of(out).is_file() and not out.exists(), err
        tally.add("model_exchange", "two SIGINTs 1 ms apart", "clean_error")


@pytest.mark.parametrize("extra", [[], ["--tolerance", "1e-3"]], ids=["rtol", "tolerance"])
def test_a_long_horizon_streams_with_flat_memory(fmu_dir, tmp_path, tally, extra):
    """1e8 rows on the grid (--max-steps raised to allow them) under a 2 GiB address-space limit: the rows
    reach the disk as they come and the memory stays flat, also for a run with --tolerance (its first
    solve's rows wait on a temporary file, not in memory); SIGTERM then keeps them. The grid used to be a
    list built before the first step (3 GB here: a MemoryError under the limit, the machine's memory
    without it), and a tolerance run held two solves' rows."""
    out = tmp_path / "r.csv"
    proc = _start([*LONG, *extra, "--fmu-dir", str(fmu_dir), "-o", str(out)])
    incomplete = _wait_for(tmp_path, "r.incomplete-*.csv")
    deadline = time.monotonic() + 60

    def size() -> int:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        return incomplete.stat().st_size
    while size() < 200_000:                                       # rows flowing
        time.sleep(0.05)
    rss0, size0 = _rss_kib(proc.pid), size()
    while size() < size0 + 2_000_000:                             # ~17000 more rows
        time.sleep(0.05)
    rss1, size1 = _rss_kib(proc.pid), incomplete.stat().st_size
    err, _ = _stop(proc, [signal.SIGTERM])
    assert proc.returncode == 143, err
    assert rss1 - rss0 < 2048, f"memory grew by {rss1 - rss0} KiB while {size1 - size0} bytes of rows were written"
    t = read_csv(partial_of(out))["time"]
    assert len(t) > 15000 and np.all(np.diff(t) > 0)
    np.testing.assert_allclose(np.diff(t), 1e-6, rtol=1e-6)
    case = "tolerance" if extra else "rtol"
    tally.add("model_exchange", f"1e8-row horizon ({case}), then SIGTERM", "correct")
    tally.measurements["model_exchange"][f"long_run_{case}"] = {"rss_growth_kib": rss1 - rss0, "rows": len(t),
                                                                 "bytes_written": size1 - size0}


def test_a_horizon_beyond_the_step_limit_is_refused_up_front(fmu_dir, tmp_path, tally):
    """--stop-time 1e8 (1e12 rows of the MEMS grid): the limit error of a co-simulation run, naming
    --max-steps, before anything runs (it filled the memory)."""
    out = tmp_path / "r.csv"
    run = emcosim(["run", "mems_regulation_Dd0", "--fmu-dir", str(fmu_dir), "-o", str(out), "--stop-time", "1e8", *ME],
                  timeout=120, env=ENV, preexec_fn=_limit_address_space)
    assert run.returncode == 1, run.stderr
    line = run.stderr.strip().splitlines()[-1]
    assert "makes 1e+12 recorded rows (communication points), more than the limit of 1e+08; give --max-steps" in line
    assert "Traceback" not in run.stderr and not out.exists() and not partial_of(out).exists()
    tally.add("model_exchange", "stop time 1e8", "clean_error")


def test_a_tolerance_the_solvers_cannot_keep_ends_the_run_non_zero(fmu_dir, tmp_path, tally):
    """--tolerance 1e-10 on the maglev regulation: its solves at rtol 1e-11 and 1e-12 estimate the error at
    about 5e-9, and keeping 1e-10 would take an rtol below the solvers' 1e-13. Exit 1, the message names
    --tolerance, the second solve's rows in NAME.partial.csv (it used to clamp the rtol and exit 0 with a
    complete-looking file while its own summary estimated a larger error)."""
    out = tmp_path / "r.csv"
    run = emcosim(["run", "maglev_regulation_prop2", "--fmu-dir", str(fmu_dir), "-o", str(out), "--tolerance", "1e-10",
                   *ME], timeout=300)
    assert run.returncode == 1, run.stderr
    line = run.stderr.strip().splitlines()[-1]
    assert line.startswith("emcosim: error: Model Exchange: --tolerance 1e-10 cannot be kept"), line
    assert "give a larger --tolerance" in line and "Traceback" not in run.stderr
    partial = partial_of(out)
    assert not out.exists() and "cannot be kept" in partial_note(partial)
    t = read_csv(partial)["time"]
    step = float(read_scenario(ROOT / "scenarios" / "maglev_regulation_prop2").step_size)
    assert t[0] == 0.0 and t[-1] == 20.0 and len(t) == round(20.0 / step) + 1      # every row of the second solve
    tally.add("model_exchange", "tolerance 1e-10 not kept", "clean_error")


def test_a_plant_failing_in_a_tolerance_run_leaves_its_rows(fmu_dir, tmp_path, tally):
    """The MEMS loop with p_0 = -5e-9 N s (the gap closes at t = 1.436e-5 s) under --tolerance 1e-4, a row
    every microsecond: exit 1 naming the plant's reason, and the rows before the failure in
    NAME.partial.csv, as without --tolerance and in co-simulation (there was no file at all)."""
    out = tmp_path / "r.csv"
    run = emcosim(["run", "mems_regulation_Dd0", "--fmu-dir", str(fmu_dir), "-o", str(out), "--tolerance", "1e-4",
                   "--set", "plant.p_0=-5e-9", "--step-size", "1e-6", "--record", "plant.q", *ME], timeout=300)
    assert run.returncode == 1, run.stderr
    line = run.stderr.strip().splitlines()[-1]
    partial = partial_of(out)
    assert "gap has closed" in line and f"saved to {partial}" in line, line
    assert not out.exists() and "gap has closed" in partial_note(partial)
    data = read_csv(partial)
    np.testing.assert_allclose(data["time"], np.arange(15) * 1e-6, rtol=1e-9)       # up to the failure
    q = data["plant.q"]
    assert q[0] == 1.5e-5 and np.all(np.diff(q) < 0) and q[-1] + 1.5e-5 > 0           # inside the gap
    tally.add("model_exchange", "plant fails in a tolerance run", "clean_error")

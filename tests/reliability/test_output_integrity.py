"""Issue 15, output files of `emcosim run` under attack: two runs writing the same file, kill -9,
SIGINT and SIGTERM, a full disk (a file-size limit, RLIMIT_FSIZE, on the process: no root needed),
and a horizon far too long to keep in memory. Every run is a subprocess.

What must hold: the destination is either absent, the previous result or a complete result, never a
torn file; what was computed survives in NAME.partial.csv (or, after kill -9, in
NAME.incomplete-PID.csv, up to its last flush) with a first line saying why; the exit status says
what happened (0 only for a complete result, 130/143 for SIGINT/SIGTERM); unpacked FMUs of a
killed run are removed at the next start; memory stays flat on any horizon."""
from __future__ import annotations

import csv
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from emcosim.engine.results import read_csv

from ..integrity_helpers import build_toys, emcosim, partial_note, partial_of, popen, toy_loop

pytestmark = pytest.mark.reliability

LONG = ["--stop-time", "1e6", "--step-size", "1e-2", "--no-progress"]      # 1e8 steps: hours


@pytest.fixture(scope="module")
def toys(tmp_path_factory) -> dict[str, Path]:
    return build_toys(tmp_path_factory.mktemp("toys"))


def wait_for_rows(path_glob, folder: Path, rows: int, timeout: float = 60) -> Path:
    """The file matching path_glob in folder once it holds at least `rows` lines."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for p in folder.glob(path_glob):
            with open(p, "rb") as f:
                if f.read().count(b"\n") > rows:
                    return p
        time.sleep(0.05)
    raise AssertionError(f"no {path_glob} with {rows} rows in {folder} after {timeout} s")


def _wait_for_growth(path: Path, size: int, timeout: float = 120) -> int:
    """The size of `path` once it has reached `size` bytes (the run keeps writing rows)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        now = path.stat().st_size
        if now >= size:
            return now
        time.sleep(0.05)
    raise AssertionError(f"{path} did not reach {size} bytes in {timeout} s")


def complete_rows(path: Path) -> list[dict[str, float]]:
    """The rows of a result file, each as {column name: value} (comment lines skipped)."""
    with open(path, newline="") as f:
        lines = [x for x in f if not x.startswith("#")]
    header, *rows = list(csv.reader(lines))
    return [dict(zip(header, map(float, row))) for row in rows]


def test_two_runs_writing_the_same_file_never_leave_it_torn(toys, tmp_path, tally):
    """Two runs (different gains) with the same -o at once; a reader polling the file meanwhile only
    ever sees a complete result, and the last one is one of the two runs, whole."""
    out = tmp_path / "r.csv"
    n = 20_000
    loops = {k: toy_loop(tmp_path / f"k{k}", toys, k=k, stop_time=n * 0.01) for k in (-1.0, -0.5)}
    procs = [popen(["run", str(loop), "-o", str(out), "--no-progress"]) for loop in loops.values()]
    seen = 0
    while any(p.poll() is None for p in procs):
        time.sleep(0.002)
        try:
            data = out.read_bytes()
        except FileNotFoundError:
            continue
        lines = [line for line in data.splitlines() if not line.startswith(b"#")]   # the error estimate's line
        assert data.endswith(b"\n") and len(lines) == n + 2, f"a reader saw a torn file: {len(lines)} lines"
        seen += 1
    for p in procs:
        assert p.wait() == 0, p.stderr.read()
    x = read_csv(out)["plant.x"]
    assert len(x) == n + 1
    assert any(np.allclose(x, (1 + 0.01 * k) ** np.arange(n + 1), rtol=1e-9, atol=0) for k in loops)
    assert not list(tmp_path.glob("r.incomplete-*"))
    tally.add("output_integrity", "two runs, same -o", "correct")
    tally.measurements["output_integrity"]["complete_reads_while_running"] = seen


def test_kill_9_keeps_the_flushed_rows_and_the_next_start_cleans_up(toys, tmp_path, tally):
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {"TMPDIR": str(tmp)}
    loop = toy_loop(tmp_path / "loop", toys)
    out = tmp_path / "r.csv"
    proc = popen(["run", str(loop), "-o", str(out), *LONG], env=env)
    incomplete = wait_for_rows("r.incomplete-*.csv", tmp_path, 4000)      # rows flushed while the run goes on
    unpacked = [d for d in tmp.iterdir() if d.name.startswith(f"emcosim-{proc.pid}-")]
    proc.kill()
    proc.wait()
    assert len(unpacked) == 2                                   # the two FMUs of the loop
    rows = complete_rows(incomplete)
    assert len(rows) >= 2000 and not out.exists()               # what was flushed before the kill
    # (atol: past 70,000 rows the values are subnormal, where x_{n+1} = 0.99 x_n and 0.99**n round apart)
    np.testing.assert_allclose([r["plant.x"] for r in rows], 0.99 ** np.arange(len(rows)), rtol=1e-9, atol=1e-300)
    later = emcosim(["run", str(loop), "--stop-time", "0.1", "-o", str(out), "--no-progress"], env=env)
    assert later.returncode == 0, later.stderr
    assert f"pid {proc.pid}) that was killed; marked partial" in later.stderr, later.stderr
    note = partial_note(incomplete)
    assert f"(pid {proc.pid}, started " in note and "ended without a clean exit" in note, note
    assert f"{len(rows)} rows" in note, note
    assert len(complete_rows(incomplete)) == len(rows)
    assert not [d for d in tmp.iterdir() if d.name.startswith(f"emcosim-{proc.pid}-")]   # cleaned at this start
    tally.add("output_integrity", "kill -9", "clean_error")
    tally.measurements["output_integrity"]["rows_kept_after_kill_9"] = len(rows)


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_stops_between_steps_and_keeps_the_rows(fmu_dir, tmp_path, tally, signum, status):
    """The maglev loop (Python FMUs: the signal used to land inside an FMU's do_step) stopped after
    some seconds: exit 128 + signal, one error line, the rows in NAME.partial.csv, no NAME.csv."""
    out = tmp_path / "r.csv"
    proc = popen(["run", "maglev_tracking_D0_R2.82", "--fmu-dir", str(fmu_dir), "-o", str(out), "--no-progress",
                  "--step-size", "5e-4"])                # 80000 steps: long enough to be stopped mid-run
    wait_for_rows("r.incomplete-*.csv", tmp_path, 200)                   # mid-run: a few hundred steps done
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, (proc.returncode, err)
    lines = [x for x in err.splitlines() if x.strip()]
    name = signal.Signals(signum).name
    assert len(lines) == 1 and lines[0].startswith(f"emcosim: error: interrupted by {name};"), err
    partial = partial_of(out)
    assert f"saved to {partial}" in lines[0] and not out.exists()
    assert f"interrupted by {name}" in partial_note(partial)
    data = read_csv(partial)
    assert len(data["time"]) > 100 and np.all(np.diff(data["time"]) > 0)
    assert all(np.all(np.isfinite(v)) for v in data.values())
    tally.add("output_integrity", f"{name} during a run", "clean_error")


def _limit_file_size(limit: int):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_full_disk_marks_the_partial_file(toys, tmp_path, tally):
    """A file-size limit of 1 MiB (what a full disk does to a growing file): a clear error, the rows
    that fitted kept in NAME.partial.csv with its comment line, the file within the limit."""
    limit = 1 << 20
    loop = toy_loop(tmp_path / "loop", toys)
    out = tmp_path / "r.csv"
    proc = subprocess.run([sys.executable, "-m", "emcosim.cli", "run", str(loop), "-o", str(out), "--stop-time",
                           "1e4", "--no-progress"], capture_output=True, text=True, timeout=300,
                          preexec_fn=_limit_file_size(limit))
    assert proc.returncode == 1, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    partial = partial_of(out)
    assert "File too large" in line and f"saved to {partial}" in line and "Traceback" not in proc.stderr, proc.stderr
    assert not out.exists() and partial.stat().st_size <= limit
    assert "File too large" in partial_note(partial)
    x = read_csv(partial)["plant.x"]
    assert len(x) > 5000
    np.testing.assert_allclose(x, 0.99 ** np.arange(len(x)), rtol=1e-9)
    assert f"{len(x)} rows up to t = " in line
    tally.add("output_integrity", "full disk (RLIMIT_FSIZE)", "clean_error")


def _rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def test_long_horizon_streams_to_disk_with_flat_memory(toys, tmp_path, tally):
    """--stop-time 1e6 (1e8 steps): rows reach the disk while the run goes and the memory stays flat
    (it grew by megabytes a second when every row was kept until the end)."""
    loop = toy_loop(tmp_path / "loop", toys)
    out = tmp_path / "r.csv"
    proc = popen(["run", str(loop), "-o", str(out), *LONG])
    incomplete = wait_for_rows("r.incomplete-*.csv", tmp_path, 4000)
    rss0, size0 = _rss_kib(proc.pid), incomplete.stat().st_size
    size1 = _wait_for_growth(incomplete, size0 + 2_000_000)            # ~30,000 more rows on the disk
    rss1 = _rss_kib(proc.pid)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert rss1 - rss0 < 2048, f"memory grew by {rss1 - rss0} KiB while {size1 - size0} bytes of rows were written"
    rows = len(read_csv(partial_of(out))["time"])
    tally.add("output_integrity", "stop time 1e6 (streamed)", "correct")
    tally.measurements["output_integrity"]["long_run"] = {"rss_growth_kib": rss1 - rss0, "rows": rows,
                                                          "bytes_written": size1 - size0}


def test_killed_export_keeps_the_old_fmu_and_the_next_start_cleans_up(fmu_dir, tmp_path, tally):
    """Issue 26, item 2: kill -9 while `export` builds the container. The old loop.fmu is still there
    (it used to be deleted first), nothing is left beside it, and the next `emcosim` command removes
    the export's temporary folder (its name used to be one that nothing removed)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {"TMPDIR": str(tmp)}
    out = tmp_path / "dest" / "loop.fmu"
    out.parent.mkdir()
    out.write_bytes(b"the old FMU")
    proc = popen(["export", "mems_regulation_Dd0", "--fmu-dir", str(fmu_dir), "-o", str(out)], env=env)
    deadline = time.monotonic() + 60
    while not any((d / "unzip").is_dir() for d in tmp.iterdir()):          # the container is being built
        assert proc.poll() is None and time.monotonic() < deadline, "the export ended before it could be killed"
    proc.kill()
    proc.wait()
    assert out.read_bytes() == b"the old FMU" and [p.name for p in out.parent.iterdir()] == ["loop.fmu"]
    left = [d.name for d in tmp.iterdir()]
    assert left, "the killed export left no temporary folder (killed too late?)"
    later = emcosim(["info", "mems_regulation_Dd0", "--fmu-dir", str(fmu_dir)], env=env)
    assert later.returncode == 0, later.stderr
    assert list(tmp.iterdir()) == [], f"left after the next start: {left}"
    tally.add("output_integrity", "kill -9 of an export", "clean_error")

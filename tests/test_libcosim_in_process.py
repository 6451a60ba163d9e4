"""Issue 26, item 9: engine/libcosim.py said that libcosim's worker threads, driving pythonfmu FMUs, corrupt
the heap so that the process aborts at exit. Measured with this suite's FMUs: they do not. Each case runs
libcosim in a fresh process of its own (not the child process simulate_libcosim uses), which must exit with
status 0 after printing its result: a return of the heap corruption (status 134 or -6/-11) fails here."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from emcosim.engine.ssd import read_scenario

ROOT = Path(__file__).resolve().parents[1]
RUN = """
import sys
from emcosim.engine.libcosim import _simulate
from emcosim.engine.ssd import read_scenario
s = read_scenario(sys.argv[1], fmu_dir=sys.argv[2])
r = _simulate(s, 0.5, None, None, ["plant.q"])
print(len(r.rows), r.rows[-1][0])
"""


@pytest.mark.parametrize("attempt", range(3))
def test_libcosim_in_this_process_exits_cleanly(attempt, fmu_dir):
    pytest.importorskip("libcosimpy")
    proc = subprocess.run([sys.executable, "-c", RUN, str(ROOT / "scenarios" / "maglev_tracking_D-1_R0.82"),
                           str(fmu_dir)], capture_output=True, text=True, timeout=120, cwd=str(ROOT))
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])
    rows, t_end = proc.stdout.strip().splitlines()[-1].split()      # libcosim logs to stdout too
    steps = round(0.5 / float(read_scenario(ROOT / "scenarios" / "maglev_tracking_D-1_R0.82").step_size))
    assert int(rows) == steps + 1 and float(t_end) == 0.5      # the scenario's steps over 0.5 s, and t = 0

"""Concurrency: two `emcosim run` processes at the same time (different scenarios, short stop times)
give CSVs identical, byte for byte, to the same runs made alone."""
from __future__ import annotations

import subprocess
import sys

import pytest

from .harness import ROOT

pytestmark = pytest.mark.reliability

RUNS = {"mems_tracking_Dd-0.4": "2e-3", "maglev_tracking_D-1_R0.82": "0.5"}


def _cmd(name, stop, fmu_dir, out):
    return [sys.executable, "-m", "emcosim.cli", "run", name, "--fmu-dir", str(fmu_dir), "--stop-time", stop,
            "-o", str(out), "--no-progress"]


def test_two_scenarios_at_once_equal_alone(reliability_fmus, tmp_path, tally):
    fmu_dir = reliability_fmus["MEMS"].parent
    alone = {}
    for name, stop in RUNS.items():
        out = tmp_path / f"alone-{name}.csv"
        proc = subprocess.run(_cmd(name, stop, fmu_dir, out), capture_output=True, text=True, cwd=str(ROOT), timeout=600)
        assert proc.returncode == 0, proc.stderr
        alone[name] = out.read_bytes()
    procs = {name: subprocess.Popen(_cmd(name, stop, fmu_dir, tmp_path / f"together-{name}.csv"), cwd=str(ROOT),
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for name, stop in RUNS.items()}
    for name, proc in procs.items():
        _, err = proc.communicate(timeout=600)
        assert proc.returncode == 0, err.decode()
    for name in RUNS:
        together = (tmp_path / f"together-{name}.csv").read_bytes()
        assert len(together.splitlines()) > 10
        assert together == alone[name], f"{name}: the concurrent run differs from the run alone"
        tally.add("concurrency", name, "correct")

"""Fixtures of the reliability suite (`pytest -m reliability`): the built FMUs (session), the worker
subprocess that runs every FMU call (session), and the tally of cases written to JSON at the end."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from .harness import ALL, RESULTS_JSON, TALLY, WorkerProcess


@pytest.fixture(scope="session")
def reliability_fmus(fmu_dir, tmp_path_factory) -> dict[str, Path]:
    """Model identifier -> FMU of the session's build, copied into a session folder (a rebuild of
    build/fmus by someone else during the run cannot swap files under the suite)."""
    target = tmp_path_factory.mktemp("reliability_fmus")
    source = fmu_dir
    missing = [m for m in ALL if not (source / f"{m}.fmu").is_file()]
    if missing:
        pytest.fail(f"FMUs missing in {source}: {missing}")
    return {m: Path(shutil.copy2(source / f"{m}.fmu", target / f"{m}.fmu")) for m in ALL}


@pytest.fixture(scope="session")
def worker():
    w = WorkerProcess()
    yield w
    w.close()


@pytest.fixture(scope="session")
def tally():
    return TALLY


def pytest_sessionfinish(session, exitstatus):
    if TALLY.counts or TALLY.measurements:
        RESULTS_JSON.parent.mkdir(parents=True, exist_ok=True)
        RESULTS_JSON.write_text(json.dumps(TALLY.as_dict(), indent=1, sort_keys=True))


def pytest_terminal_summary(terminalreporter):
    if TALLY.counts:
        t = TALLY.totals()
        terminalreporter.write_line(
            f"reliability: {t.get('cases', 0)} cases, {t.get('correct', 0)} correct results, "
            f"{t.get('clean_error', 0)} clean errors (details: {RESULTS_JSON})")

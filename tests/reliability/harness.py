"""Harness of the reliability suite: the worker subprocess, the FMUs, the case tally.

Every FMU call runs in a worker subprocess (`_worker.py`): a crash of the worker fails the test that
caused it (with the request that killed it) and the next request starts a new worker; a request that
takes longer than its timeout counts as a hang, kills the worker and fails the test.
"""
from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WORKER = Path(__file__).with_name("_worker.py")
sys.path.insert(0, str(WORKER.parent))
import _worker  # noqa: E402  (protocol helpers; importing it loads no FMU)

sys.path.remove(str(WORKER.parent))

PLANTS = ("MEMS", "Maglev")
CONTROLLERS = ("MEMS_Proposition1", "MEMS_Theorem2", "Maglev_Proposition2", "Maglev_Theorem3")
ALL = PLANTS + CONTROLLERS + ("Reference",)
OK, WARNING, DISCARD, ERROR, FATAL = 0, 1, 2, 3, 4
DEFAULT_TIMEOUT = 120.0                  # seconds per request: far above any legitimate case (< 5 s)
RESULTS_JSON = Path(os.environ.get("EMCOSIM_RELIABILITY_JSON", ROOT / "build" / "reliability" / "counts.json"))


class WorkerCrash(AssertionError):
    """The worker process died or hung while serving a request."""


class WorkerProcess:
    """A persistent worker subprocess speaking the line protocol of `_worker.py`."""

    def __init__(self):
        self.proc: subprocess.Popen | None = None
        self.stderr = None
        self.restarts = 0

    def _start(self) -> None:
        self.stderr = tempfile.TemporaryFile(mode="w+b")      # never a pipe: a full pipe would block the worker
        self.proc = subprocess.Popen([sys.executable, str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.stderr, cwd=str(ROOT))

    def stderr_tail(self, n: int = 2000) -> str:
        if self.stderr is None:
            return ""
        self.stderr.seek(0)
        return self.stderr.read().decode("utf-8", "replace")[-n:]

    def call(self, request: dict, timeout: float = DEFAULT_TIMEOUT):
        if self.proc is None or self.proc.poll() is not None:
            if self.proc is not None:
                self.restarts += 1
            self._start()
        self.proc.stdin.write((_worker.dumps(request) + "\n").encode())
        self.proc.stdin.flush()
        line = self._read_line(timeout, request)
        answer = _worker.loads(line[len(_worker.RESULT_PREFIX):])
        if "harness_error" in answer:
            raise RuntimeError(f"harness error for {request['cmd']}: {answer['harness_error']}")
        return answer["answer"]

    def _read_line(self, timeout: float, request: dict) -> str:
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        buf = b""
        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    self.proc.kill()
                    self.proc.wait()
                    raise WorkerCrash(f"worker hung (> {timeout:g} s) on {_short(request)}")
                if not sel.select(left):
                    continue
                chunk = os.read(self.proc.stdout.fileno(), 1 << 16)
                if not chunk:
                    code = self.proc.wait()
                    raise WorkerCrash(f"worker died (exit status {code}) on {_short(request)}; "
                                      f"stderr: {self.stderr_tail()}")
                buf += chunk
                if buf.endswith(b"\n"):
                    lines = [x for x in buf.decode().splitlines() if x.startswith(_worker.RESULT_PREFIX)]
                    if lines:
                        return lines[-1]
        finally:
            sel.close()

    def close(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.stdin.close()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.stderr is not None:
            self.stderr.close()


def _short(request: dict) -> str:
    text = _worker.dumps(request)
    return text if len(text) < 600 else text[:600] + "..."


def run_worker_once(command: str, request: dict, timeout: float = 300.0) -> dict:
    """Run one command in a fresh worker process (`_worker.py COMMAND JSON`)."""
    proc = subprocess.run([sys.executable, str(WORKER), command, _worker.dumps(request)], capture_output=True,
                          cwd=str(ROOT), timeout=timeout)
    lines = [x for x in proc.stdout.decode().splitlines() if x.startswith(_worker.RESULT_PREFIX)]
    if proc.returncode != 0 or not lines:
        raise WorkerCrash(f"worker {command} exited with status {proc.returncode}: {proc.stderr.decode()[-2000:]}")
    answer = _worker.loads(lines[-1][len(_worker.RESULT_PREFIX):])
    if "harness_error" in answer:
        raise RuntimeError(answer["harness_error"])
    return answer["answer"]


# ---- the tally of cases, written at the end of the session -----------------------------------------
class Tally:
    """Cases per (group, subject, outcome); outcomes are 'correct' or 'clean_error' (anything else
    fails its test before it is counted). Extra measurements go to `measurements`."""

    def __init__(self):
        self.counts: dict[str, dict[str, dict[str, int]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(int)))
        self.measurements: dict[str, dict] = defaultdict(dict)
        self.started = time.time()

    def add(self, group: str, subject: str, outcome: str, n: int = 1) -> None:
        self.counts[group][subject][outcome] += n

    def totals(self) -> dict[str, int]:
        out: dict[str, int] = defaultdict(int)
        for subjects in self.counts.values():
            for outcomes in subjects.values():
                for outcome, n in outcomes.items():
                    out[outcome] += n
                    out["cases"] += n
        return dict(out)

    def as_dict(self) -> dict:
        return {"counts": json.loads(json.dumps(self.counts)), "totals": self.totals(),
                "measurements": dict(self.measurements), "seconds": round(time.time() - self.started, 1)}


TALLY = Tally()

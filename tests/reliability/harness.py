"""Harness of the reliability suite: the worker subprocess, the FMUs, the case tally.

Every FMU call runs in a worker subprocess (`fmu_worker.py`): a crash of the worker fails the test that
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
WORKER = Path(__file__).with_name("fmu_worker.py")
sys.path.insert(0, str(WORKER.parent))
import fmu_worker  # noqa: E402  (protocol helpers; importing it loads no FMU)

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
    """A persistent worker subprocess speaking the line protocol of `fmu_worker.py`."""

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
        self.proc.stdin.write((fmu_worker.dumps(request) + "\n").encode())
        self.proc.stdin.flush()
        line = self._read_line(timeout, request)
        answer = fmu_worker.loads(line[len(fmu_worker.RESULT_PREFIX):])
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
                    lines = [x for x in buf.decode().splitlines() if x.startswith(fmu_worker.RESULT_PREFIX)]
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
    text = fmu_worker.dumps(request)
    return text if len(text) < 600 else text[:600] + "..."


def run_worker_once(command: str, request: dict, timeout: float = 300.0) -> dict:
    """Run one command in a fresh worker process (`fmu_worker.py COMMAND JSON`)."""
    proc = subprocess.run([sys.executable, str(WORKER), command, fmu_worker.dumps(request)], capture_output=True,
                          cwd=str(ROOT), timeout=timeout)
    lines = [x for x in proc.stdout.decode().splitlines() if x.startswith(fmu_worker.RESULT_PREFIX)]
    if proc.returncode != 0 or not lines:
        raise WorkerCrash(f"worker {command} exited with status {proc.returncode}: {proc.stderr.decode()[-2000:]}")
    answer = fmu_worker.loads(lines[-1][len(fmu_worker.RESULT_PREFIX):])
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


def reset_case(identifier: str) -> dict:
    """Parameters other than the defaults, and inputs varying per step."""
    if identifier == "MEMS":
        return {"h": 1e-6, "values": {"c1": 40e-9, "q_0": 2e-5}, "steps": [{"u": 20.0 + k} for k in range(8)],
                "first_values": {"a1": 0.5}, "first_steps": [{"u": 30.0}] * 5}
    if identifier == "Maglev":
        return {"h": 1e-3, "values": {"R_e": 2.0, "q_0": 0.002}, "steps": [{"u": 0.5 + 0.1 * k} for k in range(8)],
                "first_values": {"m": 0.1}, "first_steps": [{"u": 3.0}] * 5}
    if identifier == "Reference":
        return {"h": 1e-3, "values": {"kind": 2, "q_from": 1e-5, "q_to": 2e-5, "t_start": 1e-3, "duration": 4e-3},
                "steps": [{}] * 8, "first_values": {"kind": 1, "omega": 50.0}, "first_steps": [{}] * 5}
    mems = identifier.startswith("MEMS")
    base = {"q": 2.5e-5, "p": 1e-10, "x_e": 4e-11} if mems else {"q": 0.002, "p": 0.001, "x_e": 0.9}
    jet = ({"q_star": 3e-5, "q_star_dot": 0.01, "q_star_ddot": -3.0, "q_star_dddot": 100.0} if mems else
           {"q_star": 0.002, "q_star_dot": 0.01, "q_star_ddot": -0.3, "q_star_dddot": 2.0})
    inputs = dict(base, **jet) if identifier.endswith(("Theorem2", "Theorem3")) else base
    steps = [{k: v * (1 + 0.03 * i) for k, v in inputs.items()} for i in range(8)]
    gains = {"MEMS_Proposition1": {"D_d": 2e-5}, "MEMS_Theorem2": {"D_d": -0.3},
             "Maglev_Proposition2": {"q_d": 0.002}, "Maglev_Theorem3": {"D_d": -0.5}}[identifier]
    return {"h": 1e-6, "values": gains, "steps": steps, "first_values": {}, "first_steps": steps[::-1]}

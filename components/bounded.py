"""Bounded work for what a plant description file makes emcosim compute (issue 31: no file can hang it).

time_limit(seconds)   a block of symbolic work (sympy, Python code) stopped after `seconds`: SIGALRM raises
                      SymbolicTimeout (a BaseException, so that no `except Exception` inside sympy swallows
                      it); the block ends and `limit.expired` says so. Main thread only (elsewhere no limit).
in_worker(fn, *args)  fn(*args) in a forked worker process, its result sent back pickled. The parent waits
                      in 0.1 s polls, so that a signal (Ctrl-C, SIGTERM) or the time limit ends the wait at
                      once even when the worker is stuck inside C (a huge integer power); the worker is then
                      killed. The worker ignores SIGINT (the parent decides) and dies with its parent.
"""
from __future__ import annotations

import os
import pickle
import select
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator

WORKER_SECONDS = 600.0
"""Default time limit of the worker that parses and checks one description (its symbolic steps have their
own, shorter limits, components.description.SYMBOLIC_SECONDS)."""
POLL = 0.1
"""Seconds between two looks of the waiting parent (for a signal, the time limit, the worker's end)."""


class SymbolicTimeout(BaseException):
    """A time_limit expired (raised by SIGALRM inside the limited block, caught by time_limit)."""


class WorkerTimeout(ValueError):
    """The worker did not finish within its time limit (it was killed)."""


@dataclass
class Limit:
    deadline: float
    expired: bool = False


_active: list[Limit] = []
_previous_handler: Any = None


def _on_alarm(signum: int, frame: Any) -> None:
    now = time.monotonic()
    hit = [limit for limit in _active if limit.deadline <= now]
    for limit in hit:
        limit.expired = True
    if hit:
        raise SymbolicTimeout()


def _arm() -> None:
    first = min(limit.deadline for limit in _active) - time.monotonic()
    signal.setitimer(signal.ITIMER_REAL, max(first, 1e-3), 0.2)     # again every 0.2 s until the block ends


@contextmanager
def time_limit(seconds: float) -> Iterator[Limit]:
    """Run the block for at most `seconds` (see the module's docstring); nests (the earliest deadline wins,
    each block ends on its own)."""
    global _previous_handler
    limit = Limit(time.monotonic() + seconds)
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "setitimer"):
        yield limit
        return
    if not _active:
        _previous_handler = signal.signal(signal.SIGALRM, _on_alarm)
    _active.append(limit)
    _arm()
    try:
        yield limit
    except SymbolicTimeout:
        if not limit.expired:                          # an outer block's limit: that block ends
            raise
    finally:
        _active.remove(limit)
        if _active:
            _arm()
        else:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, _previous_handler or signal.SIG_DFL)


def _die_with_parent() -> None:
    """Linux: the kernel kills this process when its parent dies (prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes
        ctypes.CDLL(None).prctl(1, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def in_worker(fn: Callable[..., Any], *args: Any, seconds: float = WORKER_SECONDS, what: str = "the work") -> Any:
    """fn(*args) in a forked worker process (see the module's docstring); its exception is raised here.
    WorkerTimeout after `seconds`. Without fork (not POSIX) fn runs in this process."""
    if not hasattr(os, "fork"):
        return fn(*args)
    read, write = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:                                       # the worker
        code = 0
        try:
            os.close(read)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            _die_with_parent()
            try:
                message: tuple = ("ok", fn(*args))
            except BaseException as exc:               # noqa: BLE001 - every failure goes to the parent
                message = ("error", exc)
            try:
                data = pickle.dumps(message)
            except Exception:                          # an unpicklable result or exception: its text
                data = pickle.dumps(("error", ValueError(f"{type(message[1]).__name__}: {message[1]}")))
            with os.fdopen(write, "wb") as out:
                out.write(data)
        except BaseException:                          # noqa: BLE001
            code = 1
        finally:
            os._exit(code)
    os.close(write)
    chunks: list[bytes] = []
    deadline = time.monotonic() + seconds
    done = False
    try:
        while True:
            if time.monotonic() > deadline:
                raise WorkerTimeout(f"{what}: not finished after {seconds:g} s (the limit); stopped")
            ready, _, _ = select.select([read], [], [], POLL)
            if ready:
                chunk = os.read(read, 1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
        done = True
    finally:
        os.close(read)
        if not done:
            os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
    if not chunks:
        raise ValueError(f"{what}: the worker process ended without a result (status {status})")
    kind, value = pickle.loads(b"".join(chunks))
    if kind == "error":
        raise value
    return value

"""The loader checks every FMI argument before it reads the host's arrays (issue 31, item 2;
fmus/emcosim_fmu_loader.c, point 6 of its header), in a C host (tests/fixtures/c_guard.c) whose every array
ends at a PROT_NONE guard page: one element read or written past what the loader may touch kills the host.

On main before the fix, the first call with a count past its array (fmi2SetReal, 20 value references for a
one-element array) ended the host with SIGSEGV (exit -11): the loader copied the value references before it
looked at nvr; fmi2SetContinuousStates read x[0..nx-1] before nx was checked, the same way.

The same host and the loader built with AddressSanitizer and UndefinedBehaviorSanitizer run the wrong
counts and the illegal calls of both state machines (calls out of order, a NULL, unknown and freed instance,
a double fmi2FreeInstance, foreign and freed FMU states) with no finding; a deliberate heap read past an array
in the host is reported, so the check can fail.
"""
from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import pytest

from .c_host import (
    CALLS_SOURCE,
    GUARD_SOURCE,
    SANITIZE,
    THREADS_SOURCE,
    compile_c_host,
    compile_test_loader,
    extract,
    run_calls,
    run_guard,
    threads_command,
)

# LeakSanitizer stays on for the loader's own allocations. The interpreter the loader starts is never finalized
# (on purpose: fmus/emcosim_fmu_loader.c, header), so what Python, numpy and scipy, pythonfmu's library and
# OpenSSL (hashlib) hold at exit is reported as leaked (9 MB in 7000 allocations): those libraries are suppressed.
LEAK_SUPPRESSIONS = "leak:libpython\nleak:site-packages\nleak:libpythonfmu-export\nleak:libcrypto\n"
# Every called function must be one of these, and each list must be exercised (the test cannot pass empty)
GUARDED = {"setr-count", "getr-count", "seti-count", "geti-count", "setb-count", "gets-count", "jac-unknown-count",
           "jac-known-count", "setx-count", "getx-count", "der-count", "nominals-count", "indicators-count",
           "dset-count", "dget-count", "deser-count", "deser-huge", "ser-short", "setr-null", "setx-null", "der-null",
           "deser-null", "sersize-null", "dset-null"}
ILLEGAL = {"me-setx-instantiated", "me-setx-event", "me-setx-terminated", "me-dostep", "me-setx-freed",
           "cs-dostep-instantiated", "cs-setx", "cs-dostep-terminated", "cs-dostep-freed", "null-setx", "null-getr",
           "unknown-deser", "unknown-nominals"}


@pytest.fixture(scope="module")
def c_guard(tmp_path_factory) -> Path:
    exe = tmp_path_factory.mktemp("c_guard") / "c_guard"
    reason = compile_c_host(exe, GUARD_SOURCE)
    if reason:
        pytest.skip(reason)
    return exe


def _check(run, lines: list[list[str]], expected: set[str]) -> list[list[str]]:
    """The host ran to its end; each refused call got fmi2Error (3), each right call fmi2OK (0); the calls
    of `expected` were made. The host's lines "bad|ok LABEL STATUS"."""
    assert run.returncode == 0, f"exit status {run.returncode} after {lines[-1:]}: {run.stderr[-1500:]}"
    calls = [w for w in lines if w[0] in ("bad", "ok")]
    assert lines[-1] == ["done", str(len(calls))], lines[-3:]
    wrong = [w for w in calls if w[2] != ("3" if w[0] == "bad" else "0")]
    assert not wrong, (wrong, run.stderr[-1500:])
    assert expected <= {w[1] for w in calls}, expected - {w[1] for w in calls}
    return calls


def _logged_errors(stderr: str) -> list[str]:
    """The host's logger's lines of status fmi2Error (tests/fixtures/c_host_common.h: "[name] 3 category: text")."""
    return [line for line in stderr.splitlines() if line.startswith("[") and line.split("] ", 1)[1].startswith("3 ")]


@pytest.mark.parametrize("identifier", ["MEMS", "MEMS_Theorem2"])
def test_counts_past_the_arrays_and_null_arrays_are_refused_before_a_read(c_guard, fmus, tmp_path, identifier):
    """Each array-taking function, on a Model Exchange and a Co-Simulation instance, with a count past its
    array (nx + 1, ni + 1, more value references than the FMU has variables of the type, a serialized state's
    size + 1 and SIZE_MAX, a buffer one byte short) and with NULL arrays: fmi2Error and one message each, and
    the host lives on (before the fix: SIGSEGV at the first one). The right calls then work. The plant has 3
    states, 1 event indicator, 19 Real and no Integer variables; the controller no state, 17 Real and 1
    Integer variable."""
    folder, _ = extract(fmus[identifier], tmp_path)
    run, lines = run_guard(c_guard, folder, "guard")
    calls = _check(run, lines, GUARDED if identifier == "MEMS" else GUARDED - {"setx-null", "der-null"})
    refused = [w for w in calls if w[0] == "bad"]
    assert len(refused) > 60 and len(_logged_errors(run.stderr)) == len(refused), run.stderr[-3000:]
    for words in ("fmi2SetContinuousStates: 1 values for 0 states" if identifier != "MEMS" else
                  "fmi2SetContinuousStates: 4 values for 3 states",
                  "fmi2GetReal: 18 value references, more than this FMU's 17 Real variables" if identifier != "MEMS"
                  else "fmi2GetReal: 20 value references, more than this FMU's 19 Real variables",
                  "is not the serialized state's length", "NULL array or pointer argument"):
        assert words in run.stderr, (words, run.stderr[-3000:])


def test_illegal_calls_of_both_state_machines_are_refused(c_guard, fmus, tmp_path):
    """Model Exchange calls out of order (states set after fmi2Instantiate, in initialization and event mode,
    after fmi2Terminate and fmi2Reset; fmi2NewDiscreteStates in continuous-time mode; Co-Simulation functions),
    Co-Simulation ones (doStep before initialization and after fmi2Terminate; Model Exchange functions), a
    NULL and an unknown instance in each of the 40 functions that take one, fmi2FreeInstance twice and calls
    on the freed instance: each fmi2Error; the right calls between them fmi2OK; the host exits with 0."""
    folder, _ = extract(fmus["MEMS"], tmp_path)
    run, lines = run_guard(c_guard, folder, "illegal")
    calls = _check(run, lines, ILLEGAL)
    assert len([w for w in calls if w[1].startswith(("null-", "unknown-"))]) == 2 * 40
    assert run.stderr.count("fmi2FreeInstance called with an unknown or freed instance") == 2 + 1


@pytest.mark.parametrize("cc", ["gcc", "clang"])
def test_loader_is_c99_and_warning_free(cc, tmp_path):
    """The loader compiles as C99 (-std=c99, POSIX) with -Wall -Wextra -Werror under gcc and clang (skipped
    where clang is not installed: apt-get install clang)."""
    if shutil.which(cc) is None:
        pytest.skip(f"needs {cc}")
    assert compile_test_loader(tmp_path / "loader.so", ["-std=c99", "-D_GNU_SOURCE", "-O2"], cc) is None


# ---- AddressSanitizer and UndefinedBehaviorSanitizer ----------------------------------------------------
@pytest.fixture(scope="module")
def sanitized(tmp_path_factory, fmus) -> dict[str, Path]:
    """The plant and a controller FMU extracted with their loader built under the sanitizers, the hosts of
    tests/fixtures/c_guard.c, c_calls.c and c_threads.c built under them too (so libasan is loaded first, as
    it must be: no LD_PRELOAD), and the LeakSanitizer suppressions."""
    work = tmp_path_factory.mktemp("sanitized")
    folder, _ = extract(fmus["MEMS"], work)
    controller, _ = extract(fmus["MEMS_Proposition1"], work)
    loader = folder / "binaries" / "linux64" / "MEMS.so"
    reason = compile_test_loader(loader, SANITIZE + ["-O1"])
    if reason is None:
        shutil.copy2(loader, controller / "binaries" / "linux64" / "MEMS_Proposition1.so")
    hosts = {"guard": work / "c_guard", "calls": work / "c_calls", "threads": work / "c_threads"}
    for name, source in (("guard", GUARD_SOURCE), ("calls", CALLS_SOURCE), ("threads", THREADS_SOURCE)):
        reason = reason or compile_c_host(hosts[name], source, sanitize=True)
    if reason:
        pytest.skip(reason)
    (work / "lsan.supp").write_text(LEAK_SUPPRESSIONS)
    return {"folder": folder, "controller": controller, **hosts, "suppressions": work / "lsan.supp"}


def _sanitizer_env(sanitized) -> dict[str, str]:
    return {"ASAN_OPTIONS": "halt_on_error=1:detect_leaks=1",
            "LSAN_OPTIONS": f"suppressions={sanitized['suppressions']}:print_suppressions=0",
            "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1"}


def _findings(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines()
            if "AddressSanitizer" in line or "LeakSanitizer" in line or "runtime error:" in line]


@pytest.mark.parametrize("mode", ["guard", "illegal"])
def test_wrong_counts_and_illegal_calls_under_sanitizers(sanitized, mode):
    """The wrong counts (both instances) and the illegal calls of both state machines, with the loader and
    the host built with -fsanitize=address,undefined: the same answers as without, and no finding of
    AddressSanitizer, LeakSanitizer (the loader's own allocations) or UndefinedBehaviorSanitizer."""
    if shutil.which("gcc") is None:
        pytest.skip("needs gcc")
    run, lines = run_guard(sanitized["guard"], sanitized["folder"], mode, env=_sanitizer_env(sanitized))
    assert not _findings(run.stderr), run.stderr[-4000:]
    _check(run, lines, GUARDED if mode == "guard" else ILLEGAL)


def test_bad_calls_and_a_logger_that_calls_back_under_sanitizers(sanitized):
    """tests/test_c_host.py's bad calls (a changed and a doubled deserialization, a foreign state, doStep after
    fmi2Terminate, fmi2FreeInstance twice) and its logger that calls back into the instance, fmi2Reset and
    fmi2FreeInstance included, under the sanitizers: no finding, the host exits with 0."""
    folder = sanitized["folder"]
    for calls in (["inst", "init", "sget", "ser", "flip", "60", "deser", "deser", "cut", "40", "deser", "step", "0",
                   "1e-6", "sbogus", "term", "step", "1e-6", "1e-6", "free", "free", "inst", "init", "free"],
                  ["inst", "init", "reenter", "12", "reenter_free", "setr", "11", "nan", "step", "0", "1e-6",
                   "getr", "12", "free"]):
        run, lines = run_calls(sanitized["calls"], folder, calls, env=_sanitizer_env(sanitized))
        assert run.returncode == 0 and not _findings(run.stderr), run.stderr[-4000:]
        assert ["free"] in lines, lines


def test_two_fmus_instantiated_at_once_from_two_threads_under_sanitizers(sanitized):
    """tests/test_c_host.py's race (issue 26, item 7: two FMUs start Python from two threads at once), 3
    rounds, under the sanitizers: no finding, every round of both threads fmi2OK with a finite output."""
    command = threads_command(sanitized["threads"], [sanitized["folder"], sanitized["controller"]], ["q", "u"], 3)
    env = [f"{k}={v}" for k, v in _sanitizer_env(sanitized).items()]
    run = subprocess.run([*command[:2], *env, *command[2:]], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and not _findings(run.stderr), run.stderr[-4000:]
    rounds = [line.split() for line in run.stdout.splitlines() if line.startswith("round")]
    assert len(rounds) == 6 and all(r[4] == "0" and math.isfinite(float(r[5])) for r in rounds), rounds


def test_sanitizer_reports_a_read_past_an_array(sanitized):
    """The check can fail: a heap read one element past an array in the host, after the loader has started
    Python and made an instance, is reported (by UndefinedBehaviorSanitizer first: "load of address ... with
    insufficient space"; AddressSanitizer's heap-buffer-overflow when UBSan is off) and ends the process
    non-zero."""
    env = _sanitizer_env(sanitized)
    run, _ = run_guard(sanitized["guard"], sanitized["folder"], "oob", env=env)
    assert run.returncode != 0 and "insufficient space" in run.stderr and _findings(run.stderr), run.stderr[-2000:]
    run, _ = run_guard(sanitized["guard"], sanitized["folder"], "oob", env={**env, "UBSAN_OPTIONS": "halt_on_error=0"})
    assert run.returncode != 0 and "AddressSanitizer: heap-buffer-overflow" in run.stderr, run.stderr[-2000:]

"""pythonfmu 0.7.0 as the emcosim FMUs use it: the one module that imports pythonfmu, and every workaround
of its defects, each with what it works around and how it was measured (docs/reliability.md has the
findings' full stories).

The FMU's binary (fmus/emcosim_fmu_loader.c) forwards only fmi2Instantiate, fmi2Reset and fmi2FreeInstance
to pythonfmu's library and answers every other FMI call itself through the slave's `fmi2_*` methods
(fmus/slave.py): pythonfmu 0.7.0 turns any Python exception into fmi2Fatal and then releases the slave
object once too often, returns fmi2OK whatever a setter logs, forwards log messages only to hosts that
instantiated with loggingOn, and answers "not supported" to the derivative functions and to every Model
Exchange function. What remains of pythonfmu here is the slave's base class and its variable
registration, used by its library to create the Python object of an instance.
"""
from __future__ import annotations

import ctypes
import threading
from typing import Any

from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real
from pythonfmu._version import __version__ as PYTHONFMU_VERSION
from pythonfmu.enums import Fmi2Status

__all__ = ["DefaultExperiment", "Fmi2Causality", "Fmi2Slave", "Fmi2Status", "Fmi2Variability", "Integer",
           "PYTHONFMU_VERSION", "Real", "hold_script_globals", "keep_thread_state", "raise_to_host",
           "register_new_slave", "take_new_slave"]

# pythonfmu versions whose reference counting was measured to behave as described below
REFCOUNT_COMPENSATED_VERSIONS = {"0.7.0"}


def hold_script_globals(namespace: dict) -> None:
    """Call at the top level of every FMU script with globals().

    Works around: pythonfmu 0.7.0 finds the slave class by re-executing the script in the module's
    namespace at each fmi2Instantiate and then releases that namespace (a borrowed reference) once too
    often; a script without functions of its own loses its globals after the first instance is freed, and
    the next fmi2Instantiate crashed the host. Each execution of the
    script therefore takes one reference here: the re-executions are balanced, the first import keeps one
    (the module lives for the process)."""
    if PYTHONFMU_VERSION in REFCOUNT_COMPENSATED_VERSIONS:
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(namespace))


def raise_to_host(slave: Any, exc: Exception, message: str) -> None:
    """Fail the current pythonfmu call (pythonfmu reports fmi2Fatal) with `message`, keeping the instance
    valid. Works around: pythonfmu 0.7.0 releases the slave's references once more than it holds after an
    exception (two failed calls and the host crashed), so they get one extra reference first.
    Versions of pythonfmu not measured get a log entry instead of the exception."""
    if PYTHONFMU_VERSION not in REFCOUNT_COMPENSATED_VERSIONS:
        slave.log_error(message)
        return
    for obj in (slave, type(slave), slave.log_queue):
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))
    raise RuntimeError(message) from exc


_PINNED_THREADS: set[int] = set()


def keep_thread_state() -> None:
    """Keep the calling thread's Python thread state alive between FMI calls, if the host created the
    thread (a C host calls from its own threads: Python sees a threading._DummyThread).

    Works around: pythonfmu enters Python with PyGILState_Ensure and leaves with PyGILState_Release in
    every FMI call; for a thread Python did not create, that creates and destroys a thread state each time
    (measured in a C host: a controller's doStep took 12.7 us, 2.0 us with the thread state kept). One
    more PyGILState_Ensure, never released, keeps the thread state; pythonfmu's Release still releases the
    GIL after each call (CPython's gilstate counter stays above zero). Done for the thread that
    instantiates the FMU (other threads keep working, at the higher cost). Cost: one thread state per host
    thread, freed by Py_Finalize."""
    thread = threading.current_thread()
    if not isinstance(thread, threading._DummyThread) or thread.ident in _PINNED_THREADS:
        return
    ctypes.pythonapi.PyGILState_Ensure()
    _PINNED_THREADS.add(thread.ident)


_NEW_SLAVES: dict[int, Any] = {}


def register_new_slave(slave: Any) -> None:
    """Called by every slave's constructor: see `take_new_slave`."""
    _NEW_SLAVES[threading.get_ident()] = slave


def take_new_slave() -> Any:
    """The slave constructed last on the calling thread and not taken yet, or None.

    Works around: pythonfmu's library gives a host no access to the Python object of an instance. The
    loader calls this right after forwarding fmi2Instantiate and fmi2Reset to pythonfmu (which constructs
    the slave on the calling thread, and a new one on reset), to know the object whose `fmi2_*` methods
    answer the FMI functions."""
    return _NEW_SLAVES.pop(threading.get_ident(), None)

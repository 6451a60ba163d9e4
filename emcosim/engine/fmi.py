"""The engine's one adapter to fmpy's FMI 2.0 classes: reading a modelDescription, instantiating an FMU for
Co-Simulation (fmpy's FMU2Slave) or Model Exchange (FMU2Model) with a logger, and the raw ctypes function
of an FMI call.

Works around: fmpy's Python wrappers (`slave.getReal(...)`, ...) convert their arguments and check the
status on every call, a Python layer of about 1-2 us per call on this project's machine (docs/scenarios.md);
the master calls the FMI functions of preallocated arrays millions of times. fmpy keeps the raw functions
in its private `_functions` dict; this module is the one place that reads it (`raw`, `bare`).

Works around, second: fmpy's raw functions carry `argtypes`, so ctypes converts every argument through
its type's `from_param` on every call. `bare` gives the same C function without them (the caller passes
ctypes objects of the exact C types). Measured on the native maglev plant (build.py --native), 1e5 calls
each, this project's 2-core machine: fmi2GetDerivatives 0.44 -> 0.21 us, fmi2GetReal of 3 values 0.59 ->
0.24 us, fmi2SetTime 0.25 -> 0.17 us (a prebuilt c_double); the Model Exchange engine makes 8-10 such
calls per evaluation (ode.py).
"""
from __future__ import annotations

import ctypes
from typing import Callable

from fmpy import calloc, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Model,
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
    fmi2EventInfo,
    fmi2FMUstate,
)

__all__ = ["FMICallException", "STATUS", "bare", "fmi2EventInfo", "fmi2FMUstate", "instantiate", "raw",
           "read_model_description"]

STATUS = ["ok", "warning", "discard", "error", "fatal", "pending"]


def instantiate(model_description, unzipdir: str, name: str, model_exchange: bool,
                log: Callable[[int, str], None]):
    """An instantiated FMU2Slave (Co-Simulation) or FMU2Model (Model Exchange) whose messages go to
    log(status, text), and the ctypes callbacks (keep them alive as long as the instance). Raises fmpy's
    exception if fmi2Instantiate returns NULL."""
    def logger(component, instance_name, status, category, message):
        # FMI 2.0 passes a printf format; the ctypes callback gets no variadic arguments, so a message is taken
        # as formatted text whose "%%" stand for "%" (what FMUs that log plain text, like ours, send)
        log(status, message.decode("utf-8", "replace").replace("%%", "%") if message else "")

    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(logger)
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    interface = model_description.modelExchange if model_exchange else model_description.coSimulation
    cls = FMU2Model if model_exchange else FMU2Slave
    fmu = cls(guid=model_description.guid, unzipDirectory=unzipdir, modelIdentifier=interface.modelIdentifier,
              instanceName=name)
    fmu.instantiate(callbacks=callbacks, loggingOn=True)
    return fmu, callbacks


def raw(fmu, function: str):
    """The raw ctypes function `function` ("fmi2GetReal", ...) of an fmpy FMU instance (module docstring)."""
    return fmu._functions[function]


_BARE = ctypes.CFUNCTYPE(ctypes.c_int)          # an fmi2Status function whose arguments ctypes passes as given


def bare(fmu, function: str):
    """The C function `function` of an fmpy FMU instance without fmpy's argument types (module docstring):
    every argument must be a ctypes object of the C parameter's type (c_void_p for the fmi2Component,
    c_size_t for sizes, c_double, c_int, arrays or c_void_p addresses for pointers); returns the fmi2Status."""
    return _BARE(ctypes.cast(fmu._functions[function], ctypes.c_void_p).value)

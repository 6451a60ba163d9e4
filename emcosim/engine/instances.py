"""The FMU instances of a scenario: what the engine knows of each (`Instance`), creating and freeing them."""
from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from . import fmi, stopping, tempdirs
from .archive import extract_archive
from .errors import Interrupted, ScenarioError
from .ssd import Scenario


@dataclass
class Instance:
    """One FMU of the scenario: its component name, its .fmu, modelDescription and variables by name, the
    fmpy instance once instantiated (`fmu`) and the messages it logged ("[status] text"); the input
    derivative order it declares it uses and the device whose model it holds (vendor.py; None: not declared)
    and what loading it warned of."""

    name: str
    path: Path
    model_description: Any                           # fmpy's ModelDescription
    variables: dict[str, Any]                        # name -> fmpy ModelVariable
    fmu: Any = None                                  # fmpy's FMU2Slave or FMU2Model, once instantiated
    messages: list[str] = field(default_factory=list)
    callbacks: Any = None
    model_exchange: bool = False                     # instantiated for Model Exchange
    input_order_used: int | None = None              # emcosim's vendor annotation (vendor.py)
    device: Any = None                               # the device it declares (vendor.Device), or None
    notes: list[str] = field(default_factory=list)   # warnings of loading ("text"), kept over resets

    def variable(self, name: str, scenario: Scenario):
        try:
            return self.variables[name]
        except KeyError:
            raise ScenarioError(f"{scenario.path}: unknown variable '{self.name}.{name}' "
                                f"(not in {self.path.name})") from None

    def raw(self, function: str):
        """The raw ctypes function of an FMI call of this instance (fmi.raw)."""
        return fmi.raw(self.fmu, function)

    @property
    def component(self):
        """The fmi2Component handle of the instance."""
        return self.fmu.component


def instantiate(inst: Instance, workdirs: list, model_exchange: bool = False) -> None:
    """Unpack the FMU into a temporary folder of this process (listed in `workdirs`) and instantiate it."""
    unzipdir = str(tempdirs.make(inst.name))          # emcosim-PID-...: removed at the next start if killed
    workdirs.append(unzipdir)
    extract_archive(inst.path, Path(unzipdir))       # within the archive limits (a zip bomb is refused)

    def log(status: int, text: str) -> None:
        inst.messages.append(f"[{fmi.STATUS[status] if 0 <= status < 6 else status}] {text}")

    try:
        inst.fmu, inst.callbacks = fmi.instantiate(inst.model_description, unzipdir, inst.name, model_exchange, log)
    except Exception:
        signum = stopping.requested()
        if signum is not None:
            # a stop was asked for and a second signal landed inside the FMU's instantiation (a Python FMU
            # turns the Signalled into its own fatal error, issue 40): the run was stopped, not failed
            raise Interrupted(signum) from None
        raise ScenarioError(f"{inst.path}: component '{inst.name}' could not be instantiated"
                            f"{last_message(inst)}") from None
    inst.model_exchange = model_exchange


def free(inst: Instance) -> None:
    """fmi2Terminate (if possible) and fmi2FreeInstance; the instance is then uninstantiated."""
    if inst.fmu is None:
        return
    try:
        inst.fmu.terminate()
    except Exception:
        pass
    try:
        inst.fmu.freeInstance()
    except Exception:
        pass
    inst.fmu = None


def reset_all(instances: dict[str, Instance], instantiate_again: Callable[[], None]) -> None:
    """fmi2Reset of every instance (their messages cleared); if one fails, every instance is freed and
    `instantiate_again` starts them from scratch."""
    try:
        for inst in instances.values():
            inst.fmu.reset()
            inst.messages.clear()
    except Exception:                     # noqa: BLE001 - any failure: start from scratch
        for inst in instances.values():
            free(inst)
            inst.messages.clear()
        instantiate_again()


def free_all(instances: dict[str, Instance], workdirs: list) -> None:
    """Free every instance and delete the folders their FMUs were unpacked into."""
    for inst in instances.values():
        free(inst)
    for d in workdirs:
        shutil.rmtree(d, ignore_errors=True)
    workdirs.clear()


def last_message(inst: Instance) -> str:
    """': <the last message that is not [ok]>', or '' (for error messages)."""
    errors = [m for m in inst.messages if not m.startswith("[ok]")]
    return f": {' '.join(errors[-1].split())}" if errors else ""

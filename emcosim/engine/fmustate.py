"""Saving and restoring the states of FMUs (fmi2GetFMUstate, fmi2SetFMUstate, fmi2FreeFMUstate), the one
way the engine does it: the trial of input derivative orders at the first point (master.py), the
rollback of implicit coupling's trial steps (implicit.py) and of rejected error-controlled steps
(stepcontrol.py)."""
from __future__ import annotations

import ctypes

from .errors import SimulationError
from .fmi import fmi2FMUstate


class States:
    """fmi2GetFMUstate / fmi2SetFMUstate / fmi2FreeFMUstate of a list of FMUs (instances.Instance), as raw
    ctypes calls (fmi.raw); a failure is a SimulationError that names the FMU, the function and the time.
    `why`: what the rollback is for, for the messages."""

    def __init__(self, instances: list, why: str):
        self.instances = instances
        self.why = why
        self.calls = [(inst, inst.component, inst.raw("fmi2GetFMUstate"), inst.raw("fmi2SetFMUstate"),
                       inst.raw("fmi2FreeFMUstate")) for inst in instances]

    def save(self, t: float) -> list:
        states: list = []
        for inst, component, get, _, _ in self.calls:
            state = fmi2FMUstate()
            if get(component, ctypes.byref(state)) > 1:
                self.free(states)
                raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in fmi2GetFMUstate at "
                                      f"t = {t:.9g} s ({self.why})")
            states.append(state)
        return states

    def restore(self, states: list, t: float) -> None:
        for (inst, component, _, set_, _), state in zip(self.calls, states):
            if set_(component, state) > 1:
                raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in fmi2SetFMUstate at "
                                      f"t = {t:.9g} s ({self.why})")

    def free(self, states: list) -> None:
        for (_, component, _, _, free), state in zip(self.calls, states):
            free(component, ctypes.byref(state))

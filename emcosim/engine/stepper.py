"""The stepper of one copy of a scenario's FMUs: resolve the values (and derivatives) at a communication
point in dependency order, record a row, step every FMU. The public interface that the master's runs,
the step control (stepcontrol.py) and implicit coupling (implicit.py) drive:

    stepper.t = t; stepper.resolve()      # values (and derivatives) at t, in dependency order
    stepper.row()                         # the recorded values at t
    stepper.step(t, h)                    # every FMU from t to t + h (implicit coupling: iterated)
    stepper.step_some(t, h, do_step)      # some FMUs only
    stepper.value_setter(component, names), stepper.failed(transfer, exc), stepper.fmu_time(), ...
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable

from . import coupling
from .errors import SimulationError
from .fmi import STATUS, FMICallException
from .instances import Instance, last_message
from .plan import Plan, resolve_values
from .ssd import Scenario
from .transfer import Mirror, NonFinite, Transfer


class Stepper:
    """Resolve, record and step; the hot loop of the master.

    derivatives: the output-derivative transfers (coupling.DerivativePlan) resolved after the values
    at every communication point, or None (zero-order hold). stepped: the components this stepper
    steps (default: all; a shadow copy for error estimation leaves the shared sources out)."""

    def __init__(self, scenario: Scenario, instances: dict[str, Instance], plan: Plan, slots: list,
                 derivatives: coupling.DerivativePlan | None = None, stepped: list[str] | None = None):
        self.scenario, self.instances, self.plan, self.slots = scenario, instances, plan, slots
        self.derivatives = derivatives
        self.order = [inst for name, inst in instances.items() if stepped is None or name in stepped]
        self.do_step = [(inst, inst.raw("fmi2DoStep"), inst.component) for inst in self.order]
        self.implicit: Any = None                          # implicit coupling (implicit.Implicit), set by the run
        self.reset_counters()
        self.step_time = 0.0
        self.step_times = {inst.name: 0.0 for inst in self.order}
        self.n_steps = 0
        self.t = scenario.start_time
        self._values_at: float | None = None              # the values are resolved at this time already

    def resolve(self, with_derivatives: bool = True) -> None:
        """Get and set every connected value at self.t in dependency order (the recorded ones too), then the
        derivatives (coupling.DerivativePlan); an FMU's failure or a value that is not finite ends the run."""
        slots = self.slots
        if self._values_at == self.t:                     # an implicit step resolved them at its end
            self._values_at = None
            return
        self._values_at = None
        try:
            resolve_values(self.plan, slots)
        except FMICallException as exc:
            self.failed(exc.transfer, exc)
        except NonFinite as exc:
            raise SimulationError(exc.message(self.t)) from None
        if self.derivatives is not None and with_derivatives:
            self._check_failure(self.derivatives_resolve())

    def derivatives_resolve(self):
        """Resolve the output derivatives at self.t (after the values): None, or (the transfer that
        failed, its FMICallException); a derivative that is not finite ends the run."""
        try:
            return self.derivatives.resolve(self.t, self.slots)
        except NonFinite as exc:
            raise SimulationError(exc.message(self.t)) from None

    def _check_failure(self, failure) -> None:
        if failure is not None:
            self.failed(*failure)

    def failed(self, transfer, exc: FMICallException):
        inst = transfer.inst
        raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in {exc.function} "
                              f"at t = {self.t:.9g} s{last_message(inst)}") from None

    def row(self) -> list:
        slots = self.slots
        return [slots[s] for s in self.plan.column_slots]

    def reset_counters(self) -> None:
        """Plans (their transfers and extrapolation histories) are reused across runs: start afresh."""
        for transfer in self.transfers():
            transfer.elapsed = 0.0
        for extrapolation in self.derivatives.extrapolations if self.derivatives is not None else []:
            extrapolation.history.clear()
        if self.derivatives is not None and self.derivatives.guard is not None:
            self.derivatives.guard.history.clear()

    def mirror(self, main: "Stepper", shared: set[str]) -> None:
        """Read the outputs (and output derivatives) of the components `shared` with `main` from
        main's buffers; main resolves each communication point first."""
        def values(gets):
            return [(Mirror(t, main.slots, [main.plan.slot[n] for n in names]) if t.inst.name in shared else t, names)
                    for t, names in gets]
        plan = self.plan
        self.plan = dataclasses.replace(plan, stages=[(values(gets), sets) for gets, sets in plan.stages],
                                        record=values(plan.record))
        d, md = self.derivatives, main.derivatives
        if d is not None and md is not None:
            def derivatives(gets):
                return [Mirror(t, md.values, [md.slot[(f"{t.inst.name}.{v}", k)] for v, k in t.entries])
                        if t.inst.name in shared else t for t in gets]
            self.derivatives = dataclasses.replace(d, passes=[[(derivatives(gets), sets) for gets, sets in levels]
                                                              for levels in d.passes])

    def transfers(self) -> list:
        """Every get/set transfer of a communication point (values, records, derivatives)."""
        out = [t for gets, sets in self.plan.stages for t, _ in gets + sets] + [t for t, _ in self.plan.record]
        out += self.implicit.transfers() if self.implicit is not None else []
        return out + (self.derivatives.transfers() if self.derivatives is not None else [])

    def fmu_time(self) -> float:
        return self.step_time + sum(t.elapsed for t in self.transfers())

    def fmu_times(self) -> dict[str, float]:
        """Wall time inside each FMU (doStep, get, set, derivatives)."""
        out = dict(self.step_times)
        for transfer in self.transfers():
            out[transfer.inst.name] = out.get(transfer.inst.name, 0.0) + transfer.elapsed
        return out

    def step(self, t: float, h: float) -> None:
        """Step every FMU from t to t + h (with implicit coupling: iterated, the values at t + h resolved)."""
        if self.implicit is not None:
            self.implicit.step(t, h)
            self._values_at = t + h
        else:
            self.step_some(t, h, self.do_step)
        self.n_steps += 1
        self.t = t + h

    def step_some(self, t: float, h: float, do_step: list) -> None:
        """fmi2DoStep from t over h of the FMUs `do_step` ([(instance, fmi2DoStep, component)])."""
        tic = time.perf_counter()
        times = self.step_times
        for inst, fn, comp in do_step:
            t_in = time.perf_counter()
            status = fn(comp, t, h, 1)
            times[inst.name] += time.perf_counter() - t_in
            if status > 1:
                self.step_time += time.perf_counter() - tic
                raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in fmi2DoStep "
                                      f"from t = {t:.9g} s (step {h:.3g} s, status {STATUS[status] if status < 6 else status})"
                                      f"{last_message(inst)}")
        self.step_time += time.perf_counter() - tic

    def value_setter(self, component: str, names: list[str]) -> Callable[[list[float]], None]:
        """A function that sets the Real inputs `names` of `component` to given values."""
        transfer = Transfer(self.instances[component], names, getter=False)

        def set_values(values: list[float]) -> None:
            for i, v in enumerate(values):
                transfer.values[i] = v
            try:
                transfer()
            except FMICallException as exc:
                self.failed(transfer, exc)
            except NonFinite as exc:
                raise SimulationError(exc.message(self.t)) from None
        return set_values

"""The linearization of a scenario's FMUs at a point: x' = A x + B w, z = C x + D w (issue 41).

Any FMI 2.0 Model Exchange FMUs wired by an SSP scenario; no physics. The FMUs are instantiated and
initialized as for a Model Exchange run (model_exchange.initialize: parameters, start values, the initial
event), then set to time t and the state x (fmi2SetTime, fmi2SetContinuousStates, the connected values
resolved in dependency order: ode.System.set_point). Each FMU with states or inputs gives its own Jacobian by
fmi2GetDirectionalDerivative, one call per known (a state or a Real input), of every unknown (the derivatives
and the Real outputs):

    der = A_o x + B_o u + ...,   y = C_o x + D_o u + E_y w        (every FMU's blocks, one matrix each)
    u = M y + E_u w                                                (the connections: M holds their factors)

w are the named inputs: a disturbance added to an input variable (E_u, e.g. at `plant.u`) or to an output
variable (E_y, e.g. the reference's `reference.q_star`, which then reaches every input it feeds). Solving
the connections (the chain rule; I - D_o M is invertible when the loop has no algebraic loop, which the
dependency plan already refused otherwise):

    y = (I - D_o M)^-1 (C_o x + (D_o E_u + E_y) w),   u = M y + E_u w,
    A = A_o + B_o dU/dx,   B = B_o dU/dw,

and a named output z is a state (a row of the identity), an output y or an input u. A equals the Jacobian
the Model Exchange solver takes (ode._JacobianPlan, in unscaled states); here every output and input is
kept, so that any of them can be named. The states are named "component.variable" (the variables that the
FMU's <Derivatives> point at), in the order of the ODE's state vector.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from . import binding
from . import instances as instances_
from .errors import ScenarioError, SimulationError
from .fmi import FMICallException
from .instances import Instance, last_message
from .model_exchange import initialize
from .ode import Statistics, System
from .options import Experiment
from .plan import make_plan
from .ssd import Scenario

RTOL = 1e-8        # the tolerance fmi2SetupExperiment passes (an FMU with an inner solver may use it)


@dataclass
class Linearization:
    """x' = A x + B w, z = C x + D w at time t and state x [the FMUs' units]: A [1/s], the columns of B per
    unit of each input, the rows of C and D in each output's unit."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: list[str]
    inputs: list[str]
    outputs: list[str]
    t: float
    x: np.ndarray                                       # the state it was taken at
    units: dict[str, str] = field(default_factory=dict)  # each state's, input's and output's unit ('' if none)

    @property
    def poles(self) -> np.ndarray:
        """The eigenvalues of A [1/s], sorted by real part (the slowest decay first)."""
        lam = np.linalg.eigvals(self.A) if self.A.size else np.zeros(0, complex)
        return lam[np.lexsort((lam.imag, -lam.real))]

    def report(self, title: str = "") -> str:
        """A, B, C, D with their row and column names, the operating point and the poles, as text."""
        def unit(name: str) -> str:
            return f" [{self.units[name]}]" if self.units.get(name) else ""

        def matrix(label: str, M: np.ndarray, rows: list[str], columns: list[str]) -> list[str]:
            if not M.size:
                return [f"{label}: empty ({len(rows)} x {len(columns)})"]
            width = max(14, *(len(c) + 2 for c in columns))
            head = max(len(r) for r in rows)
            lines = [f"{label}:", " " * head + "".join(f"{c:>{width}}" for c in columns)]
            lines += [f"{r:<{head}}" + "".join(f"{v:>{width}.6g}" for v in row) for r, row in zip(rows, M)]
            return lines

        lines = [title] if title else []
        lines.append(f"linearized at t = {self.t:g} s, state:")
        lines += [f"  {n} = {v:.10g}{unit(n)}" for n, v in zip(self.states, self.x)]
        lines.append(f"x' = A x + B w, z = C x + D w; w: {', '.join(self.inputs) or 'none'}; "
                     f"z: {', '.join(self.outputs) or 'none'}")
        lines += matrix("A [1/s]", self.A, self.states, self.states)
        lines += matrix("B", self.B, self.states, self.inputs)
        lines += matrix("C", self.C, self.outputs, self.states)
        lines += matrix("D", self.D, self.outputs, self.inputs)
        lines.append("poles [1/s] (eigenvalues of A):")
        for lam in self.poles:
            what = (f"time constant {1 / abs(lam.real):.4g} s" if lam.real < 0 else
                    "unstable" if lam.real > 0 else "on the imaginary axis")
            if lam.imag:
                what += f", {abs(lam.imag) / (2 * np.pi):.4g} Hz, damping ratio {-lam.real / abs(lam):.4g}"
            lines.append(f"  {lam.real:.10g} {'-' if lam.imag < 0 else '+'} {abs(lam.imag):.10g}j   {what}")
        return "\n".join(lines)

    def to_json(self) -> str:
        """The linearization as JSON: the names, units, time, state, A, B, C, D and the poles (re, im)."""
        import json

        return json.dumps({"t": self.t, "states": self.states, "inputs": self.inputs, "outputs": self.outputs,
                           "units": self.units, "x": self.x.tolist(), "A": self.A.tolist(), "B": self.B.tolist(),
                           "C": self.C.tolist(), "D": self.D.tolist(),
                           "poles": [[float(p.real), float(p.imag)] for p in self.poles]}, indent=1)


def state_names(scenario: Scenario) -> list[str]:
    """The continuous states of the scenario's FMUs, "component.variable", in the ODE's order."""
    instances = binding.load(scenario, model_exchange=True)
    return [name for inst in instances.values() for name in _states_of(inst)]


def _states_of(inst: Instance) -> list[str]:
    return [f"{inst.name}.{d.variable.derivative.name}" for d in inst.model_description.derivatives]


def _reals(inst: Instance, causality: str) -> list:
    return [v for v in inst.model_description.modelVariables if v.type == "Real" and v.causality == causality]


def linearize(scenario: Scenario, t: float | None = None, state: Mapping[str, float] | None = None,
              inputs: Sequence[str] = (), outputs: Sequence[str] | None = None,
              start_values: Mapping[str, str | float] | None = None) -> Linearization:
    """The linearization (module docstring) at time t (default: the start time) and the state `state`
    ("component.variable" -> value; the states not named keep their initial values, those of the scenario's
    start values), for the inputs `inputs` and the outputs `outputs` (default: the states). A ScenarioError
    names what cannot be linearized (an unknown or unsuitable name, an FMU without directional derivatives)."""
    t0 = scenario.start_time
    t = t0 if t is None else float(t)
    if not np.isfinite(t) or t < t0:
        raise ScenarioError(f"{scenario.path}: linearization time t = {t:g} s must be finite and not before the start "
                            f"time {t0:g} s")
    instances = binding.load(scenario, model_exchange=True)
    connections = binding.check_connections(scenario, instances)
    workdirs: list = []
    try:
        for inst in instances.values():
            instances_.instantiate(inst, workdirs, model_exchange=True)
        plan = make_plan(scenario, instances, connections, None)
        system = System(scenario, instances, connections, plan)
        system.statistics = Statistics("linearization", RTOL, exact_jacobian=True)
        parameters = binding.parameter_values(scenario, instances, dict(start_values or {}))
        stop = max(scenario.stop_time or t0, t) + 1.0
        initialize(system, parameters, Experiment(t0, stop, stop - t0, None), RTOL)
        names = [name for inst in instances.values() for name in _states_of(inst)]
        x = system.states()
        for name, value in (state or {}).items():
            if name not in names:
                raise ScenarioError(f"{scenario.path}: '{name}' is not a continuous state of the scenario "
                                    f"(states: {', '.join(names) or 'none'})")
            x[names.index(name)] = float(value)
        if not np.all(np.isfinite(x)):
            raise ScenarioError(f"{scenario.path}: the state to linearize at is not finite: {x.tolist()}")
        system.set_point(t, x / system.scale)
        return _assemble(scenario, instances, connections, names, x, t, list(inputs),
                         names if outputs is None else list(outputs))
    except SimulationError as exc:
        raise ScenarioError(f"linearization: {exc}") from None
    finally:
        instances_.free_all(instances, workdirs)


def _assemble(scenario: Scenario, instances: dict[str, Instance], connections, names: list[str], x: np.ndarray,
              t: float, inputs: list[str], outputs: list[str]) -> Linearization:
    """A, B, C, D (module docstring) from every FMU's directional derivatives at the point the FMUs are at."""
    n = len(names)
    ys = [(inst, v) for inst in instances.values() for v in _reals(inst, "output")]
    us = [(inst, v) for inst in instances.values() for v in _reals(inst, "input")]
    y_index = {f"{inst.name}.{v.name}": i for i, (inst, v) in enumerate(ys)}
    u_index = {f"{inst.name}.{v.name}": i for i, (inst, v) in enumerate(us)}
    A_o, B_o = np.zeros((n, n)), np.zeros((n, len(us)))
    C_o, D_o = np.zeros((len(ys), n)), np.zeros((len(ys), len(us)))
    offset = 0
    for inst in instances.values():
        md = inst.model_description
        derivatives = [d.variable for d in md.derivatives]
        own_y = [v for v in _reals(inst, "output")]
        own_u = [v for v in _reals(inst, "input")]
        rows = [(A_o, offset + i) for i in range(len(derivatives))] + [(C_o, y_index[f"{inst.name}.{v.name}"])
                                                                       for v in own_y]
        knowns = [(v, offset + j, True) for j, v in enumerate(d.variable.derivative for d in md.derivatives)]
        knowns += [(v, u_index[f"{inst.name}.{v.name}"], False) for v in own_u]
        unknowns = derivatives + own_y
        if unknowns and knowns:
            if not md.modelExchange.providesDirectionalDerivative:
                raise ScenarioError(f"{inst.path.name}: component '{inst.name}' provides no directional derivatives "
                                    "(providesDirectionalDerivative): its Jacobian is not known")
            refs = [v.valueReference for v in unknowns]
            for v, column, is_state in knowns:
                try:
                    column_values = inst.fmu.getDirectionalDerivative(refs, [v.valueReference], [1.0])
                except FMICallException:
                    raise SimulationError(f"{inst.path.name}: component '{inst.name}' failed in "
                                          f"fmi2GetDirectionalDerivative at t = {t:.9g} s{last_message(inst)}") from None
                for (target, row), value in zip(rows, column_values):
                    if target is A_o:
                        (A_o if is_state else B_o)[row, column] = value
                    else:
                        (C_o if is_state else D_o)[row, column] = value
        offset += len(derivatives)
    M = np.zeros((len(us), len(ys)))
    for c in connections:
        if c.end in u_index and c.start in y_index:
            M[u_index[c.end], y_index[c.start]] = c.factor
    E_u, E_y = np.zeros((len(us), len(inputs))), np.zeros((len(ys), len(inputs)))
    for k, name in enumerate(inputs):
        if name in u_index:
            E_u[u_index[name], k] = 1.0
        elif name in y_index:
            E_y[y_index[name], k] = 1.0
        else:
            comp, _, var = name.partition(".")
            known = instances[comp].variables.get(var) if comp in instances else None
            what = (f"a {known.causality} of {instances[comp].path.name}, not a Real input or output" if known is not None
                    else "not a variable of a component")
            raise ScenarioError(f"{scenario.path}: input '{name}': {what} (a disturbance is added to an input or "
                                f"output variable; the directional derivatives of FMI 2.0 are taken with respect to "
                                f"states and inputs; these are: {', '.join([*u_index, *y_index])})")
    I_DM = np.eye(len(ys)) - D_o @ M
    try:
        Y_x = np.linalg.solve(I_DM, C_o)
        Y_w = np.linalg.solve(I_DM, D_o @ E_u + E_y)
    except np.linalg.LinAlgError:
        raise ScenarioError(f"{scenario.path}: the connections form an algebraic loop: no linearization") from None
    U_x, U_w = M @ Y_x, M @ Y_w + E_u
    A, B = A_o + B_o @ U_x, B_o @ U_w
    C, D = np.zeros((len(outputs), n)), np.zeros((len(outputs), len(inputs)))
    for k, name in enumerate(outputs):
        if name in names:
            C[k, names.index(name)] = 1.0
        elif name in y_index:
            C[k], D[k] = Y_x[y_index[name]], Y_w[y_index[name]]
        elif name in u_index:
            C[k], D[k] = U_x[u_index[name]], U_w[u_index[name]]
        else:
            raise ScenarioError(f"{scenario.path}: output '{name}': not a state, Real output or input of a component "
                                f"(these are: {', '.join(dict.fromkeys([*names, *y_index, *u_index]))})")
    units = {}
    for name in dict.fromkeys([*names, *inputs, *outputs]):
        comp, _, var = name.partition(".")
        variable = instances[comp].variables.get(var) if comp in instances else None
        units[name] = _unit(instances[comp], variable) if variable is not None else ""
    return Linearization(A, B, C, D, names, inputs, outputs, t, x.copy(), units)


def _unit(inst: Instance, variable) -> str:
    """A variable's unit: its own, else its declared type's ('' if neither)."""
    if variable.unit:
        return variable.unit
    declared = getattr(variable, "declaredType", None)
    return (getattr(declared, "unit", None) or "") if declared is not None else ""


FMU_COMPONENT = "fmu"          # the component name of a lone FMU (linearize_fmu); its names are given without it


def linearize_fmu(path, at: Mapping[str, float] | None = None, inputs: Sequence[str] | None = None,
                  outputs: Sequence[str] | None = None, t: float = 0.0,
                  parameters: Mapping[str, str | float] | None = None) -> Linearization:
    """One FMU alone at an operating point: `at` gives states and input values by variable name ("q", "u");
    the rest keep their start values; `parameters` override parameters. `inputs` default to every Real
    input, `outputs` to every Real output; the names in the result are the FMU's variable names."""
    from .ssd import Component

    path = Path(path)
    scenario = Scenario(path.stem, path, [Component(FMU_COMPONENT, path)], [], start_time=float(t))
    md_inst = binding.load(scenario, model_exchange=True)[FMU_COMPONENT]
    states = {d.variable.derivative.name for d in md_inst.model_description.derivatives}
    reals_in = [v.name for v in _reals(md_inst, "input")]
    state, values = {}, {f"{FMU_COMPONENT}.{k}": v for k, v in (parameters or {}).items()}
    for name, value in (at or {}).items():
        if name in states:
            state[f"{FMU_COMPONENT}.{name}"] = value
        elif name in reals_in:
            values[f"{FMU_COMPONENT}.{name}"] = value
        else:
            raise ScenarioError(f"{path}: operating point: '{name}' is not a continuous state or a Real input of the FMU "
                                f"(these are: {', '.join([*sorted(states), *reals_in]) or 'none'})")
    full = f"{FMU_COMPONENT}."
    outputs = [v.name for v in _reals(md_inst, "output")] if outputs is None else list(outputs)
    lin = linearize(scenario, float(t), state, [full + n for n in (reals_in if inputs is None else inputs)],
                    [full + n for n in outputs], values)

    def bare(names: list[str]) -> list[str]:
        return [n[len(full):] for n in names]
    lin.states, lin.inputs, lin.outputs = bare(lin.states), bare(lin.inputs), bare(lin.outputs)
    lin.units = {k[len(full):]: v for k, v in lin.units.items()}
    return lin

"""SSP scenarios for a device: its plant FMU in closed loop with one of its controller FMUs.

A regulation scenario (Proposition 1/2) connects the plant's states to the controller and the controller's
u back to the plant; the set-point q_d is a controller parameter. A tracking scenario (Theorem 2/3) adds
one Reference FMU per position q_i (reference_<q_i>), whose jet q*, q*', q*'', q*''' feeds the
controller's inputs <q_i>_star, <q_i>_star_dot, ... The plant starts at rest at the positions q_0 with
the electrical state of the assignable equilibrium there (the set E of Section 3), unless the initial
state is given whole. The files are the same kind as the paper's scenarios/ folders, so `emcosim run`,
`certify`, `sweep` and `pack` take them.
"""
from __future__ import annotations

import dataclasses
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from components import catalog, certificates
from components.device import Device, VariableSpec
from components.operating_point import switches
from components.ph_plant import Jet
from components.references import KINDS

from ..engine.ssd import PARAMETER_SET, Component, Connection, Connector, Parameter, Scenario
from ..engine.ssd_writer import parameter_set_xml, system_structure_xml

REFERENCE_OUT = ("q_star", "q_star_dot", "q_star_ddot", "q_star_dddot")   # the Reference FMU's outputs
PLANT_RTOL = 1e-6          # the plant FMU's integration tolerance (as the paper's scenarios)


@dataclass
class Setup:
    """What a device scenario is: the design, its gains, the set-point or references, the start and the horizon.

    design       "Proposition1" | "Proposition2" | "Theorem2" | "Theorem3" (one the device has)
    gains        gain values by FMU name (the design's defaults where absent)
    references   tracking: one dict per position, {"kind": "constant" | "sinusoid" | "smooth_step", and that
                 kind's parameters}; regulation: empty
    q_0          initial positions; None: q_d (regulation) or q*(0) (tracking)
    p_0          initial momenta; None: rest (p = 0)
    x_e_0        initial electrical state; None: x_e of the equilibrium at q_0 (the set E of Section 3; x_e = 0
                 where the potential holds q_0 alone)
    eta_0        the whole initial state (q, p, x_e) instead of q_0, p_0, x_e_0
    """

    design: str
    stop_time: float
    step_size: float | None                        # None: chosen from the loop at its initial state (step_choice.py)
    gains: dict[str, float] = field(default_factory=dict)
    references: list[dict] = field(default_factory=list)
    q_0: Sequence[float] | None = None
    eta_0: Sequence[float] | None = None
    name: str | None = None
    p_0: Sequence[float] | None = None
    x_e_0: Sequence[float] | None = None

    def start_text(self) -> str:
        """How the initial state was chosen, for the scenario's notes."""
        if self.eta_0 is not None:
            return " (given)"
        p = "p given" if self.p_0 is not None else "at rest (p = 0)"
        x = "x_e given" if self.x_e_0 is not None else "x_e of the equilibrium at q_0"
        return f": {p}, {x}"


def reference_components(q: Sequence[VariableSpec], references: Sequence[Mapping], owner: str) -> list:
    """The components.references generators of a tracking setup, one per position q_i (ValueError naming
    the wrong entry)."""
    if len(references) != len(q):
        raise ValueError(f"{owner} tracks {len(q)} position(s) ({', '.join(v.name for v in q)}): give one "
                         f"reference for each, not {len(references)}")
    out = []
    for spec, v in zip(references, q):
        values = dict(spec)
        kind = values.pop("kind", "sinusoid")
        known = KINDS[kind].PARAMETERS if kind in KINDS else {}
        if kind in KINDS and set(values) - set(known):
            raise ValueError(f"reference of {v.name}: a {kind} reference has no parameter(s) "
                             f"{sorted(set(values) - set(known))}; its parameters: {sorted(known)}")
        try:
            out.append(catalog.reference(kind, values))
        except ValueError as exc:
            raise ValueError(f"reference of {v.name}: {exc}") from None
    return out


class StackedReference:
    """One reference generator per position as one reference: jet(t) of n_m-vectors (Jet), values(t)."""

    def __init__(self, generators: Sequence):
        self.generators = list(generators)

    def jet(self, t: float) -> Jet:
        return stacked_jet(self.generators, t)


def stacked_jet(references: Sequence, t: float) -> Jet:
    """The reference jet of every position at time t (Jet of n_m-vectors)."""
    values = np.array([r.values(t) for r in references], dtype=float)      # n_m x 4
    return Jet(*values.T)


def initial_state(device: Device, setup: Setup, controller) -> np.ndarray:
    """eta(0): given whole (eta_0), or from q_0, p_0, x_e_0, each defaulting to: q_0 the set-point (regulation) or
    q*(0) (tracking); p_0 = 0 (rest); x_e_0 the electrical state of the equilibrium at q_0 (Section 3, set E;
    EMPlant.equilibrium, x_e = 0 where the potential holds q_0 alone)."""
    plant = controller.plant
    if setup.eta_0 is not None:
        if (setup.q_0, setup.p_0, setup.x_e_0) != (None, None, None):
            raise ValueError("give the whole initial state or q_0, p_0, x_e_0, not both")
        eta = _vector(setup.eta_0, plant.n, "the initial state", device.name,
                      ", ".join(v.name for v in device.states))
    else:
        if setup.q_0 is not None:
            q_0 = _vector(setup.q_0, device.n_m, "q_0", device.name, ", ".join(v.name for v in device.q))
        elif controller.tracking:
            q_0 = stacked_jet(reference_components(device.q, setup.references, device.name), 0.0).q
        else:
            q_0 = plant.split(controller.target())[0]
        p_0 = (np.zeros(device.n_m) if setup.p_0 is None
               else _vector(setup.p_0, device.n_m, "p_0", device.name, ", ".join(v.name for v in device.p)))
        if setup.x_e_0 is not None:
            x_e_0 = _vector(setup.x_e_0, device.n_e, "x_e_0", device.name, ", ".join(v.name for v in device.x_e))
        else:
            try:
                x_e_0 = plant.split(plant.equilibrium(q_0))[2]
            except ValueError as exc:
                raise ValueError(f"no assignable equilibrium at q_0 = {q_0.tolist()} to take x_e_0 from: {exc}; "
                                 "give x_e_0") from None
        eta = np.concatenate([q_0, p_0, x_e_0])
    plant.check_state(eta)
    return eta


def _vector(values: Sequence[float], n: int, what: str, owner: str, names: str) -> np.ndarray:
    """`values` as a finite n-vector (ValueError naming `what` and the expected entries otherwise)."""
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.shape != (n,):
        raise ValueError(f"{what} has {v.size} entries; {owner} has {n} ({names})")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{what} = {v.tolist()} must be finite")
    return v


def parameter_doc(unit: str | None, text: str) -> str:
    """A parameter's description for the comment before it in an .ssv: the text and, unless it has none or
    is "1", its unit in brackets."""
    return f"{text} [{unit}]" if unit and unit != "1" else text


def reference_parameters(kind: int, values: Mapping[str, float]) -> list[Parameter]:
    """The Reference FMU's parameter set: its kind (0 constant, 1 sinusoid, 2 smooth step) and that kind's
    parameters with their units and descriptions (components.catalog.REFERENCE_PARAMETERS)."""
    specs = catalog.REFERENCE_PARAMETERS
    params = [Parameter("kind", "Integer", int(kind), None, "0 constant, 1 sinusoid, 2 smooth step")]
    return params + [Parameter(k, "Real", float(x), specs[k].unit,
                               parameter_doc(specs[k].unit, specs[k].description))
                     for k, x in values.items() if k != "kind"]


def scenario_files(device: Device, setup: Setup, fmu_dir: str) -> dict[str, str]:
    """File name -> text of the scenario folder; `fmu_dir` is the FMUs' folder as the .ssd should name it
    (relative to the scenario folder, or absolute). A ValueError says what is wrong with the setup (an
    unknown design or gain, an infeasible reference, an initial state outside the domain)."""
    controller, gains, references = _design(device, setup)
    design = device.designs[setup.design]
    identifier = device.controller_identifier(setup.design)
    eta_0 = initial_state(device, setup, controller)
    chosen = None
    if setup.step_size is None:                   # the step of the loop at its initial state (step_choice.py)
        from .step_choice import default_step

        step, coupling, how = default_step(controller, eta_0, stacked_jet(references, 0.0) if references else None,
                                           setup.stop_time)
        setup, chosen = dataclasses.replace(setup, step_size=step), (coupling, how)
    name = setup.name or f"{device.name.lower()}_{setup.design.lower()}"
    files = _parameter_sets(device, setup, gains, eta_0)

    def fmu(model: str) -> Path:
        return Path(os.path.join(fmu_dir, f"{model}.fmu"))

    states, inputs = [v.name for v in device.states], [v.name for v in device.u]
    jet_inputs = [n for n, _, _ in device.jet_names()] if design.tracking else []
    components = [Component(f"reference_{v.name}", fmu("Reference"), [Connector(n, "output", "Real") for n in REFERENCE_OUT],
                            parameter_sources=[f"reference_{v.name}.ssv"], description=f"reference {v.name}*(t)")
                  for v in (device.q if references else ())]
    components.append(Component("controller", fmu(identifier),
                                [Connector(n, "input", "Real") for n in states + jet_inputs]
                                + [Connector(n, "output", "Real") for n in inputs],
                                parameter_sources=["controller.ssv"], description=f"static controller {identifier}"))
    components.append(Component("plant", fmu(device.name),
                                [Connector(n, "input", "Real") for n in inputs]
                                + [Connector(n, "output", "Real") for n in states + ["H"]],
                                parameter_sources=["plant.ssv"], description=f"{device.name} plant"))
    connections = [Connection("plant", s, "controller", s) for s in states]
    for i, v in enumerate(device.q if references else ()):
        # the Reference FMU's outputs are declared in m (m/s, ...): a position in another unit (rad) takes
        # the numbers as they are (SSP suppressUnitConversion), which its reference's parameters are given in
        connections += [Connection(f"reference_{v.name}", out, "controller", jet_inputs[order * device.n_m + i],
                                   suppress_unit_conversion=v.unit != "m")
                        for order, out in enumerate(REFERENCE_OUT)]
    connections += [Connection("controller", n, "plant", n) for n in inputs]
    if references:
        what = "tracking of " + ", ".join(f"{v.name}* ({s.get('kind', 'sinusoid')})" for v, s in zip(device.q, setup.references))
    else:
        what = f"regulation to q_d = {[float(x) for x in controller.plant.split(controller.target())[0]]}"
    description = f"{device.name} {what} with {setup.design}"
    notes = [f"{name}: {description}.",
             f"Initial state ({', '.join(states)}) = {[float(x) for x in eta_0]}" + setup.start_text(),
             f"Communication step {setup.step_size:g} s, stop time {setup.stop_time:g} s."
             + (f" {chosen[1]}." if chosen else ""),
             "Written by `emcosim plant scenario` from the device's description."]
    scenario = Scenario(name, Path("SystemStructure.ssd"), components, connections, 0.0, setup.stop_time,
                        setup.step_size, description, notes,
                        coupling="implicit" if chosen and chosen[0] == "implicit" else None)
    files["SystemStructure.ssd"] = system_structure_xml(scenario, {c.name: str(c.source) for c in components},
                                                        setup.step_size, tolerance=PLANT_RTOL)
    return files


def _design(device: Device, setup: Setup) -> tuple:
    """(controller, gain values, reference generators) of a setup, each checked (ValueError)."""
    if setup.design not in device.designs:
        raise ValueError(f"{device.name}: no design {setup.design!r}; the designs that apply: {sorted(device.designs)}")
    if not (math.isfinite(setup.stop_time) and setup.stop_time > 0):
        raise ValueError(f"stop time {setup.stop_time} must be finite and > 0")
    if setup.step_size is not None and not (math.isfinite(setup.step_size) and 0 < setup.step_size <= setup.stop_time):
        raise ValueError(f"step size {setup.step_size} must be finite, > 0 and at most the stop time")
    design = device.designs[setup.design]
    identifier = device.controller_identifier(setup.design)
    unknown = set(setup.gains) - set(design.gains) - {"strict"}
    if unknown:
        raise ValueError(f"{identifier}: unknown gain(s) {sorted(unknown)}; its gains: {sorted(design.gains)}")
    strict = setup.gains.get("strict", 1)
    if strict not in (0, 1):
        raise ValueError(f"{identifier}: strict = {strict} must be 0 (warn and run) or 1 (refuse)")
    gains = {name: float(setup.gains.get(name, spec.default)) for name, spec in design.gains.items()}
    controller = device.controller(setup.design, gains)                  # checks the gains
    if not design.tracking and setup.references:
        raise ValueError(f"{identifier} regulates to q_d (a gain): it takes no reference")
    references = reference_components(device.q, setup.references, identifier) if design.tracking else []
    times = np.linspace(0.0, setup.stop_time, 201) if references else np.zeros(0)
    branches = []
    branch_of = getattr(controller.plant, "electrical_branch", None)      # n_e > n_m: the energized ports
    for t in times:
        try:
            jet = stacked_jet(references, float(t))
            controller.target(jet)                                          # Definition 1: x_e* exists
            branches.append(branch_of(jet) if branch_of is not None else ())
        except ValueError as exc:
            raise ValueError(f"the reference is not feasible at t = {t:g} s: {exc}") from None
    why = switches(list(times), branches, [v.name for v in device.x_e])
    if why:
        raise ValueError(f"the reference is not feasible with the operating-point rule: {why}")
    check_conditions(identifier, controller, stacked_jet(references, 0.0) if references else None, int(strict))
    return controller, {**gains, "strict": int(strict)}, references


def check_conditions(identifier: str, controller: Any, jet: Any, strict: int) -> None:
    """The design's conditions that its parameters decide (components.certificates.design_checks), at the point
    and in the words of the controller FMU's initialization: with strict = 1 (a scenario's default) a violation
    is refused (ValueError) as eq. (pHcondition) is by the controller's construction, with strict = 0 it is a
    DesignConditionWarning and the scenario's controller runs anyway (issue 42: one rule for every condition)."""
    failed = certificates.violated(controller, jet)
    if not failed:
        return
    text = certificates.violation_text(identifier, controller, failed, strict)
    if strict:
        raise ValueError(text)
    warnings.warn(certificates.DesignConditionWarning(text), stacklevel=2)


def _parameter_sets(device: Device, setup: Setup, gains: Mapping[str, float], eta_0: np.ndarray) -> dict[str, str]:
    """plant.ssv (parameters, initial state, rtol), controller.ssv (its model of the plant, gains) and one
    reference_<q_i>.ssv per tracked position."""
    design = device.designs[setup.design]
    plant = [Parameter(p.name, "Real", float(p.default), p.unit, parameter_doc(p.unit, p.description))
             for p in device.parameters.values()]
    start = [Parameter(f"{v.name}_0", "Real", float(x), v.unit,
                       parameter_doc(v.unit, f"initial value of {v.name}: {v.description}"))
             for v, x in zip(device.states, eta_0)]
    rtol = Parameter("rtol", "Real", PLANT_RTOL, None, "relative tolerance of the plant's internal integrator")
    controller = [Parameter(p.name, p.type, p.value, p.unit, f"plant parameter (same as plant.ssv): {p.description}")
                  for p in plant]
    controller += [Parameter(k, "Real", v, design.gains[k].unit, parameter_doc(design.gains[k].unit, design.gains[k].description))
                   for k, v in gains.items() if k != "strict"]
    controller.append(Parameter("strict", "Integer", int(gains["strict"]), None,
                                "1: refuse to initialize when the parameters violate a condition of the design, "
                                "0: warn and run (as `plant scenario` did)"))
    files = {"plant.ssv": parameter_set_xml(PARAMETER_SET, plant + start + [rtol]),
             "controller.ssv": parameter_set_xml(PARAMETER_SET, controller)}
    codes = {kind: code for code, kind in catalog.REFERENCE_KINDS.items()}
    for v, spec in zip(device.q, setup.references if design.tracking else ()):
        params = reference_parameters(codes[spec.get("kind", "sinusoid")], spec)
        files[f"reference_{v.name}.ssv"] = parameter_set_xml(PARAMETER_SET, params)
    return files


def parse_reference(text: str) -> dict:
    """'KIND[:NAME=VALUE,...]' (e.g. 'sinusoid:offset=0.001,amplitude=3e-4,omega=31.4') as a reference spec."""
    kind, _, rest = text.partition(":")
    kind = kind.strip()
    if kind not in catalog.REFERENCE_KINDS.values():
        raise ValueError(f"reference {text!r}: kind {kind!r} is not one of {sorted(catalog.REFERENCE_KINDS.values())}")
    spec: dict = {"kind": kind}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        try:
            spec[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"reference {text!r}: {item!r} is not NAME=NUMBER") from None
        if not eq:
            raise ValueError(f"reference {text!r}: {item!r} is not NAME=NUMBER")
    return spec


def gain_values(items: Sequence[str]) -> Mapping[str, float]:
    """['NAME=VALUE', ...] as a mapping (ValueError naming a malformed item)."""
    out = {}
    for item in items:
        key, eq, value = item.partition("=")
        try:
            out[key.strip()] = float(value)
        except ValueError:
            eq = ""
        if not eq:
            raise ValueError(f"--gain {item!r} is not NAME=NUMBER")
    return out

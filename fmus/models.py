"""The seven emcosim FMUs, one row each: which adapter, which device (components.catalog.DEVICES) and design,
what the FMU shows on its own (its start values and DefaultExperiment). build.py builds one FMU per row;
`slave_class` makes the row's slave class, which the FMU's generated script binds to the model identifier.
Any other device (a plant description's generated module, a test's): `device_slave_classes`, the same
adapters with start values of its own (build.py, `build_device`).

Default experiments (docs/fmus.md, "Run with fmpy"):
- MEMS: the open-loop response to a constant 25 V from the paper's initial state (q, p, x_e) = (15e-6 m,
  0, 0): the electrode is pulled to its static equilibrium and rings (damping ratio ~0.01); <= 1000 steps,
  so that fmpy keeps the step as its output interval.
- Maglev: the paper gives no maglev initial state (erratum 7): the equilibrium at q = 0.0025 m (half way to
  the magnet at c = 0.005 m), eta = (0.0025, 0, sqrt(2 k b)); with the coil voltage held at 0 V the flux
  decays and the ball falls (the open loop is unstable).
- the controllers: u for constant start inputs (the MEMS initial state, the maglev equilibrium);
- Reference: the paper's MEMS tracking reference q* = 0.05 + 0.05 sin(30 t) (eq. csim), kind 1.
"""
from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Sequence

import numpy as np

from components import maglev
from components.catalog import DEVICES
from components.device import Device

from .controller import ControllerSlave
from .model_description import DeviceIdentity
from .plant import PlantSlave
from .reference import ReferenceSlave

MAGLEV_EQUILIBRIUM = tuple(float(v) for v in maglev.Maglev().equilibrium([0.0025]))


@dataclass(frozen=True)
class Model:
    """One FMU: its adapter class and the class attributes the adapter reads."""

    adapter: type
    summary: str
    experiment: tuple[float, float, float]                   # start, stop, step of the DefaultExperiment
    attributes: dict[str, Any] = field(default_factory=dict)


MODELS: dict[str, Model] = {
    "MEMS": Model(PlantSlave, "MEMS optical switch (paper Section 7.1): input voltage u, outputs q, p, x_e and "
                  "the energy H", (0.0, 9e-4, 1e-6),
                  {"device": DEVICES["MEMS"], "initial_state": (15e-6, 0.0, 0.0), "input_start": 25.0}),
    "Maglev": Model(PlantSlave, "magnetic levitation system (paper Section 7.2): input voltage u, outputs q, p, "
                    "x_e and the energy H", (0.0, 0.5, 1e-3),
                    {"device": DEVICES["Maglev"], "initial_state": MAGLEV_EQUILIBRIUM, "input_start": 0.0}),
    "MEMS_Proposition1": Model(ControllerSlave, "Proposition 1 (eq. c1) for the MEMS optical switch: u from "
                               "(q, p, x_e)", (0.0, 1e-3, 1e-4),
                               {"device": DEVICES["MEMS"], "design": "Proposition1", "input_start": (15e-6, 0.0, 0.0)}),
    "MEMS_Theorem2": Model(ControllerSlave, "Theorem 2 (eq. u1-track) for the MEMS optical switch: u from "
                           "(q, p, x_e) and the reference jet", (0.0, 1e-3, 1e-4),
                           {"device": DEVICES["MEMS"], "design": "Theorem2",
                             "input_start": (15e-6, 0.0, 0.0, 3e-5, 0.0, 0.0, 0.0)}),
    "Maglev_Proposition2": Model(ControllerSlave, "Proposition 2 (eq. u2) for the magnetic levitation system: u "
                                 "from (q, p, x_e)", (0.0, 0.1, 1e-2),
                                 {"device": DEVICES["Maglev"], "design": "Proposition2", "input_start": MAGLEV_EQUILIBRIUM}),
    "Maglev_Theorem3": Model(ControllerSlave, "Theorem 3 (eq. tracker2) for the magnetic levitation system: u "
                             "from (q, p, x_e) and the reference jet", (0.0, 0.1, 1e-2),
                             {"device": DEVICES["Maglev"], "design": "Theorem3",
                               "input_start": MAGLEV_EQUILIBRIUM + (0.0025, 0.0, 0.0, 0.0)}),
    "Reference": Model(ReferenceSlave, "reference generator: constant, sinusoid or smooth transition; outputs the "
                       "jet q*, q*', q*'', q*'''", (0.0, 0.5, 1e-3)),
}


def slave_class(identifier: str) -> type:
    """The slave class of the FMU `identifier`: its adapter with the row's attributes (and, for a plant or
    controller, its device identity: the digest of the module that defines the device's plant)."""
    model = MODELS[identifier]
    attributes = dict(model.attributes)
    if "device" in attributes:                  # read when the modelDescription is written (the build), not at run
        device, adapter = attributes["device"], model.adapter   # time: a host may have deleted the source's folder
        attributes["device_identity"] = property(
            lambda self: identity(device, source_digest(sys.modules[device.plant.__module__]), adapter))
    return type(identifier, (model.adapter,), {"model_identifier": identifier, "summary": model.summary,
                                               "experiment": model.experiment, **attributes,
                                               "__module__": __name__})


def source_digest(module: ModuleType) -> str:
    """sha256 of a module's source file: the digest of a device's model where no description file gives one."""
    return hashlib.sha256(Path(module.__file__ or "").read_bytes()).hexdigest()


def identity(device: Device, model: str, adapter: type) -> DeviceIdentity:
    """The device identity a plant or controller FMU declares (fmus.model_description.DeviceIdentity)."""
    return DeviceIdentity(device.name, model, "plant" if issubclass(adapter, PlantSlave) else "controller")


def _identity(device: Device, module: ModuleType, model: str | None, adapter: type) -> DeviceIdentity | property:
    """`identity` with the digest `model`, or (None) a property giving it with the digest of the device module,
    read when the modelDescription is written, not at run time."""
    if model is not None:
        return identity(device, model, adapter)
    return property(lambda self: identity(device, source_digest(module), adapter))


# the paper's equation of each design's control law
LAWS = {"Proposition1": "eq. c1", "Proposition2": "eq. u2", "Theorem2": "eq. u1-track", "Theorem3": "eq. tracker2"}
DEFAULT_EXPERIMENT = (0.0, 1.0, 1e-3)


def module_device(module: ModuleType, designs: Sequence[str] | None = None) -> Device:
    """The Device of a device module: its `DEVICE` (a Device, or a function returning one) or its function
    `device(designs)` (a plant description's generated module, components.codegen: the designs asked for)."""
    device = getattr(module, "DEVICE", None)
    if device is not None and not isinstance(device, Device) and callable(device):
        device = device()
    if device is None and callable(getattr(module, "device", None)):
        device = module.device(None if designs is None else list(designs))
    if not isinstance(device, Device):
        raise ValueError(f"device module {module.__name__} defines neither DEVICE (a components.device.Device or a "
                         "function returning one) nor device(designs)")
    return device


def default_initial_state(device: Device, q_d: Sequence[float] | None = None) -> tuple[float, ...]:
    """A plant FMU's start values of q_0, p_0, x_e_0 when the device module gives none (INITIAL_STATE): the
    equilibrium eta_d = (q_d, 0, x_e_d) (EMPlant.equilibrium) at `q_d` (a description's [controller] q_d, whether
    or not a regulation design applies), else at the default q_d of the first regulation design, else eta = 0, else
    the plant at rest and unenergized at `q_d`; ValueError if none is admissible (check_state)."""
    plant = device.plant()
    if q_d is not None:
        try:
            return tuple(float(v) for v in plant.equilibrium(np.asarray(q_d, dtype=float)))
        except (ValueError, ArithmeticError, NotImplementedError):
            pass
    for design in device.designs.values():
        names = ["q_d"] if "q_d" in design.gains else [f"q_d_{i + 1}" for i in range(device.n_m)]
        if not design.tracking and all(n in design.gains for n in names):
            try:
                return tuple(float(v) for v in plant.equilibrium(np.array([design.gains[n].default for n in names])))
            except (ValueError, ArithmeticError, NotImplementedError):
                continue
    eta = np.zeros(len(device.states))
    try:
        plant.check_state(eta)
    except ValueError as exc:
        if q_d is None:
            raise ValueError(f"{device.name}: eta = 0 is not admissible ({exc}) and no regulation design gives an "
                             "equilibrium: give the device module an INITIAL_STATE") from None
        eta[:device.n_m] = np.asarray(q_d, dtype=float)     # at rest and unenergized at q_d (no equilibrium there:
        try:                                                # coupled coils with n_e > n_m have no operating point)
            plant.check_state(eta)
        except ValueError as exc_q_d:
            raise ValueError(f"{device.name}: neither eta = 0 ({exc}) nor the plant at rest at q_d ({exc_q_d}) is "
                             "admissible and no regulation design gives an equilibrium: give the device module an "
                             "INITIAL_STATE") from None
    return tuple(eta.tolist())


def holding_input(device: Device, eta: Sequence[float]) -> tuple[float, ...]:
    """The input that holds the electrical state at eta: x_e' = (J_e - R_e) Psi(q) x_e + G_e u = 0 (the x_e-row
    of eq. open-loop elecmech), u = G_e^-1 (R_e - J_e) Psi(q) x_e."""
    plant = device.plant()
    q, _, x_e = plant.split(np.asarray(eta, dtype=float))
    u = np.linalg.solve(plant.G_e, (plant.R_e - plant.J_e) @ plant.Psi(q) @ x_e)
    return tuple(float(v) for v in u)


def default_experiment(device: Device, eta: Sequence[float], experiment: Sequence[float] = DEFAULT_EXPERIMENT
                       ) -> tuple[tuple[float, ...], tuple[float, float, float]]:
    """(input start, DefaultExperiment) of a device's plant FMU that starts at eta, such that the FMU run on its
    own (fmpy simulate) stays inside the admissible domain: the input that holds x_e where the open loop is
    stable there (every eigenvalue of F hess H with Re < 0); else u = 0 if the open loop stays inside over the
    experiment (components.monolithic.open_loop_exit); else u = 0 and the stop time half the time it takes to
    leave. (An unstable open loop leaves an equilibrium held by its own input through rounding: the solenoid
    of examples/ pulled in after 0.17 s of fmpy simulate; with u = 0 the bar of examples/ tilts into a magnet
    after 0.88 s.)"""
    from components.monolithic import open_loop_exit

    plant = device.plant()
    start, stop, step = (float(v) for v in experiment)
    held = holding_input(device, eta)
    if np.max(np.linalg.eigvals(plant.jacobian(np.asarray(eta, dtype=float))).real) < 0:
        return held, (start, stop, step)
    zero = (0.0,) * device.n_e
    leaves = open_loop_exit(plant, eta, np.zeros(device.n_e), stop - start)
    if leaves is None:
        return zero, (start, stop, step)
    stop = start + float(f"{0.5 * leaves:.2g}")
    return zero, (start, stop, min(step, (stop - start) / 100))


def device_slave_classes(module: ModuleType, designs: Sequence[str] | None = None,
                         module_name: str = __name__, model: str | None = None) -> dict[str, type]:
    """The slave classes of a device module's FMUs, by model identifier: the plant <name> (PlantSlave) and one
    controller <name>_<design> (ControllerSlave) per design (default: every design of the device).

    The module defines DEVICE or device(designs) (module_device) and may define INITIAL_STATE (q_0, p_0, x_e_0; default:
    default_initial_state) and EXPERIMENT ((start, stop, step) of every FMU's DefaultExperiment; default
    DEFAULT_EXPERIMENT; `default_experiment` keeps the plant FMU's own run inside its domain and chooses its
    input start); a controller's inputs start at the plant's initial state and, tracking, the jet of the
    constant reference q* = q_0. Every class declares the device identity (`identity`) with the digest `model`
    (build_device: of the description file; default: of the device module's source)."""
    device = module_device(module, designs)
    chosen = list(device.designs) if designs is None else list(designs)
    unknown = [d for d in chosen if d not in device.designs]
    if unknown:
        raise ValueError(f"{device.name}: no design(s) {unknown}; the designs of the device: {sorted(device.designs)}")
    gain_q_d = getattr(module, "GAIN_DEFAULTS", {}).get("q_d")          # a described device's [controller] q_d
    initial = tuple(float(v) for v in getattr(module, "INITIAL_STATE", None)
                    or default_initial_state(device, None if gain_q_d is None else [row[0] for row in gain_q_d]))
    if len(initial) != len(device.states):
        raise ValueError(f"{device.name}: INITIAL_STATE has {len(initial)} entries, expected {len(device.states)} "
                         f"({', '.join(v.name for v in device.states)})")
    u_0, experiment = default_experiment(device, initial, getattr(module, "EXPERIMENT", DEFAULT_EXPERIMENT))
    u_names = ", ".join(v.name for v in device.u)
    classes = {device.name: type(device.name, (PlantSlave,), {
        "model_identifier": device.name, "experiment": experiment, "device": device, "initial_state": initial,
        "input_start": u_0[0] if device.n_e == 1 else u_0, "__module__": module_name,
        "device_identity": _identity(device, module, model, PlantSlave),
        "summary": f"{device.description}: inputs {u_names}, outputs the states and the energy H"})}
    q0 = initial[:device.n_m]
    for name in chosen:
        design = device.designs[name]
        identifier = device.controller_identifier(name)
        jet = (q0 + (0.0,) * (3 * device.n_m)) if design.tracking else ()
        classes[identifier] = type(identifier, (ControllerSlave,), {
            "model_identifier": identifier, "experiment": experiment, "device": device, "design": name,
            "input_start": initial + jet, "__module__": module_name,
            "device_identity": _identity(device, module, model, ControllerSlave),
            "summary": f"{name} ({LAWS[name]}) for {device.description}: {u_names} from the states"
                       + (" and the reference jet" if design.tracking else "")})
    return classes

"""The suite's plants, controllers and references by name, built from flat parameter dictionaries.

One place maps the names used in FMUs and scenario files (MEMS_Theorem2, rbar_e, D_d, ...) onto the
components' constructors, with every gain's unit and description, so the FMU adapters, the
certification command and the reports all construct the same objects. Each plant kind is a
components.device.Device (DEVICES); `register` adds one (a plant description's).
"""
from __future__ import annotations

from typing import Callable, Mapping

from . import maglev, mems
from .controller import Controller
from .device import Design, Device, VariableSpec
from .parameters import Parameter
from .ph_plant import EMPlant
from .proposition1 import Proposition1
from .proposition2 import Proposition2
from .references import KINDS, Reference
from .theorem2 import Theorem2
from .theorem3 import Theorem3

_q_d = {"MEMS": Parameter("q_d", 3e-5, "m", "set-point position", "any"),
        "Maglev": Parameter("q_d", 0.0025, "m", "set-point position (q_d < c)", "any")}
_rbar_e = Parameter("rbar_e", 100.0, "Ohm", "desired series resistance: R_e_bar = 1/rbar_e (K_e = 1/rbar_e - 1/r_e)")
_D_d_mems = Parameter("D_d", 0.0, "C/m", "coupled damping D_d of eq. (closedloop)", "any")
_R_e_bar = Parameter("R_e_bar", 2.82, "Ohm", "desired electrical damping R_e_bar = R_e + K_e > 0 (eq. barRe); the "
                     "paper's conditions ask K_e >= 0 (Prop. 2), K_e > 0 (Thm. 3), i.e. R_e_bar >= R_e = 2.25")
_k_c = Parameter("k_c", 20.0, "1", "weight of Theta_2 / Phi_2 = k_c/2 (z - L)^2 (SI numbers; z mixes units)")
_D_d_maglev = Parameter("D_d", 0.0, "Wb/m", "coupled damping D_d of eq. (closedloop), general convention "
                        "(the paper's Sec. 7.2 value divided by 2k)", "any")

_gains_mems_prop1 = {p.name: p for p in (_q_d["MEMS"], _rbar_e, Parameter(
    "D_d", 0.0, "C/m", "coupled damping D_d of eq. (closedloop); |D_d| < sqrt(4 R_m / rbar_e) (eq. pHcondition)", "any"))}
_gains_maglev_prop2 = {p.name: p for p in (_q_d["Maglev"], _R_e_bar, _k_c, Parameter(
    "D_d", 0.0, "Wb/m", "coupled damping D_d of eq. (closedloop); with R_m = 0 only D_d = 0 keeps the pH structure", "any"))}


def _variables(module) -> dict[str, tuple[VariableSpec, ...]]:
    states = {name: (VariableSpec(name, *module.STATES[name]),) for name in ("q", "p", "x_e")}
    return {**states, "u": (VariableSpec(*module.INPUT),)}


DEVICES: dict[str, Device] = {
    "MEMS": Device("MEMS", mems.MEMS.name, mems.PARAMETERS, **_variables(mems), plant=mems.MEMS, designs={
        "Proposition1": Design("Proposition1", _gains_mems_prop1, lambda P, g: Proposition1(
            P, g["q_d"], mems.R_e_bar_from_rbar_e(g["rbar_e"]), D_d=g["D_d"])),
        "Theorem2": Design("Theorem2", {p.name: p for p in (_rbar_e, _D_d_mems)}, lambda P, g: Theorem2(
            P, mems.R_e_bar_from_rbar_e(g["rbar_e"]), D_d=g["D_d"]))}),
    "Maglev": Device("Maglev", maglev.Maglev.name, maglev.PARAMETERS, **_variables(maglev), plant=maglev.Maglev, designs={
        "Proposition2": Design("Proposition2", _gains_maglev_prop2, lambda P, g: Proposition2(
            P, g["q_d"], g["R_e_bar"], k_c=g["k_c"], D_d=g["D_d"])),
        "Theorem3": Design("Theorem3", {p.name: p for p in (_R_e_bar, _k_c, _D_d_maglev)}, lambda P, g: Theorem3(
            P, g["R_e_bar"], k_c=g["k_c"], D_d=g["D_d"]))}),
}
PLANTS: dict[str, tuple[Callable[..., EMPlant], dict[str, Parameter]]] = {}
GAINS: dict[str, dict[str, Parameter]] = {}
CONTROLLER_PLANT: dict[str, str] = {}
TRACKING: dict[str, bool] = {}


def register(device: Device) -> None:
    """Make a device's plant and controllers known by their FMU names (PLANTS, GAINS, CONTROLLER_PLANT,
    TRACKING; plant(), controller()). A name taken by another device is refused."""
    if device.name in DEVICES and DEVICES[device.name] is not device:
        raise ValueError(f"a device named {device.name!r} is already registered")
    DEVICES[device.name] = device
    PLANTS[device.name] = (device.plant, device.parameters)
    for design in device.designs.values():
        identifier = device.controller_identifier(design.name)
        GAINS[identifier] = design.gains
        CONTROLLER_PLANT[identifier] = device.name
        TRACKING[identifier] = design.tracking


def _split(values: Mapping[str, float], *groups: Mapping[str, Parameter], owner: str) -> list[dict]:
    unknown = set(values) - set().union(*groups)
    if unknown:
        raise ValueError(f"{owner}: unknown parameter(s) {sorted(unknown)}")
    return [{k: v for k, v in values.items() if k in g} for g in groups]


def plant(name: str, values: Mapping[str, float] = {}) -> EMPlant:
    """A plant by device name ("MEMS", "Maglev", a registered description) with the given physical
    parameters (defaults: the device's)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant {name!r}; known: {sorted(PLANTS)}")
    make, _ = PLANTS[name]
    return make(**values)


def controller(name: str, values: Mapping[str, float] = {}) -> Controller:
    """A controller by FMU name (<device>_<design>) from its gains and its model of the plant (physical
    parameters)."""
    if name not in GAINS:
        raise ValueError(f"unknown controller {name!r}; known: {sorted(GAINS)}")
    device = DEVICES[CONTROLLER_PLANT[name]]
    values = {k: v for k, v in values.items() if k != "strict"}    # the FMU's own switch (fmus/controller.py), no gain
    plant_values, gain_values = _split(values, device.parameters, GAINS[name], owner=name)
    return device.controller(name[len(device.name) + 1:], {**plant_values, **gain_values})


for _device in list(DEVICES.values()):
    register(_device)


REFERENCE_KINDS = {0: "constant", 1: "sinusoid", 2: "smooth_step"}
REFERENCE_PARAMETERS = {p.name: p for cls in KINDS.values() for p in cls.PARAMETERS.values()}


def reference(kind: int | str, values: Mapping[str, float] = {}) -> Reference:
    """A reference generator: kind 0/'constant', 1/'sinusoid', 2/'smooth_step'; `values` may hold
    parameters of every kind (as the Reference FMU does); those of the chosen kind are used."""
    key = REFERENCE_KINDS.get(kind, kind) if not isinstance(kind, str) else kind
    if key not in KINDS:
        raise ValueError(f"parameter kind = {kind!r} must be one of {REFERENCE_KINDS}")
    unknown = set(values) - set(REFERENCE_PARAMETERS)
    if unknown:
        raise ValueError(f"reference: unknown parameter(s) {sorted(unknown)}")
    cls = KINDS[key]
    return cls(**{k: v for k, v in values.items() if k in cls.PARAMETERS})

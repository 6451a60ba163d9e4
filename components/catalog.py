"""The suite's plants, controllers and references by name, built from flat parameter dictionaries.

One place maps the names used in FMUs and scenario files (MEMS_Theorem2, rbar_e, D_d, ...) onto the
components' constructors, with every gain's unit and description, so the FMU adapters, the
certification command and the reports all construct the same objects.
"""
from __future__ import annotations

from typing import Mapping

from . import maglev, mems
from .controller import Controller
from .parameters import Parameter, resolve
from .ph_plant import EMPlant
from .proposition1 import Proposition1
from .proposition2 import Proposition2
from .references import KINDS, Reference
from .theorem2 import Theorem2
from .theorem3 import Theorem3

PLANTS: dict[str, tuple[type[EMPlant], dict[str, Parameter]]] = {
    "MEMS": (mems.MEMS, mems.PARAMETERS),
    "Maglev": (maglev.Maglev, maglev.PARAMETERS),
}

_q_d = {"MEMS": Parameter("q_d", 3e-5, "m", "set-point position", "any"),
        "Maglev": Parameter("q_d", 0.0025, "m", "set-point position (q_d < c)", "any")}
_rbar_e = Parameter("rbar_e", 100.0, "Ohm", "desired series resistance: R_e_bar = 1/rbar_e (K_e = 1/rbar_e - 1/r_e)")
_D_d_mems = Parameter("D_d", 0.0, "C/m", "coupled damping D_d of eq. (closedloop)", "any")
_R_e_bar = Parameter("R_e_bar", 2.82, "Ohm", "desired electrical damping R_e_bar = R_e + K_e > 0 (eq. barRe); the "
                     "paper's conditions ask K_e >= 0 (Prop. 2), K_e > 0 (Thm. 3), i.e. R_e_bar >= R_e = 2.25")
_k_c = Parameter("k_c", 20.0, "1", "weight of Theta_2 / Phi_2 = k_c/2 (z - L)^2 (SI numbers; z mixes units)")
_D_d_maglev = Parameter("D_d", 0.0, "Wb/m", "coupled damping D_d of eq. (closedloop), general convention "
                        "(the paper's Sec. 7.2 value divided by 2k)", "any")

GAINS: dict[str, dict[str, Parameter]] = {
    "MEMS_Proposition1": {p.name: p for p in (_q_d["MEMS"], _rbar_e,
                                              Parameter("D_d", 0.0, "C/m", "coupled damping D_d of eq. (closedloop); "
                                                        "|D_d| < sqrt(4 R_m / rbar_e) (eq. pHcondition)", "any"))},
    "MEMS_Theorem2": {p.name: p for p in (_rbar_e, _D_d_mems)},
    "Maglev_Proposition2": {p.name: p for p in (_q_d["Maglev"], _R_e_bar, _k_c,
                                                Parameter("D_d", 0.0, "Wb/m", "coupled damping D_d of eq. (closedloop); "
                                                          "with R_m = 0 only D_d = 0 keeps the pH structure", "any"))},
    "Maglev_Theorem3": {p.name: p for p in (_R_e_bar, _k_c, _D_d_maglev)},
}
CONTROLLER_PLANT = {name: name.split("_")[0] for name in GAINS}
TRACKING = {"MEMS_Proposition1": False, "MEMS_Theorem2": True, "Maglev_Proposition2": False, "Maglev_Theorem3": True}


def _split(values: Mapping[str, float], *groups: Mapping[str, Parameter], owner: str) -> list[dict]:
    unknown = set(values) - set().union(*groups)
    if unknown:
        raise ValueError(f"{owner}: unknown parameter(s) {sorted(unknown)}")
    return [{k: v for k, v in values.items() if k in g} for g in groups]


def plant(name: str, values: Mapping[str, float] = {}) -> EMPlant:
    """A plant ("MEMS" or "Maglev") with the given physical parameters (defaults: the paper's)."""
    if name not in PLANTS:
        raise ValueError(f"unknown plant {name!r}; known: {sorted(PLANTS)}")
    cls, _ = PLANTS[name]
    return cls(**values)


def controller(name: str, values: Mapping[str, float] = {}) -> Controller:
    """A controller by FMU name from its gains and its model of the plant (physical parameters)."""
    if name not in GAINS:
        raise ValueError(f"unknown controller {name!r}; known: {sorted(GAINS)}")
    plant_name = CONTROLLER_PLANT[name]
    plant_values, gain_values = _split(values, PLANTS[plant_name][1], GAINS[name], owner=name)
    P = plant(plant_name, plant_values)
    g = resolve(GAINS[name], gain_values, name)
    if name == "MEMS_Proposition1":
        return Proposition1(P, g["q_d"], mems.R_e_bar_from_rbar_e(g["rbar_e"]), D_d=g["D_d"])
    if name == "MEMS_Theorem2":
        return Theorem2(P, mems.R_e_bar_from_rbar_e(g["rbar_e"]), D_d=g["D_d"])
    if name == "Maglev_Proposition2":
        return Proposition2(P, g["q_d"], g["R_e_bar"], k_c=g["k_c"], D_d=g["D_d"])
    return Theorem3(P, g["R_e_bar"], k_c=g["k_c"], D_d=g["D_d"])


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

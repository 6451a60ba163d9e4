"""A device: one kind of weakly coupled EM plant (eq. open-loop elecmech) with the controllers that apply to it.

What the FMU adapters, the scenario writers and the checks need to know about a plant kind, in one record:
its physical parameters, the names, units and descriptions of its variables (q, p, x_e: n_m, n_m, n_e
entries; u: n_e entries), how to build the plant from parameter values, and the designs (Proposition 1/2,
Theorem 2/3) that apply, each with its gains and how to build the controller. The paper's MEMS switch and
maglev are devices (components.catalog), and so is every plant description file (components.description).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

from .controller import Controller
from .parameters import Parameter, resolve
from .ph_plant import EMPlant

DESIGNS = ("Proposition1", "Proposition2", "Theorem2", "Theorem3")
TRACKING_DESIGNS = {"Proposition1": False, "Proposition2": False, "Theorem2": True, "Theorem3": True}


@dataclass(frozen=True)
class VariableSpec:
    """One entry of q, p, x_e or u: its FMI name, unit and description."""

    name: str
    unit: str
    description: str


@dataclass(frozen=True)
class Design:
    """One of the paper's four controllers for a device.

    name     "Proposition1" | "Proposition2" | "Theorem2" | "Theorem3"
    gains    the controller's parameters besides the plant's: q_d (regulation), R_e_bar, D_d, k_c under the
             paper's names (entries q_d_1, R_e_bar_1_2, ... where n > 1), or a device's own form (MEMS: rbar_e)
    make     (plant, gain values) -> the components controller
    """

    name: str
    gains: dict[str, Parameter]
    make: Callable[[EMPlant, Mapping[str, float]], Controller]

    @property
    def tracking(self) -> bool:
        return TRACKING_DESIGNS[self.name]


@dataclass(frozen=True)
class Device:
    """A plant kind and its controllers. `plant(**values)` builds the plant (defaults: the parameters'
    defaults; a ValueError names a bad parameter)."""

    name: str
    description: str
    parameters: dict[str, Parameter]
    q: tuple[VariableSpec, ...]
    p: tuple[VariableSpec, ...]
    x_e: tuple[VariableSpec, ...]
    u: tuple[VariableSpec, ...]
    plant: Callable[..., EMPlant]
    designs: dict[str, Design]

    @property
    def n_m(self) -> int:
        return len(self.q)

    @property
    def n_e(self) -> int:
        return len(self.x_e)

    @property
    def states(self) -> tuple[VariableSpec, ...]:
        """q, p, x_e in the order of eta (eq. open-loop elecmech)."""
        return self.q + self.p + self.x_e

    def controller_identifier(self, design: str) -> str:
        """The FMU model identifier of a design: <device>_<design> (MEMS_Theorem2)."""
        return f"{self.name}_{design}"

    def jet_names(self) -> list[tuple[str, str, str]]:
        """(name, unit, description) of a tracking controller's reference inputs, in the order of
        Controller.u_derivative (every position of q*, then of its first, second and third derivative):
        <q_i>_star, <q_i>_star_dot, <q_i>_star_ddot, <q_i>_star_dddot (MEMS, maglev: q_star, ..., the
        Reference FMU's outputs)."""
        out = []
        for suffix, rate, what in (("", "", "reference position"), ("_dot", "/s", "first derivative of the reference"),
                                   ("_ddot", "/s2", "second derivative of the reference"),
                                   ("_dddot", "/s3", "third derivative of the reference")):
            for v in self.q:
                out.append((f"{v.name}_star{suffix}", v.unit + rate, f"{what} {v.name}*: {v.description}"))
        return out

    def controller(self, design: str, values: Mapping[str, float] = {}) -> Controller:
        """The controller of `design` from plant parameters and gains in one flat mapping (defaults where
        absent); unknown names are refused."""
        if design not in self.designs:
            raise ValueError(f"{self.name}: no design {design!r}; the designs that apply: {sorted(self.designs)}")
        d = self.designs[design]
        unknown = set(values) - set(self.parameters) - set(d.gains)
        if unknown:
            owner = self.controller_identifier(design)
            raise ValueError(f"{owner}: unknown parameter(s) {sorted(unknown)}")
        plant = self.plant(**{k: v for k, v in values.items() if k in self.parameters})
        gains = resolve(d.gains, {k: v for k, v in values.items() if k in d.gains}, self.controller_identifier(design))
        return d.make(plant, gains)

"""What each design commands at the start of a scenario, and how fast its closed loop is (issue 34).

`plant check` reports, for every design that applies, the input u(eta_0) it commands at the scenario's initial
state (the same default as `plant scenario`: q_0 = q_d or q*(0), at rest, x_e of the equilibrium at q_0; or
the q_0, p_0, x_e_0 given) and the fastest rate of its closed loop there: the largest |lambda| of the closed
loop's Jacobian F_d hess H_d(eta_0) (eq. closedloop: by the matching identity the closed loop is
eta' = F_d grad H_d). Where the description states the actuator's range ([model] u_max), a design whose start
input leaves it is reported "applies, but exceeds the actuator".
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from components.device import Device

from .scenario import Setup, initial_state, reference_components, stacked_jet


@dataclass
class Start:
    """A design's input at the initial state and its closed loop's fastest rate there."""

    design: str
    eta_0: list[float]
    u_0: list[float]
    fastest_rate: float                    # 1/s
    exceeds: list[int]                     # inputs i with |u_0,i| > u_max_i

    def text(self, u_names: Sequence[str], u_max: Sequence[float] | None) -> str:
        inputs = ", ".join(f"{n} = {u:.4g}" for n, u in zip(u_names, self.u_0))
        out = f"at eta_0 = ({', '.join(f'{x:.4g}' for x in self.eta_0)}) it commands {inputs}; fastest closed-loop " \
              f"rate max |eig F_d hess H_d(eta_0)| = {self.fastest_rate:.4g} 1/s"
        if self.exceeds and u_max is not None:
            over = ", ".join(f"|{u_names[i]}| = {abs(self.u_0[i]):.4g} > u_max = {u_max[i]:.4g}" for i in self.exceeds)
            out += f"; exceeds the actuator: {over}"
        return out


def starts(device: Device, u_max: Sequence[float] | None, references: Sequence[dict] = (),
           q_0: Sequence[float] | None = None, p_0: Sequence[float] | None = None,
           x_e_0: Sequence[float] | None = None, gains: Mapping[str, float] | None = None) -> dict[str, Start | str]:
    """Per design of `device` (default gains, or `gains` where the design has them): its Start, or why none was
    computed (a tracking design without a reference, a start with no equilibrium to take x_e from)."""
    out: dict[str, Start | str] = {}
    for name, design in device.designs.items():
        if design.tracking and not references:
            out[name] = "no reference given: its start needs one (--reference)"
            continue
        setup = Setup(name, 1.0, 1.0, references=list(references) if design.tracking else [], q_0=q_0, p_0=p_0,
                      x_e_0=x_e_0)
        try:
            controller = device.controller(name, {k: v for k, v in (gains or {}).items() if k in design.gains})
            eta_0 = initial_state(device, setup, controller)
            jet = stacked_jet(reference_components(device.q, references, device.name), 0.0) if design.tracking else None
            u_0 = np.atleast_1d(np.asarray(controller.u(eta_0, jet), dtype=float))
            J = controller.F_d() @ controller.hess_H_d(eta_0, jet)
            rate = float(np.max(np.abs(np.linalg.eigvals(J))))
        except (ValueError, ArithmeticError, NotImplementedError) as exc:
            out[name] = " ".join(str(exc).split())
            continue
        exceeds = [i for i, u in enumerate(u_0) if u_max is not None and not abs(u) <= u_max[i]]
        out[name] = Start(name, [float(x) for x in eta_0], [float(u) for u in u_0], rate, exceeds)
    return out


def attach(report: Any, device: Device, desc: Any, **start_args: Any) -> None:
    """Add each design's start (`starts`) to its verdict in a components.plant_check.Report: the text, and
    `exceeds_actuator` where its start input leaves [model] u_max."""
    u_max = getattr(desc, "u_max", None)
    found = starts(device, u_max, **start_args)
    names = [v.name for v in device.u]
    for verdict in report.design_verdicts:
        s = found.get(verdict.name)
        if isinstance(s, Start):
            verdict.start = s.text(names, u_max)
            verdict.exceeds_actuator = bool(s.exceeds)
        elif s is not None:
            verdict.start = f"start not computed: {s}"

"""Adapter: a plant of components/ (MEMS, maglev) as an FMI 2.0 slave, for Co-Simulation and Model Exchange.

Variables: every entry of the plant module's PARAMETERS, the initial state q_0, p_0, x_e_0, the
integration tolerance rtol (parameters); the input u; the outputs q, p, x_e (states: no direct
feedthrough) and the stored energy H. doStep calls components.plant_step.PlantStepper with u held over
the step or, when the master has set input derivatives (fmi2SetRealInputDerivatives, any orders k >= 1),
with the polynomial u + u' tau + u'' tau^2 / 2 + ... + u^(k) tau^k / k!. Output derivatives (orders 1 and
2) of q, p, x_e and H are the
exact ones of eq. (open-loop elecmech) at the current state (PlantStepper.time_derivatives); the input
they use is the polynomial's value and rate at the end of the last step until the master sets u again.
The FMU state includes the stepper's proposed substep and that end-of-step input.

Model Exchange: the continuous states are q, p, x_e with der(q), der(p), der(x_e) = f(eta, u) of eq.
(open-loop elecmech) (components.plant_step's scalar model, the one the integrator of doStep uses); their
Jacobian with respect to the states and u (fmi2GetDirectionalDerivative) is F hess H and g, exact; the one
event indicator is the margin to the boundary of the admissible domain (components: domain_margin).
"""
from __future__ import annotations

import math
from types import ModuleType
from typing import ClassVar

import numpy as np

from components import catalog
from components.ph_plant import DomainError, EMPlant
from components.plant_step import (
    DEFAULT_RTOL,
    RTOL_RANGE,
    PlantStepper,
    StepFailure,
    input_terms,
    input_value,
    nominal_scale,
)

from .slave import EMSlave
from .variables import RATE_UNITS

STATE_NAMES = ("q", "p", "x_e")
OUTPUT_INDEX = {n: i for i, n in enumerate((*STATE_NAMES, "H"))}   # output -> its entry in time_derivatives' rows
# what each state derivative depends on, from the structure of eq. (open-loop elecmech) for a constant mass:
# q' = p/m, p' = -V'(q) - 1/2 Psi'(q) x_e^2 - R_m p/m, x_e' = (J_e - R_e) Psi(q) x_e + G_e u
DERIVATIVE_DEPENDENCIES = {"q": ["p"], "p": ["q", "p", "x_e"], "x_e": ["q", "x_e", "u"]}


def _finite_numbers(values, n: int) -> bool:
    """Is `values` a list of n finite numbers (not booleans)?"""
    return isinstance(values, (list, tuple)) and len(values) == n and all(
        not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in values)


def initial_dependencies(knowns: list[str], parameters: list[str]) -> list[str]:
    """What a quantity that depends on `knowns` (states, u) depends on at initialization: the initial value
    x_0 of each state x, u, and the plant's parameters (FMI 2.0: the knowns of InitialUnknowns are the
    inputs and the variables with initial = "exact")."""
    return [f"{k}_0" if k in STATE_NAMES else k for k in knowns] + parameters


class PlantSlave(EMSlave):
    plant_module: ClassVar[ModuleType]                          # components.mems or components.maglev
    initial_state: ClassVar[tuple[float, float, float]]
    input_start: ClassVar[float] = 0.0
    # FMI 2.0 derivatives (hooks at the end of the class)
    can_interpolate_inputs = True                               # any order: the whole polynomial is integrated
    max_output_derivative_order = 2
    provides_directional_derivative = True
    number_of_event_indicators = 1                              # the margin to the domain's boundary

    def declare(self) -> None:
        module = self.plant_module
        for p in module.PARAMETERS.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        for name, start in zip(STATE_NAMES, self.initial_state):
            unit, description = module.STATES[name]
            self.parameter(f"{name}_0", start, unit, f"initial value of {name}: {description}")
        self.parameter("rtol", DEFAULT_RTOL, "1",
                       "relative tolerance of the integration inside doStep (absolute tolerance: rtol times "
                       "the nominal state scale); a tolerance given in fmi2SetupExperiment is used instead "
                       f"where it is tighter (not below {RTOL_RANGE[0]:g})")
        name, unit, description = module.INPUT
        self.input(name, self.input_start, unit, description)
        parameters = list(module.PARAMETERS)
        nominal = nominal_scale(catalog.plant(self.model_identifier))
        for i, name in enumerate(STATE_NAMES):                    # the states: no direct feedthrough from u
            unit, description = module.STATES[name]
            self.output(name, unit, description, (lambda i=i: self.state()[i]), [name], [f"{name}_0"],
                        nominal=float(nominal[i]))
        self.output("H", "J", "stored energy H(q, p, x_e) = p^2/(2 m) + V(q) + H_e(q, x_e), eq. (open-loop elecmech)",
                    self.energy, list(STATE_NAMES), initial_dependencies(list(STATE_NAMES), parameters))
        for i, name in enumerate(STATE_NAMES):
            knowns = DERIVATIVE_DEPENDENCIES[name]
            self.state_derivative(name, RATE_UNITS[module.STATES[name][0]], (lambda i=i: self.rates()[i]),
                                  knowns, initial_dependencies(knowns, parameters))
        self.plant: EMPlant | None = None
        self.stepper: PlantStepper | None = None
        self.eta: tuple[float, float, float] | None = None
        self._H: float | None = None
        self.u_end: tuple[float, float] | None = None          # (u, u') at the end of the last step
        self._rates: tuple | None = None                        # (key, time derivatives) of the last request
        self._f: tuple | None = None                            # (key, f(eta, u)) of the last request of der(x)
        self._dx: tuple | None = None                           # (eta, u, [f(eta, u)]) of the last fmi2GetDerivatives

    # ---- outputs ------------------------------------------------------------------------------
    def initial(self) -> tuple[float, float, float]:
        return tuple(float(self.values[f"{n}_0"]) for n in STATE_NAMES)

    def state(self) -> tuple[float, float, float]:
        return self.eta if self.eta is not None else self.initial()

    def energy(self) -> float:
        if self.plant is None:                                  # before initialization: parameters may change
            return float(self.make_plant().H(self.state()))
        if self._H is None:
            self._H = float(self.plant.H(self.state()))
        return self._H

    # ---- life cycle -----------------------------------------------------------------------------
    def make_plant(self) -> EMPlant:
        return catalog.plant(self.model_identifier, {n: self.values[n] for n in self.plant_module.PARAMETERS})

    def initialize(self) -> None:
        plant = self.make_plant()                                   # ValueError names parameter and condition
        stepper = PlantStepper(plant, rtol=self.integration_tolerance())
        eta = self.initial()
        try:
            plant.check_state(np.array(eta))
        except DomainError as exc:
            raise ValueError(f"initial state (q_0, p_0, x_e_0) = {eta} is not admissible: {exc}") from None
        self.plant, self.stepper, self.eta, self._H, self.u_end = plant, stepper, eta, None, None

    def integration_tolerance(self) -> float:
        """The rtol of doStep's integration: the tighter of the parameter rtol and the tolerance the master
        gives in fmi2SetupExperiment (issue 26, item 9). FMI 2.0 suggests that a slave with an error-
        controlled integrator use the master's tolerance, and an error-controlled master passes one matching
        its own (emcosim: a hundredth of it); but a master may pass one whatever it does (OMSimulator
        always passes its --tolerance, 1e-4 by default), and that must not loosen the accuracy a scenario
        set (plant.ssv: rtol = 1e-6). A master's tolerance below RTOL_RANGE's lower end counts as that end;
        an rtol outside the range is refused at initialization (PlantStepper), whatever the master gives."""
        rtol = self.values["rtol"]
        if self.tolerance is None or not RTOL_RANGE[0] <= rtol <= RTOL_RANGE[1]:
            return rtol
        return min(rtol, max(self.tolerance, RTOL_RANGE[0]))

    def step(self, t: float, h: float) -> bool:
        u = self.values["u"]
        du, d2u = self.input_rates()
        higher = self.higher_input_rates()
        try:
            self.eta = self.stepper.advance(*self.eta, u, h, du, d2u, higher)
        except (ValueError, ArithmeticError, DomainError, StepFailure) as exc:
            held = "" if du == d2u == 0.0 and not higher else f" + {du!r} tau + {d2u!r} tau^2/2"
            held += "".join(f" + {c!r} tau^{k}/{k}!" for k, c in sorted(higher.items()))
            self.log_error(f"{self.model_identifier}: doStep from t = {t:.9g} s over h = {h:.6g} s with u = {u!r}"
                           f"{held} failed: {exc}. The state is left at t = {t:.9g} s.")
            return False
        self._H = None
        if higher:                                              # the polynomial's value and rate at tau = h
            terms = input_terms(u, du, d2u, higher)
            self.u_end = (input_value(terms, h), input_value(terms, h, 1))
        else:
            self.u_end = (u + h * (du + 0.5 * h * d2u), du + h * d2u)
        return True

    # ---- Model Exchange (contract: model_exchange.ModelExchangeFunctions) --------------------------------
    def model(self):
        """components.plant_step's scalar model of the current parameters (f, its Jacobian)."""
        if self.stepper is None:                                # before initialization: parameters may change
            return PlantStepper(self.make_plant(), self.values["rtol"]).model
        return self.stepper.model

    def rates(self) -> tuple[float, float, float]:
        """(q', p', x_e') = f(eta, u), eq. (open-loop elecmech), computed once per state and input."""
        key = (self.state(), self.values["u"])
        if self._f is None or self._f[0] != key or self.stepper is None:
            (q, p, x), u = key
            self._f = (key, self.model().f(q, p, x, u))
        return self._f[1]

    def continuous_states(self) -> list[float]:
        return list(self.state())

    def set_continuous_states(self, x: list[float]) -> None:
        self.eta = (x[0], x[1], x[2])
        self._H = None

    def state_derivatives(self) -> list[float]:
        """[q', p', x_e'] = f(eta, u) of eq. (open-loop elecmech), once per state and input: the host's solver
        asks for them after every fmi2SetContinuousStates, which makes a new eta (the cache's key is its
        identity and u)."""
        eta, u, cached = self.eta, self.values["u"], self._dx
        if cached is not None and cached[0] is eta and cached[1] == u:
            return cached[2]
        if self.stepper is None or eta is None:                 # (Model Exchange asks after initialization only)
            return list(self.rates())
        dx = list(self.stepper.model.f(eta[0], eta[1], eta[2], u))
        self._dx = (eta, u, dx)
        return dx

    def event_indicators(self) -> list[float]:
        plant = self.plant if self.plant is not None else self.make_plant()
        return [float(plant.domain_margin(self.state()))]

    def nominals(self) -> list[float]:
        plant = self.plant if self.plant is not None else self.make_plant()
        return [float(v) for v in nominal_scale(plant)]

    def domain_problem(self) -> str:
        plant = self.plant if self.plant is not None else self.make_plant()
        eta = np.array(self.state())
        if plant.domain_margin(eta) > 0 and np.all(np.isfinite(eta)):
            return ""
        try:
            plant.check_state(eta)
        except DomainError as exc:
            return str(exc)
        return f"{plant.name}: the state (q, p, x_e) = {tuple(eta)} reached the boundary of the admissible domain"

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """The exact Jacobian of (der(q), der(p), der(x_e), q, p, x_e, H) with respect to (q, p, x_e, u) along
        the seeds: df/deta = F hess H and df/du = g of eq. (open-loop elecmech), grad H for H."""
        (q, p, x), u = self.state(), self.values["u"]
        model = self.model()
        _, J = model.f_jac(q, p, x, u)
        if len(J) == 6:                                         # the scalar model's nonzero entries
            J_qp, J_pq, J_pp, J_px, J_xq, J_xx = J
            J = ((0.0, J_qp, 0.0), (J_pq, J_pp, J_px), (J_xq, 0.0, J_xx))
        v = [0.0, 0.0, 0.0]
        du = 0.0
        for name, seed in zip(knowns, seeds):
            if name == "u":
                du += seed
            else:
                v[STATE_NAMES.index(name)] += seed
        out = []
        for name in unknowns:
            if name.startswith("der("):
                i = STATE_NAMES.index(name[4:-1])
                out.append(J[i][0] * v[0] + J[i][1] * v[1] + J[i][2] * v[2] + (model.g_x * du if i == 2 else 0.0))
            elif name == "H":
                plant = self.plant if self.plant is not None else self.make_plant()
                grad = plant.grad_H(np.array([q, p, x]))
                out.append(float(grad[0] * v[0] + grad[1] * v[1] + grad[2] * v[2]))
            else:
                out.append(v[STATE_NAMES.index(name)])
        return out

    # ---- FMU state ----------------------------------------------------------------------------
    def save_internal(self) -> dict:
        if self.stepper is None:
            return {}
        return {"eta": list(self.eta), "h_next": self.stepper.h_next,
                "u_end": None if self.u_end is None else list(self.u_end)}

    def internal_problem(self, state: dict) -> str:
        """'' if the integrator state of `state` can be restored, else why not (state.py): complete once
        initialized, none before; (q, p, x_e) finite and inside the domain of eq. (open-loop elecmech) for the
        state's parameters (components: check_state, as fmi2ExitInitializationMode checks q_0, p_0, x_e_0);
        the proposed substep h_next finite and >= 0 (0: none yet); the input at the end of the last step
        (u, u') finite or none."""
        internal = state["internal"]
        if not state["initialized"]:
            return "" if internal == {} else "it is not initialized but holds an integrator state"
        if not isinstance(internal, dict) or set(internal) != {"eta", "h_next", "u_end"}:
            return "its integrator state is incomplete (eta, h_next, u_end)"
        eta, h_next, u_end = internal["eta"], internal["h_next"], internal["u_end"]
        if not _finite_numbers(eta, 3):
            return f"its state (q, p, x_e) = {eta!r} is not three finite numbers"
        if not (_finite_numbers([h_next], 1) and h_next >= 0):
            return f"its integrator's proposed substep h_next = {h_next!r} s is not a finite number >= 0"
        if u_end is not None and not _finite_numbers(u_end, 2):
            return f"its input at the end of the last step (u, du/dt) = {u_end!r} is not two finite numbers"
        try:
            self.plant_of(state["values"]).check_state(np.array(eta, dtype=float))
        except (ValueError, DomainError) as exc:
            return f"its state (q, p, x_e) = {tuple(eta)} is not admissible: {exc}"
        return ""

    def plant_of(self, values: dict) -> EMPlant:
        """The components plant of the parameter values `values` (this instance's when they are its own)."""
        names = self.plant_module.PARAMETERS
        if self.plant is not None and all(values[n] == self.values[n] for n in names):
            return self.plant
        return catalog.plant(self.model_identifier, {n: values[n] for n in names})

    def restore_internal(self, internal: dict) -> None:
        if internal:
            self.eta = tuple(internal["eta"])
            self.stepper.h_next = internal["h_next"]
            self.u_end = None if internal["u_end"] is None else tuple(internal["u_end"])
        self._H = None

    # ---- FMI 2.0 derivatives (contract: derivatives.DerivativeFunctions) --------------------------------
    def input_rates(self) -> tuple[float, float]:
        """(u', u'') the master set for the current communication point (0 where none was set)."""
        d = self.input_derivatives.get("u")
        return (0.0, 0.0) if not d else (d.get(1, 0.0), d.get(2, 0.0))

    def higher_input_rates(self) -> dict[int, float]:
        """{k: d^k u/dt^k} for the orders k >= 3 the master set for the current communication point."""
        d = self.input_derivatives.get("u")
        return {k: v for k, v in d.items() if k > 2} if d else {}

    def inputs_changed(self) -> None:
        """The master set u: from now on it (and the rate it sets) is the input at the current time."""
        self.u_end = None

    def output_derivative(self, name: str, order: int) -> float:
        """d^order/dt^order of q, p, x_e or H at the current communication point: eta' = f(eta, u),
        eta'' = F hess H eta' + g u' (components: PlantStepper.time_derivatives)."""
        return self.output_derivatives([(name, order)])[0]

    def output_derivatives(self, requests: list[tuple[str, int]]) -> list[float]:
        """`output_derivative` for every (name, order) of a request, from one `time_derivatives`."""
        rows = self.time_derivatives()
        return [float(rows[order][OUTPUT_INDEX[name]]) for name, order in requests]

    def time_derivatives(self) -> tuple:
        """(None, (q', p', x_e', H'), (q'', p'', x_e'', H'')) at the current state with the input in force
        (the value and rate the master set, else the end of the last step's polynomial), computed once
        per state and input."""
        u, du = self.u_end if self.u_end is not None else (self.values["u"], self.input_rates()[0])
        if self.stepper is None:                                # before initialization: parameters may change
            return self._rows(PlantStepper(self.make_plant(), self.values["rtol"]), self.state(), u, du)
        key = (self.state(), u, du)
        if self._rates is None or self._rates[0] != key:
            self._rates = (key, self._rows(self.stepper, *key))
        return self._rates[1]

    @staticmethod
    def _rows(stepper: PlantStepper, eta, u: float, du: float) -> tuple:
        first, second, H1, H2 = stepper.time_derivatives(*eta, u, du)
        return (None, (*first, H1), (*second, H2))                # indexed by the order

"""Adapter: a plant of components/ (a components.device.Device: MEMS, maglev, a described plant) as an FMI 2.0
slave, for Co-Simulation and Model Exchange.

Variables (names, units and descriptions from the device; the paper's plants: q, p, x_e, u): every entry
of the device's parameters, the initial state <name>_0 of every state, the integration tolerance rtol
(parameters); the inputs u (n_e entries); the outputs q, p, x_e (states, n_m + n_m + n_e entries: no direct
feedthrough) and the stored energy H.

n_m = n_e = 1 (the paper's plants) runs on scalars (components.plant_step.PlantStepper, with the
electrical layer in closed form); any other n on numpy arrays (components.plant_step.GeneralStepper): the
same FMI contract, with vectors where there are scalars. doStep integrates with u held over the step or,
when the master has set input derivatives (fmi2SetRealInputDerivatives, any orders k >= 1, per input),
with the polynomial u + u' tau + u'' tau^2 / 2 + ... + u^(k) tau^k / k!. Output derivatives (orders 1 and
2) of q, p, x_e and H are the exact ones of eq. (open-loop elecmech) at the current state
(PlantStepper.time_derivatives, EMPlant.time_derivatives); the input they use is the polynomial's value
and rate at the end of the last step until the master sets u again. The FMU state includes the stepper's
proposed substep and that end-of-step input.

Nominal values of the states (the outputs' `nominal`, fmi2GetNominalsOfContinuousStates):
components.plant_step.nominal_scale, from the parameters alone (n > 1: per axis, from the distance to the
domain's boundary along the axis, else 1).

Model Exchange: the continuous states are q, p, x_e with der(q), der(p), der(x_e) = f(eta, u) of eq.
(open-loop elecmech) (the model the integrator of doStep uses); the Derivatives' dependencies follow the
block structure of that equation (`derivative_dependencies`); their
Jacobian with respect to the states and u (fmi2GetDirectionalDerivative) is F hess H and g, exact; the one
event indicator is the margin to the boundary of the admissible domain (components: domain_margin).
"""
from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from components.device import Device
from components.ph_plant import DomainError, EMPlant
from components.plant_step import (
    DEFAULT_RTOL,
    RTOL_RANGE,
    GeneralStepper,
    PlantStepper,
    StepFailure,
    input_terms,
    input_value,
    make_stepper,
    nominal_scale,
    vector_input,
    vector_terms,
)

from .slave import EMSlave
from .variables import RATE_UNITS

H_SCALAR = "stored energy H(q, p, x_e) = p^2/(2 m) + V(q) + H_e(q, x_e), eq. (open-loop elecmech)"
H_GENERAL = "stored energy H(q, p, x_e) = 1/2 p^T M(q)^-1 p + V(q) + H_e(q, x_e), eq. (open-loop elecmech)"


def derivative_dependencies(device: Device, constant_mass: bool) -> dict[str, list[str]]:
    """What each state derivative depends on, from the block structure of eq. (open-loop elecmech):
    q' = M^-1(q) p (on p, and on q when M depends on q); p' = -grad_q H - R_m M^-1 p (on q, p, x_e);
    x_e' = (J_e - R_e) Psi(q) x_e + G_e u (on q, x_e, u). state name -> names of the knowns."""
    q, p, x, u = ([v.name for v in group] for group in (device.q, device.p, device.x_e, device.u))
    out = {name: p + ([] if constant_mass else q) for name in q}
    out.update({name: q + p + x for name in p})
    out.update({name: q + x + u for name in x})
    return out


def _finite_numbers(values, n: int) -> bool:
    """Is `values` a list of n finite numbers (not booleans)?"""
    return isinstance(values, (list, tuple)) and len(values) == n and all(
        not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) for v in values)


def initial_dependencies(knowns: list[str], parameters: list[str], states: list[str]) -> list[str]:
    """What a quantity that depends on `knowns` (states, inputs) depends on at initialization: the initial
    value x_0 of each state x, the inputs, and the plant's parameters (FMI 2.0: the knowns of
    InitialUnknowns are the inputs and the variables with initial = "exact")."""
    return [f"{k}_0" if k in states else k for k in knowns] + parameters


class PlantSlave(EMSlave):
    device: ClassVar[Device]                                    # the plant kind (components.device)
    initial_state: ClassVar[tuple[float, ...]]                  # start of q_0, p_0, x_e_0 (n entries)
    input_start: ClassVar[float | tuple[float, ...]] = 0.0      # start of u (a number, or n_e numbers)
    # FMI 2.0 derivatives (hooks at the end of the class)
    can_interpolate_inputs = True                               # any order: the whole polynomial is integrated
    max_output_derivative_order = 2
    provides_directional_derivative = True
    number_of_event_indicators = 1                              # the margin to the domain's boundary

    def declare(self) -> None:
        device = self.device
        self.state_specs = device.states
        names = [v.name for v in self.state_specs]
        self.input_names = [v.name for v in device.u]
        self.scalar = device.n_m == 1 and device.n_e == 1       # the scalar path (PlantStepper)
        self.index = {n: i for i, n in enumerate(names)}
        self.output_index = {**self.index, "H": len(names)}    # output -> its entry in time_derivatives' rows
        for p in device.parameters.values():
            self.parameter(p.name, p.default, p.unit, p.description)
        for v, start in zip(self.state_specs, self.initial_state, strict=True):
            self.parameter(f"{v.name}_0", start, v.unit, f"initial value of {v.name}: {v.description}")
        self.parameter("rtol", DEFAULT_RTOL, "1",
                       "relative tolerance of the integration inside doStep (absolute tolerance: rtol times "
                       "the nominal state scale); a tolerance given in fmi2SetupExperiment is used instead "
                       f"where it is tighter (not below {RTOL_RANGE[0]:g})")
        starts = (self.input_start,) if isinstance(self.input_start, (int, float)) else tuple(self.input_start)
        for v, start in zip(device.u, starts, strict=True):
            self.input(v.name, start, v.unit, v.description)
        parameters = list(device.parameters)
        default = device.plant()
        nominal = nominal_scale(default)
        for i, v in enumerate(self.state_specs):                 # the states: no direct feedthrough from u
            self.output(v.name, v.unit, v.description, (lambda i=i: self.state()[i]), [v.name], [f"{v.name}_0"],
                        nominal=float(nominal[i]))
        self.output("H", "J", H_SCALAR if device.n_m == 1 and default.constant_mass else H_GENERAL,
                    self.energy, names, initial_dependencies(names, parameters, names))
        dependencies = derivative_dependencies(device, default.constant_mass)
        for i, v in enumerate(self.state_specs):
            knowns = dependencies[v.name]
            self.state_derivative(v.name, RATE_UNITS[v.unit], (lambda i=i: self.rates()[i]),
                                  knowns, initial_dependencies(knowns, parameters, names))
        self.plant: EMPlant | None = None
        self.stepper: PlantStepper | GeneralStepper | None = None
        self.eta: tuple[float, ...] | None = None
        self._H: float | None = None
        self.u_end: tuple[float, ...] | None = None            # (u..., u'...) at the end of the last step
        self._rates: tuple | None = None                        # (key, time derivatives) of the last request
        self._f: tuple | None = None                            # (key, f(eta, u)) of the last request of der(x)
        self._dx: tuple | None = None                           # (eta, u, [f(eta, u)]) of the last fmi2GetDerivatives

    # ---- outputs ------------------------------------------------------------------------------
    def initial(self) -> tuple[float, ...]:
        return tuple(float(self.values[f"{v.name}_0"]) for v in self.state_specs)

    def state(self) -> tuple[float, ...]:
        return self.eta if self.eta is not None else self.initial()

    def energy(self) -> float:
        if self.plant is None:                                  # before initialization: parameters may change
            return float(self.make_plant().H(np.array(self.state())))
        if self._H is None:
            eta = self.state()
            self._H = float(self.plant.H(eta if self.scalar else np.array(eta)))
        return self._H

    def inputs(self) -> np.ndarray:
        """u (n_e entries) as the master set it."""
        return np.array([self.values[n] for n in self.input_names])

    # ---- life cycle -----------------------------------------------------------------------------
    def make_plant(self) -> EMPlant:
        return self.plant_of(self.values)

    def initialize(self) -> None:
        plant = self.make_plant()                                   # ValueError names parameter and condition
        stepper = make_stepper(plant, rtol=self.integration_tolerance())
        eta = self.initial()
        try:
            plant.check_state(np.array(eta))
        except DomainError as exc:
            names = ", ".join(f"{v.name}_0" for v in self.state_specs)
            raise ValueError(f"initial state ({names}) = {eta} is not admissible: {exc}") from None
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
        if not self.scalar:
            return self.step_general(t, h)
        u = self.values[self.input_names[0]]
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

    def vector_derivatives(self) -> dict[int, list[float]]:
        """{k: [d^k u_i/dt^k for every input i]} the master set for the current communication point (0 where
        an input has none of that order)."""
        orders = sorted({k for d in self.input_derivatives.values() for k in d})
        return {k: [self.input_derivatives.get(n, {}).get(k, 0.0) for n in self.input_names] for k in orders}

    def step_general(self, t: float, h: float) -> bool:
        """doStep for any n_m, n_e: GeneralStepper with the input polynomial of every input."""
        u, derivatives = self.inputs(), self.vector_derivatives()
        try:
            eta = self.stepper.step(np.array(self.eta), u, h, derivatives)
        except (ValueError, ArithmeticError, DomainError, StepFailure) as exc:
            rates = "".join(f" + {c} tau^{k}/{k}!" for k, c in derivatives.items())
            self.log_error(f"{self.model_identifier}: doStep from t = {t:.9g} s over h = {h:.6g} s with "
                           f"{self.input_names} = {u.tolist()}{rates} failed: {exc}. The state is left at "
                           f"t = {t:.9g} s.")
            return False
        self.eta = tuple(float(v) for v in eta)
        self._H = None
        terms = vector_terms(u, derivatives, len(u))           # the polynomial's value and rate at tau = h
        self.u_end = tuple(vector_input(terms, h).tolist() + vector_input(terms, h, 1).tolist())
        return True

    # ---- Model Exchange (contract: model_exchange.ModelExchangeFunctions) --------------------------------
    def model(self):
        """components.plant_step's scalar model of the current parameters (f, its Jacobian): n_m = n_e = 1."""
        if self.stepper is None:                                # before initialization: parameters may change
            return PlantStepper(self.make_plant(), self.values["rtol"]).model
        return self.stepper.model

    def rates(self) -> tuple[float, ...]:
        """(q', p', x_e') = f(eta, u), eq. (open-loop elecmech), computed once per state and input."""
        if not self.scalar:
            key = (self.state(), tuple(self.inputs().tolist()))
            if self._f is None or self._f[0] != key or self.stepper is None:
                plant = self.plant if self.stepper is not None else self.make_plant()
                self._f = (key, tuple(float(v) for v in plant.f(np.array(key[0]), np.array(key[1]))))
            return self._f[1]
        key = (self.state(), self.values[self.input_names[0]])
        if self._f is None or self._f[0] != key or self.stepper is None:
            (q, p, x), u = key
            self._f = (key, self.model().f(q, p, x, u))
        return self._f[1]

    def continuous_states(self) -> list[float]:
        return list(self.state())

    def set_continuous_states(self, x: list[float]) -> None:
        self.eta = tuple(x) if not self.scalar else (x[0], x[1], x[2])
        self._H = None

    def state_derivatives(self) -> list[float]:
        """[q', p', x_e'] = f(eta, u) of eq. (open-loop elecmech), once per state and input: the host's solver
        asks for them after every fmi2SetContinuousStates, which makes a new eta (the cache's key is its
        identity and u)."""
        if not self.scalar:
            return list(self.rates())
        eta, u, cached = self.eta, self.values[self.input_names[0]], self._dx
        if cached is not None and cached[0] is eta and cached[1] == u:
            return cached[2]
        if self.stepper is None or eta is None:                 # (Model Exchange asks after initialization only)
            return list(self.rates())
        dx = list(self.stepper.model.f(eta[0], eta[1], eta[2], u))
        self._dx = (eta, u, dx)
        return dx

    def event_indicators(self) -> list[float]:
        plant = self.plant if self.plant is not None else self.make_plant()
        eta = self.state()
        return [float(plant.domain_margin(eta if self.scalar else np.array(eta)))]

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
        names = ", ".join(v.name for v in self.state_specs)
        return f"{plant.name}: the state ({names}) = {tuple(eta)} reached the boundary of the admissible domain"

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """The exact Jacobian of (der(q), der(p), der(x_e), q, p, x_e, H) with respect to (q, p, x_e, u) along
        the seeds: df/deta = F hess H and df/du = g of eq. (open-loop elecmech), grad H for H."""
        if not self.scalar:
            return self.directional_general(unknowns, knowns, seeds)
        (q, p, x), u = self.state(), self.values[self.input_names[0]]
        model = self.model()
        _, J = model.f_jac(q, p, x, u)
        if len(J) == 6:                                         # the scalar model's nonzero entries
            J_qp, J_pq, J_pp, J_px, J_xq, J_xx = J
            J = ((0.0, J_qp, 0.0), (J_pq, J_pp, J_px), (J_xq, 0.0, J_xx))
        v = [0.0, 0.0, 0.0]
        du = 0.0
        index = self.index
        for name, seed in zip(knowns, seeds):
            if name in index:
                v[index[name]] += seed
            else:
                du += seed
        out = []
        for name in unknowns:
            if name.startswith("der("):
                i = index[name[4:-1]]
                out.append(J[i][0] * v[0] + J[i][1] * v[1] + J[i][2] * v[2] + (model.g_x * du if i == 2 else 0.0))
            elif name == "H":
                plant = self.plant if self.plant is not None else self.make_plant()
                grad = plant.grad_H(np.array([q, p, x]))
                out.append(float(grad[0] * v[0] + grad[1] * v[1] + grad[2] * v[2]))
            else:
                out.append(v[index[name]])
        return out

    def directional_general(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """`directional_derivative` for any n: J = F hess H (EMPlant.jacobian), g, grad H, as matrices."""
        plant = self.plant if self.plant is not None else self.make_plant()
        eta = np.array(self.state())
        v, du = np.zeros(len(eta)), np.zeros(len(self.input_names))
        u_index = {n: i for i, n in enumerate(self.input_names)}
        for name, seed in zip(knowns, seeds):
            if name in self.index:
                v[self.index[name]] += seed
            else:
                du[u_index[name]] += seed
        rates = plant.jacobian(eta) @ v + plant.g() @ du
        out = []
        for name in unknowns:
            if name.startswith("der("):
                out.append(float(rates[self.index[name[4:-1]]]))
            elif name == "H":
                out.append(float(plant.grad_H(eta) @ v))
            else:
                out.append(float(v[self.index[name]]))
        return out

    # ---- FMU state ----------------------------------------------------------------------------
    def save_internal(self) -> dict:
        if self.stepper is None:
            return {}
        return {"eta": list(self.eta), "h_next": self.stepper.h_next,
                "u_end": None if self.u_end is None else list(self.u_end)}

    def internal_problem(self, state: dict) -> str:
        """'' if the integrator state of `state` can be restored, else why not (state.py): complete once
        initialized, none before; the state (q, p, x_e) finite and inside the domain of eq. (open-loop
        elecmech) for the state's parameters (components: check_state, as fmi2ExitInitializationMode checks
        the initial state); the proposed substep h_next finite and >= 0 (0: none yet); the input at the end
        of the last step (u, u', n_e numbers each) finite or none; the parameter rtol in RTOL_RANGE."""
        internal = state["internal"]
        if not state["initialized"]:
            return "" if internal == {} else "it is not initialized but holds an integrator state"
        if not isinstance(internal, dict) or set(internal) != {"eta", "h_next", "u_end"}:
            return "its integrator state is incomplete (eta, h_next, u_end)"
        eta, h_next, u_end = internal["eta"], internal["h_next"], internal["u_end"]
        n, n_e = len(self.state_specs), len(self.input_names)
        rtol = state["values"]["rtol"]                 # as at initialization (PlantStepper), issue 40
        if not RTOL_RANGE[0] <= rtol <= RTOL_RANGE[1]:
            return f"its parameter rtol = {rtol!r} violates 1e-14 <= rtol <= 1e-2"
        if not _finite_numbers(eta, n):
            return f"its state (q, p, x_e) = {eta!r} is not {'three' if n == 3 else n} finite numbers"
        if not (_finite_numbers([h_next], 1) and h_next >= 0):
            return f"its integrator's proposed substep h_next = {h_next!r} s is not a finite number >= 0"
        if u_end is not None and not _finite_numbers(u_end, 2 * n_e):
            return (f"its input at the end of the last step (u, du/dt) = {u_end!r} is not "
                    f"{'two' if n_e == 1 else 2 * n_e} finite numbers")
        try:
            self.plant_of(state["values"]).check_state(np.array(eta, dtype=float))
        except (ValueError, DomainError) as exc:
            return f"its state (q, p, x_e) = {tuple(eta)} is not admissible: {exc}"
        return ""

    def plant_of(self, values: dict) -> EMPlant:
        """The components plant of the parameter values `values` (this instance's when they are its own)."""
        names = self.device.parameters
        if self.plant is not None and all(values[n] == self.values[n] for n in names):
            return self.plant
        return self.device.plant(**{n: values[n] for n in names})

    def restore_internal(self, internal: dict) -> None:
        if internal:
            self.eta = tuple(internal["eta"])
            self.stepper.h_next = internal["h_next"]
            self.u_end = None if internal["u_end"] is None else tuple(internal["u_end"])
        self._H = None

    # ---- FMI 2.0 derivatives (contract: derivatives.DerivativeFunctions) --------------------------------
    def input_rates(self) -> tuple[float, float]:
        """(u', u'') the master set for the current communication point (0 where none was set): n_e = 1."""
        d = self.input_derivatives.get(self.input_names[0])
        return (0.0, 0.0) if not d else (d.get(1, 0.0), d.get(2, 0.0))

    def higher_input_rates(self) -> dict[int, float]:
        """{k: d^k u/dt^k} for the orders k >= 3 the master set for the current communication point: n_e = 1."""
        d = self.input_derivatives.get(self.input_names[0])
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
        index = self.output_index
        return [float(rows[order][index[name]]) for name, order in requests]

    def time_derivatives(self) -> tuple:
        """(None, (q', p', x_e', H'), (q'', p'', x_e'', H'')) at the current state with the input in force
        (the value and rate the master set, else the end of the last step's polynomial), computed once
        per state and input."""
        if not self.scalar:
            n_e = len(self.input_names)
            if self.u_end is not None:
                u, du = self.u_end[:n_e], self.u_end[n_e:]
            else:
                d = self.input_derivatives
                u = tuple(self.inputs().tolist())
                du = tuple(d[n].get(1, 0.0) if n in d else 0.0 for n in self.input_names)
        else:
            u, du = self.u_end if self.u_end is not None else (self.values[self.input_names[0]], self.input_rates()[0])
        if self.stepper is None:                                # before initialization: parameters may change
            return self._rows(make_stepper(self.make_plant(), self.values["rtol"]), self.state(), u, du)
        key = (self.state(), u, du)
        if self._rates is None or self._rates[0] != key:
            self._rates = (key, self._rows(self.stepper, *key))
        return self._rates[1]

    @staticmethod
    def _rows(stepper: PlantStepper | GeneralStepper, eta, u, du) -> tuple:
        if isinstance(stepper, GeneralStepper):
            first, second, H1, H2 = stepper.time_derivatives(np.array(eta), np.array(u), np.array(du))
        else:
            first, second, H1, H2 = stepper.time_derivatives(*eta, u, du)
        return (None, (*first, H1), (*second, H2))                # indexed by the order

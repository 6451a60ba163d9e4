"""The FMI 2.0 derivative functions of an emcosim FMU: fmi2SetRealInputDerivatives,
fmi2GetRealOutputDerivatives and fmi2GetDirectionalDerivative (pythonfmu 0.7.0 answers "not supported":
the FMU's binary answers them through these methods).

Contract: validation here, physics in the adapters' hooks `output_derivative` (or `output_derivatives`,
a whole request at once) and `directional_derivative`; the capabilities are class attributes written
into modelDescription.xml. A derivative request (value references and orders) is checked once; a master
repeats it at every communication point. Input derivatives are kept in `input_derivatives` for the next
doStep only (a master sets them again for every step) and are part of the FMU state.

Input derivative orders: FMI 2.0 has no attribute that declares up to which order an FMU that declares
canInterpolateInputs takes them, and masters send what their sources give (OMSimulator with
--inputExtrapolation: the source's maxOutputDerivativeOrder). So an FMU accepts every order >= 1 and
uses what it needs (issue 26, item 9): `input_derivative_orders_used` orders are kept, higher ones are
accepted and dropped (a controller that needs only first derivatives), and declared in modelDescription.xml
(model_description.py: emcosim's vendor annotation, so that a master passes no order that is dropped);
None keeps every order (a plant integrates the whole polynomial). `max_input_derivative_order` refuses orders
above it with fmi2Error, as an FMU of another vendor may (the tests' toy FMUs do, to test masters against it);
None refuses none.
"""
from __future__ import annotations

import math
from typing import ClassVar

from .status import DONE as _OK
from .status import ERROR, MODEL_EXCHANGE, OK


class DerivativeFunctions:
    """The derivative functions of EMSlave (slave.py)."""

    can_interpolate_inputs: ClassVar[bool] = False          # canInterpolateInputs
    max_input_derivative_order: ClassVar[int | None] = None  # orders above are refused (None: none is refused)
    input_derivative_orders_used: ClassVar[int | None] = None  # orders above are dropped (None: all are kept)
    max_output_derivative_order: ClassVar[int] = 0          # maxOutputDerivativeOrder
    provides_directional_derivative: ClassVar[bool] = False  # providesDirectionalDerivative

    def init_derivatives(self) -> None:
        self.input_derivatives: dict[str, dict[int, float]] = {}     # input name -> {order: value}
        # validated derivative requests: (vrs, orders) -> names (set; None for an order that is dropped) or
        # [(name, order)] (get); a master repeats the same request at every communication point, so it is
        # checked once
        self._derivative_sets: dict[tuple, list[str | None]] = {}
        self._derivative_gets: dict[tuple, list[tuple[str, int]]] = {}
        self._directional: dict[tuple, tuple[list[str], list[str]]] = {}

    def fmi2_set_real_input_derivatives(self, vrs: list[int], orders: list[int],
                                        values: list[float]) -> tuple[int, str]:
        """Store d^order(input)/dt^order at the current communication point for the next doStep
        (`input_derivatives`; all or nothing). Returns (fmi2Status, message)."""
        try:
            names = self._derivative_sets.get((tuple(vrs), tuple(orders)))
            if names is not None:                                     # fast path: a request checked before
                total = sum(values)
                if total - total == 0.0:                              # all finite (else nan, or an overflow)
                    store = self.input_derivatives
                    for name, order, value in zip(names, orders, values):
                        if name is None:                              # an order this FMU does not use
                            continue
                        rates = store.get(name)
                        if rates is None:
                            store[name] = rates = {}
                        rates[order] = float(value)
                    return _OK
        except Exception:                                             # noqa: BLE001 - found again below
            pass
        where = f"{self.model_identifier}: fmi2SetRealInputDerivatives"
        try:
            problem = self.cs_only("fmi2SetRealInputDerivatives")      # (never cached: no fast path either)
            if problem:
                return ERROR, problem
            if not self.can_interpolate_inputs:
                return ERROR, f"{where}: this FMU does not interpolate inputs (canInterpolateInputs = false)"
            staged: dict[str, dict[int, float]] = {}
            kept: list[str | None] = []
            for vr, order, value in zip(vrs, orders, values):
                name = self._real_inputs.get(vr)
                if name is None:
                    return ERROR, f"{where}: {self._describe_vr(vr)} is not a Real input"
                problem = self._order_problem(order)
                if problem:
                    return ERROR, f"{where}: order {order!r} for input {name} {problem}"
                if not math.isfinite(value):
                    return ERROR, f"{where}: derivative of order {order} of input {name} = {value} is not finite"
                used = self.input_derivative_orders_used
                kept.append(name if used is None or order <= used else None)
                if kept[-1] is not None:
                    staged.setdefault(name, {})[int(order)] = float(value)
            for name, derivatives in staged.items():
                self.input_derivatives.setdefault(name, {}).update(derivatives)
            self._derivative_sets[(tuple(vrs), tuple(orders))] = kept
            return OK, ""
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, f"{where} failed: {type(exc).__name__}: {exc}"

    def _order_problem(self, order) -> str:
        """'' if fmi2SetRealInputDerivatives takes derivatives of this order, else why not."""
        if isinstance(order, bool) or not isinstance(order, int) or order < 1:
            return "is not an integer >= 1 (FMI 2.0: order 1 is the first derivative)"
        top = self.max_input_derivative_order
        if top is not None and order > top:
            return f"is not in 1..{top}"
        return ""

    def fmi2_get_real_output_derivatives(self, vrs: list[int], orders: list[int]) -> tuple[int, list[float], str]:
        """d^order(output)/dt^order at the current communication point, from the hook
        `output_derivatives` (`output_derivative` for each entry). A request checked once (value references
        and orders) is not checked again. Returns (fmi2Status, values, message)."""
        key = None
        try:
            key = (tuple(vrs), tuple(orders))
            requests = self._derivative_gets.get(key)
            if requests is not None:                                  # fast path: a request checked before
                values = self.output_derivatives(requests)
                total = sum(values)
                if total - total == 0.0:                              # all finite (else nan, or an overflow)
                    return OK, values, ""
        except Exception:                                             # noqa: BLE001 - found again below
            pass
        where = f"{self.model_identifier}: fmi2GetRealOutputDerivatives"
        name, order = "", 0
        problem = self.cs_only("fmi2GetRealOutputDerivatives")          # (never cached: no fast path either)
        if problem:
            return ERROR, [], problem
        try:
            requests = []
            for vr, order in zip(vrs, orders):
                var = self._variable(vr)
                if var is None or var.causality != "output":
                    return ERROR, [], f"{where}: {self._describe_vr(vr)} is not a Real output"
                if not 1 <= order <= self.max_output_derivative_order:
                    return ERROR, [], (f"{where}: order {order} for output {var.name} is not in 1.."
                                       f"{self.max_output_derivative_order} (maxOutputDerivativeOrder)")
                requests.append((var.name, order))
            values = []
            for name, order in requests:
                value = float(self.output_derivative(name, order))
                if not math.isfinite(value):
                    return ERROR, [], f"{where}: derivative of order {order} of {name} = {value} is not finite"
                values.append(value)
            if key is not None:
                self._derivative_gets[key] = requests
            return OK, values, ""
        except (ValueError, ArithmeticError) as exc:
            return ERROR, [], f"{where}: derivative of order {order} of {name}: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{where} failed: {type(exc).__name__}: {exc}"

    def fmi2_get_directional_derivative(self, unknowns: list[int], knowns: list[int],
                                        seeds: list[float]) -> tuple[int, list[float], str]:
        """sum_j d(unknown_i)/d(known_j) seeds_j, from the hook `directional_derivative`: unknowns are
        outputs (and, Model Exchange, state derivatives der(x)), knowns are inputs (and, Model Exchange,
        continuous states). A request of the same value references is checked once. Returns
        (fmi2Status, values, message)."""
        where = f"{self.model_identifier}: fmi2GetDirectionalDerivative"
        problem = self.me_refusal("fmi2GetDirectionalDerivative") if self.interface == MODEL_EXCHANGE else ""
        if problem:                                                   # Model Exchange: from initialization on
            return ERROR, [], problem
        try:
            key = (tuple(unknowns), tuple(knowns))
            names = self._directional.get(key)
            if names is None:
                if not self.provides_directional_derivative:
                    return ERROR, [], f"{where}: not provided by this FMU (providesDirectionalDerivative = false)"
                problem, names = self._directional_names(unknowns, knowns)
                if problem:
                    return ERROR, [], f"{where}: {problem}"
                self._directional[key] = names
            total = sum(seeds)
            if not total - total == 0.0:                              # a seed is nan or inf (or they overflow)
                for name, seed in zip(names[1], seeds):
                    if not math.isfinite(seed):
                        return ERROR, [], f"{where}: seed {seed} for {name} is not finite"
            values = [float(v) for v in self.directional_derivative(names[0], names[1], [float(x) for x in seeds])]
            if len(values) != len(names[0]):
                return ERROR, [], f"{where}: {len(values)} values for {len(names[0])} unknowns"
            total = sum(values)
            if not total - total == 0.0:
                for name, value in zip(names[0], values):
                    if not math.isfinite(value):
                        return ERROR, [], f"{where}: directional derivative of {name} = {value} is not finite"
            return OK, values, ""
        except (ValueError, ArithmeticError) as exc:
            return ERROR, [], f"{where}: {exc}"
        except Exception as exc:                                      # noqa: BLE001 - reported, never raised
            return ERROR, [], f"{where} failed: {type(exc).__name__}: {exc}"

    def _directional_names(self, unknowns: list[int], knowns: list[int]) -> tuple[str, tuple[list[str], list[str]]]:
        """('', (unknown names, known names)) or (what is wrong, ...)."""
        states = set(self.state_names)
        unknown_names, known_names = [], []
        for vr in unknowns:
            var = self._variable(vr)
            if var is None or not (var.causality == "output" or var.derivative_of is not None):
                return f"unknown {self._describe_vr(vr)} is not a Real output or state derivative", ([], [])
            unknown_names.append(var.name)
        for vr in knowns:
            var = self._variable(vr)
            if var is None or not (vr in self._real_inputs or var.name in states):
                return f"known {self._describe_vr(vr)} is not a Real input or continuous state", ([], [])
            known_names.append(var.name)
        return "", (unknown_names, known_names)

    def output_derivative(self, name: str, order: int) -> float:
        """Hook: d^order(output `name`)/dt^order at the current communication point. Raise ValueError
        (or ArithmeticError) with the reason when it cannot be computed."""
        raise ValueError(f"output derivatives are not provided by {self.model_identifier}")

    def output_derivatives(self, requests: list[tuple[str, int]]) -> list[float]:
        """Hook: the floats `output_derivative(name, order)` for a checked request [(name, order), ...],
        all at once (an adapter computes what the entries share once). Any exception, or a value that
        is not finite, makes the caller ask `output_derivative` entry by entry to report it."""
        return [float(self.output_derivative(name, order)) for name, order in requests]

    def directional_derivative(self, unknowns: list[str], knowns: list[str], seeds: list[float]) -> list[float]:
        """Hook: for each output or state derivative in `unknowns`, sum_j d(unknown)/d(knowns_j) * seeds_j
        (knowns: inputs or continuous states)."""
        raise ValueError(f"directional derivatives are not provided by {self.model_identifier}")

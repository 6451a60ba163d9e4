"""Adapter: the reference generators of components.references as one FMI 2.0 slave (Co-Simulation and Model
Exchange: outputs that are functions of time, no states).

Integer parameter kind selects the generator (0 constant, 1 sinusoid, 2 smooth_step); every parameter
of the three generators is a parameter of the FMU (names from their PARAMETERS). The outputs are the
reference jet (q*, q*', q*'', q*''') at the current communication point (Model Exchange: at the time of
fmi2SetTime); they depend on no input, only on the independent variable `time`.
Output derivatives of order k (fmi2GetRealOutputDerivatives, k <= 3) are analytic: q_star of order k is
q*^(k), q_star_dddot of order k is q*^(3+k) (components.references.Reference.derivatives).
"""
from __future__ import annotations

from components import catalog, references

from .slave import EMSlave

KIND_CODES = catalog.REFERENCE_KINDS
OUTPUTS = references.JET_VARIABLES
OUTPUT_INDEX = {name: k for k, (name, _, _) in enumerate(OUTPUTS)}      # jet output -> its order k0


class ReferenceSlave(EMSlave):
    max_output_derivative_order = 3                             # FMI 2.0 derivatives (hook at the end)

    def declare(self) -> None:
        self.parameter("kind", 1, None, "reference generator: " + ", ".join(
            f"{code} {name} ({references.KINDS[name].name})" for code, name in KIND_CODES.items()), integer=True)
        for code, name in KIND_CODES.items():
            for p in references.KINDS[name].PARAMETERS.values():
                self.parameter(p.name, p.default, p.unit, f"{p.description} (kind {code}, {name})")
        all_parameters = ["kind"] + [p for name in KIND_CODES.values() for p in references.KINDS[name].PARAMETERS]
        for i, (name, unit, description) in enumerate(OUTPUTS):     # functions of time alone
            self.output(name, unit, description, (lambda i=i: self.jet()[i]), ["time"], all_parameters + ["time"])
        self.independent_time()
        self.reference = None
        self._derivatives_time = None
        self._derivatives: tuple[float, ...] = ()

    def make_reference(self) -> references.Reference:
        kind = self.values["kind"]
        if kind not in KIND_CODES:
            raise ValueError(f"parameter kind = {kind} violates kind in {{0, 1, 2}} "
                             f"({', '.join(f'{c} {n}' for c, n in KIND_CODES.items())})")
        return catalog.reference(kind, {n: self.values[n] for n in catalog.REFERENCE_PARAMETERS})

    def initialize(self) -> None:
        self.reference = self.make_reference()
        self._derivatives_time = None

    def jet(self) -> tuple[float, float, float, float]:
        """(q*, q*', q*'', q*''') at the current communication point: the first entries of `all_derivatives`."""
        return tuple(map(float, self.all_derivatives(3)[:4]))

    def step(self, t: float, h: float) -> bool:
        return True

    # ---- FMI 2.0 derivatives (contract: derivatives.DerivativeFunctions) --------------------------------
    def output_derivative(self, name: str, order: int) -> float:
        """d^order/dt^order of the jet output `name` (the jet's entry k0 = q*^(k0)): q*^(k0 + order)."""
        return self.output_derivatives([(name, order)])[0]

    def output_derivatives(self, requests: list[tuple[str, int]]) -> list[float]:
        """`output_derivative` for every (name, order) of a request, from one `all_derivatives`: a master
        asks for every output at its orders in one call."""
        entries = [OUTPUT_INDEX[name] + order for name, order in requests]
        derivatives = self.all_derivatives(max(entries, default=0))
        return [float(derivatives[k]) for k in entries]

    def all_derivatives(self, top: int) -> tuple[float, ...]:
        """(q*, q*', ..., q*^(n)) at the current communication point, n >= top, computed once per
        communication point up to the highest order asked for (components.references.Reference.derivatives:
        each entry is the same whatever the order asked)."""
        if self._derivatives_time != self.time or len(self._derivatives) <= top or self.reference is None:
            reference = self.reference if self.reference is not None else self.make_reference()
            self._derivatives = reference.derivatives(self.time, top)
            self._derivatives_time = self.time if self.reference is not None else None
        return self._derivatives

"""Higher-order coupling: input interpolation with the output derivatives of FMI 2.0 co-simulation.

With a zero-order hold the master sets an input's value at t_n and the FMU holds it over the step
[t_n, t_n + h]: the coupling error of a step is O(h) and the global error O(h). FMI 2.0 lets a source
FMU give the time derivatives of an output at the communication point (`maxOutputDerivativeOrder`,
fmi2GetRealOutputDerivatives) and a target FMU accept derivatives of an input
(`canInterpolateInputs`, fmi2SetRealInputDerivatives), which it uses as the Taylor polynomial
u(t_n + s) = sum_j u^(j)(t_n) s^j / j! over the step. With derivatives up to order K on every
connection the coupling error of a step is O(h^(K+1)) and the global error O(h^(K+1)).

Order of a connection (`connection_orders`): the order the source can give (its
maxOutputDerivativeOrder; for an output with direct feedthrough also no more than the orders on the
inputs it depends on, since its derivatives follow from theirs by the chain rule), 0 unless the
target declares canInterpolateInputs, no more than the target declares it uses (emcosim's vendor
annotation, vendor.py) or was found to accept, and no more than the order asked for (`coupling_order`;
default: all both ends offer, up to MAX_ORDER). FMUs that declare nothing are coupled with a
zero-order hold, exactly as without this module.

Order of the calls at a communication point (`DerivativePlan`): the values first, level by level
(master.py); then the derivatives order by order, k = 1..K, and within each order level by level,
in the same dependency order as the values: a state's k-th derivative depends on the input's value
and derivatives below k (all set before), a feedthrough output's k-th derivative on its inputs' k-th
derivatives (set earlier in the same pass, from lower levels). So plant -> controller -> plant
chains get their derivatives like their values: the controller's du/dt is read after the plant's
and the reference's output derivatives have been set on its inputs. Sources without inputs give all
their orders in one call. A linear transformation y -> factor * y + offset on a connection scales
every derivative by the factor. The calls are transfers (transfer.py), as the values'.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from . import dependencies
from .fmi import FMICallException
from .history import History, taylor
from .options import MAX_COUPLING_ORDER as MAX_ORDER  # the highest order the master passes when none is asked for
from .transfer import Transfer


@dataclass(frozen=True)
class Capabilities:
    """What an FMU declares for higher-order coupling (modelDescription.xml, CoSimulation)."""

    interpolates_inputs: bool     # canInterpolateInputs
    output_order: int             # maxOutputDerivativeOrder


def capabilities(model_description) -> Capabilities:
    cs = model_description.coSimulation
    return Capabilities(bool(cs.canInterpolateInputs), max(0, int(cs.maxOutputDerivativeOrder or 0)))


def connection_orders(instances: dict, connections, level: dict[str, int], depends: dict[str, set[str]],
                      requested: int | None = None, accepted: dict[str, int] | None = None) -> dict[str, int]:
    """Derivative order of every connection, by its input's full name (module docstring).

    level: full output name -> dependency level (dependencies.levels); depends: full output name ->
    full input names it depends on (direct feedthrough). requested: the order asked for (None: as
    high as both ends allow, up to MAX_ORDER; options.check refuses any other).
    accepted: component -> the highest input derivative order it declares it uses (emcosim's vendor
    annotation, vendor.py) or was found to accept (FMI 2.0 does not declare it; see
    master.Simulation's first communication point)."""
    cap = MAX_ORDER if requested is None else requested
    caps = {name: capabilities(inst.model_description) for name, inst in instances.items()}
    order_of: dict[str, int] = {}                      # input full name -> order
    available: dict[str, int] = {}                     # output full name -> order it can give
    for out in sorted(level, key=level.get):
        comp = out.partition(".")[0]
        n = caps[comp].output_order
        for inp in depends.get(out, ()):
            if inp in order_of:
                n = min(n, order_of[inp])
        available[out] = n
        for c in connections:
            if c.start == out:
                target = caps[c.end_element]
                limit = (accepted or {}).get(c.end_element, MAX_ORDER)
                order_of[c.end] = min(n, cap, limit) if target.interpolates_inputs else 0
    return order_of


def extrapolated_orders(instances: dict, connections, orders: dict[str, int], requested: int | None = None,
                        accepted: dict[str, int] | None = None) -> dict[str, int]:
    """Inputs that get one derivative order more than their source gives (module docstring):
    input full name -> that order (orders[input] + 1), where the target interpolates and neither
    the order asked for nor the order the target accepts is reached yet."""
    cap = MAX_ORDER if requested is None else requested
    out = {}
    for c in connections:
        if not capabilities(instances[c.end_element].model_description).interpolates_inputs:
            continue
        k = orders[c.end] + 1
        if k <= cap and k <= (accepted or {}).get(c.end_element, MAX_ORDER):
            out[c.end] = k
    return out


class _Extrapolation:
    """One derivative order more than the source gives, for the inputs of one target: the backward
    difference of the highest order passed, between the previous communication point and this one,

        u^(k+1)(t_n) ~ (u^(k)(t_n) - u^(k)(t_{n-1})) / (t_n - t_{n-1})      (u^(0) = u),

    an O(h) estimate whose term u^(k+1) s^(k+1)/(k+1)! errs by O(h^(k+2)) over a step: the global error
    falls to O(h^(k+2)), one order more. It is used only while it predicts better than holding u^(k):
    at every point the master compares e_hold = |u^(k)(t_n) - u^(k)(t_{n-1})| with e_extrapolated =
    |u^(k)(t_n) - u^(k)(t_{n-1}) - u^(k+1)_estimate(t_{n-1}) (t_n - t_{n-1})| (sums fading by 0.8 per
    point); in the asymptotic range their ratio is O(h), and where the coupled loop oscillates at
    the edge of stability (a stiff closed-loop mode) extrapolating makes it worse: then 0 is passed
    (the polynomial of the source's own orders). At the first point 0 (no difference yet), at the
    second the estimate (no comparison yet; a transient at the start is where it pays most). The
    history keeps the points before t only, so a step that is rolled back and retried
    (stepcontrol.py) uses the point it starts from, not the abandoned one."""

    FADE, GAIN = 0.8, 1.0

    def __init__(self, transfer: Transfer, below: list, inputs: list[str]):
        self.transfer = transfer
        self.below = below                   # slot (derivative values) of order k, or None for k = 0
        self.value_slots: list[int] = []     # slot (master's value buffer) of each input, for k = 0
        self.inputs = inputs
        self.history = History()             # t -> (values of order k, estimate of order k + 1, e_hold, e_extrapolated)
        self.guarded: list[int] = []         # index of each input in the plan's _Guard (-1: none)

    def __call__(self, t: float, values: list[float], slots: list[float]) -> None:
        now = [values[b] if b is not None else slots[v] for b, v in zip(self.below, self.value_slots)]
        last = self.history.last(t)
        out = self.transfer.values
        estimate, hold, extrapolated = [0.0] * len(now), 0.0, 0.0
        if last is not None:
            t_prev, (before, previous_estimate, hold, extrapolated) = last
            dt = t - t_prev
            change = miss = 0.0
            for i, (a, b) in enumerate(zip(now, before)):
                estimate[i] = (a - b) / dt
                change = max(change, abs(a - b))
                miss = max(miss, abs(a - b - previous_estimate[i] * dt)) if previous_estimate is not None else miss
            if previous_estimate is not None:
                hold = self.FADE * hold + change
                extrapolated = self.FADE * extrapolated + miss
        use = last is not None and (last[1][1] is None or extrapolated < self.GAIN * hold)
        for i in range(len(now)):
            out[i] = estimate[i] if use else 0.0
        for i, s in enumerate(self.transfer.slots):
            values[s] = out[i]
        self.history.add(t, (now, estimate if last is not None else None, hold, extrapolated))


class _Guard:
    """Hold an input (pass no derivatives to it) while its polynomial predicts worse than holding.

    Over a step the target follows P(s) = u + u' s + ... from the source's derivatives at t_n. Where
    the closed loop through that input is stiff at the communication step (a loop gain lambda with
    lambda h >> 1, e.g. the MEMS voltage law with rbar_e != r_e: du/dx_e ~ 3e9 V/Wb), the polynomial
    extrapolates a mode that decays (or flips sign) within the step, and explicit higher-order
    coupling diverges at any step where the zero-order hold stays bounded. At every communication
    point the master compares, per input, e_hold = |u(t_n) - u(t_{n-1})| with e_poly = |u(t_n) -
    P_{n-1}(t_n - t_{n-1})| (sums fading by 0.8 per point, P from the source's derivatives whether
    passed or not); in the asymptotic range e_poly / e_hold = O(h) and the derivatives are passed,
    else (e_poly > 2 e_hold) the input is held (its derivatives set to 0) until the polynomial predicts
    better again.
    At the first point there is nothing to compare: see `first`. The history keeps the points before
    t only (a rolled-back step does not count)."""

    FADE = 0.8
    MARGIN = 2.0         # held only where the polynomial errs clearly more (not on one noisy comparison)

    def __init__(self, inputs: list[str], value_slots: list[int], derivative_slots: list[list[int]]):
        self.inputs = inputs
        self.value_slots = value_slots              # slot of each input in the master's value buffer
        self.derivative_slots = derivative_slots    # per input: slots of its orders 1..K (source values x factor)
        self.held = [False] * len(inputs)
        self.history = History()                    # t -> (values, derivatives, e_hold sums, e_poly sums)

    def decide(self, t: float, slots: list[float]) -> None:
        last = self.history.last(t)
        if last is None:                            # nothing to compare yet (see `first`)
            self.held = None
            return
        t_prev, (before, ders, hold, poly) = last
        dt = t - t_prev
        for i, s in enumerate(self.value_slots):
            u = slots[s]
            p = taylor(before[i], ders[i], dt)
            self.held[i] = self.FADE * poly[i] + abs(u - p) > self.MARGIN * (self.FADE * hold[i] + abs(u - before[i]))

    def first(self, derived: list[list[float]], slots: list[float], dt: float) -> None:
        """At the first point (nothing to compare): hold an input whose polynomial would change it by
        more than ten times its magnitude within one step dt (a source's derivative of a stiff loop;
        an input at 0 has no magnitude to compare with and follows its polynomial)."""
        held = []
        for i, s in enumerate(self.value_slots):
            u = slots[s]
            change = taylor(0.0, derived[i], dt)
            held.append(abs(change) > 10.0 * abs(u) > 0.0)
        self.held = held

    def record(self, t: float, slots: list[float], derived: list[list[float]]) -> None:
        """After the derivatives of point t were resolved: derived[i], the source's derivatives of input i."""
        now = [slots[s] for s in self.value_slots]
        last = self.history.last(t)
        if last is not None:
            t_prev, (before, ders, hold, poly) = last
            dt = t - t_prev
            new_hold, new_poly = [], []
            for i, u in enumerate(now):
                p = taylor(before[i], ders[i], dt)
                new_hold.append(self.FADE * hold[i] + abs(u - before[i]))
                new_poly.append(self.FADE * poly[i] + abs(u - p))
        else:
            new_hold, new_poly = [0.0] * len(now), [0.0] * len(now)
        self.history.add(t, (now, derived, new_hold, new_poly))


@dataclass
class DerivativePlan:
    """The derivative transfers of a communication point, and where their values are kept.

    passes: per order k = 1..K, per level: (gets, sets); a get is a derivative Transfer, a set is
        (Transfer, [(source slot, factor, guard index, order)]).
    extrapolations: the extrapolated top orders (_Extrapolation), set after the passes.
    slot: (full name, order) -> index into `values` (outputs and connected inputs).
    orders: input full name -> coupling order.
    """

    passes: list
    slot: dict[tuple[str, int], int]
    orders: dict[str, int]             # input -> degree of its polynomial (exact and extrapolated orders)
    values: list[float]
    extrapolations: list = field(default_factory=list)
    guard: _Guard | None = None        # holds inputs whose polynomial predicts worse than holding
    first_step: float = 0.0            # the run's first communication step (the guard's first decision)

    @property
    def max_order(self) -> int:
        return max(self.orders.values(), default=0)

    def transfers(self) -> list[Transfer]:
        return ([t for levels in self.passes for gets, sets in levels for t in gets + [s for s, _ in sets]]
                + [e.transfer for e in self.extrapolations])

    def resolve(self, t: float, slots: list[float]):
        """Get and set every derivative of the communication point t (after the values; `slots`:
        the master's value buffer). Returns None, or (the transfer that failed, its FMICallException)."""
        guard = self.guard
        if guard is None:
            return self._run(t, slots, None, None)
        guard.decide(t, slots)
        derived = [[0.0] * len(d) for d in guard.derivative_slots]
        if guard.held is None:                   # the first point: the source's derivatives, then decide
            guard.held = [False] * len(guard.inputs)
            failure = self._run(t, slots, guard.held, derived)
            if failure is not None:
                return failure
            guard.first(derived, slots, self.first_step)
            if not any(guard.held):
                guard.record(t, slots, derived)
                return None
        failure = self._run(t, slots, guard.held, derived)
        if failure is None:
            guard.record(t, slots, derived)
        return failure

    def _run(self, t: float, slots: list[float], held: list[bool] | None, derived: list | None):
        values = self.values
        try:
            for levels in self.passes:
                for gets, sets in levels:
                    for transfer in gets:
                        transfer()
                        got = transfer.values
                        for i, s in enumerate(transfer.slots):
                            values[s] = got[i]
                    for transfer, sources in sets:
                        out = transfer.values
                        for i, (src, factor, g, k) in enumerate(sources):
                            v = values[src] * factor
                            if g >= 0:
                                derived[g][k - 1] = v
                                if held[g]:
                                    v = 0.0
                            out[i] = v
                            values[transfer.slots[i]] = v
                        transfer()
            for extrapolation in self.extrapolations:
                transfer = extrapolation.transfer
                extrapolation(t, values, slots)
                if held is not None and any(g >= 0 and held[g] for g in extrapolation.guarded):
                    for i, g in enumerate(extrapolation.guarded):
                        if g >= 0 and held[g]:            # a held input gets no extrapolated order either,
                            transfer.values[i] = 0.0
                            values[transfer.slots[i]] = 0.0
                    extrapolation.history.clear()         # and the backward differences start afresh
                transfer()
        except FMICallException as exc:
            return transfer, exc
        return None

    def polynomial(self, full: str) -> list[int]:
        """Slots of the derivatives 1..order of an input, in order (empty for a zero-order hold)."""
        return [self.slot[(full, k)] for k in range(1, self.orders.get(full, 0) + 1)]


def plan_derivatives(instances: dict, connections, level: dict[str, int], orders: dict[str, int],
                     extrapolated: dict[str, int] | None = None,
                     value_slot: dict[str, int] | None = None, read_only: set[str] | None = None) -> DerivativePlan:
    """The derivative transfers for the connection orders `orders` (connection_orders) and the
    inputs that get one order more by extrapolation (extrapolated_orders); value_slot: full name ->
    slot of the master's value buffer (for an extrapolated first order). read_only: inputs whose
    sources' derivatives are got but not set on them (implicit.py sets those inputs itself)."""
    slot: dict[tuple[str, int], int] = {}

    def slot_of(key: tuple[str, int]) -> int:
        return slot.setdefault(key, len(slot))

    K = max(orders.values(), default=0)
    fed = {c.end_element for c in connections}
    sources = {name for name in instances if name not in fed}      # FMUs without connected inputs
    need: dict[str, int] = {}                                      # output -> highest order needed
    for c in connections:
        if orders[c.end] > 0:
            need[c.start] = max(need.get(c.start, 0), orders[c.end])
    n_levels = max(level.values(), default=-1) + 1
    # the inputs that take exact derivatives and whose value the master holds in its buffer (_Guard),
    # of FMUs that integrate them (an output not fed through from an input, i.e. a state): a
    # feedthrough FMU uses its input derivatives for its output derivatives, which must stay exact
    dynamic = {name for name, inst in instances.items() if dependencies.has_state(inst.model_description)}
    guarded_inputs = [c.end for c in connections if orders[c.end] > 0 and c.end in (value_slot or {})
                      and c.end_element in dynamic]
    guarded = {name: i for i, name in enumerate(guarded_inputs)}
    passes = []
    for k in range(1, K + 1):
        levels = []
        for lv in range(n_levels):
            gets = []
            by_comp: dict[str, list[tuple[str, int]]] = {}
            for out in sorted(o for o in need if level[o] == lv):
                comp, _, var = out.partition(".")
                if comp in sources:
                    if k == 1:                                     # a source: every order at once
                        by_comp.setdefault(comp, []).extend((var, j) for j in range(1, need[out] + 1))
                elif need[out] >= k:
                    by_comp.setdefault(comp, []).append((var, k))
            for comp, entries in by_comp.items():
                t = Transfer(instances[comp], [v for v, _ in entries], getter=True, orders=[j for _, j in entries])
                t.slots = [slot_of((f"{comp}.{v}", j)) for v, j in entries]
                gets.append(t)
            sets = []
            targets: dict[str, list] = {}
            for c in connections:
                if level[c.start] == lv and orders[c.end] >= k and c.end not in (read_only or ()):
                    targets.setdefault(c.end_element, []).append(c)
            for comp, conns in targets.items():
                t = Transfer(instances[comp], [c.end_connector for c in conns], getter=False, orders=[k] * len(conns))
                t.slots = [slot_of((c.end, k)) for c in conns]
                sets.append((t, [(slot_of((c.start, k)), c.factor, guarded.get(c.end, -1), k) for c in conns]))
            levels.append((gets, sets))
        passes.append(levels)
    extra = []
    by_target: dict[str, list] = {}
    for c in connections:
        if c.end in (extrapolated or {}):
            by_target.setdefault(c.end_element, []).append(c)
    for comp, conns in by_target.items():
        t = Transfer(instances[comp], [c.end_connector for c in conns], getter=False,
                     orders=[extrapolated[c.end] for c in conns])
        t.slots = [slot_of((c.end, extrapolated[c.end])) for c in conns]
        below = [slot_of((c.end, extrapolated[c.end] - 1)) if extrapolated[c.end] > 1 else None for c in conns]
        e = _Extrapolation(t, below, [c.end for c in conns])
        e.value_slots = [(value_slot or {}).get(c.end, -1) for c in conns]
        e.guarded = [guarded.get(c.end, -1) for c in conns]
        extra.append(e)
    degree = dict(orders) | dict(extrapolated or {})
    guard = None
    if guarded_inputs:
        guard = _Guard(guarded_inputs, [value_slot[name] for name in guarded_inputs],
                       [[slot_of((name, k)) for k in range(1, orders[name] + 1)] for name in guarded_inputs])
    return DerivativePlan(passes, slot, degree, [0.0] * len(slot), extra, guard)

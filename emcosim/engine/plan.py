"""The plan of a communication point: which outputs the master gets and which inputs it sets, in which order
(the levels of the dependency graph, dependencies.py), batched per FMU and type into transfers, with one
buffer of values (slots) that connects them. Built once per scenario and record; the stepper runs it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from . import dependencies
from .binding import TRANSFER_TYPES
from .errors import ScenarioError
from .fmi import FMICallException
from .ssd import Scenario
from .transfer import Transfer


@dataclass
class Plan:
    """What the master does at a communication point, precomputed."""

    stages: list                     # [(gets, sets)] per level: gets [(Transfer, full names)],
                                     # sets [(Transfer, [(source slot, factor, offset)])]
    record: list                     # extra gets for recorded variables that are not connected outputs
    columns: list[str]               # recorded full names
    column_slots: list[int]          # slot of each column in the value buffer
    level: dict = field(default_factory=dict)      # connected output -> dependency level
    depends: dict = field(default_factory=dict)    # full output name -> full inputs it depends on
    input_slots: list = field(default_factory=list)  # [(connected input full name, value slot)]
    dynamic: set = field(default_factory=set)      # components with an output not fed through from an input
    slot: dict = field(default_factory=dict)       # full name -> slot in the value buffer


def make_plan(scenario: Scenario, instances: dict, connections, record) -> Plan:
    """The plan of the scenario's connections (binding.check_connections) and the recorded variables
    `record` (None: every connector of the scenario)."""
    depends = {}
    for name, inst in instances.items():
        for out, ins in dependencies.feedthrough(inst.model_description).items():
            depends[f"{name}.{out}"] = {f"{name}.{i}" for i in ins}
    pairs = [(c.start, c.end) for c in connections]
    level = dependencies.levels(pairs, depends)
    slot: dict[str, int] = {}

    def slot_of(full: str) -> int:
        return slot.setdefault(full, len(slot))

    stages = []
    for k in range(max(level.values(), default=-1) + 1):
        outs = [o for o in level if level[o] == k]
        gets = _batches(instances, outs, slot_of, getter=True)
        fed = [c for c in connections if level[c.start] == k]
        sets = []
        for transfer, names in _batches(instances, [c.end for c in fed], slot_of, getter=False):
            conn_of = {c.end: c for c in fed}
            sources = [(slot_of(conn_of[n].start), conn_of[n].factor, conn_of[n].offset) for n in names]
            sets.append((transfer, sources))
        stages.append((gets, sets))
    if record is None:
        columns = default_record(scenario, connections) or [c.start for c in connections] + [c.end for c in connections]
        columns = list(dict.fromkeys(columns))
    else:
        columns = list(record)
    for full in columns:
        comp_name, _, var_name = full.partition(".")
        if comp_name not in instances or var_name not in instances[comp_name].variables:
            raise ScenarioError(f"{scenario.path}: cannot record unknown variable '{full}'")
        if instances[comp_name].variables[var_name].type not in TRANSFER_TYPES:
            raise ScenarioError(f"{scenario.path}: cannot record {full}: only Real, Integer and Boolean")
    fetched = set(level) | {c.end for c in connections}
    extra = [f for f in columns if f not in fetched]
    record_gets = _batches(instances, extra, slot_of, getter=True)
    dynamic = {name for name, inst in instances.items() if dependencies.has_state(inst.model_description)}
    return Plan(stages, record_gets, columns, [slot_of(f) for f in columns], level, depends,
                [(c.end, slot_of(c.end)) for c in connections], dynamic, slot)


def default_record(scenario, connections=None) -> list[str]:
    """What a run records when not told: every output connector and every input that no connection feeds
    unchanged (in component order), so each connected value is recorded once (a connection's two ends carry
    the same value; an input fed through a linear transformation or a unit conversion differs from its source
    and is recorded). `connections`: the run's, with the unit conversions folded in (binding.connections);
    default the .ssd's. Empty for a scenario that declares no connectors."""
    connections = scenario.connections if connections is None else connections
    fed = {c.end for c in connections if c.factor == 1.0 and c.offset == 0.0}
    return [f"{c.name}.{k.name}" for c in scenario.components for k in c.connectors
            if k.kind == "output" or (k.kind == "input" and f"{c.name}.{k.name}" not in fed)]


def _batches(instances, fulls: list[str], slot_of, getter: bool):
    """Group full names by (component, type) into transfers; returns [(transfer, names)]."""
    groups: dict[tuple[str, str], list[str]] = {}
    for full in fulls:
        comp_name, _, var_name = full.partition(".")
        var = instances[comp_name].variables[var_name]
        groups.setdefault((comp_name, var.type), []).append(full)
    out = []
    for (comp_name, type_), names in groups.items():
        local = [n.partition(".")[2] for n in names]
        transfer = Transfer(instances[comp_name], local, getter, type_)
        transfer.slots = [slot_of(n) for n in names]
        out.append((transfer, names))
    return out


def n_slots(plan: Plan) -> int:
    """The size of the plan's value buffer."""
    n = 0
    for gets, sets in plan.stages:
        for t, _ in gets:
            n = max([n] + [s + 1 for s in t.slots])
        for t, _ in sets:
            n = max([n] + [s + 1 for s in t.slots])
    for t, _ in plan.record:
        n = max([n] + [s + 1 for s in t.slots])
    return max([n] + [s + 1 for s in plan.column_slots])


def resolve_values(plan: Plan, slots: list, record: bool = True) -> None:
    """Get and set every connected value at the current instant, level by level, into `slots` (and, with
    `record`, the recorded variables that no connection carries). Raises the failing call's
    FMICallException with the transfer as its `transfer`, or transfer.NonFinite."""
    transfer = None
    try:
        for gets, sets in plan.stages:
            for transfer, _ in gets:
                transfer()
                values = transfer.values
                for i, s in enumerate(transfer.slots):
                    slots[s] = values[i]
            for transfer, sources in sets:
                values = transfer.values
                for i, (src, factor, offset) in enumerate(sources):
                    v = slots[src] if factor == 1.0 and offset == 0.0 else factor * slots[src] + offset
                    values[i] = v
                    slots[transfer.slots[i]] = v
                transfer()
        if record:
            for transfer, _ in plan.record:
                transfer()
                values = transfer.values
                for i, s in enumerate(transfer.slots):
                    slots[s] = values[i]
    except FMICallException as exc:
        exc.transfer = transfer
        raise

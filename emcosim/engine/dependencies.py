"""The dependency graph of a scenario and the order in which the master resolves outputs.

Nodes are connected outputs "component.variable". An output depends on the inputs its FMU's
ModelStructure lists (`Outputs/Unknown@dependencies`; no attribute means every input, FMI 2.0
section 2.2.8), and each connected input on the output that feeds it. The master resolves outputs
level by level: level 0 outputs depend on no connected input (states, sources); an output of level
k depends on outputs of levels < k only. A cycle of such dependencies is an algebraic loop, which
the master refuses, naming the cycle.
"""
from __future__ import annotations

from .errors import ScenarioError


def feedthrough(model_description) -> dict[str, set[str]]:
    """Inputs each output depends on, from an fmpy ModelDescription's ModelStructure."""
    inputs = {v.name for v in model_description.modelVariables if v.causality == "input"}
    deps = {v.name: set(inputs) for v in model_description.modelVariables if v.causality == "output"}
    for unknown in model_description.outputs:
        if unknown.dependencies is not None:
            deps[unknown.variable.name] = {v.name for v in unknown.dependencies if v.name in inputs}
    return deps


def has_state(model_description) -> bool:
    """True if some output does not depend on any input: the FMU integrates (a plant), it is not a
    static map of its inputs (a controller with direct feedthrough only)."""
    return any(not inputs for inputs in feedthrough(model_description).values())


def levels(connections: list[tuple[str, str]], depends: dict[str, set[str]]) -> dict[str, int]:
    """Level of every connected output.

    connections: (output, input) pairs of full names "component.variable".
    depends: full output name -> full input names it depends on (direct feedthrough).
    Raises ScenarioError naming the cycle if there is an algebraic loop.
    """
    source_of = {}                                   # input -> the output feeding it
    for out, inp in connections:
        source_of[inp] = out
    outputs = list(dict.fromkeys(out for out, _ in connections))

    def predecessors(out: str) -> list[str]:         # outputs this output depends on, via inputs
        return [source_of[i] for i in sorted(depends.get(out, ())) if i in source_of]

    level: dict[str, int] = {}
    visiting: list[str] = []                         # the current path, to name a cycle
    for start in outputs:
        if start in level:
            continue
        stack = [(start, iter(predecessors(start)))]
        visiting.append(start)
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                stack.pop()
                visiting.pop()
                level[node] = 1 + max((level[p] for p in predecessors(node)), default=-1)
            elif nxt in level:
                continue
            elif nxt in visiting:
                cycle = visiting[visiting.index(nxt):] + [nxt]
                raise ScenarioError("algebraic loop (a cycle of direct feedthrough): "
                                    + describe_cycle(list(reversed(cycle)), source_of))
            else:
                visiting.append(nxt)
                stack.append((nxt, iter(predecessors(nxt))))
    return level


def describe_cycle(outputs: list[str], source_of: dict[str, str]) -> str:
    """'a.y -> b.u -> b.y -> a.u -> a.y' for a cycle of outputs in signal-flow order."""
    parts = [outputs[0]]
    for prev, out in zip(outputs, outputs[1:]):
        inp = next((i for i, o in sorted(source_of.items()) if o == prev and i.split(".")[0] == out.split(".")[0]), None)
        if inp:
            parts.append(inp)
        parts.append(out)
    return " -> ".join(parts)

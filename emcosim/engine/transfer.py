"""One batched FMI call on preallocated arrays, the unit of everything the master moves between FMUs.

A `Transfer` gets or sets the values of one type of one FMU (fmi2GetReal, fmi2SetReal, ...), or, with
derivative orders, gets output derivatives (fmi2GetRealOutputDerivatives) or sets input derivatives
(fmi2SetRealInputDerivatives). It calls the raw FMI function (fmi.raw) on arrays built once, times itself
(the time inside the FMU) and checks every Real it gets or is about to set: a NaN or infinity is a
`NonFinite` naming the variable (an FMU may return one with fmi2OK).
"""
from __future__ import annotations

import ctypes
import math
import time
from typing import Any, Sequence

from .fmi import FMICallException
from .instances import last_message

C_TYPES: dict[str, Any] = {"Real": ctypes.c_double, "Integer": ctypes.c_int, "Boolean": ctypes.c_int}


class Transfer:
    """fmi2Get<type>/fmi2Set<type> of `names` of one FMU, or with `orders` (Real only) its output
    derivatives (getter) or input derivatives (setter) of those orders. `slots`: where a plan keeps each
    entry's value; `elapsed`: the wall time inside the FMU so far."""

    def __init__(self, inst, names: Sequence[str], getter: bool, type_: str = "Real",
                 orders: Sequence[int] | None = None):
        self.inst, self.names, self.type, self.getter = inst, list(names), type_, getter
        n = len(self.names)
        self.n = n
        self.vr = (ctypes.c_uint * n)(*[inst.variables[v].valueReference for v in self.names])
        self.values = (C_TYPES[type_] * n)()
        self.orders = None if orders is None else list(orders)
        if orders is None:
            self.function = f"{'fmi2Get' if getter else 'fmi2Set'}{type_}"
            self.args: tuple = (inst.component, self.vr, n, self.values)
        else:
            self.function = "fmi2GetRealOutputDerivatives" if getter else "fmi2SetRealInputDerivatives"
            self.order = (ctypes.c_int * n)(*orders)
            self.args = (inst.component, self.vr, n, self.order, self.values)
        self.call = inst.raw(self.function)
        self.slots: list[int] = []
        self.elapsed = 0.0
        self.real = type_ == "Real"
        # the values as plain doubles: summing this view is about 5x cheaper than summing the ctypes array
        # (whose items are boxed one by one), measured in benchmarks/bench_integrity.py
        self.view = memoryview(self.values).cast("B").cast("d") if self.real else None
        self._check_before = self.real and not getter
        self._check_after = self.real and getter

    @property
    def entries(self) -> list[tuple[str, int]]:
        """[(variable, order)] of a derivative transfer."""
        return list(zip(self.names, self.orders or [0] * self.n))

    def __call__(self) -> None:
        if self._check_before:
            self.check_finite()
        tic = time.perf_counter()
        status = self.call(*self.args)
        self.elapsed += time.perf_counter() - tic
        if status > 1:
            raise FMICallException(self.function, status)
        if self._check_after:
            self.check_finite()

    def check_finite(self) -> None:
        """Raise NonFinite for the first value that is not finite."""
        if math.isfinite(sum(self.view)):                    # a NaN or inf anywhere makes the sum one
            return
        for i, v in enumerate(self.values):
            if not math.isfinite(v):
                raise NonFinite(self, i, v)


class NonFinite(Exception):
    """A NaN or infinity got from (or about to be set on) an FMU variable, or one of its derivatives."""

    def __init__(self, transfer: Transfer, index: int, value: float):
        super().__init__(transfer.names[index])
        self.transfer, self.name, self.value = transfer, transfer.names[index], value
        self.order = None if transfer.orders is None else transfer.orders[index]

    def message(self, t: float) -> str:
        transfer = self.transfer
        inst = transfer.inst
        if self.order is None:
            if transfer.getter:
                return (f"{inst.name}.{self.name} = {self.value} at t = {t:.9g} s: {inst.path.name} (component "
                        f"'{inst.name}') returned a value that is not finite{last_message(inst)}")
            return (f"{inst.name}.{self.name} = {self.value} at t = {t:.9g} s: the value to set on this input "
                    f"(after the connection's transformation) is not finite")
        what = f"derivative of order {self.order} of {inst.name}.{self.name} = {self.value} at t = {t:.9g} s"
        if transfer.getter:
            return (f"{what}: {inst.path.name} (component '{inst.name}') returned a value that is not finite "
                    "(fmi2GetRealOutputDerivatives)")
        return f"{what}: the value to set on this input (fmi2SetRealInputDerivatives) is not finite"


class Mirror:
    """In place of a get of the shadow copy (stepcontrol.py) from a source it shares with the main copy: the
    values the main copy read at the same communication point, copied instead of asked again."""

    def __init__(self, transfer: Transfer, source: list, source_slots: list[int]):
        self.inst, self.slots, self.function = transfer.inst, transfer.slots, transfer.function
        self.names, self.orders = transfer.names, transfer.orders
        self.values = [0.0] * len(source_slots)
        self.source, self.source_slots = source, source_slots
        self.elapsed = 0.0

    def __call__(self) -> None:
        values, source = self.values, self.source
        for i, s in enumerate(self.source_slots):
            values[i] = source[s]

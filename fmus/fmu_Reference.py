"""FMU Reference: the reference jet (q*, q*', q*'', q*''') of components.references.

Default experiment: the paper's MEMS tracking reference q* = 0.05 + 0.05 sin(30 t) (eq. csim), kind 1.
"""
from .em_fmu_reference import ReferenceSlave


class Reference(ReferenceSlave):
    model_identifier = "Reference"
    summary = "reference generator: constant, sinusoid or smooth transition; outputs the jet q*, q*', q*'', q*'''"
    experiment = (0.0, 0.5, 1e-3)

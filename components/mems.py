"""MEMS optical switch (Section 7.1): an electrostatic comb/parallel-plate actuator.

n_m = n_e = 1, constant mass m, J_e = 0, R_e = 1/r_e, G_e = 1/r_e, and
    V(q) = 1/2 a1 q^2 + 1/4 a2 q^4,   Psi(q) = 1 / (c1 (q + c0)),
so H_e = x_e^2 / (2 c1 (q + c0)) is the energy of a capacitor with capacitance c1 (q + c0).
q is the displacement [m], p the momentum [kg m/s], x_e the charge [C], u the voltage [V].
Admissible domain: q + c0 > 0 (the gap has not closed).

The formulas are written once, in components/plants/mems.toml; the model functions (V_s, dV, d2V, psi,
dpsi, d2psi) are generated from it into components/plants/mems_model.py (python -m components.codegen).
"""
from __future__ import annotations

import numpy as np

from .plants import mems_model

PARAMETERS = mems_model.PARAMETERS
STATES = {v.name: (v.unit, v.description) for kind in ("q", "p", "x_e") for v in mems_model.VARIABLES[kind]}
INPUT = tuple(vars(mems_model.VARIABLES["u"][0]).values())


class MEMS(mems_model.MEMS):
    """MEMS optical switch with the paper's Section 7 parameters as defaults."""

    name = "MEMS optical switch"
    domain_reasons = ("the capacitor gap has closed",)


def R_e_bar_from_rbar_e(rbar_e: float) -> np.ndarray:
    """Desired electrical damping of the MEMS examples: K_e = 1/rbar_e - 1/r_e, so
    R_e_bar = R_e + K_e = 1/rbar_e (eq. closedPrameterreg, eq. barRe)."""
    if not (np.isfinite(rbar_e) and rbar_e > 0):
        raise ValueError(f"parameter rbar_e = {rbar_e} violates rbar_e > 0 (desired series resistance)")
    return np.array([[1.0 / rbar_e]])

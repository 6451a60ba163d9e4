"""Independent truths for the generated laws: the feasible reference of Definition 1 in closed form, as it was
written by hand in components/ before it was printed from components.laws (ph_plant.OneDOFPlant.feasible_scalar
at 637d7e7).

The generated function (components/plants/*_model.py: feasible_scalar) must agree with it to 1e-12 relative
(tests/test_laws_python.py). It takes any OneDOFPlant (its dV, d2V, dpsi, d2psi) and complex numbers.
"""
from __future__ import annotations

import cmath
import math

import numpy as np

from components.ph_plant import OneDOFPlant


def feasible_scalar(plant: OneDOFPlant, q, qd, qdd, qddd):
    """(q*, p*, x_e*, x_e*') of the reference jet (q*, q*', q*'', q*'''), Definition 1.

    The p-row of eq. (open-loop elecmech) gives the electrical force the reference needs,
        -1/2 Psi'(q*) x_e*^2 = m q*'' + R_m q*' + V'(q*) =: F*,
    whose real root is x_e* = s sqrt(2 F* / g), g = -Psi'(q*), s = x_e_sign, when F* / g > 0.
    Differentiating x_e*^2 = 2 F* / g in time: x_e*' = (F*' g - F* g') / (x_e* g^2).
    """
    if not plant.q_min < q.real < plant.q_max:                 # False for nan and inf too
        plant.check_state(np.array([q, 0.0, 0.0]))                   # raises with the reason
    m, R_m = plant.m, float(plant.R_m[0, 0])
    force = m * qdd + R_m * qd + plant.dV(q)                       # F* (p-row)
    force_dot = m * qddd + R_m * qdd + plant.d2V(q) * qd             # dF*/dt
    g = -plant.dpsi(q)
    g_dot = -plant.d2psi(q) * qd
    ratio = 2.0 * force / g
    if not ratio.real > 0:
        raise ValueError(f"{plant.name}: infeasible reference at q* = {q:.6g}: no real x_e* solves "
                         f"-1/2 Psi'(q*) x_e*^2 = m q*'' + R_m q*' + V'(q*) = {force:.6g}")
    x_e = plant.x_e_sign * (cmath.sqrt(ratio) if isinstance(ratio, complex) else math.sqrt(ratio))
    return q, m * qd, x_e, (force_dot * g - force * g_dot) / (x_e * g * g)

"""Magnetic levitation system (Section 7.2): a ball below an electromagnet.

n_m = n_e = 1, constant mass m, J_e = 0, G_e = 1, and
    H_e = (c - q) x_e^2 / (2 k),  V(q) = b q,
so Psi(q) = (c - q)/k is the inverse inductance. q is the ball position [m] (the magnet is at q = c),
p the momentum [kg m/s], x_e the flux linkage [Wb], u the coil voltage [V].
Admissible domain: q < c (the ball has not reached the magnet).

The formulas are written once, in components/plants/maglev.toml; the model functions, and Gamma = 1/(2k),
phi = x_e^3/3 of Assumptions 2/4 (Section 7.2, derived from Psi), are generated from it into
components/plants/maglev_model.py (python -m components.codegen).
"""
from __future__ import annotations

from .plants import maglev_model

PARAMETERS = maglev_model.PARAMETERS
STATES = {v.name: (v.unit, v.description) for kind in ("q", "p", "x_e") for v in maglev_model.VARIABLES[kind]}
INPUT = tuple(vars(maglev_model.VARIABLES["u"][0]).values())


class Maglev(maglev_model.Maglev):
    """Magnetic levitation system with the paper's Section 7.2 parameters as defaults.

    Gamma = 1/(2k) of Assumption 4: grad_q H_e = -Gamma grad phi_2(x_e), grad phi_2 = x_e^2 (eq. assHe),
    phi_2 = x_e^3 / 3 (phi_s, dphi, d2phi; phi, grad_phi, hess_phi on arrays).
    """

    name = "magnetic levitation system"
    domain_reasons = ("the ball has reached the magnet",)


def D_d_from_paper(D_d_paper: float, k: float = PARAMETERS["k"].default) -> float:
    """Convert the paper's maglev coupled damping (Section 7.2, eq. controlmaglv) to the general D_d.

    eq. (controlmaglv) prints the momentum coefficient (-1 + D_d)/(2 k m), while eq. (tracker2) gives
    (D_d - Gamma)/m with Gamma = 1/(2k): the paper's maglev D_d is 2 k times the general one.
    """
    return D_d_paper / (2.0 * k)

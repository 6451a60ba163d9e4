"""Independent truths for the generated laws: the control laws of the four designs in scalars, and the feasible
reference of Definition 1 in closed form, as they were written by hand in components/ before the laws were
printed from components.laws (controller.py's Scalars, proposition1.law_c1_scalar, proposition2.law_u2_scalar,
the designs' u_scalar, ph_plant.OneDOFPlant.feasible_scalar at 637d7e7).

The generated functions (components/plants/*_model.py: feasible_scalar, law_<family>_at, law_<family>_tracking;
Controller.scalars) must agree with these to 1e-12 relative (tests/test_laws_python.py). Each takes any
OneDOFPlant (its V_s, dV, ..., psi, dpsi, d2psi, dphi) and accepts complex numbers (complex step).
"""
from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from components.controller import Controller
from components.ph_plant import OneDOFPlant


@dataclass(frozen=True)
class Scalars:
    """The design matrices of a one-degree-of-freedom loop (n_m = n_e = 1) as plain numbers."""

    m_inv: float        # M^-1
    G_inv: float        # G_e^-1
    JR_bar: float       # J_e - R_e_bar
    RJ: float           # R_e - J_e
    K_e: float          # R_e_bar - R_e, eq. (barRe)
    D_d: float          # coupled damping, eq. (closedloop)
    Gamma: float        # coupling of the target structure, eq. (closedloop)


def scalars(controller: Controller) -> Scalars:
    plant = controller.plant
    return Scalars(1.0 / plant.m, float(controller.G_inv[0, 0]), float(controller.JR_bar[0, 0]),
                   float((plant.R_e - plant.J_e)[0, 0]), float(controller.K_e[0, 0]),
                   float(controller.D_d[0, 0]), float(controller.Gamma[0, 0]))


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


def law_c1_scalar(plant: OneDOFPlant, s: Scalars, q, p, x_e, grad_Phi):
    """eq. (c1) for n_m = n_e = 1: u = G_e^-1 { (J_e - R_e_bar) dPhi_1 - K_e Psi(q) x_e + D_d p / m }."""
    return s.G_inv * (s.JR_bar * grad_Phi - s.K_e * plant.psi(q) * x_e + s.D_d * s.m_inv * p)


def law_u2_scalar(plant: OneDOFPlant, s: Scalars, q, p, x_e, grad_z_Phi):
    """eq. (u2) for n_m = n_e = 1:
    u = G_e^-1 { (R_e - J_e) Psi(q) x_e + (D_d - Gamma) p / m + (J_e - R_e_bar) dphi(x_e) } - dPhi/dz."""
    return (s.G_inv * (s.RJ * plant.psi(q) * x_e + (s.D_d - s.Gamma) * s.m_inv * p + s.JR_bar * plant.dphi(x_e))
            - grad_z_Phi)


def u_scalar(controller, q, p, x_e, jet=None):
    """The law of `controller` (Proposition1, Theorem2, Proposition2, Theorem3) in scalars, as written by hand."""
    plant, s = controller.plant, scalars(controller)
    design = type(controller).__name__
    if design == "Proposition1":
        W, center = float(controller.W[0, 0]), float(controller.center[0])
        return law_c1_scalar(plant, s, q, p, x_e, W * (x_e - center))
    if design == "Theorem2":                                          # eq. (u1-track), L_2 of eq. (feasibleT2)
        W = float(controller.W[0, 0])
        q_s, p_s, x_s, x_s_dot = feasible_scalar(plant, *jet)
        L2 = ((x_s_dot - s.D_d * s.m_inv * p_s) / s.JR_bar - plant.psi(q_s) * x_s) / W
        return law_c1_scalar(plant, s, q, p, x_e, W * (x_e - x_s + L2))
    A, K_c = float(controller.A[0, 0]), float(controller.K_c[0, 0])
    z = A * (s.Gamma * q + x_e)                                         # eq. (z)
    if design == "Proposition2":
        return law_u2_scalar(plant, s, q, p, x_e, K_c * (z - float(controller.L[0])))
    if design == "Theorem3":                                          # eq. (tracker2), L_3 of eq. (L2), erratum 2
        q_s, p_s, x_s, x_s_dot = feasible_scalar(plant, *jet)
        rhs = s.G_inv * ((s.D_d - s.Gamma) * s.m_inv * p_s + s.JR_bar * plant.dphi(x_s) - x_s_dot)
        L3 = A * (s.Gamma * q_s + x_s) - rhs / K_c
        return law_u2_scalar(plant, s, q, p, x_e, K_c * (z - L3))
    raise ValueError(f"no hand-written law for {design}")

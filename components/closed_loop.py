"""Target closed-loop structure with coupled damping, eqs. (closedloop), (Eq:R-J), (pHcondition).

    eta' = F_d grad H_d,   F_d = J_d - R_d =
        [[ 0,  I,                0          ],
         [-I, -R_m,              Gamma      ],
         [ 0, -Gamma^T + D_d,    J_e - R_e_bar]]

Gamma (n_m x n_e) is zero for Proposition 1 and Theorem 2; D_d (n_e x n_m) is the coupled damping;
R_e_bar = R_e + K_e (eq. barRe) the desired electrical damping.
"""
from __future__ import annotations

import numpy as np


def F_d(R_m: np.ndarray, J_e: np.ndarray, R_e_bar: np.ndarray, Gamma: np.ndarray, D_d: np.ndarray) -> np.ndarray:
    """F_d of eq. (closedloop)."""
    m, e = R_m.shape[0], J_e.shape[0]
    F = np.zeros((2 * m + e, 2 * m + e))
    F[:m, m:2 * m] = np.eye(m)
    F[m:2 * m, :m] = -np.eye(m)
    F[m:2 * m, m:2 * m] = -R_m
    F[m:2 * m, 2 * m:] = Gamma
    F[2 * m:, m:2 * m] = -Gamma.T + D_d
    F[2 * m:, 2 * m:] = J_e - R_e_bar
    return F


def J_d_R_d(R_m, J_e, R_e_bar, Gamma, D_d) -> tuple[np.ndarray, np.ndarray]:
    """Skew part J_d and symmetric part R_d of F_d, eq. (Eq:R-J)."""
    F = F_d(R_m, J_e, R_e_bar, Gamma, D_d)
    return 0.5 * (F - F.T), -0.5 * (F + F.T)


def ph_margin(R_m: np.ndarray, R_e_bar: np.ndarray, D_d: np.ndarray) -> float:
    """Smallest eigenvalue of R_m - 1/4 D_d^T R_e_bar^-1 D_d, eq. (pHcondition).

    Uses the symmetric part of R_e_bar (R_e_bar > 0 by eq. barRe). The closed loop is a pH system
    (R_d >= 0) exactly when this is >= 0.
    """
    Rs = 0.5 * (R_e_bar + R_e_bar.T)
    S = R_m - 0.25 * D_d.T @ np.linalg.solve(Rs, D_d)
    return float(np.min(np.linalg.eigvalsh(0.5 * (S + S.T))))


def scalar_D_d_bound(R_m: float, R_e_bar: float) -> float:
    """For n_m = n_e = 1, eq. (pHcondition) reads D_d^2 <= 4 R_m R_e_bar: the bound on |D_d|."""
    return float(np.sqrt(4.0 * R_m * R_e_bar))


def check_ph_condition(R_m, R_e_bar, D_d, strict: bool, owner: str) -> None:
    """Raise ValueError if D_d violates eq. (pHcondition) (strictly, for Proposition 1)."""
    margin = ph_margin(R_m, R_e_bar, D_d)
    ok = margin > 0 if strict else margin >= -1e-12 * max(1.0, float(np.max(np.abs(R_m))))
    if not ok:
        rel = ">" if strict else ">="
        msg = (f"{owner}: parameter D_d = {D_d.tolist()} violates the pH condition (eq. pHcondition) "
               f"R_m - 1/4 D_d^T R_e_bar^-1 D_d {rel} 0 (smallest eigenvalue {margin:.3g})")
        if R_m.shape == (1, 1) and R_e_bar.shape == (1, 1):
            bound = scalar_D_d_bound(R_m[0, 0], 0.5 * (R_e_bar + R_e_bar.T)[0, 0])
            msg += f"; admissible: |D_d| {'<' if strict else '<='} {bound:.6g}"
        raise ValueError(msg)


def check_R_e_bar(R_e_bar: np.ndarray, J_e: np.ndarray, owner: str) -> None:
    """eq. (barRe): R_e_bar > 0 (symmetric part) and J_e - R_e_bar invertible."""
    if not np.all(np.isfinite(R_e_bar)):
        raise ValueError(f"{owner}: parameter R_e_bar = {R_e_bar.tolist()} must be finite")
    lam = np.linalg.eigvalsh(0.5 * (R_e_bar + R_e_bar.T))
    if not np.min(lam) > 0:
        raise ValueError(f"{owner}: parameter R_e_bar = {R_e_bar.tolist()} violates R_e_bar = R_e + K_e > 0 "
                         f"(eq. barRe; smallest eigenvalue {np.min(lam):.3g})")

"""The default communication step of a device scenario (`emcosim plant scenario` without --step-size), chosen
from the closed loop's linearization at its initial state.

At the initial state eta_0 and at the target eta*(0) it is driven to (with the reference's jet at t = 0):

    J_open   = df/deta = F hess H(eta)                   (eq. open-loop elecmech; components.ph_plant.jacobian)
    J_closed = J_open + g du/deta(eta)                    (du/deta by central differences of the control law)

The step is the largest round one (1, 2, 2.5, 4, 5 times a power of ten) at most RESOLVE / |lambda| for
  - accuracy: the fastest eigenvalue of J_closed that MAX_STEPS steps over the horizon can resolve (faster
    ones, such as the MEMS electrical pole at 9e9 1/s, are the plant's own: its integrator takes them), and
  - stability of explicit coupling: the fastest eigenvalue the feedback creates (an eigenvalue of J_closed that
    is not one of J_open).
Where the second needs more than MAX_STEPS steps, the loop is stiff for explicit coupling: the scenario gets
implicit coupling (L-stable, engine/implicit.py) at the accuracy step. The run's own estimate (engine/doubling.py)
then says whether the step was accurate. On the paper's MEMS loops this gives 1e-6 s explicit for D_d = -1
(explicitly it needed 4e-6 s) and 2.5e-6 s implicit for D_d = -0.4; it is conservative where the coupling is
exact (K_e = 0: 2.5e-6 s where the paper's scenarios take 1e-4 s).
"""
from __future__ import annotations

import math

import numpy as np

RESOLVE = 0.05            # h |lambda|: a twentieth of the fastest mode's time constant
MAX_STEPS = 1e5           # more explicit steps than this over the horizon: implicit coupling instead
ROUND = (1.0, 2.0, 2.5, 4.0, 5.0)


def round_down(h: float) -> float:
    """The largest round step (1, 2, 2.5, 4, 5 times a power of ten) at most h."""
    exponent = math.floor(math.log10(h))
    for mantissa in reversed(ROUND):
        step = mantissa * 10.0 ** exponent
        if step <= h * (1 + 1e-12):
            return float(f"{step:.12g}")
    return float(f"{5.0 * 10.0 ** (exponent - 1):.12g}")


def modes(controller, eta_0: np.ndarray, jet=None) -> tuple[np.ndarray, np.ndarray]:
    """(every eigenvalue of the closed loop's Jacobian at eta_0, those of them the feedback creates) [1/s]."""
    plant = controller.plant
    eta_0 = np.asarray(eta_0, dtype=float)
    J_open = plant.jacobian(eta_0)
    K = np.zeros((plant.n_e, plant.n))
    for i in range(plant.n):
        d = 1e-6 * max(abs(eta_0[i]), 1e-3 * float(np.max(np.abs(eta_0)) or 1.0), 1e-300)
        up, down = eta_0.copy(), eta_0.copy()
        up[i] += d
        down[i] -= d
        K[:, i] = (controller.u(up, jet) - controller.u(down, jet)) / (2 * d)
    open_modes = np.linalg.eigvals(J_open)
    closed = np.linalg.eigvals(J_open + plant.g() @ K)
    feedback = np.array([lam for lam in closed if np.min(np.abs(open_modes - lam)) > 1e-3 * max(abs(lam), 1e-300)])
    return closed, feedback


def default_step(controller, eta_0: np.ndarray, jet, stop_time: float) -> tuple[float, str, str]:
    """(step [s], coupling "explicit" or "implicit", how it was chosen: one sentence for the scenario's notes).
    The modes are those at the initial state and at the target eta*(0) it is driven to (at an uncharged initial
    state the force, quadratic in x_e, does not depend on it to first order, so the linearization there alone
    misses the feedback the charged loop has)."""
    found = [modes(controller, eta, jet) for eta in (eta_0, controller.target(jet))]
    closed = np.abs(np.concatenate([c for c, _ in found]))
    feedback = np.abs(np.concatenate([f for _, f in found]))
    if not (np.all(np.isfinite(closed)) and np.all(np.isfinite(feedback))):
        raise ValueError("the loop's linearization at its initial state is not finite: give --step-size")
    cap = RESOLVE * MAX_STEPS / stop_time                     # the fastest mode MAX_STEPS steps can resolve
    resolvable = closed[closed <= cap]
    accuracy = float(resolvable.max()) if resolvable.size else 0.0
    stability = float(feedback.max()) if feedback.size else 0.0
    fastest = max(accuracy, stability)
    if fastest == 0.0:
        step = round_down(stop_time / 1000)
        return step, "explicit", f"Default step {step:g} s: the loop's linearization has no mode, so a thousandth of the horizon"
    explicit = round_down(min(RESOLVE / fastest, stop_time))
    if stop_time / explicit <= MAX_STEPS * (1 + 1e-9):
        return explicit, "explicit", (
            f"Default step {explicit:g} s, explicit coupling: {RESOLVE:g} over the fastest mode of the closed loop's "
            f"linearization at the initial state and at the target, |lambda| = {fastest:.3g} 1/s (modes above "
            f"{cap:.3g} 1/s, which {MAX_STEPS:.0e} steps cannot resolve and the plant integrates itself, left out)")
    step = round_down(min(RESOLVE / accuracy, stop_time)) if accuracy else round_down(stop_time / MAX_STEPS)
    return step, "implicit", (
        f"Default step {step:g} s, implicit coupling: the feedback adds a mode at |lambda| = {stability:.3g} 1/s, which "
        f"explicit coupling would need steps of {explicit:g} s for; implicit coupling is stable at any step, and "
        f"{step:g} s is {RESOLVE:g} over the fastest mode {MAX_STEPS:.0e} steps can resolve "
        f"(|lambda| = {accuracy:.3g} 1/s)")

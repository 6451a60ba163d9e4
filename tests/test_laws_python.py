"""Definition 1 stated once (components.laws.feasible_reference), printed as Python (components.codegen: the
generated feasible_scalar), against the closed form written by hand (tests/hand_written_laws.py, components/
before it was generated): at random parameters and reference jets of the paper's MEMS and maglev, the
feasible reference and its complex-step derivative agree to 1e-12 relative; an infeasible reference is refused
by both."""
from __future__ import annotations

import numpy as np
import pytest

from components import maglev, mems
from components.theorem3 import Theorem3
from tests.hand_written_laws import feasible_scalar

RTOL = 1e-12


def close(a, b, rtol=RTOL) -> bool:
    return abs(a - b) <= rtol * max(abs(b), 1e-300)


def _mems(rng):
    plant = mems.MEMS(a1=rng.uniform(0.3, 0.6), r_e=rng.uniform(50, 200), R_m=rng.uniform(1e-7, 1e-6))
    jet = (rng.uniform(1e-6, 0.08), rng.normal(0, 1), rng.normal(0, 30), rng.normal(0, 1e3))
    state = np.array([rng.uniform(-1e-5, 0.1), rng.normal(0, 1e-9), rng.normal(0, 3e-6)])
    return plant, 3e-5, jet, state


def _maglev(rng):
    plant = maglev.Maglev(k=rng.uniform(0.5, 0.8), R_m=rng.uniform(0.0, 0.05))
    jet = (rng.uniform(-0.005, 0.0045), rng.normal(0, 1e-3), rng.normal(0, 1e-2), rng.normal(0, 1e-2))
    state = np.array([rng.uniform(-0.01, 0.0049), rng.normal(0, 0.01), rng.normal(0, 0.5)])
    return plant, 0.0025, jet, state


@pytest.mark.parametrize("make", [_mems, _maglev], ids=["MEMS", "Maglev"])
def test_generated_feasible_reference_equals_the_hand_written(make):
    rng = np.random.default_rng(32)
    for _ in range(40):
        plant, _, jet, _ = make(rng)
        for a, b in zip(plant.feasible_scalar(*jet), feasible_scalar(plant, *jet)):
            assert close(a, b), (plant.name, jet)
        v = rng.normal(size=4) * np.abs(jet)                          # complex step: x_e*, x_e*' along v
        z = [complex(x, 1e-30 * d) for x, d in zip(jet, v)]
        for a, b in zip(plant.feasible_scalar(*z), feasible_scalar(plant, *z)):
            assert close(a.imag, b.imag, 1e-11), (plant.name, jet)


def test_infeasible_and_outside_references_are_refused_as_before():
    plant = maglev.Maglev()
    controller = Theorem3(plant, 2.82, k_c=10.0)
    falling = (0.0025, 0.0, -20.0, 0.0)                               # faster than free fall: no real x_e*
    for call in (lambda: plant.feasible_scalar(*falling), lambda: controller.u_scalar(0.0025, 0.0, 0.2, falling),
                 lambda: feasible_scalar(plant, *falling)):
        with pytest.raises(ValueError, match=r"infeasible reference at q\* = 0.0025: no real x_e\*"):
            call()
    outside = (0.006, 0.0, 0.0, 0.0)                                  # above the magnet
    for call in (lambda: plant.feasible_scalar(*outside), lambda: controller.u_scalar(0.0025, 0.0, 0.2, outside),
                 lambda: feasible_scalar(plant, *outside)):
        with pytest.raises(ValueError, match="violates q < c"):
            call()

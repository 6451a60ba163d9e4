"""The control laws stated once (components.laws), printed as C (components.c_codegen.law_c_source), against
the hand-written numpy laws of components/ (proposition1.py, theorem2.py, proposition2.py, theorem3.py).

Each C law is compiled with gcc -std=c99 -Wall -Wextra -Werror -pedantic and called through ctypes at random
states, gains and reference jets: the regulation laws with the feasible reference given (from
OneDOFPlant.equilibrium), the tracking laws with the jet alone (Definition 1 in closed form, in C)."""
from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from components.c_codegen import law_c_source
from components.catalog import DEVICES
from components.description import load
from components.ph_plant import Jet
from components.plant_step import nominal_scale
from components.proposition1 import Proposition1
from components.proposition2 import Proposition2
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3

PLANTS = Path(__file__).resolve().parents[1] / "components" / "plants"
pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def compile_laws(name: str, family: str, tracking: bool, folder: Path) -> ctypes.CDLL:
    desc = load(PLANTS / f"{name.lower()}.toml")
    source = folder / f"{family}_{tracking}.c"
    source.write_text(law_c_source(desc, [family], tracking))
    library = source.with_suffix(".so")
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-fPIC", "-shared",
                    str(source), "-o", str(library), "-lm"], check=True, capture_output=True, text=True)
    return ctypes.CDLL(str(library))


def c_law(lib: ctypes.CDLL, family: str, par, gains, eta, ref) -> float:
    out = (ctypes.c_double * 1)()
    arrays = [(ctypes.c_double * len(a))(*a) for a in (par, gains, eta, ref)]
    getattr(lib, f"emc_law_{family}")(*arrays, out)
    return out[0]


# (plant, family, regulation design, tracking design, gain sets (R_e_bar, D_d, W or k_c), q_d)
CASES = [("MEMS", "c1", Proposition1, Theorem2, [(0.01, 0.0, 1.0), (0.01, 1e-4, 1.0), (0.01, -1.0, 1.0),
                                                  (0.02, -0.4, 1.0)], 3e-5),
         ("Maglev", "u2", Proposition2, Theorem3, [(2.82, 0.0, 20.0), (0.82, -0.78, 20.0), (2.82, -0.78, 5.0)],
          0.0025)]


@pytest.mark.parametrize("name, family, regulation, tracking, gain_sets, q_d", CASES, ids=[c[0] for c in CASES])
def test_c_laws_equal_the_numpy_laws(tmp_path: Path, name, family, regulation, tracking, gain_sets, q_d) -> None:
    plant = DEVICES[name].plant()
    desc = load(PLANTS / f"{name.lower()}.toml")
    par = [plant.params[p] for p in desc.parameters]
    with_reference = compile_laws(name, family, False, tmp_path)
    with_jet = compile_laws(name, family, True, tmp_path)
    rng = np.random.default_rng(11)
    p_scale = nominal_scale(plant)[1]
    for R_e_bar, D_d, weight in gain_sets:
        gains = [R_e_bar, D_d, weight]
        extra = {"k_c": weight} if family == "u2" else {}
        trk = tracking(plant, R_e_bar, D_d=D_d, **extra)
        try:                              # regulation needs eq. (pHcondition): Proposition 1 strictly, 2 weakly
            reg = regulation(plant, [q_d], R_e_bar, D_d=D_d, **extra)
        except ValueError:
            reg = trk                     # the tracking law at a constant reference is the regulation law
        eta_d = plant.equilibrium(np.array([q_d]))
        constant = Jet(*(np.array([v]) for v in (q_d, 0.0, 0.0, 0.0)))
        for _ in range(20):
            eta = eta_d * (1.0 + rng.uniform(-0.3, 0.3, 3)) + np.array([0.0, rng.uniform(-0.3, 0.3) * p_scale, 0.0])
            if not plant.domain_margin(eta) > 0:
                continue
            want = float(reg.u(eta, None if reg is not trk else constant)[0])
            got = c_law(with_reference, family, par, gains, eta, [eta_d[0], eta_d[1], eta_d[2], 0.0])
            assert got == pytest.approx(want, rel=1e-12, abs=1e-12 * abs(want)), "regulation, reference given"
            got = c_law(with_jet, family, par, gains, eta, [q_d, 0.0, 0.0, 0.0])
            assert got == pytest.approx(want, rel=1e-12, abs=1e-12 * abs(want)), "regulation, jet"
            w = 30.0
            jet = Jet(*(np.array([v]) for v in (q_d * (1 + rng.uniform(-0.2, 0.2)), q_d * w * rng.uniform(-0.1, 0.1),
                                                  q_d * w * w * rng.uniform(-0.1, 0.1),
                                                  q_d * w ** 3 * rng.uniform(-0.1, 0.1))))
            want = float(trk.u(eta, jet)[0])
            got = c_law(with_jet, family, par, gains, eta, [float(v[0]) for v in (jet.q, jet.qd, jet.qdd, jet.qddd)])
            assert got == pytest.approx(want, rel=1e-11, abs=1e-12 * abs(want)), "tracking, jet"

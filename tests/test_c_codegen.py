"""The C99 model functions (components.c_codegen) against the Python plant of the same description.

The generated C is compiled with gcc -std=c99 -Wall -Wextra -Werror and called through ctypes at random
states; the truth is the Python plant (components/plants/*_model.py, from components.codegen, composed
by components.ph_plant's numpy code: grad H, F grad H + g u, F hess H), which shares the symbolic
derivatives of V and Psi but not the composition of H, f and its Jacobian.
"""
from __future__ import annotations

import ctypes
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from components.c_codegen import FUNCTIONS, MODEL_HEADER, model_c_source
from components.catalog import DEVICES
from components.description import load

PLANTS = Path(__file__).resolve().parents[1] / "components" / "plants"
pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def compile_model(desc, folder: Path) -> ctypes.CDLL:
    (folder / "emc_model.h").write_text(MODEL_HEADER)
    (folder / "model.c").write_text(model_c_source(desc))
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2", "-fPIC", "-shared",
                    "model.c", "-o", "model.so", "-lm"], cwd=folder, check=True, capture_output=True, text=True)
    return ctypes.CDLL(str(folder / "model.so"))


def call(lib: ctypes.CDLL, name: str, par, eta, u, size: int) -> np.ndarray:
    out = (ctypes.c_double * size)()
    arrays = [(ctypes.c_double * len(a))(*a) for a in (par, eta, u)]
    getattr(lib, f"emc_{name}")(*arrays, out)
    return np.array(out[:])


def random_states(plant, rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """States inside the domain, on the scales of the plant (nominal_scale), momenta and charges of both signs."""
    from components.plant_step import nominal_scale
    L, P, X = nominal_scale(plant)
    out = []
    while len(out) < count:
        eta = np.array([rng.uniform(-1.5, 1.5) * L, rng.uniform(-3, 3) * P, rng.uniform(-3, 3) * X])
        if plant.domain_margin(eta) > 0:
            out.append(eta)
    return out


def close(c: np.ndarray, py: np.ndarray) -> None:
    """1e-12 relative, per entry, with an absolute floor of 1e-14 of the largest entry (cancellation)."""
    py = np.asarray(py, dtype=float).ravel()
    np.testing.assert_allclose(c, py, rtol=1e-12, atol=1e-14 * float(np.max(np.abs(py), initial=0.0)))


@pytest.mark.parametrize("name", ["MEMS", "Maglev"])
def test_c_model_equals_python(tmp_path: Path, name: str) -> None:
    desc = load(PLANTS / f"{name.lower()}.toml")
    lib = compile_model(desc, tmp_path)
    plant = DEVICES[name].plant()
    par = [plant.params[p] for p in desc.parameters]
    rng = np.random.default_rng(32)
    sizes = {"V": 1, "grad_V": 1, "hess_V": 1, "Psi": 1, "dPsi": 1, "d2Psi": 1, "M_inv": 1, "H": 1,
             "grad_H": 3, "hess_H": 9, "f": 3, "jacobian": 9, "g": 3, "margin": 1}
    assert set(sizes) == set(FUNCTIONS)
    for eta in random_states(plant, rng, 50):
        u = [rng.uniform(-30, 30)]
        q = eta[:1]
        truth = {"V": plant.V(q), "grad_V": plant.grad_V(q), "hess_V": plant.hess_V(q), "Psi": plant.Psi(q),
                 "dPsi": plant.dPsi(q), "d2Psi": plant.d2Psi(q), "M_inv": plant.M_inv(q), "H": plant.H(eta),
                 "grad_H": plant.grad_H(eta), "hess_H": plant.hess_H(eta), "f": plant.f(eta, u), "jacobian": plant.jacobian(eta),
                 "g": plant.g(), "margin": plant.domain_margin(eta)}
        for fn, size in sizes.items():
            close(call(lib, fn, par, eta, u, size), truth[fn])


def test_c_parameter_check(tmp_path: Path) -> None:
    """emc_check_parameters refuses what Parameter.check refuses, and names the first such parameter."""
    desc = load(PLANTS / "mems.toml")
    lib = compile_model(desc, tmp_path)
    names = list(desc.parameters)
    good = [p.default for p in desc.parameters.values()]
    check = lib.emc_check_parameters
    check.restype = ctypes.c_int

    def first_bad(values) -> int:
        return check((ctypes.c_double * len(values))(*values))

    assert first_bad(good) == -1
    for bad, index in (({"c1": 0.0}, names.index("c1")), ({"a2": -1.0}, names.index("a2")),
                       ({"m": float("nan")}, names.index("m")), ({"r_e": 1e200}, names.index("r_e")),
                       ({"R_m": float("inf"), "c0": -1.0}, names.index("c0"))):
        values = [bad.get(n, v) for n, v in zip(names, good)]
        assert first_bad(values) == index
        with pytest.raises(ValueError):            # the Python truth refuses the same value
            desc.parameters[names[index]].check(values[index])
    assert first_bad([good[i] if n != "a2" else 0.0 for i, n in enumerate(names)]) == -1   # a2 >= 0

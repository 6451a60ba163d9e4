"""The whole initial state of a device scenario (issue 34, item 3): q_0, p_0 and x_e_0, with the defaults rest
(p = 0) and the electrical state of the equilibrium at q_0, including x_e = 0 where the potential holds q_0
alone."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from components import description as descriptions
from emcosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"


def _start(ssv: str) -> dict[str, float]:
    return {m[0]: float(m[1]) for m in re.findall(r'name="(\w+)_0"><ssv:Real value="([^"]+)"', ssv)}


def test_q0_where_the_spring_is_relaxed_starts_at_x_e_0(tmp_path, capsys):
    """The solenoid's spring is relaxed at q = 0: (q, p, x_e) = 0 is an equilibrium with u = 0 (the plant's own
    vector field vanishes there), so `--q0 0` starts there instead of refusing (no root of F* = 0 was found)."""
    out = tmp_path / "s"
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Proposition1", "--out", str(out),
            "--stop-time", "0.1", "--step-size", "1e-4", "--q0", "0"]
    assert main(args) == 0, capsys.readouterr().err
    start = _start((out / "plant.ssv").read_text())
    assert start == {"q": 0.0, "p": 0.0, "x_e": 0.0}
    from emcosim.devices import registry
    _, _, device = registry.load(str(SOLENOID))
    plant = device.plant()
    assert np.all(plant.f(np.zeros(3), np.zeros(1)) == 0)


def test_p0_and_x_e0_are_taken_as_given(tmp_path, capsys):
    out = tmp_path / "s"
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Proposition1", "--out", str(out),
            "--stop-time", "0.1", "--step-size", "1e-4", "--q0", "0.0005", "--p0", "0.001", "--x-e0", "0.02"]
    assert main(args) == 0, capsys.readouterr().err
    assert _start((out / "plant.ssv").read_text()) == {"q": 0.0005, "p": 0.001, "x_e": 0.02}
    assert "p given, x_e given" in (out / "SystemStructure.ssd").read_text()


def test_default_x_e0_holds_q0_at_rest(tmp_path, capsys):
    """Only q_0 given: p_0 = 0 and x_e_0 balances the spring there (independently: k_s q = -1/2 Psi'(q) x_e^2)."""
    out = tmp_path / "s"
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Proposition1", "--out", str(out),
            "--stop-time", "0.1", "--step-size", "1e-4", "--q0", "0.0007"]
    assert main(args) == 0, capsys.readouterr().err
    start = _start((out / "plant.ssv").read_text())
    values = descriptions.load(SOLENOID).parameters
    k_s, g0, k, L = (values[n].default for n in ("k_s", "g0", "k", "L_inf"))
    q = 0.0007
    dpsi = -k / (k + L * (g0 - q)) ** 2            # d/dq of (g0 - q) / (k + L (g0 - q))
    assert start["p"] == 0.0
    assert start["x_e"] == pytest.approx(np.sqrt(2 * k_s * q / -dpsi), rel=1e-12)


@pytest.mark.parametrize("extra, message", [
    (["--p0", "1", "2"], "p_0 has 2 entries"),
    (["--x-e0", "nan"], "x_e_0 = [nan] must be finite"),
])
def test_a_wrong_initial_state_is_refused_in_one_line(tmp_path, capsys, extra, message):
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Proposition1", "--out", str(tmp_path / "s"),
            "--stop-time", "0.1", "--step-size", "1e-4", *extra]
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("emcosim: error: ") and message in err[-1]
    assert not (tmp_path / "s").exists()

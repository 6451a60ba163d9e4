"""`emcosim plant check | build | scenario` as a user types them: verdicts printed, a wrong description
refused with one line naming the entry and nothing built, scenario folders written only where safe."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from emcosim.cli import main

ROOT = Path(__file__).resolve().parents[1]
MAGLEV = ROOT / "components" / "plants" / "maglev.toml"
SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"


def test_check_prints_each_assumption_with_its_test_and_the_designs(capsys, tmp_path):
    assert main(["plant", "check", str(MAGLEV), "--json", str(tmp_path / "r.json")]) == 0
    out = capsys.readouterr().out
    assert "Assumption 1 (eq. ass:class1): fails" in out and "R_m > 0 -- " in out and "exact at the parameter values" in out
    assert "Assumption 2 (eq. assHereg): holds" in out
    assert "Proposition2 applies" in out and "Proposition1 does not apply" in out
    report = json.loads((tmp_path / "r.json").read_text())
    assert [d["name"] for d in report["designs"] if d["applies"]] == ["Proposition2", "Theorem3"]


def test_check_of_a_set_point_beyond_the_magnet_says_it_is_not_assignable(capsys):
    assert main(["plant", "check", str(MAGLEV), "--q-d", "0.006"]) == 0
    out = capsys.readouterr().out
    assert "Set-point q_d assignable (set E, Section 3): fails" in out
    assert "Proposition2 does not apply" in out


def test_check_of_a_reference_decides_theorem_2_along_it(capsys):
    """The solenoid's potential H(q, x_e) stops being convex in q near q = 1.3 mm at the flux that holds it
    there (hess_q H = k_s + x_e^2 Psi''/2, Psi'' < 0): Assumption 3 (eq. cond1T2) holds on the tube around a
    small reference about q = 1 mm and fails on the tube around a wide one."""
    assert main(["plant", "check", str(SOLENOID), "--reference", "sinusoid:offset=0.001,amplitude=5e-5,omega=31.4"]) == 0
    out = capsys.readouterr().out
    assert "Reference feasible (Definition 1)" in out and "Theorem2     applies" in out
    assert main(["plant", "check", str(SOLENOID), "--reference", "sinusoid:offset=0.001,amplitude=3e-4,omega=31.4"]) == 0
    out = capsys.readouterr().out
    assert "Assumption 3 (eq. cond1T2): fails" in out and "Theorem2     does not apply" in out


WRONG = {
    "unknown symbol": ('Psi = "(g0 - q)/(k + L_inf*(g0 - q))"', 'Psi = "(g0 - q)/(k + L_oo*(g0 - q))"', "[model] Psi"),
    "indefinite R_m": ('R_m = "R_m"', 'R_m = "-R_m - 1"', "[model] R_m"),
    "singular G_e": ('G_e = "1"', 'G_e = "0"', "[model] G_e"),
    "Psi not positive definite": ('Psi = "(g0 - q)/(k + L_inf*(g0 - q))"', 'Psi = "-(g0 - q)/(k + L_inf*(g0 - q))"',
                                  "[model] Psi"),
}


@pytest.mark.parametrize("case", list(WRONG))
def test_a_wrong_description_is_refused_naming_the_entry_and_nothing_is_built(case, tmp_path, capsys):
    old, new, entry = WRONG[case]
    text = SOLENOID.read_text()
    assert old in text
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new))
    out = tmp_path / "fmus"
    assert main(["plant", "build", str(bad), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("emcosim: error: ") and entry in err[0], err
    assert not out.exists()


def test_scenario_refuses_a_folder_with_other_files(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Proposition1", "--out", str(out),
            "--stop-time", "0.1", "--step-size", "1e-4"]
    assert main(args) == 1
    assert "notes.txt" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "mine" and sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_scenario_of_a_design_that_does_not_apply_is_refused(tmp_path, capsys):
    args = ["plant", "scenario", str(SOLENOID), "--controller", "Theorem3", "--out", str(tmp_path / "s"),
            "--stop-time", "0.1", "--step-size", "1e-4"]
    assert main(args) == 1
    assert "solenoid.toml: Theorem3 does not apply: Assumption 4" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_ctrl_c_during_plant_build_exits_130_and_leaves_no_half_written_fmu(tmp_path, monkeypatch, capsys):
    """A SIGINT while the FMUs are written (here: inside the first archive's write) stops the build at once
    with exit 130; nothing reaches --out and the build's marked temporary folder is removed."""
    import os
    import signal
    import tempfile

    from fmus import build

    original = build._write_fmu
    calls = []

    def write_then_interrupt(target, files):
        calls.append(target)
        original(target.with_suffix(".probe"), files)            # prove the write path works, then
        os.kill(os.getpid(), signal.SIGINT)                       # the user presses Ctrl-C in the middle
        original(target, files)

    monkeypatch.setattr(build, "_write_fmu", write_then_interrupt)
    out = tmp_path / "fmus"
    assert main(["plant", "build", str(SOLENOID), "--out", str(out)]) == 130
    assert "interrupted by SIGINT" in capsys.readouterr().err
    assert calls and not calls[0].exists() and (not out.exists() or not list(out.iterdir()))
    assert not list(Path(tempfile.gettempdir()).glob(f"emcosim-{os.getpid()}-plant_build-*"))


def test_a_signal_a_command_never_looked_at_still_makes_it_exit_nonzero(monkeypatch, capsys):
    """A command that runs to its end without checking for a stop (graceful handling records the signal)
    does not exit 0 after Ctrl-C: it says so and exits 128 + signal."""
    import os
    import signal

    from emcosim import cli

    def info_then_signal(args):
        os.kill(os.getpid(), signal.SIGTERM)
        return 0

    parser = cli._parser
    monkeypatch.setattr(cli, "_parser", lambda: _with_func(parser(), "info", info_then_signal))
    assert main(["info"]) == 128 + signal.SIGTERM
    assert "finished before it could stop" in capsys.readouterr().err


def _with_func(parser, command, func):
    """`parser` with `func` as the command's function (set_defaults binds it when the parser is made)."""
    for action in parser._subparsers._group_actions:
        action.choices[command].set_defaults(func=func)
    return parser

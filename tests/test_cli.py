"""What a user types: `emcosim --version`, suggestions for a misspelled scenario, negative numbers
as option values, errors that name the option typed, `info` without a stray header, a default
recording of each connected value once, progress bars only on a terminal, units on the exported
closed loop's variables."""
from __future__ import annotations

import io
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from emcosim.cli import main
from emcosim.engine.results import read_csv

ROOT = Path(__file__).resolve().parents[1]


def one_line_error(capsys) -> str:
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("emcosim: error:") and "\n" not in err, err
    return err


def test_version():
    run = subprocess.run([sys.executable, "-m", "emcosim.cli", "--version"], capture_output=True, text=True)
    assert run.returncode == 0 and run.stdout.strip() == f"emcosim {version('emcosim')}"


@pytest.mark.parametrize("typed, meant", [("mems_regulaton_Dd0", "mems_regulation_Dd0"),
                                          ("maglev_tracking_D-1_R0.8", "maglev_tracking_D-1_R0.82")])
def test_misspelled_scenario_suggests_the_closest(typed, meant, capsys):
    assert main(["run", typed, "--no-progress"]) == 1
    err = one_line_error(capsys)
    assert "did you mean" in err and meant in err


def test_certify_suggests_too(capsys):
    assert main(["certify", "mems_regulaton_Dd-1"]) == 1
    assert "mems_regulation_Dd-1" in one_line_error(capsys)


@pytest.mark.parametrize("args, message", [
    (["run", "mems_regulation_Dd0", "--step-size", "-1e-5"], "--step-size -1e-05: must be a positive number"),
    (["run", "mems_regulation_Dd0", "--tolerance", "-.5"], "--tolerance -0.5: must be a number between 0 and 1"),
    (["run", "mems_regulation_Dd0", "--stop-time", "-2E-3"], "--stop-time -0.002 must be after the start time"),
    (["run", "mems_regulation_Dd0", "--max-step", "1e-4"], "--max-step bounds the steps that --tolerance chooses"),
])
def test_negative_numbers_are_parsed_then_refused_clearly(args, message, capsys):
    assert main(args + ["--no-progress"]) == 1                   # not argparse's usage error (status 2)
    assert message in one_line_error(capsys)


def test_sweep_names_the_option_typed(capsys, tmp_path):
    assert main(["sweep", "mems_regulation_Dd0", "--grid", "nosuch.x=0:1:3", "--out", str(tmp_path)]) == 1
    assert one_line_error(capsys).startswith("emcosim: error: --grid nosuch.x: no component 'nosuch'")
    assert main(["sweep", "mems_regulation_Dd0", "--sample", "plant.nope=0:1", "--samples", "2",
                 "--out", str(tmp_path)]) == 1
    assert one_line_error(capsys).startswith("emcosim: error: --sample plant.nope: unknown variable 'nope'")


def test_info_of_an_unknown_scenario_prints_only_the_error(capsys):
    assert main(["info", "mems_regulation_Dd0", "nosuch"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.startswith("emcosim: error: nosuch") and captured.err.count("\n") == 1


def test_default_recording_holds_each_connected_value_once(fmu_dir, tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["run", "maglev_tracking_D0_R2.82", "--stop-time", "2e-3", "--fmu-dir", str(fmu_dir),
                 "--output", str(out), "--no-progress"]) == 0
    columns = list(read_csv(out))
    assert columns == ["time", "reference.q_star", "reference.q_star_dot", "reference.q_star_ddot",
                       "reference.q_star_dddot", "controller.u", "plant.q", "plant.p", "plant.x_e", "plant.H"]
    assert main(["run", "maglev_tracking_D0_R2.82", "--stop-time", "2e-3", "--fmu-dir", str(fmu_dir),
                 "--output", str(out), "--record", "plant.q,controller.q", "--no-progress"]) == 0
    assert list(read_csv(out)) == ["time", "plant.q", "controller.q"]          # --record takes any choice


def test_coupling_is_the_scenarios_unless_chosen(fmu_dir, tmp_path, capsys):
    """mems_regulation_Dd-1 declares implicit coupling (emcosim:Coupling): `info` says so, `run` reports
    the trial steps; --coupling explicit runs it explicitly; --coupling implicit with a coupling order
    is refused in one line."""
    assert main(["info", "mems_regulation_Dd-1"]) == 0
    assert "implicit coupling" in capsys.readouterr().out
    args = ["run", "mems_regulation_Dd-1", "--stop-time", "1e-4", "--fmu-dir", str(fmu_dir),
            "--output", str(tmp_path / "r.csv"), "--no-progress"]
    assert main(args) == 0
    assert "implicit coupling: " in capsys.readouterr().out
    # explicitly, the implicit scenario's step is unstable (docs/scenarios.md): the run's estimate says so (exit 5)
    assert main(args + ["--coupling", "explicit"]) == 5
    captured = capsys.readouterr()
    assert "implicit coupling" not in captured.out and "estimated coupling error" in captured.err
    assert main(args + ["--coupling", "implicit", "--coupling-order", "2"]) == 1
    assert "--coupling-order 2" in one_line_error(capsys)


def test_help_says_how_to_choose_variables(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--record" in text and "emcosim info SCENARIO" in text and "each connected value is recorded once" in text


def test_results_are_ignored_by_git():
    assert "results/" in (ROOT / ".gitignore").read_text().split()


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bars_only_on_a_terminal():
    from emcosim.progress import Counter, ProgressBar
    tty, log = Terminal(), io.StringIO()
    for stream in (tty, log):
        bar = ProgressBar("run", delay=0.0, stream=stream)
        bar(0.5)
        bar(1.0)
        bar.close()
        counter = Counter(3, "sweep", stream=stream)
        for _ in range(3):
            counter.advance()
        counter.close()
    assert "100.0%" in tty.getvalue() and "3/3" in tty.getvalue()
    assert log.getvalue() == ""


def test_hold_engines_refuse_a_default_step_chosen_for_implicit_coupling(fmu_dir, tmp_path, capsys):
    """mems_regulation_Dd-1's default step (25 us) is for implicit coupling; the container FMU, libcosim and
    ecos hold each input over a step and at that step return finite but wrong numbers (libcosim: the
    position at 1.4e3 m after 2 ms). Without a step they refuse with one line that says why; with one
    they run (the container exported at 0.5 us)."""
    from emcosim.engine.ecos import simulate_ecos
    from emcosim.engine.errors import ScenarioError
    from emcosim.engine.libcosim import simulate_libcosim
    from emcosim.engine.ssd import read_scenario
    fmu = tmp_path / "loop.fmu"
    assert main(["export", "mems_regulation_Dd-1", "-o", str(fmu), "--fmu-dir", str(fmu_dir)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "default step 2.5e-05 s is for implicit coupling" in err, err
    assert "the container FMU holds each input" in err and not fmu.exists()
    s = read_scenario(ROOT / "scenarios" / "mems_regulation_Dd-1", fmu_dir=fmu_dir)
    for run, engine in ((simulate_libcosim, "libcosim"), (simulate_ecos, "ecos")):
        with pytest.raises(ScenarioError, match=f"is for implicit coupling; {engine} holds each input"):
            run(s, stop_time=1e-4)
    assert main(["export", "mems_regulation_Dd-1", "-o", str(fmu), "--fmu-dir", str(fmu_dir), "--step-size", "5e-7"]) == 0
    assert fmu.is_file()


def test_exported_loop_has_units(fmu_dir, tmp_path):
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu
    fmu = tmp_path / "loop.fmu"
    assert main(["export", "maglev_regulation_prop2", "-o", str(fmu), "--fmu-dir", str(fmu_dir)]) == 0
    assert validate_fmu(str(fmu)) == []
    md = read_model_description(str(fmu))
    units = {v.name: v.unit for v in md.modelVariables}
    plant = {v.name: v.unit for v in read_model_description(str(fmu_dir / "Maglev.fmu")).modelVariables}
    assert units["plant.q"] == "m" and units["plant.x_e"] == "Wb" and units["controller.u"] == "V"
    assert all(units[f"plant.{n}"] == plant[n] for n in ("q", "p", "x_e", "H", "m", "k"))
    assert {u.name for u in md.unitDefinitions} >= {"m", "Wb", "V", "J"}


def test_info_of_a_scenario_shows_its_values_beside_the_fmus_defaults(fmu_dir, capsys):
    """Issue 41 item 3: `info SCENARIO` lists what the scenario sets (from its .ssv files and .ssd, read here
    with ElementTree), each beside the FMU's start value (read with fmpy), '*' where they differ; a value the
    scenario does not change is shown once, unmarked."""
    import xml.etree.ElementTree as ET

    from fmpy import read_model_description

    folder = ROOT / "scenarios" / "maglev_tracking_D-1_R0.82"
    ssv = {}
    for name in ("plant", "controller"):
        for p in ET.parse(folder / f"{name}.ssv").getroot().iter("{http://ssp-standard.org/SSP1/SystemStructureParameterValues}Parameter"):
            ssv[f"{name}.{p.get('name')}"] = float(next(iter(p)).get("value"))
    defaults = {f"{comp}.{v.name}": float(v.start) for comp, fmu in (("plant", "Maglev"), ("controller", "Maglev_Theorem3"))
                for v in read_model_description(str(fmu_dir / f"{fmu}.fmu")).modelVariables
                if v.causality == "parameter" and v.type == "Real"}
    assert (ssv["plant.q_0"], ssv["plant.rtol"], ssv["controller.R_e_bar"]) == (0.0015, 1e-06, 0.82)
    assert main(["info", "maglev_tracking_D-1_R0.82", "--fmu-dir", str(fmu_dir)]) == 0
    out = capsys.readouterr().out
    for full in ("plant.q_0", "plant.rtol", "controller.R_e_bar", "controller.D_d"):
        name = full.partition(".")[2]
        assert ssv[full] != defaults[full]
        assert f"* {name} [" in out and f"= {ssv[full]!r}  (FMU default: {defaults[full]!r})" in out, full
    assert f"  R_e [Ohm] = {ssv['plant.R_e']!r}  coil resistance" in out            # the same as the default
    assert "* stop time [s] = 40.0" in out and "* step size [s] = 0.0125" in out
    assert "R_e_bar [Ohm] = 2.82" not in out                       # the FMU default is no longer shown as the value


def test_settings_api_is_what_info_prints(fmu_dir):
    """emcosim.settings: the library part of `info SCENARIO` (the CLI only prints it)."""
    import emcosim

    experiment, components = emcosim.settings(emcosim.load_scenario("maglev_tracking_D-1_R0.82", fmu_dir))
    by_name = {s.name: s for rows in components.values() for s in rows}
    assert (by_name["controller.R_e_bar"].value, by_name["controller.R_e_bar"].default) == (0.82, 2.82)
    assert by_name["controller.R_e_bar"].differs and not by_name["plant.R_e"].differs
    assert by_name["controller.strict"].source is None and by_name["plant.q_0"].source.endswith("plant.ssv")
    assert "plant.u" not in by_name                                # connected: the master sets it
    assert [s.name for s in experiment] == ["start time", "stop time", "step size", "coupling"]

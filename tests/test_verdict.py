"""Issue 41, item 2: one verdict, one place (engine/verdict.py). The README's solenoid case at a 1e-4 s step,
which `emcosim run` refuses with exit 5, used to come back from `emcosim.run` silently (result.warnings == []).
Now the library decides and both apply it: the API raises ResultNotAccepted carrying the rows, accept="warn"
returns them with a warning, the figure is marked, and the command line's exit 5 and message are unchanged.

Independent truth: the same loop at the README's own step (2e-5 s, five times shorter): the 1e-4 s run's
voltage is off from it by more than the threshold of its range, so the refusal is deserved."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import emcosim
from emcosim.cli import main
from emcosim.engine.doubling import THRESHOLD
from emcosim.engine.errors import OptionError, ScenarioError
from emcosim.engine.results import Result
from emcosim.engine.verdict import judge

ROOT = Path(__file__).resolve().parents[1]
SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"


@pytest.fixture(scope="module")
def readme_case(tmp_path_factory) -> Path:
    """The README's `plant build` and `plant scenario` of the solenoid (Proposition1, q0 = 0.7 mm, 0.1 s) at the
    step its text says `emcosim run` refuses: 1e-4 s."""
    work = tmp_path_factory.mktemp("solenoid")
    emcosim.build_plant(SOLENOID, work / "fmus")
    return emcosim.write_scenario(SOLENOID, work / "scenario", "Proposition1", stop_time=0.1, step_size=1e-4,
                                  q0=[0.0007], fmu_dir=work / "fmus")


def test_the_readme_case_raises_the_typed_exception_with_its_rows(readme_case):
    with pytest.raises(emcosim.ResultNotAccepted) as caught:
        emcosim.run(readme_case)
    exc = caught.value
    assert isinstance(exc, ScenarioError)                          # the library's error base
    result = exc.result
    assert isinstance(result, Result) and len(result) == 1001 and result.accepted is False
    assert "estimated coupling error" in str(exc) and "of its range (controller.u)" in str(exc)
    fine = emcosim.run(readme_case, emcosim.RunOptions(step_size=2e-5))   # the README's own step: accepted
    assert fine.accepted is True
    u, u_fine = result["controller.u"], fine["controller.u"][::5]
    assert np.array_equal(result.time, fine.time[::5]) or np.allclose(result.time, fine.time[::5], atol=1e-12)
    assert np.max(np.abs(u - u_fine)) > THRESHOLD * np.ptp(u_fine)   # the refusal is deserved


def test_accept_warn_returns_the_result_marked_with_a_warning(readme_case):
    with pytest.warns(emcosim.ResultNotAcceptedWarning, match="estimated coupling error"):
        result = emcosim.run(readme_case, accept="warn")
    assert result.accepted is False and len(result) == 1001
    assert any(w.startswith("not accepted: estimated coupling error") for w in result.warnings), result.warnings
    spec = emcosim.figure(emcosim.load_scenario(readme_case), result)
    assert spec.mark.startswith("NOT ACCEPTED: estimated coupling error")
    with warnings.catch_warnings():
        warnings.simplefilter("error")                            # an accepted result: no warning, no mark
        fine = emcosim.run(readme_case, emcosim.RunOptions(step_size=2e-5), accept="warn")
    assert fine.warnings == [] and emcosim.figure(emcosim.load_scenario(readme_case), fine).mark == ""


def test_the_command_lines_exit_5_is_unchanged(readme_case, tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["run", str(readme_case.parent), "-o", str(out), "--no-progress"]) == 5
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith("emcosim: warning: estimated coupling error") and (
        "of its range (--error-threshold); a shorter --step-size, --coupling implicit or --tolerance gives a "
        f"result that keeps it; 1001 rows up to t = 0.1 s saved to {tmp_path / 'r.partial.csv'} (exit status 5, "
        "docs/cli.md)") in last, last
    assert not out.exists() and (tmp_path / "r.partial.csv").is_file()


def test_a_larger_threshold_accepts_it_in_both(readme_case, tmp_path, capsys):
    assert emcosim.run(readme_case, error_threshold=0.5).accepted is True
    assert main(["run", str(readme_case.parent), "-o", str(tmp_path / "r.csv"), "--no-progress",
                 "--error-threshold", "0.5"]) == 0


@pytest.mark.parametrize("value", [-1.0, 0.0, math.nan, math.inf])
def test_a_bad_threshold_or_accept_is_refused_before_the_run(value):
    with pytest.raises(OptionError, match=r"^error_threshold \S+: must be a positive number$"):
        emcosim.run("no-such-scenario", error_threshold=value)
    with pytest.raises(OptionError, match="accept 'ignore': must be one of 'raise', 'warn'"):
        emcosim.run("no-such-scenario", accept="ignore")


def rows(values: list[list[float]]) -> Result:
    result = Result(["a", "b"])
    for row in values:
        result.append(row[0], row[1:])
    return result


def test_every_value_finite_and_the_horizon_reached():
    """The verdict's other two conditions, on results made by hand (the engine itself ends a run at a value
    that is not finite; a result read back from a file need not have been made by it)."""
    good = rows([[0.0, 1.0, 2.0], [0.5, 1.0, 2.0], [1.0, 1.0, 2.0]])
    assert judge(good, horizon=1.0).accepted and judge(good, horizon=1.0 + 1e-13).accepted
    short = judge(good, horizon=2.0)
    assert not short.accepted and "does not reach its horizon 2 s (the last row is at t = 1 s)" in short.summary()
    nan = judge(rows([[0.0, 1.0, 2.0], [0.5, 1.0, math.nan], [1.0, math.inf, 2.0]]), horizon=1.0)
    assert not nan.accepted and nan.summary() == "not accepted: b is not finite at t = 0.5 s"

"""Issue 40, items 4, 13, 14: every run has a stated bound. A horizon below the engine's resolution of time
(options.min_horizon) is refused, naming stop_time, whatever the interface and coupling (on main: Model
Exchange at 1e-200 s stepped LSODA on the spot up to 1e8 steps, for hours; implicit coupling ended in a bare
ZeroDivisionError); a solver that stops moving time on ends the run (model_exchange.MAX_STALLED_STEPS); the
run options take any real number, numpy's included, and no bool."""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

import emcosim
from emcosim.engine import options as options_module
from emcosim.engine.errors import OptionError, SimulationError

SCENARIO = "maglev_regulation_prop2"


@pytest.mark.parametrize("flags", [["--interface-type", "ModelExchange"],
                                   ["--interface-type", "ModelExchange", "--tolerance", "1e-3"],
                                   ["--coupling", "implicit"]])
def test_a_horizon_below_the_time_resolution_is_refused_at_once(flags, fmu_dir, tmp_path):
    tic = time.monotonic()
    try:
        run = subprocess.run([sys.executable, "-m", "emcosim.cli", "run", SCENARIO, *flags, "--stop-time", "1e-200",
                              "--fmu-dir", str(fmu_dir), "--no-progress", "-o", str(tmp_path / "r.csv")],
                             capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("a run of 1e-200 s did not end within 120 s")
    assert time.monotonic() - tic < 120
    err = run.stderr.strip()
    assert run.returncode != 0 and err.startswith("emcosim: error:") and "\n" not in err, err
    assert "--stop-time" in err and "Traceback" not in err and "ZeroDivision" not in err, err


@pytest.mark.parametrize("settings", [dict(interface_type="ModelExchange"), dict(coupling="implicit"), {}])
def test_the_api_names_stop_time(settings, fmu_dir):
    with pytest.raises(OptionError) as caught:          # (max_steps: main ran into it, after 1e5 steps on the spot)
        emcosim.run(SCENARIO, emcosim.RunOptions(stop_time=1e-200, max_steps=1e5, **settings))
    assert caught.value.options == ("stop_time",)


def test_a_horizon_at_the_resolution_runs(fmu_dir):
    result = emcosim.run(SCENARIO, emcosim.RunOptions(stop_time=options_module.TIME_RESOLUTION,
                                                      interface_type="ModelExchange"))
    assert result.time[0] == 0.0 and result.time[-1] == options_module.TIME_RESOLUTION


def test_a_solver_that_does_not_move_time_on_ends_the_run(monkeypatch, fmu_dir):
    """Without the horizon's floor LSODA's step underflows to 0 at 1e-200 s: the stall bound ends it (on
    main, with max_steps 1e5, it ran into max_steps after 1e5 steps on the spot)."""
    monkeypatch.setattr(options_module, "TIME_RESOLUTION", 0.0)
    tic = time.monotonic()
    with pytest.raises(SimulationError, match="stuck at t = 0 s"):
        emcosim.run(SCENARIO, emcosim.RunOptions(stop_time=1e-200, interface_type="ModelExchange", max_steps=1e5))
    assert time.monotonic() - tic < 30


@pytest.mark.parametrize("field", ["stop_time", "step_size", "max_steps", "tolerance", "rtol"])
def test_a_bool_is_no_number(field):
    with pytest.raises(OptionError) as caught:
        emcosim.RunOptions(**{field: True}, **({"interface_type": "ModelExchange"} if field == "rtol" else {}))
    assert field in caught.value.options


@pytest.mark.parametrize("value", [np.float32(1e-3), np.float16(1e-3), np.float64(1e-3), np.int64(1), 1, 1e-3])
def test_any_real_number_is_a_step(value):
    options = emcosim.RunOptions(step_size=value, stop_time=value)
    assert type(options.step_size) is float and options.step_size == float(value)
    assert type(options.stop_time) is float


def test_numpy_integers_for_integer_fields():
    options = emcosim.RunOptions(coupling_order=np.int32(2), max_steps=np.int64(10))
    assert (options.coupling_order, options.max_steps) == (2, 10)
    assert type(options.coupling_order) is int and type(options.max_steps) is int
    with pytest.raises(OptionError):
        emcosim.RunOptions(coupling_order=np.bool_(True))

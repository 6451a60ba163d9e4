"""Run a scenario in another independent engine: ecos (pip package ecospy, the Easy co-simulation
engine; its native library needs Debian's libtbb12).

ecos reads the packed .ssp archive itself (its own SSP parser and FMI library) and applies an .ssv
parameter set only when it is selected by name at initialization: the archive's sets all carry the
name `ssd.PARAMETER_SET`, which is selected here. Its fixed-step algorithm is, like libcosim's,
Jacobi-style: a direct-feedthrough controller's output reaches the plant one step late (measured:
tests/test_ssp_engines.py). Like libcosim it runs in a child process, so that nothing it leaves
behind at exit can take the caller down.
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path

from .errors import ScenarioError
from .results import Result
from .ssd import PARAMETER_SET, Scenario
from .ssp import pack_ssp


def simulate_ecos(scenario: Scenario, stop_time: float | None = None, step_size: float | None = None,
                  record: list[str] | None = None) -> Result:
    """Run `scenario` (packed into a temporary .ssp with the FMUs it resolved) in ecos with a fixed
    step, recording `record` (default: every output connector) at every communication point
    t0 + n h."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    step_size = scenario.hold_step(step_size, "ecos")
    context = multiprocessing.get_context("spawn")
    try:
        with ProcessPoolExecutor(1, mp_context=context) as pool:
            columns, rows = pool.submit(_simulate_here, scenario, stop_time, step_size, record).result()
    except BrokenProcessPool as exc:
        raise ScenarioError(f"ecos: the process running {scenario.name} died ({exc})") from None
    result = Result(columns)
    result.rows = rows
    return result


def _simulate_here(scenario: Scenario, stop_time, step_size, record) -> tuple[list[str], list[list[float]]]:
    try:
        from ecospy import EcosSimulation
    except ImportError as exc:
        raise ScenarioError(f"ecos is not installed (pip install ecospy): {exc}") from None
    except OSError as exc:                                   # the native library lacks libtbb12
        raise ScenarioError(f"ecos cannot load its library ({exc}); on Debian: apt-get install libtbb12") from None
    t0 = scenario.start_time
    t_stop = scenario.stop_time if stop_time is None else stop_time
    h = scenario.hold_step(step_size, "ecos")
    n_steps = math.ceil((t_stop - t0) / h - 1e-9)
    if record is None:
        record = [f"{c.name}.{k.name}" for c in scenario.components for k in c.connectors if k.kind == "output"]
    names = [f"{comp}::{var}" for comp, _, var in (r.partition(".") for r in record)]
    with tempfile.TemporaryDirectory(prefix="emcosim-ecos-") as tmp:
        archive = pack_ssp(scenario, Path(tmp) / "scenario.ssp")
        try:
            sim = EcosSimulation(ssp_path=str(archive), step_size=h)
            if not sim.init(t0, PARAMETER_SET):
                raise ScenarioError(f"ecos could not initialize {scenario.name}")
            result = Result(record)
            result.append(t0, [sim.get_real(n) for n in names])
            for n in range(1, n_steps + 1):
                sim.step(1)
                result.append(t0 + n * h, [sim.get_real(name) for name in names])
            sim.terminate()
        except ScenarioError:
            raise
        except Exception as exc:                             # ecospy raises bare Exceptions with ecos's message
            raise ScenarioError(f"ecos: {scenario.name}: {' '.join(str(exc).split())}") from None
    return result.columns, result.rows

"""Issue 40 item 6: an interrupt is an interrupt wherever it lands. Two SIGINTs: the first asks the run to
stop (stopping.on_signals), the second lands inside an FMU call, which a Python FMU turns into its own fatal
error. Here the signals are raised at the moment of each FMU's instantiation (a hook on fmi.instantiate, no
timing: it holds on a busy machine), and the run must end as interrupted (exit 130), not as the FMU's
failure (on main: exit 1, "Reference.fmu: component 'reference' could not be instantiated")."""
from __future__ import annotations

import signal

import pytest

from emcosim.cli import main
from emcosim.engine import fmi


@pytest.mark.parametrize("landing", [0, 1])
@pytest.mark.parametrize("interface", ["ModelExchange", "CoSimulation"])
def test_a_second_ctrl_c_during_instantiation_is_an_interrupt(landing, interface, monkeypatch, fmu_dir, tmp_path,
                                                              capsys):
    real = fmi.instantiate
    calls = []

    def instantiate(*args, **kwargs):
        calls.append(1)
        if len(calls) == landing + 1:                   # the (landing+1)-th FMU of the scenario
            signal.raise_signal(signal.SIGINT)          # the first: recorded
            try:
                signal.raise_signal(signal.SIGINT)      # the second: Signalled, inside the FMU's call
            except KeyboardInterrupt as exc:            # as pythonfmu reports it
                raise RuntimeError(f"[fatal] Fatal py exception encountered: [ctor] findClass {exc!r}") from None
        return real(*args, **kwargs)

    monkeypatch.setattr(fmi, "instantiate", instantiate)
    out = tmp_path / "r.csv"
    status = main(["run", "maglev_regulation_prop2", "--interface-type", interface, "--stop-time", "0.01",
                   "--fmu-dir", str(fmu_dir), "--no-progress", "-o", str(out)])
    err = capsys.readouterr().err
    assert len(calls) == landing + 1, calls
    assert status == 130, err
    assert "could not be instantiated" not in err and "Traceback" not in err, err
    assert "interrupted by SIGINT" in err.strip().splitlines()[-1], err
    assert not out.exists(), err

"""Rollback: random sequences of doStep, fmi2GetFMUstate, fmi2SetFMUstate (directly or through
fmi2SerializeFMUstate / fmi2DeSerializeFMUstate) and fmi2FreeFMUstate on every FMU; after every step
and every restore the outputs equal the straight run's at the same step index, bit for bit."""
from __future__ import annotations

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from .harness import ALL, reset_case

pytestmark = pytest.mark.reliability

N_STEPS = 12
OPS = st.lists(st.one_of(st.just(["step"]), st.just(["step"]), st.just(["step"]), st.just(["save"]),
                         st.tuples(st.sampled_from(["restore", "serial", "free"]), st.integers(0, 7)).map(list)),
               min_size=10, max_size=60)


def _case(identifier: str) -> dict:
    case = reset_case(identifier)
    steps = (case["steps"] * 2)[:N_STEPS]
    if identifier in ("MEMS", "Maglev"):                 # inputs that differ at every step
        steps = [{"u": s["u"] * (1 + 0.01 * k)} for k, s in enumerate(steps)]
    return {"h": case["h"], "values": case["values"], "steps": steps}


@pytest.mark.parametrize("identifier", ALL)
def test_restored_run_reproduces_straight_run_bit_for_bit(reliability_fmus, worker, tally, identifier):
    case = _case(identifier)
    path = str(reliability_fmus[identifier])
    totals = {}

    @settings(max_examples=12, deadline=None, derandomize=True, database=None, phases=(Phase.explicit, Phase.generate),
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
    @given(ops=OPS)
    def check(ops):
        ops = ops + [["step"]] * N_STEPS                 # always finish the run
        r = worker.call({"cmd": "rollback", "fmu": path, "ops": ops, **case})
        assert r["ok"], r["reason"]
        for k, v in r["counts"].items():
            totals[k] = totals.get(k, 0) + v
        tally.add("rollback", identifier, "correct")

    check()
    assert totals["restore"] + totals["serial"] > 0 and totals["compared"] > N_STEPS
    tally.measurements["rollback"][identifier] = totals

"""The catalog builds the same objects the FMUs and scenarios name."""
import numpy as np
import pytest

from components import catalog
from components.maglev import Maglev
from components.mems import MEMS, R_e_bar_from_rbar_e
from components.references import Constant, Sinusoid
from components.theorem2 import Theorem2
from components.theorem3 import Theorem3


def test_controllers_by_name_equal_direct_construction():
    eta = np.array([2e-5, 1e-10, 3e-11])
    jet = Constant(q_d=3e-5).jet(0)
    a = catalog.controller("MEMS_Theorem2", {"rbar_e": 50.0, "D_d": -0.4, "a1": 0.5})
    b = Theorem2(MEMS(a1=0.5), R_e_bar_from_rbar_e(50.0), D_d=-0.4)
    assert a.u(eta, jet)[0] == b.u(eta, jet)[0]
    eta = np.array([0.002, 0.01, 1.0])
    jet = Sinusoid(offset=0.0025, amplitude=0.001, omega=5.0).jet(0.3)
    a = catalog.controller("Maglev_Theorem3", {"R_e_bar": 2.82, "k_c": 10.0, "D_d": -0.5})
    b = Theorem3(Maglev(), 2.82, k_c=10.0, D_d=-0.5)
    assert a.u(eta, jet)[0] == b.u(eta, jet)[0]


def test_every_gain_has_unit_and_description():
    for gains in catalog.GAINS.values():
        for p in gains.values():
            assert p.unit and p.description


@pytest.mark.parametrize("name,values,match", [
    ("MEMS_Theorem2", {"rbar_e": -1.0}, "rbar_e"),
    ("MEMS_Proposition1", {"D_d": -1.0}, "D_d"),
    ("Maglev_Theorem3", {"k_c": 0.0}, "k_c"),
    ("Maglev_Theorem3", {"kc": 1.0}, "unknown parameter"),
    ("Maglev_Theorem3", {"c": -1.0}, "\\bc\\b"),
    ("Nope", {}, "unknown controller"),
])
def test_bad_names_and_values_are_refused(name, values, match):
    with pytest.raises(ValueError, match=match):
        catalog.controller(name, values)


def test_reference_by_kind():
    r = catalog.reference(1, {"offset": 0.1, "amplitude": 0.2, "omega": 3.0, "q_d": 7.0, "q_from": 1.0})
    assert r.jet(0.0).q[0] == pytest.approx(0.1)
    assert catalog.reference("constant", {"q_d": 7.0}).jet(5.0).q[0] == 7.0
    with pytest.raises(ValueError, match="kind"):
        catalog.reference(5)

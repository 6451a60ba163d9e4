"""FMU Maglev_Proposition2: set-point regulation of the maglev by Proposition 2, eq. (u2)."""
from .components import maglev
from .em_fmu_controller import ControllerSlave

EQUILIBRIUM = tuple(float(v) for v in maglev.Maglev().equilibrium([0.0025]))


class Maglev_Proposition2(ControllerSlave):
    model_identifier = "Maglev_Proposition2"
    summary = "Proposition 2 (eq. u2) for the magnetic levitation system: u from (q, p, x_e)"
    plant_module = maglev
    input_start = EQUILIBRIUM
    experiment = (0.0, 0.1, 1e-2)

"""FMU Maglev_Theorem3: tracking of the maglev by Theorem 3, eq. (tracker2)."""
from .components import maglev
from .em_fmu_controller import ControllerSlave

EQUILIBRIUM = tuple(float(v) for v in maglev.Maglev().equilibrium([0.0025]))


class Maglev_Theorem3(ControllerSlave):
    model_identifier = "Maglev_Theorem3"
    summary = "Theorem 3 (eq. tracker2) for the magnetic levitation system: u from (q, p, x_e) and the reference jet"
    plant_module = maglev
    input_start = EQUILIBRIUM + (0.0025, 0.0, 0.0, 0.0)
    experiment = (0.0, 0.1, 1e-2)

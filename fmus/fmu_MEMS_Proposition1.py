"""FMU MEMS_Proposition1: set-point regulation of the MEMS switch by Proposition 1, eq. (c1)."""
from .components import mems
from .em_fmu_controller import ControllerSlave


class MEMS_Proposition1(ControllerSlave):
    model_identifier = "MEMS_Proposition1"
    summary = "Proposition 1 (eq. c1) for the MEMS optical switch: u from (q, p, x_e)"
    plant_module = mems
    input_start = (15e-6, 0.0, 0.0)
    experiment = (0.0, 1e-3, 1e-4)

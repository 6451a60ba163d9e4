"""FMU MEMS_Theorem2: tracking (and regulation) of the MEMS switch by Theorem 2, eq. (u1-track)."""
from .components import mems
from .em_fmu_controller import ControllerSlave


class MEMS_Theorem2(ControllerSlave):
    model_identifier = "MEMS_Theorem2"
    summary = "Theorem 2 (eq. u1-track) for the MEMS optical switch: u from (q, p, x_e) and the reference jet"
    plant_module = mems
    input_start = (15e-6, 0.0, 0.0, 3e-5, 0.0, 0.0, 0.0)
    experiment = (0.0, 1e-3, 1e-4)

"""FMU MEMS: the MEMS optical switch of Section 7.1 (components.mems) as a co-simulation plant.

Default experiment: open-loop response to a constant 25 V from the paper's initial state
(q, p, x_e) = (15e-6 m, 0, 0): the electrode is pulled to its static equilibrium and rings
(damping ratio ~0.01).
"""
from .components import mems
from .em_fmu_plant import PlantSlave


class MEMS(PlantSlave):
    model_identifier = "MEMS"
    summary = "MEMS optical switch (paper Section 7.1): input voltage u, outputs q, p, x_e and the energy H"
    plant_module = mems
    initial_state = (15e-6, 0.0, 0.0)
    input_start = 25.0
    experiment = (0.0, 9e-4, 1e-6)          # <= 1000 steps: fmpy keeps the step as output interval

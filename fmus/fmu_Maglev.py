"""FMU Maglev: the magnetic levitation system of Section 7.2 (components.maglev) as a co-simulation plant.

The paper gives no maglev initial state (erratum 7): the default is the equilibrium at q = 0.0025 m
(half way to the magnet at c = 0.005 m), eta = (0.0025, 0, sqrt(2 k b)). Default experiment: the open
loop is unstable; with the coil voltage held at 0 V the flux decays and the ball falls.
"""
from .components import maglev
from .em_fmu_plant import PlantSlave

Q_START = 0.0025


class Maglev(PlantSlave):
    model_identifier = "Maglev"
    summary = "magnetic levitation system (paper Section 7.2): input voltage u, outputs q, p, x_e and the energy H"
    plant_module = maglev
    initial_state = tuple(float(v) for v in maglev.Maglev().equilibrium([Q_START]))
    input_start = 0.0
    experiment = (0.0, 0.5, 1e-3)

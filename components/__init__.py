"""Plant and controller mathematics of "Energy-Based Control Approaches for Weakly Coupled
Electromechanical Systems": port-Hamiltonian plants, feasible references, the four static
controllers and a monolithic closed-loop simulator. Plain Python + numpy; nothing here knows FMI.
"""

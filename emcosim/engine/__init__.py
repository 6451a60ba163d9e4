"""The generic co-simulation engine: SSP scenarios of FMI 2.0 co-simulation FMUs, run by a master on
fmpy. It imports nothing of components/ or of the paper (emcosim.paper is a client of it)."""

"""The paper's layer: its scenarios, the monolithic cross-check, reports, certificates, sweeps and
studies. A client of emcosim.engine (through its public functions) and of components/."""

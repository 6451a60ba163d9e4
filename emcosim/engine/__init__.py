"""The generic engine: SSP scenarios of FMI 2.0 FMUs, run by a co-simulation master on fmpy (master.py) or as
one ODE of the FMUs' states (model_exchange.py). It imports nothing of components/, fmus/ or the paper
(emcosim.paper is a client of it, like any user's program); docs/architecture.md maps its modules."""

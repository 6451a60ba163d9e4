"""emcosim: co-simulation master and command line for the weakly coupled EM controller FMUs."""
__version__ = "0.1.0"

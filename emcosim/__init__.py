"""emcosim: FMI 2.0 components, SSP scenarios and a co-simulation engine for the energy-based controllers of
weakly coupled electromechanical systems.

From Python (the functions are emcosim.api's; the command line `emcosim` is a thin layer over them):

    >>> import emcosim
    >>> result = emcosim.run("maglev_regulation_prop2", emcosim.RunOptions(stop_time=1.0))
    >>> result.to_pandas().attrs["units"]["plant.q"]
    'm'
"""
__version__ = "0.1.0"

from .api import (  # noqa: E402 - after __version__, which the build reads
    Result,
    ResultNotAccepted,
    ResultNotAcceptedWarning,
    RunOptions,
    Scenario,
    build_plant,
    certify,
    check_plant,
    default_record,
    figure,
    find_scenario,
    linearize,
    linearize_fmu,
    load_scenario,
    paper_fmu_dir,
    run,
    scenario_dirs,
    scenario_names,
    settings,
    sweep,
    units_of,
    write_scenario,
)

__all__ = ["__version__", "Result", "ResultNotAccepted", "ResultNotAcceptedWarning",
           "RunOptions", "Scenario", "build_plant", "certify", "check_plant",
           "default_record", "figure", "find_scenario", "linearize", "linearize_fmu", "load_scenario", "paper_fmu_dir",
           "run", "scenario_dirs", "scenario_names", "settings", "sweep", "units_of", "write_scenario"]

"""The emcosim FMUs: pythonfmu slaves that map FMI variables onto components/ objects and back.

Layout (docs/architecture.md):
- slave.py          EMSlave, the base of every slave, and the FMI calls the FMU's binary answers through it;
- variables.py, model_description.py, state.py, derivatives.py, model_exchange.py: its jobs, one a module;
- pythonfmu_workarounds.py: the one module that imports pythonfmu, and what is worked around in it;
- plant.py, controller.py, reference.py: the adapters; models.py: the table of the seven FMUs and the
  slave classes of any other device;
- emcosim_fmu_loader.c: the FMU's binary; build.py: builds FMUs from all of this.

The modules import components/ and pythonfmu by their own names, as in this source tree; inside an FMU they
live in the bundle package `emcosim_fmu_<build tag>` (with copies of components/ and pythonfmu), and the
build rewrites those import roots to the bundle's (build.py, `rewrite_imports`).
"""

BUILD = "source tree"   # the build fingerprint; build.py writes the real one into the FMU's copy of this file

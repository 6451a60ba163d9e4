"""A device module for fmus.build.build_device with n_m = n_e = 1: the paper's maglev (components.maglev and
its designs in components.catalog) under another name, so that its FMUs run the scalar path of the adapters
and can be compared with the suite's Maglev FMUs."""
from __future__ import annotations

import dataclasses

from components.catalog import DEVICES

DEVICE = dataclasses.replace(DEVICES["Maglev"], name="Levitator", description="the paper's maglev, renamed (tests)")

"""emcosim's vendor annotation in an FMU's modelDescription.xml (FMI 2.0, section 2.2.6: <VendorAnnotations>,
one <Tool> per tool, holding one element of the tool's own):

    <VendorAnnotations>
      <Tool name="org.emcosim"><InputDerivatives orderUsed="1"/></Tool>
    </VendorAnnotations>

Works around: FMI 2.0 has no attribute for the input derivative order a Co-Simulation slave uses.
canInterpolateInputs says it takes input derivatives, not up to which order, so a master passes what the
sources give. An FMU that accepts every order and drops those above k (emcosim's controllers: k = 1)
declares orderUsed="k", and the master passes it no order above k (master.Simulation seeds its accepted
orders with it); an FMU without the annotation gets what its sources give, and one that refuses an order is
still found out at the first communication point (master.Simulation._settle_orders). Any FMU may carry it:
the engine reads nothing else of the FMU's models.

orderUsed is an integer >= 0 in decimal digits; a value above the highest order the master passes limits
nothing. An annotation that cannot be read (not an integer, negative, no orderUsed, modelDescription.xml
unreadable here) is ignored with a warning (`result.warnings`): the FMU runs as without it.

A second Tool says which device's model an FMU holds (fmus/model_description.py writes it):

    <Tool name="org.emcosim.device"><Device name="Solenoid" model="<sha256>" role="controller"/></Tool>

A plant declares the device it is, a controller the device it was designed for. The engine compares these
declarations and nothing else (binding.check_devices, binding.model_differences): connected FMUs that declare
different devices are refused, and same-named parameters whose values differ between connected FMUs of one
device are reported. An FMU without the Tool (any other vendor's) is not compared; one whose Tool cannot be
read (an attribute missing or empty) is not compared either, with a warning.
"""
from __future__ import annotations

import re
import zipfile
from pathlib import Path
from typing import NamedTuple
from xml.etree import ElementTree as ET

TOOL = "org.emcosim"                  # the names fmus/model_description.py writes
INPUT_DERIVATIVES = "InputDerivatives"
ORDER_USED = "orderUsed"
DEVICE_TOOL = "org.emcosim.device"
DEVICE = "Device"
MAX_TEXT = 200                        # characters of each attribute of <Device> (they go into messages)
LIMITLESS = 10**6                     # orderUsed above this: as good as no limit (kept an int of bounded size)
_DIGITS = re.compile(r"[0-9]+")


class Device(NamedTuple):
    """The device whose model an FMU declares it holds: its name, the digest of its model, the FMU's role."""

    name: str
    model: str
    role: str

    def shown(self) -> str:
        """For messages: "controller of device 'Solenoid' (model 0123abcd4567)"."""
        return f"{self.role} of device {self.name!r} (model {self.model[:12]})"


def device(fmu: Path) -> tuple[Device | None, str]:
    """(the device `fmu` declares, or None if it declares none; a warning, or '')."""
    where = f"{fmu.name}: <Tool name=\"{DEVICE_TOOL}\"> in modelDescription.xml"
    try:
        tool = _tool(fmu, DEVICE_TOOL)
    except Exception as exc:                  # noqa: BLE001 - whatever the file holds: ignored, said why
        return None, f"{where} not read ({type(exc).__name__}: {_shown(str(exc))}): not compared with the FMUs it is connected to"
    element = None if tool is None else next((e for e in tool if _local(e.tag) == DEVICE), None)
    if element is None:
        return None, ""
    values = [" ".join((element.get(k) or "").split()) for k in ("name", "model", "role")]
    if not all(v and v.isprintable() and len(v) <= MAX_TEXT for v in values):
        return None, (f"{where}: <{DEVICE}> needs name, model and role, each printable text of at most {MAX_TEXT} "
                      "characters: not compared with the FMUs it is connected to")
    return Device(*values), ""


def input_order_used(fmu: Path) -> tuple[int | None, str]:
    """(the input derivative order `fmu` declares it uses, or None if it declares none; a warning, or '')."""
    where = f"{fmu.name}: <Tool name=\"{TOOL}\"> in modelDescription.xml"
    try:
        tool = _tool(fmu, TOOL)
    except Exception as exc:                  # noqa: BLE001 - whatever the file holds: ignored, said why
        return None, f"{where} not read ({type(exc).__name__}: {_shown(str(exc))}): ignored"
    element = None if tool is None else next((e for e in tool if _local(e.tag) == INPUT_DERIVATIVES), None)
    if element is None:
        return None, ""
    text = element.get(ORDER_USED)
    order = _order(text)
    if order is None:
        problem = f"has no {ORDER_USED}" if text is None else f"{ORDER_USED}={_shown(text)} is not an integer >= 0"
        return None, f"{where}: <{INPUT_DERIVATIVES}> {problem}: ignored (every order its sources give is tried)"
    return order, ""


def _tool(fmu: Path, name: str) -> ET.Element | None:
    """The first <Tool name=NAME> of <VendorAnnotations>, or None. The file is read as a stream and
    no further than <ModelVariables> (VendorAnnotations comes before it): fmpy has read the whole file already;
    expat resolves no external entity and limits entity expansion."""
    with zipfile.ZipFile(fmu) as archive, archive.open("modelDescription.xml") as xml:
        path: list[str] = []
        for event, element in ET.iterparse(xml, events=("start", "end")):
            if event == "start":
                path.append(_local(element.tag))
                if path[1:] == ["ModelVariables"]:
                    return None
                continue
            if path[1:] == ["VendorAnnotations", "Tool"] and element.get("name") == name:
                return element
            path.pop()
    return None


def _order(text: str | None) -> int | None:
    """orderUsed as an int (LIMITLESS at most), or None if it is not an integer >= 0 in decimal digits."""
    if text is None or not _DIGITS.fullmatch(text.strip()):
        return None
    digits = text.strip().lstrip("0") or "0"
    return LIMITLESS if len(digits) > 6 else min(int(digits), LIMITLESS)


def _local(tag: str) -> str:
    return tag.rpartition("}")[2]


def _shown(text: str, limit: int = 40) -> str:
    text = " ".join(text.split())
    return repr(text if len(text) <= limit else text[:limit] + "...")

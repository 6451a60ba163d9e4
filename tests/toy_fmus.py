"""Build the C toy FMUs of tests/fixtures/toy_derivatives.c: ToyDynamic (x' = a x + b u, exact for a
polynomial input), ToyStatic (y = k1 u1 + k2 u2) and ToySine (y = A sin(omega t + phi)), each with the
coupling capabilities a test asks for (canInterpolateInputs, maxOutputDerivativeOrder) written into
its modelDescription.xml. One shared library serves all three; the GUID selects the model."""
from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

SOURCE = Path(__file__).parent / "fixtures" / "toy_derivatives.c"

# name, causality, variability, start (None for outputs) per model, in value-reference order
MODELS = {
    "dynamic": [("a", "parameter", "fixed", 0.0), ("b", "parameter", "fixed", 1.0), ("x0", "parameter", "fixed", 1.0),
                ("u", "input", "continuous", 0.0), ("x", "output", "continuous", None),
                ("fail_at", "parameter", "fixed", 1e300), ("input_order", "parameter", "fixed", 3.0),
                ("nan_at", "parameter", "fixed", 1e300)],
    "static": [("k1", "parameter", "fixed", 1.0), ("k2", "parameter", "fixed", 0.0), ("u1", "input", "continuous", 0.0),
               ("u2", "input", "continuous", 0.0), ("y", "output", "continuous", None),
               ("input_order", "parameter", "fixed", 3.0)],
    "sine": [("A", "parameter", "fixed", 1.0), ("omega", "parameter", "fixed", 1.0), ("phi", "parameter", "fixed", 0.0),
             ("y", "output", "continuous", None)],
}
# output -> indices (1-based) of the inputs it depends on in Step Mode ("" for a state or a source)
DEPENDENCIES = {"dynamic": {"x": ""}, "static": {"y": "3 4"}, "sine": {"y": ""}}


def compile_library(dest: Path) -> Path | None:
    """The shared library, or None if gcc is missing."""
    if shutil.which("gcc") is None:
        return None
    import fmpy
    lib = dest / "toy_derivatives.so"
    subprocess.run(["gcc", "-O2", "-Wall", "-Werror", "-shared", "-fPIC", "-I", str(Path(fmpy.__file__).parent / "c-code"),
                    str(SOURCE), "-o", str(lib), "-lm"], check=True, capture_output=True)
    return lib


def model_description(kind: str, identifier: str, interpolate: bool, output_order: int, vendor: str | None = None) -> str:
    """vendor: the content of <VendorAnnotations> (None: no such element)."""
    variables, outputs, initial = [], [], []
    for i, (name, causality, variability, start) in enumerate(MODELS[kind]):
        initial_attr = ' initial="exact"' if causality == "parameter" else (' initial="calculated"' if start is None else "")
        start_attr = f' start="{start!r}"' if start is not None else ""
        variables.append(f'    <ScalarVariable name="{name}" valueReference="{i}" causality="{causality}" '
                         f'variability="{variability}"{initial_attr}><Real{start_attr}/></ScalarVariable>')
        if causality == "output":
            outputs.append(f'      <Unknown index="{i + 1}" dependencies="{DEPENDENCIES[kind][name]}"/>')
            initial.append(f'      <Unknown index="{i + 1}"/>')
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="{identifier}" guid="{{toy-{kind}-{identifier}}}" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{identifier}" canHandleVariableCommunicationStepSize="true"
    canGetAndSetFMUstate="true" canInterpolateInputs="{str(interpolate).lower()}" maxOutputDerivativeOrder="{output_order}"/>
{"" if vendor is None else f"  <VendorAnnotations>{vendor}</VendorAnnotations>{chr(10)}"}  <ModelVariables>
{chr(10).join(variables)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{chr(10).join(outputs)}
    </Outputs>
    <InitialUnknowns>
{chr(10).join(initial)}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def build(dest: Path, library: Path, kind: str, identifier: str, interpolate: bool = True, output_order: int = 3,
          vendor: str | None = None) -> Path:
    """Write dest/<identifier>.fmu: the toy `kind` declaring the given coupling capabilities (and
    <VendorAnnotations> holding `vendor`, if given)."""
    fmu = dest / f"{identifier}.fmu"
    with zipfile.ZipFile(fmu, "w") as z:
        z.writestr("modelDescription.xml", model_description(kind, identifier, interpolate, output_order, vendor))
        z.write(library, f"binaries/linux64/{identifier}.so")
    return fmu

"""Build every emcosim FMU into build/fmus/ and pack every scenario with its FMUs into a
self-contained SSP archive in build/ssp/ (`python build.py [--force] [--dest DIR] [--no-ssp]`).

Each FMU is a pythonfmu 0.7.0 build of one thin script in fmus/ (its module name is unique: all
FMUs loaded in a process share one interpreter), bundling the adapter modules it imports and the
identical components/ package. The archives are repacked with fixed timestamps and order, and the
GUID is derived from the content, so the same sources give byte-identical FMUs. A stamp file records
the fingerprint of all inputs: when nothing changed, nothing is rebuilt.

`python build.py --docs` also regenerates the variable tables of docs/fmus.md from the built
modelDescriptions.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent
FMU_SOURCES = ROOT / "fmus"
COMPONENTS = ROOT / "components"
DEFAULT_DEST = ROOT / "build" / "fmus"
SSP_DEST = ROOT / "build" / "ssp"
SCENARIOS = ROOT / "scenarios"
DOCS = ROOT / "docs" / "fmus.md"
STAMP = ".build-stamp.json"

# model identifier -> (script, adapter module)
FMUS: dict[str, tuple[str, str]] = {
    "MEMS": ("fmu_MEMS.py", "em_fmu_plant.py"),
    "Maglev": ("fmu_Maglev.py", "em_fmu_plant.py"),
    "MEMS_Proposition1": ("fmu_MEMS_Proposition1.py", "em_fmu_controller.py"),
    "MEMS_Theorem2": ("fmu_MEMS_Theorem2.py", "em_fmu_controller.py"),
    "Maglev_Proposition2": ("fmu_Maglev_Proposition2.py", "em_fmu_controller.py"),
    "Maglev_Theorem3": ("fmu_Maglev_Theorem3.py", "em_fmu_controller.py"),
    "Reference": ("fmu_Reference.py", "em_fmu_reference.py"),
}
FRAMEWORK = "em_fmu_framework.py"
OPTIONS = {"canGetAndSetFMUstate": True, "canSerializeFMUstate": True, "canInterpolateInputs": False}


def _sources() -> list[Path]:
    files = [Path(__file__).resolve()] + sorted(FMU_SOURCES.glob("*.py")) + sorted(COMPONENTS.rglob("*.py"))
    return [f for f in files if "__pycache__" not in f.parts]


def fingerprint() -> str:
    """sha256 over every input of the build: sources, pythonfmu (code and binaries), Python version."""
    import pythonfmu

    digest = hashlib.sha256(f"python {sys.version_info[:2]}".encode())
    pythonfmu_dir = Path(pythonfmu.__file__).parent
    inputs = _sources() + sorted(p for p in pythonfmu_dir.rglob("*") if p.is_file() and p.suffix in {".py", ".so", ".dll", ".dylib"}
                                 and "__pycache__" not in p.parts and "tests" not in p.parts)
    for f in inputs:
        digest.update(str(f.relative_to(f.parent.parent)).encode() + b"\0" + f.read_bytes())
    return digest.hexdigest()


def _repack(src: Path, dest: Path) -> None:
    """Rewrite a zip archive with sorted entries, fixed timestamps and permissions (reproducible)."""
    with zipfile.ZipFile(src) as zin:
        entries = sorted((i.filename, zin.read(i.filename)) for i in zin.infolist() if not i.is_dir())
    tmp = dest.with_suffix(".fmu.tmp")
    with zipfile.ZipFile(tmp, "w") as zout:
        for name, data in entries:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if name.startswith("binaries/") else 0o644) << 16
            zout.writestr(info, data)
    tmp.replace(dest)


def _build_one(identifier: str, dest: Path, work: Path) -> Path:
    from pythonfmu import FmuBuilder

    script, adapter = FMUS[identifier]
    project = [FMU_SOURCES / FRAMEWORK, FMU_SOURCES / adapter, COMPONENTS]
    raw = FmuBuilder.build_FMU(FMU_SOURCES / script, dest=work / f"{identifier}.fmu", project_files=project, **OPTIONS)
    target = dest / f"{identifier}.fmu"
    _repack(Path(raw), target)
    return target


def up_to_date(dest: Path | str = DEFAULT_DEST, current: str | None = None) -> bool:
    """True when every FMU in `dest` was built from the current sources (stamp fingerprint and hashes)."""
    dest = Path(dest)
    try:
        stamp = json.loads((dest / STAMP).read_text())
    except (OSError, ValueError):
        return False
    paths = {identifier: dest / f"{identifier}.fmu" for identifier in FMUS}
    return (stamp.get("fingerprint") == (current or fingerprint())
            and all(p.exists() and hashlib.sha256(p.read_bytes()).hexdigest() == stamp.get("fmus", {}).get(i)
                    for i, p in paths.items()))


def build(dest: Path | str = DEFAULT_DEST, force: bool = False, verbose: bool = True) -> dict[str, Path]:
    """Build every FMU into `dest` (skipped when the stamp says the inputs are unchanged).
    Returns model identifier -> FMU path."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    paths = {identifier: dest / f"{identifier}.fmu" for identifier in FMUS}
    stamp_file = dest / STAMP
    current = fingerprint()
    if not force and up_to_date(dest, current):
        if verbose:
            for identifier, path in paths.items():
                print(f"up to date  {path}")
        return paths
    for path in [ROOT, FMU_SOURCES]:                       # the scripts import components and the adapters
        if str(path) not in sys.path:
            sys.path.insert(0, str(path))
    hashes = {}
    with tempfile.TemporaryDirectory(prefix="emcosim_build_") as work:
        for identifier in FMUS:
            path = _build_one(identifier, dest, Path(work))
            hashes[identifier] = hashlib.sha256(path.read_bytes()).hexdigest()
            if verbose:
                print(f"built       {path}  ({path.stat().st_size / 1024:.0f} kB, sha256 {hashes[identifier][:12]})")
    stamp_file.write_text(json.dumps({"fingerprint": current, "fmus": hashes}, indent=1))
    return paths


def pack_scenarios(fmu_dir: Path | str = DEFAULT_DEST, dest: Path | str = SSP_DEST, verbose: bool = True) -> list[Path]:
    """Pack every scenario of scenarios/ with the FMUs of `fmu_dir` into a self-contained SSP archive
    dest/<name>.ssp (SystemStructure.ssd, its .ssv files, the FMUs under resources/), repacked like
    the FMUs so that the same inputs give the same bytes."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from emcosim.engine.ssp import pack_ssp

    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    out = []
    with tempfile.TemporaryDirectory(prefix="emcosim_ssp_") as work:
        for folder in sorted(p for p in SCENARIOS.iterdir() if (p / "SystemStructure.ssd").is_file()):
            raw = pack_ssp(folder, Path(work) / f"{folder.name}.ssp", fmu_dir=fmu_dir)
            target = dest / raw.name
            _repack(raw, target)
            out.append(target)
            if verbose:
                print(f"packed      {target}  ({target.stat().st_size / 1024:.0f} kB)")
    return out


# ---- documentation ------------------------------------------------------------------------------
DOCS_BEGIN = "<!-- BEGIN GENERATED VARIABLES (python build.py --docs) -->"
DOCS_END = "<!-- END GENERATED VARIABLES -->"


def variables_markdown(paths: dict[str, Path]) -> str:
    """One Markdown table per FMU, from its modelDescription.xml."""
    from fmpy import read_model_description

    parts = []
    for identifier, path in paths.items():
        md = read_model_description(str(path))
        deps = {u.variable.name: u.dependencies for u in md.outputs}
        parts.append(f"### {identifier}\n\n{md.description}\n\n"
                     f"Default experiment: {md.defaultExperiment.startTime} s to {md.defaultExperiment.stopTime} s, "
                     f"step {md.defaultExperiment.stepSize} s.\n")
        parts.append("| name | causality | start | unit | description |\n|---|---|---|---|---|")
        for v in md.modelVariables:
            start = v.start if v.start is not None else ""
            extra = ""
            if v.name in deps:
                extra = " (depends on: " + (", ".join(d.name for d in deps[v.name]) or "no input") + ")"
            parts.append(f"| {v.name} | {v.causality} | {start} | {v.unit or ''} | {v.description}{extra} |")
        parts.append("")
    return "\n".join(parts)


def update_docs(paths: dict[str, Path], docs: Path = DOCS) -> None:
    text = docs.read_text()
    head, rest = text.split(DOCS_BEGIN)
    _, tail = rest.split(DOCS_END)
    docs.write_text(f"{head}{DOCS_BEGIN}\n\n{variables_markdown(paths)}\n{DOCS_END}{tail}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dest", default=str(DEFAULT_DEST), help="output folder (default build/fmus)")
    parser.add_argument("--force", action="store_true", help="rebuild even if the inputs are unchanged")
    parser.add_argument("--docs", action="store_true", help="regenerate the variable tables of docs/fmus.md")
    parser.add_argument("--no-ssp", action="store_true", help="do not pack the scenarios into build/ssp/*.ssp")
    args = parser.parse_args(argv)
    paths = build(args.dest, force=args.force)
    if not args.no_ssp:
        pack_scenarios(args.dest)
    if args.docs:
        update_docs(paths)
        print(f"updated     {DOCS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

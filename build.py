"""Build every emcosim FMU into build/fmus/ and pack every scenario with its FMUs into a self-contained SSP
archive in build/ssp/: `python build.py [--force] [--dest DIR] [--no-ssp] [--docs]`.

The build itself is the module fmus/build.py (part of the installed package: `python -m fmus.build`); this
script adds what belongs to this repository: the scenarios' archives and the variable tables of
docs/fmus.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fmus.build import BuildError, build, variables_markdown  # noqa: E402

SSP_DEST = ROOT / "build" / "ssp"
DOCS = ROOT / "docs" / "fmus.md"
DOCS_BEGIN = "<!-- BEGIN GENERATED VARIABLES (python build.py --docs) -->"
DOCS_END = "<!-- END GENERATED VARIABLES -->"


def update_docs(paths: dict[str, Path], docs: Path = DOCS) -> None:
    """Regenerate the variable tables of docs/fmus.md from the built modelDescriptions."""
    text = docs.read_text()
    head, rest = text.split(DOCS_BEGIN)
    _, tail = rest.split(DOCS_END)
    docs.write_text(f"{head}{DOCS_BEGIN}\n\n{variables_markdown(paths)}\n{DOCS_END}{tail}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dest", default=str(ROOT / "build" / "fmus"), help="output folder (default build/fmus)")
    parser.add_argument("--force", action="store_true", help="rebuild even if the inputs are unchanged")
    parser.add_argument("--docs", action="store_true", help="regenerate the variable tables of docs/fmus.md")
    parser.add_argument("--no-ssp", action="store_true", help="do not pack the scenarios into build/ssp/*.ssp")
    parser.add_argument("--native", action="store_true", help="build the native (C) FMUs instead, into "
                        "build/native (or --dest): docs/native-fmus.md")
    args = parser.parse_args(argv)
    if args.native:
        from fmus.native_build import main as native_main
        dest = args.dest if args.dest != str(ROOT / "build" / "fmus") else str(ROOT / "build" / "native")
        return native_main(["--dest", dest])
    try:
        paths = build(args.dest, force=args.force)
    except BuildError as exc:
        print(exc, file=sys.stderr)
        return 2
    if not args.no_ssp:
        from emcosim.paper.scenarios import pack_archives
        pack_archives(args.dest, SSP_DEST)
    if args.docs:
        update_docs(paths)
        print(f"updated     {DOCS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

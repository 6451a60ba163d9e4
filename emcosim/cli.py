"""Command line interface `emcosim`."""
from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    print("emcosim: the co-simulation commands arrive with the scenario issue", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())

"""Archives the engine unpacks (.ssp scenarios, .fmu files), within limits: a "zip bomb" (a small archive
that inflates to gigabytes) and an .ssd that points at files outside its archive are refused."""
from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

from .errors import LimitError, OptionError, ScenarioError


@dataclass
class ArchiveLimits:
    """What an .ssp archive may unpack to. The defaults refuse a "zip bomb" (a small archive that
    inflates to gigabytes) and an .ssd that points at files outside its archive (absolute paths,
    `..`); a caller raises them (options max_bytes, max_files, allow_external)."""

    max_bytes: int = 2 << 30                  # total unpacked size: 2 GiB
    max_files: int = 10_000
    allow_external: bool = False


unpacked: dict[Path, tuple[Path, ArchiveLimits]] = {}    # unpacked folder -> (its .ssp, the limits used)


def extract_archive(archive: Path, target: Path, limits: ArchiveLimits | None = None) -> None:
    """Unpack a zip archive (.ssp, .fmu) into `target`, refusing more than limits.max_files entries
    or limits.max_bytes in total (declared sizes; Python's zipfile stops at the declared size of
    each entry and checks its CRC, so an entry cannot inflate beyond what it declares)."""
    limits = limits or ArchiveLimits()
    try:
        with zipfile.ZipFile(archive) as z:
            entries = z.infolist()
            if len(entries) > limits.max_files:
                raise LimitError("{archive}: archive holds {n} files, more than the limit of {limit} (raise it with "
                                 "{max_files})", "max_files", archive=archive, n=len(entries), limit=limits.max_files)
            size = sum(e.file_size for e in entries)
            if size > limits.max_bytes:
                raise LimitError("{archive}: archive unpacks to {size:.0f} MiB, more than the limit of {limit:.0f} MiB "
                                 "(raise it with {max_bytes})", "max_bytes", archive=archive, size=size / 2**20,
                                 limit=limits.max_bytes / 2**20)
            z.extractall(target)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError) as exc:
        raise ScenarioError(f"{archive}: not a valid zip archive ({exc})") from None
    except OSError as exc:
        raise ScenarioError(f"{archive}: cannot unpack to {target}: {exc.strerror or exc}") from None


def check_inside(ssd: Path, reference: str, what: str) -> None:
    """Refuse a reference of an .ssd unpacked from an .ssp that leaves the archive."""
    root = ssd.parent.resolve()
    if root not in unpacked:
        return
    archive, limits = unpacked[root]
    if limits.allow_external:
        return
    target = (root / reference).resolve()
    if Path(reference).is_absolute() or "://" in reference or not target.is_relative_to(root):
        raise OptionError("{archive}: {what} '{reference}' points outside the archive (allow it with "
                          "{allow_external})", "allow_external", archive=archive, what=what, reference=reference)

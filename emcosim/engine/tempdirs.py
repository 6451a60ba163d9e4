"""Temporary folders of a run (unpacked FMUs, unpacked .ssp archives).

Each is named `emcosim-PID-LABEL-XXXX` in the system's temporary folder and removed when the run
ends. A process killed with kill -9 (or crashed) cannot remove its folders; `clean_stale`, called
when emcosim starts, removes those whose process no longer exists (only the user's own).
"""
from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

PREFIX = "emcosim-"
_NAME = re.compile(r"^emcosim-(\d+)-")


def make(label: str) -> Path:
    """A new temporary folder of this process."""
    safe = re.sub(r"[^A-Za-z0-9_.]+", "_", label)[:40]
    return Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-{safe}-"))


def clean_stale() -> list[Path]:
    """Remove the temporary folders of emcosim processes that no longer run; returns them."""
    removed: list[Path] = []
    try:
        entries = list(Path(tempfile.gettempdir()).iterdir())
    except OSError:
        return removed
    for path in entries:
        match = _NAME.match(path.name)
        if not match or _alive(int(match.group(1))):
            continue
        try:
            if not path.is_dir() or path.is_symlink() or path.stat().st_uid != os.getuid():
                continue
        except OSError:
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True                            # another user's process (or an odd name): leave it
    return True

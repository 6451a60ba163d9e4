"""Temporary folders of a run (unpacked FMUs, unpacked .ssp archives, the work folder of an export).

Each is named `emcosim-PID-LABEL-XXXX` in the system's temporary folder, holds the marker file
`.emcosim-temp`, and is removed when the run ends. A process killed with kill -9 (or crashed) cannot
remove its folders; `clean_stale`, called when emcosim starts, removes those whose process no longer
exists: folders of the user's own (not links) that hold the marker. A folder that only has the name
is left alone.
"""
from __future__ import annotations

import os
import re
import shutil
import stat
import tempfile
from pathlib import Path

PREFIX = "emcosim-"
MARKER = ".emcosim-temp"
_MARK = b"emcosim temporary folder\n"
_NAME = re.compile(r"^emcosim-(\d+)-")


def make(label: str) -> Path:
    """A new temporary folder of this process, marked as emcosim's."""
    safe = re.sub(r"[^A-Za-z0-9_.]+", "_", label)[:40]
    path = Path(tempfile.mkdtemp(prefix=f"{PREFIX}{os.getpid()}-{safe}-"))
    fd = os.open(path / MARKER, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    try:
        os.write(fd, _MARK)
    finally:
        os.close(fd)
    return path


def clean_stale() -> list[Path]:
    """Remove the temporary folders of emcosim processes that no longer run; returns them."""
    removed: list[Path] = []
    try:
        entries = list(Path(tempfile.gettempdir()).iterdir())
    except OSError:
        return removed
    for path in entries:
        match = _NAME.match(path.name)
        if not match or _alive(int(match.group(1))) or not _marked(path):
            continue
        shutil.rmtree(path, ignore_errors=True)
        removed.append(path)
    return removed


def _marked(path: Path) -> bool:
    """A folder of ours (not a link) holding emcosim's marker (a regular file, not a link)."""
    try:
        st = os.lstat(path)
        if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
            return False
        fd = os.open(path / MARKER, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        return stat.S_ISREG(os.fstat(fd).st_mode) and os.read(fd, len(_MARK) + 1) == _MARK
    except OSError:
        return False
    finally:
        os.close(fd)


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

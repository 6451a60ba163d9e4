"""A folder of results (`emcosim reproduce`, `emcosim sweep`) written as a whole: it replaces its
destination only when complete, and only if the destination holds nothing but what an earlier run
wrote (its manifest `.emcosim` lists every file with its size and sha256). The rules are those of
outputs.py.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import shutil
import stat
import time
from pathlib import Path
from typing import Iterator

from .errors import ScenarioError
from .files import create_text, is_own_folder, one_line, open_own, partial_names, rename_noreplace, rmdir, shown, unlink
from .outputs import TIMESTAMP, reason_of, writable


class OutputFolder:
    """A folder of results (figures, tables) that replaces the destination only when complete.

    Files are written into `path` = `NAME.incomplete-PID` beside the destination, whose manifest
    `.emcosim` says so (and holds this run's lock). On success (`commit`) the manifest lists every
    file with its size and sha256 and the folder replaces the destination; the old folder loses
    exactly the files its own manifest lists. On failure (`abandon`) it becomes the first free
    `NAME.partial[-N]` with PARTIAL.txt saying why, and the destination is left as it was.

    The destination is checked first (and again when it is replaced): its parent must be writable,
    and an existing destination must be a writable folder that holds nothing but what its manifest
    lists, unchanged (or nothing at all); anything else is refused, naming what it holds."""

    MARKER = ".emcosim"

    def __init__(self, dest: str | Path):
        self.dest = Path(dest).absolute()
        parent, name = self.dest.parent, self.dest.name
        if not name or Path.cwd().resolve().is_relative_to(self.dest.resolve()):
            raise ScenarioError(f"{dest}: refusing to replace the current folder or one of its parents")
        if not parent.is_dir():
            raise ScenarioError(f"{dest}: folder {parent} does not exist")
        if not writable(parent):
            raise ScenarioError(f"{dest}: folder {parent} is not writable (the results are written beside "
                                "the destination first)")
        _check_replaceable(self.dest)
        self.notes = mark_orphan_folders(self.dest)
        self.path = self._create(parent, name)
        self.started = time.strftime(TIMESTAMP)
        try:
            self.lock = os.open(self.path / self.MARKER, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666)
            fcntl.flock(self.lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            self._write_manifest("incomplete", with_files=False)
        except OSError as exc:
            raise ScenarioError(f"{dest}: cannot create {self.path}: {exc.strerror or exc}") from None
        self.final: Path | None = None

    @staticmethod
    def _create(parent: Path, name: str) -> Path:
        for n in range(100):                              # a killed process with our pid may have left one
            path = parent / (f"{name}.incomplete-{os.getpid()}" + (f"-{n}" if n else ""))
            try:
                path.mkdir()
                return path
            except FileExistsError:
                continue
            except OSError as exc:
                raise ScenarioError(f"{parent / name}: cannot create {path}: {exc.strerror or exc}") from None
        raise ScenarioError(f"{parent / name}: too many {name}.incomplete-{os.getpid()} folders beside it")

    def _write_manifest(self, state: str, with_files: bool = True) -> None:
        """The manifest: this run, and (with_files) every file and folder written, for a later run."""
        manifest: dict = {"emcosim": "output folder", "version": 1, "state": state, "pid": os.getpid(),
                          "started": self.started}
        if with_files:
            files, folders, _ = _inventory(self.path)
            manifest.update(files={rel: {"size": s, "sha256": h} for rel, (s, h) in files.items()}, folders=folders)
        data = json.dumps(manifest, indent=1, sort_keys=True).encode() + b"\n"
        os.ftruncate(self.lock, 0)
        os.pwrite(self.lock, data, 0)
        os.fsync(self.lock)

    def commit(self) -> Path:
        """Replace the destination with the finished folder. A destination that now holds what
        emcosim did not write is left alone: the results go to a partial folder and ScenarioError says so."""
        try:
            self._write_manifest("complete")
        except OSError as exc:
            kept = self.abandon(f"cannot write the manifest: {exc.strerror or exc}")
            raise ScenarioError(f"cannot write {self.dest}: {exc.strerror or exc}; the results are in {kept}") from None
        try:
            old = _set_aside(self.dest)
        except (ScenarioError, OSError) as refused:
            why = str(refused) if isinstance(refused, ScenarioError) else f"{self.dest}: {refused.strerror or refused}"
            kept = self.abandon(f"the results are complete, but {why}")
            raise ScenarioError(f"{why}; the new results are in {kept}") from None
        try:
            if not rename_noreplace(self.path, self.dest):
                raise FileExistsError(errno.EEXIST, "created by someone else meanwhile")
        except OSError as exc:
            if old is not None:
                rename_noreplace(old, self.dest)         # put the old results back
            kept = self.abandon(f"the results are complete, but {self.dest} could not be replaced")
            raise ScenarioError(f"cannot replace {self.dest}: {exc.strerror or exc}; the new results are "
                                f"in {kept}") from None
        os.close(self.lock)
        if old is not None:
            _remove_written(old)
        self.final = self.dest
        return self.dest

    def abandon(self, reason: str) -> Path:
        """Keep what was written in the first free NAME.partial[-N], with PARTIAL.txt saying why."""
        try:
            create_text(self.path / "PARTIAL.txt", f"Partial results: {one_line(reason)}\n(run started "
                         f"{self.started}, pid {os.getpid()}; {self.dest} was left as it was)\n")
        except OSError:
            pass                                          # a full disk: the folder's name still says it
        try:
            self._write_manifest("partial")
        except OSError:
            pass
        self.final = self.path
        try:
            for candidate in partial_names(self.dest, folder=True):
                if rename_noreplace(self.path, candidate):
                    self.final = candidate
                    break
        except OSError:
            pass
        finally:
            os.close(self.lock)
        return self.final

    def discard(self) -> None:
        """Nothing worth keeping was computed (e.g. a specification error): remove the folder (this
        run created it and everything in it)."""
        os.close(self.lock)
        shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self) -> "OutputFolder":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            self.commit()
        else:
            self.abandon(reason_of(exc))


def _check_replaceable(dest: Path, contents: bool = True) -> None:
    """ScenarioError unless `dest` is absent, or a writable folder (not a link) holding nothing but
    what its manifest lists (contents: check that too)."""
    try:
        st = os.lstat(dest)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise ScenarioError(f"{dest}: {exc.strerror or exc}") from None
    if stat.S_ISLNK(st.st_mode):
        raise ScenarioError(f"{dest}: is a symbolic link; emcosim does not replace it: give the folder's own path "
                            "or another name")
    if not stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"{dest}: exists and is not a folder")
    if not writable(dest):
        raise ScenarioError(f"{dest}: folder is read-only (not replaced)")
    foreign = _foreign(dest) if contents else []
    if foreign:
        raise ScenarioError(_refusal(dest, foreign))


def _refusal(dest: Path, foreign: list[str]) -> str:
    names = ", ".join(shown(Path(f)) for f in foreign[:4]) + (f" and {len(foreign) - 4} more" if len(foreign) > 4 else "")
    return (f"{dest}: folder holds files not written by emcosim ({names}); it would be replaced: choose another "
            "folder, or move them out")


def _foreign(folder: Path) -> list[str]:
    """What `folder` holds that its manifest does not list as emcosim wrote it: every entry if it
    has no valid manifest, else every entry not listed, changed or of another kind (sorted)."""
    manifest = _read_manifest(folder)
    if manifest is None:
        try:
            entries = sorted(os.listdir(folder))
        except OSError as exc:
            raise ScenarioError(f"{folder}: {exc.strerror or exc}") from None
        return [e + (" (not a manifest of this emcosim)" if e == OutputFolder.MARKER else "") for e in entries]
    files, folders, others = _inventory(folder, manifest["files"])
    listed_folders = set(manifest["folders"])
    foreign = [f for f in folders if f not in listed_folders] + others
    for rel, (size, digest) in files.items():
        entry = manifest["files"].get(rel)
        if entry is None:
            foreign.append(rel)
        elif entry["size"] != size or entry["sha256"] != digest:
            foreign.append(f"{rel} (changed since emcosim wrote it)")
    return sorted(foreign)


def _read_manifest(folder: Path) -> dict | None:
    """The manifest of a finished (or partial) output folder, checked; None if there is none."""
    fd = open_own(folder / OutputFolder.MARKER, os.O_RDONLY, same_owner=False)
    if fd is None:
        return None
    try:
        manifest = json.loads(os.pread(fd, 64 << 20, 0))
    except (OSError, ValueError):
        return None
    finally:
        os.close(fd)
    ok = (isinstance(manifest, dict) and manifest.get("emcosim") == "output folder" and manifest.get("version") == 1
          and manifest.get("state") in ("complete", "partial") and isinstance(manifest.get("files"), dict)
          and isinstance(manifest.get("folders"), list)
          and all(isinstance(v, dict) and isinstance(v.get("size"), int) and isinstance(v.get("sha256"), str)
                  for v in manifest["files"].values()))
    return manifest if ok else None


def _inventory(root: Path, hash_only: dict | None = None) -> tuple[dict[str, tuple[int, str]], list[str], list[str]]:
    """Every entry under `root` (links not followed), the manifest left out: regular files
    (relative path -> (size, sha256)), folders, and anything else (links, devices...). With
    `hash_only` (a manifest's files), a file not listed there or of another size is not hashed."""
    files: dict[str, tuple[int, str]] = {}
    folders: list[str] = []
    others: list[str] = []
    for rel, entry in _walk(root):
        if rel == OutputFolder.MARKER:
            continue
        if entry.is_dir(follow_symlinks=False):
            folders.append(rel)
        elif entry.is_file(follow_symlinks=False):
            size = entry.stat(follow_symlinks=False).st_size
            listed = None if hash_only is None else hash_only.get(rel)
            skip = hash_only is not None and (listed is None or listed.get("size") != size)
            files[rel] = (size, "" if skip else _sha256(Path(entry.path)))
        else:
            others.append(rel)
    return files, folders, others


def _walk(root: Path, prefix: str = "") -> Iterator[tuple[str, os.DirEntry]]:
    with os.scandir(root) as entries:
        for entry in sorted(entries, key=lambda e: e.name):
            rel = prefix + entry.name
            yield rel, entry
            if entry.is_dir(follow_symlinks=False):
                yield from _walk(Path(entry.path), rel + "/")


def _sha256(path: Path) -> str:
    fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    digest = hashlib.sha256()
    try:
        while chunk := os.read(fd, 1 << 20):
            digest.update(chunk)
    finally:
        os.close(fd)
    return digest.hexdigest()


def _set_aside(dest: Path) -> Path | None:
    """Rename the destination folder to a hidden `.NAME.old-PID` (None if there is none), after
    checking (again, now that the run is over) that it holds only what emcosim wrote; put back and
    ScenarioError otherwise."""
    _check_replaceable(dest, contents=False)
    if not os.path.lexists(dest):
        return None
    for n in range(100):
        old = dest.parent / (f".{dest.name}.old-{os.getpid()}" + (f"-{n}" if n else ""))
        if rename_noreplace(dest, old):
            break
    else:
        raise ScenarioError(f"{dest}: too many {old.name} folders beside it")
    foreign = _foreign(old)                               # nobody adds to it under this name
    if foreign:
        rename_noreplace(old, dest)
        raise ScenarioError(_refusal(dest, foreign))
    return old


def _remove_written(folder: Path) -> None:
    """Delete what emcosim wrote in `folder` (its manifest's files and folders) and the folder if
    that empties it; anything else stays."""
    manifest = _read_manifest(folder)
    if manifest is not None:
        for rel in manifest["files"]:
            try:
                if stat.S_ISREG(os.lstat(folder / rel).st_mode):
                    os.unlink(folder / rel)
            except OSError:
                pass
        for rel in sorted(manifest["folders"], key=lambda r: -r.count("/")):
            rmdir(folder / rel)
        unlink(folder / OutputFolder.MARKER)
    rmdir(folder)


def mark_orphan_folders(dest: Path) -> list[str]:
    """Folders NAME.incomplete-* of killed runs get a PARTIAL.txt: each must be a folder of ours (not
    a link) whose manifest says it is being written and whose lock is free."""
    prefix = f"{dest.name}.incomplete-"
    try:
        names = sorted(n for n in os.listdir(dest.parent) if n.startswith(prefix))
    except OSError:
        return []
    notes = []
    for name in names:
        folder = dest.parent / name
        fd = open_own(folder / OutputFolder.MARKER, os.O_RDWR) if is_own_folder(folder) else None
        if fd is None:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            manifest = json.loads(os.pread(fd, 1 << 16, 0))
            pid = manifest.get("pid") if isinstance(manifest, dict) and manifest.get("state") == "incomplete" else None
            if not isinstance(pid, int) or isinstance(pid, bool):
                continue
            create_text(folder / "PARTIAL.txt", f"Partial results: the run writing this folder (pid {pid}) "
                                                 "ended without a clean exit (killed or crashed)\n")
            notes.append(f"{shown(folder)}: results of an earlier run (pid {pid}) that was killed; marked partial")
        except (OSError, ValueError):
            pass                                          # a run still writing it, marked already, not ours
        finally:
            os.close(fd)
    return notes


__all__ = ["OutputFolder", "mark_orphan_folders"]

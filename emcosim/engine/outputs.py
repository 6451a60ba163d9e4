"""How results reach the disk without losing or faking a result, and without touching what emcosim
did not write.

The rules (issues 15 and 26):
- a destination is checked before a run starts: a missing or read-only folder, a folder given as a
  file, a read-only file, a symbolic link (never written through, never replaced) are refused;
- everything is written into a new file (O_CREAT | O_EXCL | O_NOFOLLOW) beside the destination and
  renamed into place when complete: a reader never sees a half-written file, two runs writing the
  same file each leave a complete one (the last rename wins);
- what a failed or interrupted run computed is kept in `NAME.partial.SUFFIX`, or the first free
  `NAME.partial-N.SUFFIX`: an earlier partial file is never replaced; the destination is left alone;
- a file or folder left by a run that was killed is recognised by the marker emcosim writes inside
  it (and only if it is a regular file of ours, not a link): never by its name. What is written into
  it comes from that marker, never from a file name.

`ResultFile` writes a results CSV row by row: the rows go to `NAME.incomplete-PID.csv`, whose first
line (MARK_BYTES long, padded with spaces) is a comment marking it as emcosim's and partial ("being
written by pid N"). The rows reach the operating system at least every second (and every 256 KiB),
so that kill -9 loses at most the last second. On success the rows after that line are copied into
a new file that is renamed to `NAME.csv`; on an error, Ctrl-C, SIGTERM or a full disk the first line
is overwritten in place with why (no byte is added: a full disk cannot stop it) and the file is
renamed to the first free partial name. A killed run's file keeps its marker line; the next run
writing the same destination finds it unlocked (the kernel releases a killed process's `flock`) and
rewrites the line to say so.

`OutputFolder` does the same for a folder of results (`emcosim reproduce`, `emcosim sweep`): its
manifest `.emcosim` lists every file written, with its size and sha256, and a folder is replaced only
if it holds nothing else (or nothing at all). `write_file` writes one file (a figure, an FMU, a CSV
of rows in memory) by the same rules.
"""
from __future__ import annotations

import csv
import ctypes
import errno
import fcntl
import hashlib
import io
import json
import os
import re
import shutil
import signal
import stat
import time
from pathlib import Path
from typing import BinaryIO, Callable, Iterator

from .errors import ScenarioError, SimulationError

FLUSH_SECONDS = 1.0            # rows reach the operating system at least this often ...
FLUSH_BYTES = 1 << 18          # ... and whenever this much text is buffered (bounds the buffer's memory)
NO_SPACE = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
PARTIAL_MARK = "# emcosim: PARTIAL result"
MARK_BYTES = 1024              # the first line of a results file being written: its marker, then why it is partial
MAX_PARTIALS = 1000            # NAME.partial, NAME.partial-2, ... NAME.partial-1000
TIMESTAMP = "%Y-%m-%d %H:%M:%S"
_BEING_WRITTEN = re.compile(rb"# emcosim: PARTIAL result, being written by pid (\d{1,10}) "
                            rb"\(run started (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d)\)")


def write_file(dest: str | Path, write: Callable[[BinaryIO], None], partial: bool = False) -> Path:
    """Write a file with `write(f)` into a new file beside `dest`, then rename it to `dest` (replacing
    it) or, with `partial`, to the first free NAME.partial[-N].SUFFIX; returns the path written.
    OSError if the file cannot be written (nothing is left behind then)."""
    dest = Path(dest)
    if not partial:
        check_destination(dest)
    fd, temp = _create_beside(dest, "incomplete")
    try:
        with os.fdopen(os.dup(fd), "wb") as f:
            write(f)
        os.fsync(fd)
        placed = _place(temp, dest, partial)
        _fsync_folder(dest.parent)
        return placed
    except BaseException:
        _unlink(temp)
        raise
    finally:
        os.close(fd)


def write_csv(path: str | Path, header: list[str], rows, note: str | None = None) -> None:
    """A CSV of rows (exact numbers, repr), written by `write_file`."""
    path = Path(path)

    def write(f: BinaryIO) -> None:
        text = io.TextIOWrapper(f, encoding="utf-8", newline="")
        if note:
            text.write(f"# {_one_line(note)}\n")
        w = csv.writer(text)
        w.writerow(header)
        w.writerows([[repr(float(v)) for v in row] for row in rows])
        text.flush()
        text.detach()
    try:
        write_file(path, write)
    except OSError as exc:
        raise ScenarioError(f"cannot write {path}: {exc.strerror or exc}") from None


# ---- a results file written while the run goes ---------------------------------------------------

class ResultFile:
    """A results CSV written row by row (see the module docstring). Use as a context manager around
    the run: leaving the block normally puts the file in place, leaving it with an exception keeps
    the rows in a partial file marked with the exception's message.

    After the block: `final` is the file holding the rows (None if no row was computed), `rows`
    and `last_time` say how many reached it and up to which time; `notes` lists files of earlier,
    killed runs that were marked partial when this one started."""

    def __init__(self, path: str | Path, what: str = ""):
        self.path = Path(path)
        self.what = _one_line(what)[:200]       # e.g. the scenario name, for the partial file's comment
        check_destination(self.path)
        self.notes = mark_orphans(self.path)
        self.started = time.strftime(TIMESTAMP)
        try:
            self.fd, self.temp = _create_beside(self.path, "incomplete")
        except OSError as exc:
            raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)   # held while this run lives (see mark_orphans)
        try:
            os.pwrite(self.fd, _fixed_line(f"{PARTIAL_MARK}, being written by pid {os.getpid()} (run started "
                                           f"{self.started}); if this line is still here, that run did not "
                                           "end cleanly"), 0)
        except OSError as exc:
            os.close(self.fd)
            _unlink(self.temp)
            raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.buffer: list[str] = []             # lines not yet written (the first: the header)
        self.header = True                      # the buffer starts with the header line
        self.pending = 0                        # bytes in the buffer
        self.written = MARK_BYTES               # bytes on disk, all complete lines (the marker line first)
        self.rows = 0                           # data rows on disk
        self.last_time: float | None = None     # time of the last row on disk
        self.last_flush = time.monotonic()
        self.final: Path | None = None

    # the sink protocol of Result
    def start(self, columns: list[str]) -> None:
        self.buffer.append(",".join(["time", *columns]) + "\n")

    def write(self, row: list) -> None:
        line = ",".join([repr(float(v)) for v in row]) + "\n"
        self.buffer.append(line)
        self.pending += len(line)
        if self.pending >= FLUSH_BYTES or time.monotonic() - self.last_flush >= FLUSH_SECONDS:
            self.flush()

    def rewind(self) -> None:
        """Drop every row written so far (a run that starts over: the second pass of an
        error-controlled run, engine/stepcontrol.py); the next `start` writes the header again."""
        os.ftruncate(self.fd, MARK_BYTES)
        self.buffer, self.header, self.pending = [], True, 0
        self.written, self.rows, self.last_time = MARK_BYTES, 0, None

    def flush(self) -> None:
        """Hand the buffered rows to the operating system; an OSError (a full disk) keeps the
        complete rows that fit and raises SimulationError."""
        buffer, self.buffer, self.pending = self.buffer, [], 0
        header, self.header = self.header, False
        self.last_flush = time.monotonic()
        if not buffer:
            return
        try:
            self._write("".join(buffer), len(buffer) - header)
        except OSError:
            os.ftruncate(self.fd, self.written)          # no torn line: back to the last complete one
            for i, line in enumerate(buffer):             # save what fits, one row at a time
                try:
                    self._write(line, 0 if header and i == 0 else 1)
                except OSError as exc:
                    os.ftruncate(self.fd, self.written)
                    raise SimulationError(f"cannot write {self.path}: {exc.strerror or exc}") from None

    def _write(self, text: str, rows: int) -> None:
        """Write complete lines (`rows` of them data rows) after what is on disk."""
        data = text.encode()
        view = memoryview(data)
        while view:
            n = os.pwrite(self.fd, view, self.written + len(data) - len(view))
            view = view[n:]
        self.written += len(data)
        if rows:
            self.rows += rows
            self.last_time = float(text[text.rfind("\n", 0, len(text) - 1) + 1:].split(",", 1)[0])

    def commit(self) -> Path:
        """The run succeeded: the rows (without the marker line) go to a new file renamed to the
        destination. SimulationError if that fails (the rows are still in the file being written)."""
        self.flush()
        try:
            out, temp = _create_beside(self.path, "incomplete")
        except OSError as exc:
            raise SimulationError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        try:
            _copy(self.fd, out, MARK_BYTES, self.written - MARK_BYTES)
            os.fsync(out)
            os.replace(temp, self.path)
        except OSError as exc:
            _unlink(temp)
            raise SimulationError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        finally:
            os.close(out)
        _unlink(self.temp)
        _fsync_folder(self.path.parent)
        os.close(self.fd)
        self.fd = -1
        self.final = self.path
        return self.path

    def abandon(self, reason: str) -> Path | None:
        """The run failed or was interrupted: keep its rows in the first free NAME.partial[-N].csv, its
        first line saying why (returns that path), or remove the file if no row was computed."""
        if self.fd < 0:
            return self.final
        try:
            try:
                self.flush()
            except SimulationError:
                pass                                      # a full disk: keep the rows already there
            if self.rows == 0:
                _unlink(self.temp)
                return None
            try:
                os.pwrite(self.fd, self._comment(reason), 0)    # in place: the file does not grow
            except OSError:
                pass                                      # the marker line still says it is partial
            try:
                self.final = _place(self.temp, self.path, partial=True)
            except OSError:
                self.final = self.temp
            return self.final
        finally:
            os.close(self.fd)
            self.fd = -1

    def _comment(self, reason: str) -> bytes:
        what = f" of {self.what}" if self.what else ""
        upto = f"{self.rows} rows up to t = {self.last_time:.9g} s" if self.last_time is not None else "no rows"
        tail = f"; {upto} (run started {self.started}, pid {os.getpid()})"
        return _fixed_line(f"{PARTIAL_MARK}{what}: ", _one_line(reason), tail)

    def __enter__(self) -> "ResultFile":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            try:
                self.commit()
            except SimulationError as failure:            # the last rows did not fit (a full disk)
                self.abandon(reason_of(failure))
                raise
        else:
            self.abandon(reason_of(exc))


def reason_of(exc: BaseException) -> str:
    """Why a run ended early, in one line (for a partial file's comment)."""
    if isinstance(exc, KeyboardInterrupt):            # Ctrl-C, or stopping.Signalled (a second signal)
        return f"interrupted by {signal.Signals(getattr(exc, 'signal', signal.SIGINT)).name}"
    if isinstance(exc, ScenarioError):
        return _one_line(str(exc))
    return _one_line(f"{type(exc).__name__}: {exc}")


def check_destination(path: Path) -> None:
    """A ScenarioError unless a file can be written at `path` (checked before a run starts): its
    folder exists and is writable, and `path` is absent or a writable regular file (not a link)."""
    folder = path.parent
    try:
        st: os.stat_result | None = os.lstat(path)
    except OSError:
        st = None
    if st is not None and stat.S_ISLNK(st.st_mode):
        raise ScenarioError(f"{path}: is a symbolic link; emcosim neither writes through a link nor replaces "
                            "it: give the file's own path or another name")
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise ScenarioError(f"{path}: is a folder; give a file's name")
    if not folder.is_dir():
        raise ScenarioError(f"{path}: folder {folder} does not exist")
    if not _writable(folder):
        raise ScenarioError(f"{path}: folder {folder} is not writable")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{path}: exists and is not a regular file (not replaced)")
    if st is not None and not _writable(path):
        raise ScenarioError(f"{path}: exists and is read-only (not replaced)")


def _writable(path: Path) -> bool:
    """Writable by us, and not made read-only by its owner (no write bit at all: refused even for
    root, who may write anywhere)."""
    try:
        return os.access(path, os.W_OK) and bool(path.stat().st_mode & 0o222)
    except OSError:
        return False


def mark_orphans(path: Path) -> list[str]:
    """Mark the files of killed runs that wrote to `path`: among the NAME.incomplete-*.SUFFIX beside
    it, the regular files of ours whose first line is emcosim's marker of a file being written and
    whose lock is free (the kernel releases a killed process's locks). Returns a note per file."""
    head = _sibling(path, "incomplete-").name
    head, tail = head[:len(head) - len(path.suffix)], path.suffix
    try:
        names = sorted(os.listdir(path.parent))
    except OSError:
        return []
    notes = []
    for name in names:
        if name.startswith(head) and name.endswith(tail) and len(name) > len(head) + len(tail):
            note = _mark_orphan(path.parent / name)
            if note:
                notes.append(note)
    return notes


def _mark_orphan(path: Path) -> str | None:
    """Rewrite the marker line of a killed run's file (see mark_orphans) to say so; a note, or None
    if the file is not one (then it is not written)."""
    fd = _open_own(path, os.O_RDWR)
    if fd is None:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        first = os.pread(fd, MARK_BYTES, 0)
        found = _BEING_WRITTEN.match(first)
        if found is None or len(first) != MARK_BYTES or not first.endswith(b"\n"):
            return None
        pid, started = found.group(1).decode(), found.group(2).decode()   # digits and a timestamp only
        end = _last_newline(fd)                           # a torn last line is left out
        os.ftruncate(fd, end)
        rows = max(_count_lines(fd, MARK_BYTES, end) - 1, 0)
        t = _last_time(fd, end)
        run = f"the run writing this file (pid {pid}, started {started})"
        what = (f"{run} ended without a clean exit (killed or crashed); {rows} rows up to t = {t:.9g} s, its last flush"
                if rows and t is not None else f"{run} ended without a clean exit before its first row")
        os.pwrite(fd, _fixed_line(f"{PARTIAL_MARK}: {what}"), 0)
        return f"{_shown(path)}: rows of an earlier run (pid {pid}) that was killed; marked partial"
    except OSError:
        return None                                       # a run still writing it (locked), or unreadable
    finally:
        os.close(fd)


# ---- a folder of results written as a whole ------------------------------------------------------

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
        if not _writable(parent):
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
            if not _rename_noreplace(self.path, self.dest):
                raise FileExistsError(errno.EEXIST, "created by someone else meanwhile")
        except OSError as exc:
            if old is not None:
                _rename_noreplace(old, self.dest)         # put the old results back
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
            _create_text(self.path / "PARTIAL.txt", f"Partial results: {_one_line(reason)}\n(run started "
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
                if _rename_noreplace(self.path, candidate):
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
    if not _writable(dest):
        raise ScenarioError(f"{dest}: folder is read-only (not replaced)")
    foreign = _foreign(dest) if contents else []
    if foreign:
        raise ScenarioError(_refusal(dest, foreign))


def _refusal(dest: Path, foreign: list[str]) -> str:
    shown = ", ".join(_shown(Path(f)) for f in foreign[:4]) + (f" and {len(foreign) - 4} more" if len(foreign) > 4 else "")
    return (f"{dest}: folder holds files not written by emcosim ({shown}); it would be replaced: choose another "
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
    fd = _open_own(folder / OutputFolder.MARKER, os.O_RDONLY, same_owner=False)
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
        if _rename_noreplace(dest, old):
            break
    else:
        raise ScenarioError(f"{dest}: too many {old.name} folders beside it")
    foreign = _foreign(old)                               # nobody adds to it under this name
    if foreign:
        _rename_noreplace(old, dest)
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
            _rmdir(folder / rel)
        _unlink(folder / OutputFolder.MARKER)
    _rmdir(folder)


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
        fd = _open_own(folder / OutputFolder.MARKER, os.O_RDWR) if _is_own_folder(folder) else None
        if fd is None:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            manifest = json.loads(os.pread(fd, 1 << 16, 0))
            pid = manifest.get("pid") if isinstance(manifest, dict) and manifest.get("state") == "incomplete" else None
            if not isinstance(pid, int) or isinstance(pid, bool):
                continue
            _create_text(folder / "PARTIAL.txt", f"Partial results: the run writing this folder (pid {pid}) "
                                                 "ended without a clean exit (killed or crashed)\n")
            notes.append(f"{_shown(folder)}: results of an earlier run (pid {pid}) that was killed; marked partial")
        except (OSError, ValueError):
            pass                                          # a run still writing it, marked already, not ours
        finally:
            os.close(fd)
    return notes


# ---- helpers --------------------------------------------------------------------------------------

def partial_names(dest: Path, folder: bool = False) -> Iterator[Path]:
    """Where a partial result of `dest` may go, in order: NAME.partial.SUFFIX, NAME.partial-2.SUFFIX, ...
    (a folder: NAME.partial, NAME.partial-2, ...)."""
    for n in range(1, MAX_PARTIALS + 1):
        tag = "partial" if n == 1 else f"partial-{n}"
        yield dest.with_name(f"{dest.name}.{tag}") if folder else _sibling(dest, tag)


def _place(temp: Path, dest: Path, partial: bool) -> Path:
    """Rename our file `temp` to `dest` (replacing it) or to the first free partial name."""
    if not partial:
        os.replace(temp, dest)
        return dest
    for candidate in partial_names(dest):
        if _rename_noreplace(temp, candidate):
            return candidate
    raise FileExistsError(errno.EEXIST, f"{MAX_PARTIALS} partial files of {dest.name} exist already")


def _create_beside(dest: Path, tag: str) -> tuple[int, Path]:
    """A new file NAME.TAG-PID[-N].SUFFIX beside `dest`, created by this call (O_EXCL, no link
    followed) and open for reading and writing."""
    for n in range(100):                                  # a killed process with our pid may have left one
        temp = _sibling(dest, f"{tag}-{os.getpid()}" + (f"-{n}" if n else ""))
        try:
            flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
            return os.open(temp, flags, 0o666), temp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, f"too many {temp.name} files beside {dest}")


def _create_text(path: Path, text: str) -> None:
    """Write a new file (never an existing one, never through a link)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    try:
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def _open_own(path: Path, flags: int, same_owner: bool = True) -> int | None:
    """`path` opened (no link followed) if it is a regular file with one link (owned by us unless
    same_owner is False), else None."""
    try:
        st = os.lstat(path)
        if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1 or (same_owner and st.st_uid != os.geteuid()):
            return None
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    opened = os.fstat(fd)
    if (opened.st_dev, opened.st_ino) != (st.st_dev, st.st_ino):
        os.close(fd)                                      # swapped meanwhile
        return None
    return fd


def _is_own_folder(path: Path) -> bool:
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.geteuid()


_RENAME_NOREPLACE = 1
_AT_FDCWD = -100
try:
    _renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
except (AttributeError, OSError):                         # not Linux with glibc >= 2.28
    _renameat2 = None


def _rename_noreplace(src: Path, dst: Path) -> bool:
    """Rename `src` to `dst` unless `dst` exists (then False): renameat2(RENAME_NOREPLACE) where the
    system has it, else a hard link (files) or a check just before the rename (folders)."""
    if _renameat2 is not None:
        if _renameat2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), _RENAME_NOREPLACE) == 0:
            return True
        err = ctypes.get_errno()
        if err == errno.EEXIST:
            return False
        if err not in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP):
            raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        return False
    if not stat.S_ISDIR(os.lstat(src).st_mode):
        try:
            os.link(src, dst, follow_symlinks=False)
            os.unlink(src)
            return True
        except FileExistsError:
            return False
        except OSError:
            pass                                          # no hard links on this file system
    os.rename(src, dst)
    return True


def _copy(src: int, dst: int, offset: int, length: int) -> None:
    """Copy `length` bytes of file `src` from `offset` to the start of file `dst`."""
    done = 0
    try:
        while done < length:
            n = os.copy_file_range(src, dst, length - done, offset + done, done)
            if n == 0:
                break
            done += n
    except OSError as exc:
        if exc.errno not in (errno.EXDEV, errno.ENOSYS, errno.EOPNOTSUPP, errno.EINVAL):
            raise
    while done < length:                                  # no copy_file_range here
        data = os.pread(src, min(1 << 20, length - done), offset + done)
        if not data:
            break
        view = memoryview(data)
        while view:
            n = os.pwrite(dst, view, done)
            view = view[n:]
            done += n
    if done < length:
        raise OSError(errno.EIO, f"copied {done} of {length} bytes")


def _fixed_line(head: str, middle: str = "", tail: str = "") -> bytes:
    """A comment line of exactly MARK_BYTES bytes (padded with spaces): head + middle + tail (each
    without a newline), the middle cut (with "...") if the three do not fit."""
    head_b, middle_b, tail_b = (part.replace("\n", " ").encode() for part in (head, middle, tail))
    room = MARK_BYTES - 1 - len(head_b) - len(tail_b)
    if len(middle_b) > room:
        middle_b = middle_b[:max(room - 3, 0)].decode("utf-8", "ignore").encode() + b"..."[:max(room, 0)]
    line = (head_b + middle_b + tail_b)[:MARK_BYTES - 1]
    return line.decode("utf-8", "ignore").encode().ljust(MARK_BYTES - 1) + b"\n"


def _sibling(path: Path, tag: str) -> Path:
    """x.csv -> x.TAG.csv (x -> x.TAG without a suffix), in the same folder."""
    return path.with_name(f"{path.stem}.{tag}{path.suffix}" if path.suffix else f"{path.name}.{tag}")


def _one_line(text: str) -> str:
    """`text` on one line: every run of white space (newlines too) as one space."""
    return " ".join(str(text).split())


def _shown(path: Path) -> str:
    """A path for a message: as it is if printable, else quoted with escapes (a name may hold newlines)."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _rmdir(path: Path) -> None:
    try:
        os.rmdir(path)
    except OSError:
        pass


def _fsync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass                                              # not every file system syncs folders
    finally:
        os.close(fd)


def _last_newline(fd: int) -> int:
    """Length of the file up to and including its last newline (a torn last line is left out)."""
    size = os.fstat(fd).st_size
    pos = size
    while pos > 0:
        start = max(0, pos - 65536)
        i = os.pread(fd, pos - start, start).rfind(b"\n")
        if i >= 0:
            return start + i + 1
        pos = start
    return 0


def _count_lines(fd: int, start: int, end: int) -> int:
    n, pos = 0, start
    while pos < end:
        data = os.pread(fd, min(1 << 20, end - pos), pos)
        if not data:
            break
        n += data.count(b"\n")
        pos += len(data)
    return n


def _last_time(fd: int, end: int | None = None) -> float | None:
    """The time (first field) of the last complete row before `end` (default: the whole file)."""
    end = os.fstat(fd).st_size if end is None else end
    tail = os.pread(fd, min(end, 65536), max(0, end - 65536))
    lines = [x for x in tail.split(b"\n") if x and not x.startswith(b"#")]
    try:
        return float(lines[-1].split(b",")[0]) if lines else None
    except ValueError:
        return None                                       # only the header is left


__all__ = ["MARK_BYTES", "OutputFolder", "PARTIAL_MARK", "ResultFile", "check_destination", "mark_orphans",
           "partial_names", "reason_of", "write_csv", "write_file"]

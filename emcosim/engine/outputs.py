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

A results CSV that emcosim puts in place (`NAME.csv`, `NAME.partial[-N].csv`) starts with its header,
`time` first, and holds nothing but rows (issue 41): pandas.read_csv, fmpy.util.read_csv and
numpy.genfromtxt(names=True) read it as it is. What a run says beside its rows (the estimate, notes, why it
is partial, units, the scenario, options, versions) is in its sidecar `NAME.json` (`sidecar_of`), written
by the same rules and only over a sidecar of ours (`check_sidecar`).

`ResultFile` writes a results CSV row by row: the rows go to `NAME.incomplete-PID.csv`, whose first
line (MARK_BYTES long, padded with spaces) is a comment marking it as emcosim's and partial ("being
written by pid N"). The rows reach the operating system at least every second (and every 256 KiB),
so that kill -9 loses at most the last second. On success the rows after that line are copied into
a new file that is renamed to `NAME.csv`, its sidecar beside it; on an error, Ctrl-C or SIGTERM they are
copied likewise to the first free partial name, its sidecar saying why. Where that copy cannot be
written (a full disk), the first line is overwritten in place with why (no byte is added: a full disk
cannot stop it) and the file is renamed to the partial name as it is: the one results file that keeps a
comment line, so that no row is lost. A killed run's file keeps its marker line; the next run
writing the same destination finds it unlocked (the kernel releases a killed process's `flock`) and
rewrites the line to say so.

`output_folder.OutputFolder` does the same for a folder of results (`emcosim reproduce`, `emcosim
sweep`): its manifest `.emcosim` lists every file written, with its size and sha256, and a folder is
replaced only if it holds nothing else (or nothing at all). The file operations both rely on (create
beside, rename without replacing, partial names, marker lines) are in files.py. `write_file` writes
one file (a figure, an FMU, a CSV of rows in memory) by the same rules.
"""
from __future__ import annotations

import csv
import errno
import fcntl
import io
import json
import math
import os
import re
import signal
import stat
import time
from pathlib import Path
from typing import BinaryIO, Callable, Sequence

from .errors import ScenarioError, SimulationError
from .files import (
    MARK_BYTES,
    PARTIAL_MARK,
    copy,
    count_lines,
    create_beside,
    fixed_line,
    fsync_folder,
    last_newline,
    last_time,
    one_line,
    open_own,
    partial_names,
    place,
    rename_noreplace,
    shown,
    sibling,
    unlink,
)

FLUSH_SECONDS = 1.0            # rows reach the operating system at least this often ...
FLUSH_BYTES = 1 << 18          # ... and whenever this much text is buffered (bounds the buffer's memory)
NO_SPACE = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
TIMESTAMP = "%Y-%m-%d %H:%M:%S"
_BEING_WRITTEN = re.compile(rb"# emcosim: PARTIAL result, being written by pid (\d{1,10}) "
                            rb"\(run started (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d)\)")




def write_file(dest: str | Path, write: Callable[[BinaryIO], object], partial: bool = False) -> Path:
    """Write a file with `write(f)` into a new file beside `dest`, then rename it to `dest` (replacing
    it) or, with `partial`, to the first free NAME.partial[-N].SUFFIX; returns the path written.
    OSError if the file cannot be written (nothing is left behind then)."""
    dest = Path(dest)
    if not partial:
        check_destination(dest)
    fd, temp = create_beside(dest, "incomplete")
    try:
        with os.fdopen(os.dup(fd), "wb") as f:
            write(f)
        os.fsync(fd)
        placed = place(temp, dest, partial)
        fsync_folder(dest.parent)
        return placed
    except BaseException:
        unlink(temp)
        raise
    finally:
        os.close(fd)


def write_csv(path: str | Path, header: list[str], rows, why: str | None = None, meta: dict | None = None) -> None:
    """A CSV of rows (exact numbers, repr), its header first, written by `write_file`, and its sidecar (what
    `meta` says, `sidecar`); `why` a partial result's reason (the file is then named as the caller says:
    NAME.partial.csv, NAME.csv of an interrupted folder)."""
    path = Path(path)
    check_sidecar(path)
    rows = [list(r) for r in rows]

    def write(f: BinaryIO) -> None:
        text = io.TextIOWrapper(f, encoding="utf-8", newline="")
        text.write(header_line(header))
        csv.writer(text).writerows([[repr(float(v)) for v in row] for row in rows])
        text.flush()
        text.detach()
    data = sidecar(path, header[1:], "partial" if why else "complete", why, len(rows),
                   float(rows[-1][0]) if rows else None, meta)
    try:
        write_file(sidecar_of(path), lambda f: f.write(data))
        write_file(path, write)
    except OSError as exc:
        raise ScenarioError(f"cannot write {path}: {exc.strerror or exc}") from None


def header_line(header: Sequence[str]) -> str:
    """The first line of a results CSV: the columns' names (quoted by the csv module only where a name holds a
    comma or a quote)."""
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerow(list(header))
    return text.getvalue()


# ---- the sidecar: what a results file says beside its rows ----------------------------------------

SIDECAR_KIND = "results sidecar"


def sidecar_of(path: str | Path) -> Path:
    """The sidecar of a results file: NAME.json beside NAME.csv (NAME.json.json beside a file NAME.json)."""
    path = Path(path)
    return path.with_name(path.name + ".json") if path.suffix == ".json" else path.with_suffix(".json")


def sidecar(path: Path, columns: Sequence[str], status: str, why: str | None, rows: int, last_time: float | None,
            meta: dict | None = None, **extra) -> bytes:
    """The sidecar's JSON (strict: no NaN or Infinity; numbers that are not finite as null): what it belongs to
    (`csv`, `status` "complete" or "partial", `why` partial, `rows`, `last_time` [s], `columns`), then `meta`
    (the run's own: scenario, options, units, notes, warnings, coupling_error, verdict, versions: see
    emcosim.api.run) and `extra`."""
    data = {"emcosim": SIDECAR_KIND, "version": 1, "csv": path.name, "status": status, "partial": status != "complete",
            "why": why, "rows": rows, "last_time": last_time, "columns": ["time", *columns], **(meta or {}), **extra}
    return (json.dumps(_strict(data), indent=1, allow_nan=False, default=str) + "\n").encode()


def _strict(x):
    if isinstance(x, dict):
        return {str(k): _strict(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_strict(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def read_sidecar(path: str | Path) -> dict | None:
    """The sidecar of the results file `path` (None if it has none of ours)."""
    fd = open_own(sidecar_of(path), os.O_RDONLY, same_owner=False)
    if fd is None:
        return None
    try:
        with os.fdopen(fd, "rb") as f:
            data = json.loads(f.read(1 << 24))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("emcosim") == SIDECAR_KIND else None


def check_sidecar(path: Path) -> None:
    """A ScenarioError unless the sidecar of `path` can be written: absent, or a sidecar of ours (a file of
    the user's named NAME.json is never replaced)."""
    side = sidecar_of(path)
    check_destination(side)
    if os.path.lexists(side) and read_sidecar(path) is None:
        raise ScenarioError(f"{shown(side)}: exists and is not emcosim's sidecar of {path.name} (not replaced); "
                            "the results of a run are NAME.csv and NAME.json: give another name")


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
        self.what = one_line(what)[:200]       # e.g. the scenario name, for the partial file's comment
        check_destination(self.path)
        check_sidecar(self.path)
        self.notes = mark_orphans(self.path)
        self.started = time.strftime(TIMESTAMP)
        try:
            self.fd, self.temp = create_beside(self.path, "incomplete")
        except OSError as exc:
            raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)   # held while this run lives (see mark_orphans)
        try:
            os.pwrite(self.fd, fixed_line(f"{PARTIAL_MARK}, being written by pid {os.getpid()} (run started "
                                           f"{self.started}); if this line is still here, that run did not "
                                           "end cleanly"), 0)
        except OSError as exc:
            os.close(self.fd)
            unlink(self.temp)
            raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        self.buffer: list[str] = []             # lines not yet written (the first: the header)
        self.header = True                      # the buffer starts with the header line
        self.pending = 0                        # bytes in the buffer
        self.written = MARK_BYTES               # bytes on disk, all complete lines (the marker line first)
        self.rows = 0                           # data rows on disk
        self.last_time: float | None = None     # time of the last row on disk
        self.last_flush = time.monotonic()
        self.final: Path | None = None
        self.columns: list[str] = []
        self.meta: dict = {}                    # what the run says beside its rows, for the sidecar (emcosim.api.run)

    # the sink protocol of Result
    def start(self, columns: list[str], notes: Sequence[str] = ()) -> None:
        """The header, the columns' names (one buffered item); the notes of the run go to the sidecar."""
        self.columns = list(columns)
        self.meta.setdefault("notes", list(notes))
        self.buffer.append(header_line(["time", *columns]))

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
            out, temp = create_beside(self.path, "incomplete")
        except OSError as exc:
            raise SimulationError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        try:
            copy(self.fd, out, MARK_BYTES, self.written - MARK_BYTES)
            os.fsync(out)
            write_file(sidecar_of(self.path), lambda f: f.write(self._sidecar("complete", None, self.path)))
            os.replace(temp, self.path)
        except OSError as exc:
            unlink(temp)
            raise SimulationError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        finally:
            os.close(out)
        unlink(self.temp)
        fsync_folder(self.path.parent)
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
                unlink(self.temp)
                return None
            try:
                self.final = self._keep(reason)           # the rows, header first, and the sidecar
                unlink(self.temp)
                return self.final
            except OSError:
                pass                                      # a full disk: keep the rows where they are
            try:
                os.pwrite(self.fd, self._comment(reason), 0)    # in place: the file does not grow
            except OSError:
                pass                                      # the marker line still says it is partial
            try:
                self.final = place(self.temp, self.path, partial=True)
            except OSError:
                self.final = self.temp
            return self.final
        finally:
            os.close(self.fd)
            self.fd = -1

    def _sidecar(self, status: str, why: str | None, csv_path: Path) -> bytes:
        return sidecar(csv_path, self.columns, status, why, self.rows, self.last_time, self.meta,
                       of=self.what or None,
                       run={"pid": os.getpid(), "started": self.started, "ended": time.strftime(TIMESTAMP)})

    def _keep(self, reason: str) -> Path:
        """The rows copied (after the marker line) into NAME.partial[-N].csv, the first free name whose
        sidecar name is free too, and that sidecar saying why; OSError if they cannot be written."""
        out, temp = create_beside(self.path, "incomplete")
        try:
            copy(self.fd, out, MARK_BYTES, self.written - MARK_BYTES)
            os.fsync(out)
            for candidate in partial_names(self.path):
                if os.path.lexists(sidecar_of(candidate)):
                    continue
                side, side_temp = create_beside(sidecar_of(candidate), "incomplete")
                try:
                    os.write(side, self._sidecar("partial", one_line(reason), candidate))
                    os.fsync(side)
                finally:
                    os.close(side)
                if not rename_noreplace(side_temp, sidecar_of(candidate)):
                    unlink(side_temp)
                    continue
                if rename_noreplace(temp, candidate):
                    fsync_folder(self.path.parent)
                    return candidate
                unlink(sidecar_of(candidate))             # ours, just made: the CSV's name was taken meanwhile
            raise FileExistsError(errno.EEXIST, f"no free partial name for {self.path.name}")
        except BaseException:
            unlink(temp)
            raise
        finally:
            os.close(out)

    def _comment(self, reason: str) -> bytes:
        what = f" of {self.what}" if self.what else ""
        upto = f"{self.rows} rows up to t = {self.last_time:.9g} s" if self.last_time is not None else "no rows"
        tail = f"; {upto} (run started {self.started}, pid {os.getpid()})"
        return fixed_line(f"{PARTIAL_MARK}{what}: ", one_line(reason), tail)

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
        return one_line(str(exc))
    return one_line(f"{type(exc).__name__}: {exc}")


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
    if not writable(folder):
        raise ScenarioError(f"{path}: folder {folder} is not writable")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{path}: exists and is not a regular file (not replaced)")
    if st is not None and not writable(path):
        raise ScenarioError(f"{path}: exists and is read-only (not replaced)")


def writable(path: Path) -> bool:
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
    head = sibling(path, "incomplete-").name
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
    fd = open_own(path, os.O_RDWR)
    if fd is None:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        first = os.pread(fd, MARK_BYTES, 0)
        found = _BEING_WRITTEN.match(first)
        if found is None or len(first) != MARK_BYTES or not first.endswith(b"\n"):
            return None
        pid, started = found.group(1).decode(), found.group(2).decode()   # digits and a timestamp only
        end = last_newline(fd)                           # a torn last line is left out
        os.ftruncate(fd, end)
        rows = max(count_lines(fd, MARK_BYTES, end) - 1, 0)
        t = last_time(fd, end)
        run = f"the run writing this file (pid {pid}, started {started})"
        what = (f"{run} ended without a clean exit (killed or crashed); {rows} rows up to t = {t:.9g} s, its last flush"
                if rows and t is not None else f"{run} ended without a clean exit before its first row")
        os.pwrite(fd, fixed_line(f"{PARTIAL_MARK}: {what}"), 0)
        return f"{shown(path)}: rows of an earlier run (pid {pid}) that was killed; marked partial"
    except OSError:
        return None                                       # a run still writing it (locked), or unreadable
    finally:
        os.close(fd)


__all__ = ["MARK_BYTES", "PARTIAL_MARK", "ResultFile", "check_destination", "check_sidecar", "header_line",
           "mark_orphans", "partial_names", "read_sidecar", "reason_of", "sidecar", "sidecar_of", "writable",
           "write_csv", "write_file"]

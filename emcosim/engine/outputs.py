"""How results reach the disk without ever losing or faking a result.

`ResultFile` writes a results CSV safely:
- the destination is checked when it is opened, i.e. before the run starts (missing or read-only
  folder, a folder given as the file);
- rows go to `NAME.incomplete-PID.csv` in the destination's folder, flushed to the operating system
  at least every second (and every 256 KiB), so that `kill -9` loses at most the last second;
- on success that file is renamed to `NAME.csv` (atomic: two runs writing the same file at once each
  leave a complete file, the last one wins; a reader never sees a half-written file);
- on an error, Ctrl-C, SIGTERM or a full disk it becomes `NAME.partial.csv`, whose first line is a
  comment saying it is partial, why, and up to which time; an existing `NAME.csv` is left alone;
- a file left by a run that was killed (`NAME.incomplete-PID.csv`, its lock released by the kernel)
  gets the same comment line when the next run writes to the same destination.

`OutputFolder` does the same for a folder of results (`emcosim reproduce`, `emcosim sweep`).
"""
from __future__ import annotations

import csv
import errno
import fcntl
import glob
import os
import shutil
import signal
import time
from pathlib import Path

from .errors import ScenarioError, SimulationError

FLUSH_SECONDS = 1.0            # rows reach the operating system at least this often ...
FLUSH_BYTES = 1 << 18          # ... and whenever this much text is buffered (bounds the buffer's memory)
NO_SPACE = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)
PARTIAL_MARK = "# emcosim: PARTIAL result"


def write_csv(path: str | Path, header: list[str], rows, note: str | None = None) -> None:
    """A CSV of rows (exact numbers, repr), written to a temporary file and renamed into place."""
    path = Path(path)
    check_destination(path)
    temp = _sibling(path, f"incomplete-{os.getpid()}")
    try:
        with open(temp, "w", newline="") as f:
            if note:
                f.write(f"# {_one_line(note)}\n")
            w = csv.writer(f)
            w.writerow(header)
            w.writerows([[repr(float(v)) for v in row] for row in rows])
        os.replace(temp, path)
    except OSError as exc:
        _unlink(temp)
        raise ScenarioError(f"cannot write {path}: {exc.strerror or exc}") from None



# ---- a results file written while the run goes ---------------------------------------------------

class ResultFile:
    """A results CSV written row by row (see the module docstring). Use as a context manager around
    the run: leaving the block normally renames the file into place, leaving it with an exception
    keeps the rows in `NAME.partial.csv` marked with the exception's message.

    After the block: `final` is the file holding the rows (None if no row was computed), `rows`
    and `last_time` say how many reached it and up to which time; `notes` lists files of earlier,
    killed runs that were marked partial when this one started."""

    def __init__(self, path: str | Path, what: str = ""):
        self.path = Path(path)
        self.what = what                        # e.g. the scenario name, for the partial file's comment
        check_destination(self.path)
        self.notes = mark_orphans(self.path)
        for n in range(100):                      # a killed process with our pid may have left one
            self.temp = _sibling(self.path, f"incomplete-{os.getpid()}" + (f"-{n}" if n else ""))
            try:
                self.fd = os.open(self.temp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
                break
            except FileExistsError:
                continue
            except OSError as exc:
                raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        else:
            raise ScenarioError(f"cannot write {self.path}: too many {self.temp.name} files beside it")
        fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)   # held while this run lives (see mark_orphans)
        self.started = time.strftime("%Y-%m-%d %H:%M:%S")
        self.buffer: list[str] = []             # lines not yet written (the first: the header)
        self.header = True                      # the buffer starts with the header line
        self.pending = 0                        # bytes in the buffer
        self.written = 0                        # bytes on disk, all complete lines
        self.rows = 0                           # data rows on disk
        self.last_time: float | None = None     # time of the last row on disk
        self.last_flush = time.monotonic()
        self.no_space = False
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
        os.ftruncate(self.fd, 0)
        self.buffer, self.header, self.pending = [], True, 0
        self.written, self.rows, self.last_time = 0, 0, None

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
                    self.no_space = exc.errno in NO_SPACE
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
        """The run succeeded: rename the file into place."""
        self.flush()
        try:
            os.fsync(self.fd)
            os.replace(self.temp, self.path)
            _fsync_folder(self.path.parent)
        except OSError as exc:
            raise ScenarioError(f"cannot write {self.path}: {exc.strerror or exc}") from None
        finally:
            os.close(self.fd)
        self.final = self.path
        return self.path

    def abandon(self, reason: str) -> Path | None:
        """The run failed or was interrupted: keep its rows in NAME.partial.csv, marked with `reason`
        (returns that path), or remove the file if no row was computed (returns None)."""
        try:
            try:
                self.flush()
            except SimulationError:
                pass                                      # a full disk: keep the rows already there
            if self.rows == 0:
                _unlink(self.temp)
                return None
            try:
                dropped = _mark_partial(self.fd, self.written, self._comment(reason), self.no_space)
                if dropped:
                    self.rows -= dropped
                    self.last_time = _last_time(self.fd)
            except OSError:
                pass                                      # no comment line: the file's name still says it
            partial = _sibling(self.path, "partial")
            try:
                os.replace(self.temp, partial)
                self.final = partial
            except OSError:
                self.final = self.temp
            return self.final
        finally:
            os.close(self.fd)

    def _comment(self, reason: str):
        what = f" of {self.what}" if self.what else ""

        def comment(rows: int, t: float | None) -> bytes:
            upto = f"; {rows} rows up to t = {t:.9g} s" if t is not None else "; no rows"
            return (f"{PARTIAL_MARK}{what}: {_one_line(reason)}{upto} "
                    f"(run started {self.started}, pid {os.getpid()})\n").encode()
        return comment

    def __enter__(self) -> "ResultFile":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            try:
                self.flush()
            except SimulationError as failure:            # the last rows did not fit (a full disk)
                self.abandon(reason_of(failure))
                raise
            self.commit()
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
    """A ScenarioError unless a file can be written at `path` (checked before a run starts)."""
    folder = path.parent
    if path.is_dir():
        raise ScenarioError(f"{path}: is a folder; give the results file's name")
    if not folder.is_dir():
        raise ScenarioError(f"{path}: folder {folder} does not exist")
    if not _writable(folder):
        raise ScenarioError(f"{path}: folder {folder} is not writable")
    if path.exists() and not _writable(path):
        raise ScenarioError(f"{path}: exists and is read-only (not replaced)")


def _writable(path: Path) -> bool:
    """Writable by us, and not made read-only by its owner (no write bit at all: refused even for
    root, who may write anywhere)."""
    try:
        return os.access(path, os.W_OK) and bool(path.stat().st_mode & 0o222)
    except OSError:
        return False


def mark_orphans(path: Path) -> list[str]:
    """Mark the files of killed runs that wrote to `path` (NAME.incomplete-PID.csv whose lock is
    free: the kernel releases a killed process's locks) with a partial comment; returns a note per file."""
    notes = []
    marker = _sibling(path, "incomplete-").name                     # NAME.incomplete-.csv: the wildcard after the dash
    head, tail = marker.split("incomplete-", 1)
    pattern = glob.escape(head) + "incomplete-*" + glob.escape(tail)
    for name in sorted(glob.glob(os.path.join(glob.escape(str(path.parent)), pattern))):
        try:
            fd = os.open(name, os.O_RDWR)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if os.pread(fd, 1, 0) in (b"#", b""):
                continue                                  # marked already, or empty
            end = _last_newline(fd)
            pid = name.rsplit("incomplete-", 1)[1].split(".")[0].split("-")[0]
            _mark_partial(fd, end, lambda rows, t: (
                f"{PARTIAL_MARK}: the run writing this file (pid {pid}) ended without a clean exit (killed "
                f"or crashed); {rows} rows up to t = {t:.9g} s, its last flush\n" if t is not None else
                f"{PARTIAL_MARK}: the run writing this file (pid {pid}) ended before its first row\n").encode())
            notes.append(f"{name}: rows of an earlier run (pid {pid}) that was killed; marked partial")
        except (BlockingIOError, OSError):
            continue                                      # a run still writing it, or unreadable
        finally:
            os.close(fd)
    return notes


# ---- a folder of results written as a whole ------------------------------------------------------

class OutputFolder:
    """A folder of results (figures, tables) that replaces the destination only when complete.

    Files are written into `path` = `NAME.incomplete-PID` beside the destination. On success
    (`commit`) it replaces the destination: the old folder is renamed away and deleted. On failure
    (`abandon`) it becomes `NAME.partial` with PARTIAL.txt saying why, and the destination is left as
    it was. The destination is checked first: its parent must be writable, and an existing
    destination must be a writable folder that an earlier run made (it holds `.emcosim` or one of
    `recognize`) or be empty, so that a mistyped destination never deletes someone's files."""

    MARKER = ".emcosim"

    def __init__(self, dest: str | Path, recognize: tuple[str, ...] = ()):
        self.dest = Path(dest).absolute()
        parent, name = self.dest.parent, self.dest.name
        if not name or Path.cwd().resolve().is_relative_to(self.dest.resolve()):
            raise ScenarioError(f"{dest}: refusing to replace the current folder or one of its parents")
        if not parent.is_dir():
            raise ScenarioError(f"{dest}: folder {parent} does not exist")
        if not _writable(parent):
            raise ScenarioError(f"{dest}: folder {parent} is not writable (the results are written beside "
                                "the destination first)")
        if self.dest.exists():
            if not self.dest.is_dir():
                raise ScenarioError(f"{dest}: exists and is not a folder")
            if not _writable(self.dest):
                raise ScenarioError(f"{dest}: folder is read-only (not replaced)")
            known = (self.MARKER,) + tuple(recognize)
            if any(self.dest.iterdir()) and not any((self.dest / k).exists() for k in known):
                raise ScenarioError(f"{dest}: folder exists and was not written by emcosim (no {' or '.join(known)}); "
                                    "it would be replaced: choose another folder or empty it")
        self.notes = mark_orphan_folders(self.dest)
        for n in range(100):                              # a killed process with our pid may have left one
            self.path = parent / (f"{name}.incomplete-{os.getpid()}" + (f"-{n}" if n else ""))
            try:
                self.path.mkdir()
                break
            except FileExistsError:
                continue
            except OSError as exc:
                raise ScenarioError(f"{dest}: cannot create {self.path}: {exc.strerror or exc}") from None
        else:
            raise ScenarioError(f"{dest}: too many {self.path.name} folders beside it")
        try:
            self.lock = os.open(self.path / self.MARKER, os.O_WRONLY | os.O_CREAT, 0o666)
        except OSError as exc:
            raise ScenarioError(f"{dest}: cannot create {self.path}: {exc.strerror or exc}") from None
        fcntl.flock(self.lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        self.started = time.strftime("%Y-%m-%d %H:%M:%S")
        self.final: Path | None = None

    def commit(self) -> Path:
        """Replace the destination with the finished folder."""
        old = self.dest.parent / f".{self.dest.name}.old-{os.getpid()}"
        try:
            if self.dest.exists():
                os.rename(self.dest, old)
            try:
                os.rename(self.path, self.dest)
            except OSError:
                if old.exists():
                    os.rename(old, self.dest)             # put the old results back
                raise
        except OSError as exc:
            raise ScenarioError(f"cannot replace {self.dest}: {exc.strerror or exc}; the new results are "
                                f"in {self.path}") from None
        finally:
            os.close(self.lock)
        shutil.rmtree(old, ignore_errors=True)
        self.final = self.dest
        return self.dest

    def abandon(self, reason: str) -> Path:
        """Keep what was written in NAME.partial, with PARTIAL.txt saying why."""
        try:
            (self.path / "PARTIAL.txt").write_text(
                f"Partial results: {_one_line(reason)}\n(run started {self.started}, pid {os.getpid()}; "
                f"{self.dest} was left as it was)\n")
        except OSError:
            pass                                          # a full disk: the folder's name still says it
        partial = self.dest.parent / f"{self.dest.name}.partial"
        try:
            if partial.exists():
                old = self.dest.parent / f".{self.dest.name}.partial.old-{os.getpid()}"
                os.rename(partial, old)
                shutil.rmtree(old, ignore_errors=True)
            os.rename(self.path, partial)
            self.final = partial
        except OSError:
            self.final = self.path
        finally:
            os.close(self.lock)
        return self.final

    def discard(self) -> None:
        """Nothing worth keeping was computed (e.g. a specification error): remove the folder."""
        os.close(self.lock)
        shutil.rmtree(self.path, ignore_errors=True)

    def __enter__(self) -> "OutputFolder":
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if exc is None:
            self.commit()
        else:
            self.abandon(reason_of(exc))


def mark_orphan_folders(dest: Path) -> list[str]:
    """Folders NAME.incomplete-PID of killed runs (their lock is free) get a PARTIAL.txt."""
    notes = []
    for folder in sorted(dest.parent.glob(glob.escape(dest.name) + ".incomplete-*")):
        marker = folder / OutputFolder.MARKER
        if not folder.is_dir() or (folder / "PARTIAL.txt").exists() or not marker.exists():
            continue
        fd = os.open(marker, os.O_WRONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            pid = folder.name.rsplit("incomplete-", 1)[1].split("-")[0]
            (folder / "PARTIAL.txt").write_text(f"Partial results: the run writing this folder (pid {pid}) "
                                                "ended without a clean exit (killed or crashed)\n")
            notes.append(f"{folder}: results of an earlier run (pid {pid}) that was killed; marked partial")
        except OSError:
            pass                                          # a run still writing it
        finally:
            os.close(fd)
    return notes


# ---- helpers --------------------------------------------------------------------------------------

def _sibling(path: Path, tag: str) -> Path:
    """x.csv -> x.TAG.csv (x -> x.TAG without a suffix), in the same folder."""
    return path.with_name(f"{path.stem}.{tag}{path.suffix}" if path.suffix else f"{path.name}.{tag}")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def _fsync_folder(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:
        pass                                              # not every file system syncs folders
    finally:
        os.close(fd)


def _mark_partial(fd: int, end: int, comment, make_room: bool = False) -> int:
    """Put a comment line before the first `end` bytes of the file, in place (the content is moved
    up from the end backwards). `comment(rows, t)` gives the line for the number of data rows and
    the time of the last one. With make_room (the disk is full), whole rows are dropped from the end
    first so that the file does not grow. Returns the number of rows dropped."""
    rows = _count_lines(fd, end) - 1
    line = comment(rows, _last_time(fd, end))
    dropped = 0
    if make_room:
        need = len(line) + 32                             # room for the line, whatever the new numbers
        tail_start = max(0, end - need - (1 << 20))
        tail = os.pread(fd, end - tail_start, tail_start)
        cut = len(tail)
        while len(tail) - cut < need and cut > 0 and dropped < rows:
            cut = tail.rfind(b"\n", 0, cut - 1) + 1
            dropped += 1
        end = tail_start + cut
        line = comment(rows - dropped, _last_time(fd, end))
        line = line if len(line) <= need else line[:need - 1] + b"\n"
    os.ftruncate(fd, end)
    chunk, pos = 1 << 20, end
    while pos > 0:
        n = min(chunk, pos)
        pos -= n
        data = os.pread(fd, n, pos)
        os.pwrite(fd, data, pos + len(line))
    os.pwrite(fd, line, 0)
    return dropped


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


def _count_lines(fd: int, end: int) -> int:
    n, pos = 0, 0
    while pos < end:
        data = os.pread(fd, min(1 << 20, end - pos), pos)
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


__all__ = ["OutputFolder", "PARTIAL_MARK", "ResultFile", "check_destination", "mark_orphans", "reason_of", "write_csv"]

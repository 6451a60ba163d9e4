"""The small file operations results are written with: files created beside their destination
(O_CREAT | O_EXCL | O_NOFOLLOW), renamed into place without replacing what is there, partial names,
the marker line of a file being written, and reading the last row of a killed run's file.

None of them follows a symbolic link or touches a file that is not a regular file of ours; the rules
they serve are in outputs.py.
"""
from __future__ import annotations

import ctypes
import errno
import os
import stat
from pathlib import Path
from typing import Iterator

PARTIAL_MARK = "# emcosim: PARTIAL result"
MARK_BYTES = 1024              # the first line of a results file being written: its marker, then why it is partial
MAX_PARTIALS = 1000            # NAME.partial, NAME.partial-2, ... NAME.partial-1000


def partial_names(dest: Path, folder: bool = False) -> Iterator[Path]:
    """Where a partial result of `dest` may go, in order: NAME.partial.SUFFIX, NAME.partial-2.SUFFIX, ...
    (a folder: NAME.partial, NAME.partial-2, ...)."""
    for n in range(1, MAX_PARTIALS + 1):
        tag = "partial" if n == 1 else f"partial-{n}"
        yield dest.with_name(f"{dest.name}.{tag}") if folder else sibling(dest, tag)


def place(temp: Path, dest: Path, partial: bool) -> Path:
    """Rename our file `temp` to `dest` (replacing it) or to the first free partial name."""
    if not partial:
        os.replace(temp, dest)
        return dest
    for candidate in partial_names(dest):
        if rename_noreplace(temp, candidate):
            return candidate
    raise FileExistsError(errno.EEXIST, f"{MAX_PARTIALS} partial files of {dest.name} exist already")


def create_beside(dest: Path, tag: str) -> tuple[int, Path]:
    """A new file NAME.TAG-PID[-N].SUFFIX beside `dest`, created by this call (O_EXCL, no link
    followed) and open for reading and writing."""
    for n in range(100):                                  # a killed process with our pid may have left one
        temp = sibling(dest, f"{tag}-{os.getpid()}" + (f"-{n}" if n else ""))
        try:
            flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
            return os.open(temp, flags, 0o666), temp
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, f"too many {temp.name} files beside {dest}")


def create_text(path: Path, text: str) -> None:
    """Write a new file (never an existing one, never through a link)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o666)
    try:
        os.write(fd, text.encode())
    finally:
        os.close(fd)


def open_own(path: Path, flags: int, same_owner: bool = True) -> int | None:
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


def is_own_folder(path: Path) -> bool:
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.geteuid()


RENAME_NOREPLACE = 1
AT_FDCWD = -100
try:
    _renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
except (AttributeError, OSError):                         # not Linux with glibc >= 2.28
    _renameat2 = None


def rename_noreplace(src: Path, dst: Path) -> bool:
    """Rename `src` to `dst` unless `dst` exists (then False): renameat2(RENAME_NOREPLACE) where the
    system has it, else a hard link (files) or a check just before the rename (folders)."""
    if _renameat2 is not None:
        if _renameat2(AT_FDCWD, os.fsencode(src), AT_FDCWD, os.fsencode(dst), RENAME_NOREPLACE) == 0:
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


def copy(src: int, dst: int, offset: int, length: int, at: int = 0) -> None:
    """Copy `length` bytes of file `src` from `offset` to file `dst` at `at` (default: its start)."""
    done = 0
    try:
        while done < length:
            n = os.copy_file_range(src, dst, length - done, offset + done, at + done)
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
            n = os.pwrite(dst, view, at + done)
            view = view[n:]
            done += n
    if done < length:
        raise OSError(errno.EIO, f"copied {done} of {length} bytes")


def fixed_line(head: str, middle: str = "", tail: str = "") -> bytes:
    """A comment line of exactly MARK_BYTES bytes (padded with spaces): head + middle + tail (each
    without a newline), the middle cut (with "...") if the three do not fit."""
    head_b, middle_b, tail_b = (part.replace("\n", " ").encode() for part in (head, middle, tail))
    room = MARK_BYTES - 1 - len(head_b) - len(tail_b)
    if len(middle_b) > room:
        middle_b = middle_b[:max(room - 3, 0)].decode("utf-8", "ignore").encode() + b"..."[:max(room, 0)]
    line = (head_b + middle_b + tail_b)[:MARK_BYTES - 1]
    return line.decode("utf-8", "ignore").encode().ljust(MARK_BYTES - 1) + b"\n"


def sibling(path: Path, tag: str) -> Path:
    """x.csv -> x.TAG.csv (x -> x.TAG without a suffix), in the same folder."""
    return path.with_name(f"{path.stem}.{tag}{path.suffix}" if path.suffix else f"{path.name}.{tag}")


def one_line(text: str) -> str:
    """`text` on one line: every run of white space (newlines too) as one space."""
    return " ".join(str(text).split())


def shown(path: Path) -> str:
    """A path for a message: as it is if printable, else quoted with escapes (a name may hold newlines)."""
    text = str(path)
    return text if text.isprintable() else repr(text)


def unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def rmdir(path: Path) -> None:
    try:
        os.rmdir(path)
    except OSError:
        pass


def fsync_folder(folder: Path) -> None:
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


def last_newline(fd: int) -> int:
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


def count_lines(fd: int, start: int, end: int) -> int:
    n, pos = 0, start
    while pos < end:
        data = os.pread(fd, min(1 << 20, end - pos), pos)
        if not data:
            break
        n += data.count(b"\n")
        pos += len(data)
    return n


def last_time(fd: int, end: int | None = None) -> float | None:
    """The time (first field) of the last complete row before `end` (default: the whole file)."""
    end = os.fstat(fd).st_size if end is None else end
    tail = os.pread(fd, min(end, 65536), max(0, end - 65536))
    lines = [x for x in tail.split(b"\n") if x and not x.startswith(b"#")]
    try:
        return float(lines[-1].split(b",")[0]) if lines else None
    except ValueError:
        return None                                       # only the header is left


__all__ = ["MARK_BYTES", "MAX_PARTIALS", "PARTIAL_MARK", "copy", "count_lines", "create_beside", "create_text",
           "fixed_line", "fsync_folder", "is_own_folder", "last_newline", "last_time", "one_line", "open_own",
           "partial_names", "place", "rename_noreplace", "rmdir", "shown", "sibling", "unlink"]

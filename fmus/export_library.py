"""The pythonfmu export library that every emcosim FMU ships (binaries/linux64/<id>.so), with one
exit-time defect of pythonfmu 0.7.0 removed. Used by build.py; not bundled into the FMUs.

The defect (docs/reliability.md, "Exit-time heap corruption"): the library keeps its interpreter
state in a global `std::shared_ptr<PyState> pyState` and also resets it in a function marked
`__attribute__((destructor))` (`onLibraryUnload` -> `finalizePythonInterpreter`: `pyState = nullptr`).
When the library is unloaded with dlclose, the reset runs first and the C++ static destructor then
finds an empty pointer: fine. When the process exits with the library still loaded (every host that
does not unload it), glibc runs the static destructors first (exit handlers) and the ELF destructors
afterwards (`_dl_fini`): the shared_ptr is destroyed, its control block freed, and the reset then
decrements a counter inside the freed block -- a write after free that corrupts glibc's free lists
when the block sits in a doubly linked bin ("corrupted double-linked list" at exit, in ~1 of 5
processes here; valgrind names the read in finalizePythonInterpreter and the free in
__run_exit_handlers).

The fix: the `.fini_array` slot that calls `onLibraryUnload` is pointed at the library's `_fini`
(a function that does nothing). The static destructor, which the C++ runtime runs both at dlclose
and at exit, then releases `pyState` exactly once. Nothing else in the library changes. The fix is
applied only to the x86-64 ELF layout it was written for (checked symbol by symbol); any other
library is shipped unchanged and `patch` says why.
"""
from __future__ import annotations

import struct

SHT_SYMTAB, SHT_STRTAB, SHT_RELA, SHT_FINI_ARRAY = 2, 3, 4, 15
R_X86_64_RELATIVE = 8
DESTRUCTOR = "_ZN12_GLOBAL__N_115onLibraryUnloadEv"      # pythonfmu's (anonymous namespace)::onLibraryUnload()
NO_OP = "_fini"                                           # crti/crtn: sub rsp, 8; add rsp, 8; ret


class NotApplicable(ValueError):
    """The library does not have the layout the fix was written for."""


def _sections(elf: bytes) -> list[dict]:
    if elf[:4] != b"\x7fELF" or elf[4] != 2 or elf[5] != 1 or struct.unpack_from("<H", elf, 18)[0] != 62:
        raise NotApplicable("not a little-endian x86-64 ELF64 file")
    shoff, = struct.unpack_from("<Q", elf, 0x28)
    shentsize, shnum = struct.unpack_from("<HH", elf, 0x3A)
    keys = ("name", "type", "flags", "addr", "offset", "size", "link", "info", "addralign", "entsize")
    return [dict(zip(keys, struct.unpack_from("<IIQQQQIIQQ", elf, shoff + i * shentsize))) for i in range(shnum)]


def _symbols(elf: bytes, sections: list[dict]) -> dict[str, int]:
    """name -> value of every symbol in .symtab (the library is not stripped)."""
    out = {}
    for sec in (s for s in sections if s["type"] == SHT_SYMTAB):
        strtab = sections[sec["link"]]
        for k in range(sec["size"] // 24):
            st_name, _, _, _, st_value, _ = struct.unpack_from("<IBBHQQ", elf, sec["offset"] + 24 * k)
            start = strtab["offset"] + st_name
            out[elf[start:elf.index(b"\0", start)].decode()] = st_value
    return out


def patch(elf: bytes) -> bytes:
    """The library with its `onLibraryUnload` destructor slot pointed at `_fini`. Raises
    NotApplicable (with the reason) when the layout is not the one described above."""
    sections = _sections(elf)
    symbols = _symbols(elf, sections)
    if DESTRUCTOR not in symbols or NO_OP not in symbols:
        raise NotApplicable(f"no symbol {DESTRUCTOR if DESTRUCTOR not in symbols else NO_OP}")
    target, no_op = symbols[DESTRUCTOR], symbols[NO_OP]
    fini = [s for s in sections if s["type"] == SHT_FINI_ARRAY]
    if len(fini) != 1:
        raise NotApplicable("not exactly one .fini_array")
    lo, hi = fini[0]["addr"], fini[0]["addr"] + fini[0]["size"]
    out = bytearray(elf)
    hits = 0
    for sec in (s for s in sections if s["type"] == SHT_RELA):
        for k in range(sec["size"] // 24):
            at = sec["offset"] + 24 * k
            r_offset, r_info, r_addend = struct.unpack_from("<QQq", elf, at)
            if lo <= r_offset < hi and r_info & 0xFFFFFFFF == R_X86_64_RELATIVE and r_addend == target:
                struct.pack_into("<q", out, at + 16, no_op)                   # the relocation's value ...
                struct.pack_into("<Q", out, fini[0]["offset"] + r_offset - lo, no_op)   # ... and the slot
                hits += 1
    if hits != 1:
        raise NotApplicable(f"{hits} .fini_array relocations to {DESTRUCTOR} (expected 1)")
    return bytes(out)


def fini_array(elf: bytes) -> list[str]:
    """Names of the functions the .fini_array relocations point at (for tests and diagnostics)."""
    sections = _sections(elf)
    by_value: dict[int, str] = {}
    for name, value in _symbols(elf, sections).items():
        if name and (value not in by_value or name.startswith("_Z")):
            by_value[value] = name
    fini = next(s for s in sections if s["type"] == SHT_FINI_ARRAY)
    names = []
    for sec in (s for s in sections if s["type"] == SHT_RELA):
        for k in range(sec["size"] // 24):
            r_offset, r_info, r_addend = struct.unpack_from("<QQq", elf, sec["offset"] + 24 * k)
            if fini["addr"] <= r_offset < fini["addr"] + fini["size"]:
                names.append(by_value.get(r_addend, hex(r_addend)))
    return names

"""The one gate for text inside generated source (issue 40, item 1): comments and string literals of generated C
and Python.

A description's free text, units and file path never become source, not even escaped: C joins a
backslash-newline before it looks for comments (so `d*\\` + newline in a folder name ended a comment that an
escape of "*/" had "made safe"), trigraphs turn "??/" into a backslash, Python closes a docstring at `\"\"\"`.
Generated source carries only checked identifiers, numbers the printers print, the description's sha256 and
the generators' own fixed words; each of these passes `source_text`, which refuses any character outside
ALPHABET (no quote, backslash, newline, `#`, `?`, non-ASCII) and in C the comment delimiters `/*`, `*/`. The
description's text travels as data: modelDescription.xml attributes (the XML writer escapes them) and, in a
generated Python module, `text_data` (hexadecimal UTF-8 of a JSON object, decoded at import by `texts`).
"""
from __future__ import annotations

import json
from typing import Any

ALPHABET = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 _.,:;=+-*/()[]{}^'<>!|&")
"""The characters a generated comment or string literal may hold: none ends a C or Python comment, string or
line, none is a trigraph or an escape, none is outside ASCII."""
DELIMITERS = ("/*", "*/")


class SourceTextError(ValueError):
    """A text that would become part of generated source is not plain (a generator's bug or a hostile input
    that got past the loader): nothing is generated from it."""


def source_text(text: object, what: str = "generated source", c: bool = True) -> str:
    """`text` unchanged if it may stand inside a generated comment or string literal (`c`: of C, where "/*" and
    "*/" may not stand either), else SourceTextError."""
    if not isinstance(text, str):
        raise SourceTextError(f"{what}: {type(text).__name__} is not text")
    bad = sorted({c for c in text if c not in ALPHABET})
    if bad:
        raise SourceTextError(f"{what}: {bad[0]!r} may not stand in generated source (issue 40)")
    for d in DELIMITERS if c else ():
        if d in text:
            raise SourceTextError(f"{what}: {d!r} may not stand in generated source (issue 40)")
    return text


def c_comment(text: str) -> str:
    """A C block comment holding `text` (source_text)."""
    return f"/* {source_text(text, 'a C comment')} */"


def c_string(text: str) -> str:
    """A C string literal of `text` (source_text: nothing in it is an escape or a trigraph)."""
    return f'"{source_text(text, "a C string")}"'


def py_string(text: str) -> str:
    """A Python string literal of `text` (source_text)."""
    return f'"{source_text(text, "a Python string", c=False)}"'


def py_docstring(text: str) -> str:
    """A Python docstring of `text` (source_text)."""
    return f'"""{source_text(text, "a Python docstring", c=False)}"""'


def py_comment(text: str) -> str:
    """A Python comment line of `text` (source_text)."""
    return f"# {source_text(text, 'a Python comment', c=False)}"


def text_data(data: Any) -> str:
    """A Python literal of `data` (JSON: strings, numbers, lists, dicts) that holds no text: the hexadecimal
    digits of its UTF-8 JSON. `texts` is its inverse at import time."""
    return py_string(json.dumps(data, ensure_ascii=False, sort_keys=True).encode("utf-8").hex())


def texts(hex_digits: str) -> Any:
    """The data `text_data` printed (what a generated module calls at import)."""
    return json.loads(bytes.fromhex(hex_digits).decode("utf-8"))

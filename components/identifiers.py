"""The rules for names and free text that come from a plant description file (issue 31: data, never code).

A description's names become identifiers in generated source (components.codegen's Python module, native C
FMUs), FMI variable names and file names; its free text (description, units, parameter and variable
descriptions) becomes string data in modelDescription.xml, the generated module and the docs. Every rule
lives here, in `identifier_problem` and `text_problem`, so that each path from the file into code checks the
same things (docs/plant-description.md, "Names and text").
"""
from __future__ import annotations

import keyword
import re
import unicodedata

MAX_NAME = 32
"""Longest name (device, variable or parameter)."""
MAX_TEXT = 500
"""Longest free text (a description); a unit is at most MAX_UNIT characters."""
MAX_UNIT = 40

NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")          # a variable or parameter: q, x_e, R_e_bar
DEVICE_NAME = re.compile(r"[A-Za-z][A-Za-z0-9]*\Z")    # the device: FMU model identifier and file stem
UNIT = re.compile(r"[A-Za-z0-9.*/^()+-]+\Z")           # "kg.m/s", "m/s2", "1", "N.s/m"

PYTHON_KEYWORDS = frozenset(keyword.kwlist) | frozenset(keyword.softkwlist)
C_KEYWORDS = frozenset("""
    auto break case char const continue default do double else enum extern float for goto if inline int long
    register restrict return short signed sizeof static struct switch typedef union unsigned void volatile while
    bool true false NULL
""".split())
"""C99's keywords (and stdbool's / stddef's names, which a C99 file with those headers cannot redefine)."""
C_LIBRARY = frozenset("""
    abs acos acosh asin asinh atan atan2 atanh cbrt ceil copysign cos cosh erf erfc exp exp2 expm1 fabs fdim
    floor fma fmax fmin fmod frexp hypot ilogb ldexp lgamma llrint llround log log10 log1p log2 logb lrint
    lround modf nan nearbyint nextafter pow remainder remquo rint round scalbn sin sinh sqrt tan tanh tgamma
    trunc j0 j1 jn y0 y1 yn gamma isnan isinf isfinite signbit fpclassify INFINITY NAN HUGE_VAL
    malloc calloc realloc free memcpy memmove memset memcmp strlen strcmp strncmp strcpy strncpy strcat
    printf fprintf sprintf snprintf vsnprintf puts fputs stdin stdout stderr exit abort atexit assert errno
    main environ system
""".split())
"""The C library names (math.h incl. POSIX j0/y0..., stdlib.h, stdio.h, string.h) a native C printer that
emits a description's names as C identifiers would collide with."""
FMI_RESERVED = frozenset({"time"})
"""FMI's independent variable (every emcosim FMU declares `time`)."""
FMU_NAMES = frozenset({"H", "rtol", "strict"})
"""Variables every emcosim plant / controller FMU declares besides the description's (fmus/plant.py,
fmus/controller.py): the energy output, the plant's tolerance, the controller's strict flag."""
MODULE_NAMES = frozenset({"device", "PARAMETERS", "VARIABLES", "Reference", "annotations"})
"""Names a device may not have: the generated model module's own names (components.codegen: device(),
PARAMETERS, VARIABLES) and the Reference FMU's identifier, which `plant build` writes beside the device's."""
GAIN_ENTRY = re.compile(r"(q_d|R_e_bar|D_d|k_c|W)(_\d+)*\Z")
"""A controller gain or one of its entries (q_d_1, R_e_bar_1_2): FMI parameters of the controller FMUs."""


def identifier_problem(name: object, kind: str = "name") -> str | None:
    """Why `name` may not be a name of a description (None: it may). kind "device" for the device's name
    (the FMU model identifier: letters and digits only), else a variable's or parameter's.

    A name must match the pattern, be at most MAX_NAME characters and be no Python keyword, C99 keyword, C
    library name, FMI reserved name or name an emcosim FMU declares itself."""
    pattern, shape = (DEVICE_NAME, "[A-Za-z][A-Za-z0-9]*") if kind == "device" else (NAME, "[A-Za-z][A-Za-z0-9_]*")
    if not isinstance(name, str) or not pattern.match(name):
        return f"{name!r} is not an identifier {shape}"
    if len(name) > MAX_NAME:
        return f"{name!r} is longer than {MAX_NAME} characters"
    for words, what in ((PYTHON_KEYWORDS, "a Python keyword"), (C_KEYWORDS, "a C keyword"),
                        (C_LIBRARY, "a C library name (math.h, stdlib.h, stdio.h)"),
                        (FMI_RESERVED, "reserved by FMI (the independent variable)")):
        if name in words or (kind == "device" and name.lower() in words):
            return f"{name!r} is {what}; choose another"
    if kind == "device" and name.lower() in {n.lower() for n in MODULE_NAMES}:
        return (f"{name!r} is taken by the generated model module or the Reference FMU ({', '.join(sorted(MODULE_NAMES))}, "
                "in any case); choose another")
    if kind != "device" and (name in FMU_NAMES or GAIN_ENTRY.match(name)):
        return f"{name!r} is a variable every emcosim FMU declares (H, rtol, strict, the gains q_d, R_e_bar, D_d, k_c, W)"
    return None


def text_problem(text: object, limit: int = MAX_TEXT) -> str | None:
    """Why `text` may not be free text of a description (None: it may): a string of at most `limit`
    characters without control characters (XML 1.0 cannot carry most of them), format characters (a
    right-to-left override would show a reader other text than there is) or line separators."""
    if not isinstance(text, str):
        return f"{text!r} is not a string"
    if len(text) > limit:
        return f"is longer than {limit} characters"
    bad = [c for c in text if unicodedata.category(c) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp")]
    if bad:
        return f"contains the control, format, line-separator or unassigned character {bad[0]!r}"
    return None


def unit_problem(unit: object) -> str | None:
    """Why `unit` may not be a unit string (None: it may): letters, digits and . * / ^ ( ) + -, at most
    MAX_UNIT characters ("1" if dimensionless)."""
    if not isinstance(unit, str) or not UNIT.match(unit):
        return f"{unit!r} is not a unit (letters, digits and . * / ^ ( ) + -; \"1\" if dimensionless)"
    if len(unit) > MAX_UNIT:
        return f"{unit!r} is longer than {MAX_UNIT} characters"
    return None

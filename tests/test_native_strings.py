"""String literals of the native FMUs' C sources (fmus.native_build._c_string, components.source_text): only
plain text (checked names, numbers, fixed words) is printed, compiled with -std=c99 (trigraphs on) it gives back
exactly its bytes; any other text is refused, and a description's text reaches no C source (issue 40)."""
from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from components.source_text import SourceTextError
from fmus.native_build import _c_string

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")

PLAIN = ["> 0", "q_d_1", "{1b2c-3d}", "der(x_e)", "R_m - 1/4 D_d^T R_e_bar^-1 D_d"]
HOSTILE = [
    'x"); } __attribute__((constructor)) static void f(void) { system("touch pwned"); } static const char *y = ("',
    "ends in a backslash \\",
    "a trigraph ??/",
    "??/\"; int z = 1; //",
    "two\nlines\r\tand a tab",
    "unicode: \u00e9 \u202e \u2028",
    "*/ /* comment markers // too",
    "%s %n printf formats",
]


def test_hostile_text_is_refused() -> None:
    for text in HOSTILE:
        with pytest.raises(SourceTextError):
            _c_string(text)


def test_every_text_compiles_back_to_its_own_bytes(tmp_path: Path) -> None:
    rows = ",\n".join(f"    {_c_string(text)}" for text in PLAIN)
    source = tmp_path / "strings.c"
    source.write_text(
        "#include <stdio.h>\n#include <string.h>\n"
        f"static const char *const TEXTS[] = {{\n{rows}\n}};\n"
        "int main(void) {\n"
        "    size_t i;\n"
        "    for (i = 0; i < sizeof TEXTS / sizeof TEXTS[0]; i++) {\n"
        "        fwrite(TEXTS[i], 1, strlen(TEXTS[i]), stdout);\n"
        "        fputc(0, stdout);\n"
        "    }\n"
        "    return 0;\n"
        "}\n")
    exe = tmp_path / "strings"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", str(exe), str(source)], check=True,
                   capture_output=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, cwd=tmp_path).stdout
    assert out.split(b"\0")[:-1] == [t.encode("utf-8") for t in PLAIN]
    assert not (tmp_path / "pwned").exists()


def test_a_description_text_reaches_no_c_source(tmp_path: Path) -> None:
    """A description's text reaches no generated C (issue 40: not even escaped inside a comment); the payload
    below would compile as code if a "*/" in it ended a comment."""
    import re

    from fmus.native_build import build_native_description_fmus
    example = Path(__file__).resolve().parents[1] / "examples" / "parallel_plate" / "parallel_plate.toml"
    text = re.sub(r'(?m)^description = .*$', 'description = "*/ int pwn(void) { return 1; } /* x"',
                  example.read_text())
    hostile = tmp_path / "parallel_plate.toml"
    hostile.write_text(text)
    fmus = build_native_description_fmus(hostile, ["Proposition2"], tmp_path / "fmus")
    assert len(fmus) == 2
    for fmu in fmus.values():
        with zipfile.ZipFile(fmu) as z:
            sources = [z.read(n).decode() for n in z.namelist() if n.startswith("sources/") and n.endswith(".c")]
        code = [re.sub(r"/\*.*?\*/", " ", source, flags=re.S) for source in sources]
        assert not any("pwn" in source for source in sources), fmu
        assert not any("pwn" in c for c in code), fmu

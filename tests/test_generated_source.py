"""Generated source holds no text from a file or a path (issue 40, item 1).

A description file's path (folders and file name) and its free text (description, units, parameter and variable
descriptions) carry every C and Python lexical hazard: backslash-newline (which C joins before it looks for
comments: the issue's exploit), trigraphs, comment delimiters, triple quotes, quotes, `#`, line and paragraph
separators, bidi controls. The generated Python module, the generated C of the native plant and controller and
their config files must hold none of it (components.source_text is the one gate); the text still reaches
modelDescription.xml, escaped by the XML writer. The issue's payload, a constructor that creates a marker file
when the FMU's binary is loaded, must never run.
"""
from __future__ import annotations

import ctypes
import io
import re
import shutil
import tokenize
import zipfile
from pathlib import Path

import pytest

from components import c_codegen, codegen, plant_check
from components.description import DescriptionError, load, parse
from components.source_text import ALPHABET, SourceTextError, c_comment, c_string, py_docstring, py_string, texts

ROOT = Path(__file__).resolve().parents[1]
SOLENOID = ROOT / "examples" / "solenoid" / "solenoid.toml"
PAYLOAD = ('int system(const char *); __attribute__((constructor)) static void emc_pwn(void) '
           '{ int r = system("touch pwned"); (void)r; } ')
"""C that would run when the FMU's binary is loaded, if the path became code (issue 40's reproduction)."""
HAZARDS = ["\\\n", "??/", "??=", "*/", "/*", '"""', '"', "#", "\u2028", "\u2029", "\u202e", "\u200f",
           "\\", "`", "\r"]
"""The sequences no generated source may hold outside what its generator writes itself."""
TEXT = 'x*/ /* ??/ ??= """ \'\'\' " # \\ ` ' + PAYLOAD + " \\"
"""Free text with every hazard a text field may hold (components.identifiers.text_problem refuses control,
format and line-separator characters: tested in test_description_safety)."""


def _toml(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _hostile_text() -> str:
    text = SOLENOID.read_text()
    text = text.replace('"Solenoid actuator: plunger, return spring and coil with gap-dependent inductance"', _toml(TEXT))
    text = text.replace('"plunger travel (the air gap is g0 - q)"', _toml("q " + TEXT))
    text = text.replace('"mass of the plunger"', _toml("m " + TEXT))
    text = text.replace('"N/m"', _toml("N*/m/*"))                  # a unit may hold * and /
    assert text.count("emc_pwn") == 3
    return text


def _hostile_file(root: Path, unit: bool = True) -> Path:
    """The issue's path: `d*\\` + newline closes the comment in C (backslash-newline splicing), the next folder
    is C code, and the file name opens a comment again; plus Python and Unicode hazards in the folder names."""
    folder = root / "d*\\\n" / (" " + PAYLOAD) / 'q"""\u2028\u2029\u202e#\'??/ \\'
    folder.mkdir(parents=True)
    path = folder / "\\\n*x.toml"
    path.write_text(_hostile_text() if unit else _hostile_text().replace('"N*/m/*"', '"N/m"'))   # FMI: units
    return path                                                                  # are symbols (fmus.variables)


def _c_tokens(source: str) -> list[str]:
    """The comments and string and character literals of C source (after joining backslash-newlines)."""
    joined = source.replace("\\\n", "")
    return re.findall(r'/\*.*?\*/|//[^\n]*|"(?:[^"\\\n]|\\.)*"|\'(?:[^\'\\\n]|\\.)*\'', joined, flags=re.S)


def _py_tokens(source: str) -> list[str]:
    """The comments and string literals of Python source."""
    return [t.string for t in tokenize.generate_tokens(io.StringIO(source).readline)
            if t.type in (tokenize.COMMENT, tokenize.STRING)]


def _assert_clean(name: str, source: str, python: bool) -> None:
    """No hazard anywhere in `source`; every comment and literal in the gate's alphabet (components.source_text;
    in C the hand-written glue's comments span lines and its formats hold % and escapes such as a newline's)."""
    assert source.isascii(), f"{name}: non-ASCII text"
    for hazard in ("emc_pwn", "pwned", "__attribute__", "system(", "\\\n", "??", "\r", "\0", "x*/", "N*/m"):
        assert hazard not in source, f"{name}: {hazard!r}"
    glue = set() if python else {"\n", "%", "\\"}
    for token in (_py_tokens(source) if python else _c_tokens(source)):
        inner = token[2:-2] if token.startswith("/*") else token.lstrip("#").strip("\"'")
        assert set(inner) <= ALPHABET | glue, (name, token)


def _generated(desc) -> dict[str, str]:
    """Every generated source of a description that needs no compiler: the Python module and the C files."""
    designs = plant_check.check(desc).designs
    out = {"model.py": codegen.module_source(desc, "\\\n*x.toml"), "model.c": c_codegen.model_c_source(desc),
           "laws.c": c_codegen.law_c_source(desc, ["c1"], False)}
    device = codegen.device(desc, designs)
    for design in designs:
        out[f"{design}.c"] = c_codegen.controller_c_source(desc, design, list(device.designs[design].gains.values()))
    return out


def test_hostile_text_and_path_reach_no_generated_source(tmp_path: Path) -> None:
    desc = load(_hostile_file(tmp_path))
    assert desc.description == TEXT and "\n" in desc.source                 # the hazards did get in
    for name, source in _generated(desc).items():
        _assert_clean(name, source, name.endswith(".py"))
        assert desc.sha256 in source                                         # what it was made from
    module = codegen.load_module(desc)                                       # the text, as data
    plant = getattr(module, desc.name)
    assert plant.name == TEXT and module.VARIABLES["q"][0].description == "q " + TEXT
    assert module.PARAMETERS["m"].description == "m " + TEXT and module.PARAMETERS["k_s"].unit == "N*/m/*"
    assert not (tmp_path / "pwned").exists()


def test_committed_modules_pass_the_gate() -> None:
    for path in sorted((ROOT / "components" / "plants").glob("*_model.py")):
        _assert_clean(path.name, path.read_text(), True)


@pytest.mark.parametrize("text", [*HAZARDS, "\0", "\u00e9", "a\nb"])
def test_the_gate_refuses_every_hazard(text: str) -> None:
    for gate in (c_comment, c_string, py_string, py_docstring):
        if gate in (py_string, py_docstring) and text in ("*/", "/*"):
            assert gate(text)                                                # harmless in Python
            continue
        with pytest.raises(SourceTextError):
            gate(f"a {text} b")


def test_text_data_is_only_hex_digits_and_gives_the_text_back() -> None:
    from components.source_text import text_data
    data = {"t": TEXT + "\0\u2028\u202e", "u": ["N*/m"]}
    literal = text_data(data)
    assert re.fullmatch(r'"[0-9a-f]+"', literal)
    assert texts(literal[1:-1]) == data


def test_control_and_bidi_characters_in_a_text_field_are_refused_naming_file_and_entry() -> None:
    for bad in ("0000", "2028", "2029", "202e", "200f"):                   # TOML escapes \uXXXX
        with pytest.raises(DescriptionError, match=r"^hostile\.toml: \[top level\] description: "):
            parse(_hostile_text().replace("x*/", "x\\u" + bad, 1), "hostile.toml")


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")
def test_the_issue_s_exploit_builds_no_code_and_the_text_reaches_the_model_description(tmp_path: Path) -> None:
    """`emcosim plant build <path> --native` and the pythonfmu build of the hostile path: the FMUs hold no hazard
    in any source, fmpy validates them, loading the native binaries runs no payload, and modelDescription.xml
    carries the text (about 60 s: five FMUs)."""
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu

    from emcosim.cli import main
    path = _hostile_file(tmp_path / "in", unit=False)
    work = tmp_path / "work"
    work.mkdir()
    for flags in (["--native"], []):
        out = tmp_path / ("native" if flags else "pythonfmu")
        assert main(["plant", "build", str(path), "--out", str(out), *flags]) == 0
        fmus = sorted(out.glob("Solenoid*.fmu"))
        assert len(fmus) >= 2
        for fmu in fmus:
            assert validate_fmu(str(fmu)) == [], fmu
            md = read_model_description(str(fmu))
            if fmu.stem == "Solenoid":
                assert md.description.startswith(TEXT)                       # escaped by the XML writer
                assert "q " + TEXT in [v.description for v in md.modelVariables]
            with zipfile.ZipFile(fmu) as z:
                for name in z.namelist():
                    if name.endswith((".c", ".h", ".py")) and not name.startswith(("sources/fmi2", "resources/fmus/",
                                                                                  "resources/components/")):
                        generated = name.rsplit("/", 1)[-1] in {"model.c", "controller.c", "config.c", "emc_config.h"}
                        if generated or name.endswith("_model.py") or name.rsplit("/", 1)[-1].startswith("emcosim_device"):
                            _assert_clean(f"{fmu.name}:{name}", z.read(name).decode("utf-8"), name.endswith(".py"))
                if flags:
                    so = next(n for n in z.namelist() if n.endswith(".so"))
                    z.extract(so, work / fmu.stem)
                    import os
                    cwd = os.getcwd()
                    os.chdir(work)
                    try:
                        ctypes.CDLL(str(work / fmu.stem / so))
                    finally:
                        os.chdir(cwd)
    assert not (work / "pwned").exists()

"""A description file is data, never code, and the work it causes is bounded (issue 31, items 1, 4, 5, 7).

Hostile text stays inert string data in the generated module and the FMUs (a payload that would create a
marker file never runs); hostile names are refused by components.identifiers' one rule; numbers, sizes and
symbolic work have limits; a non-finite sample never decides a verdict; errors name the file and the entry.
"""
from __future__ import annotations

import ast
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from components import bounded, codegen, description, plant_check
from components.description import DescriptionError, parse
from components.identifiers import identifier_problem
from emcosim.cli import main
from tests.test_description import ISSUE_MAGLEV

ROOT = Path(__file__).resolve().parents[1]
MAGLEV = ROOT / "components" / "plants" / "maglev.toml"
EMCOSIM = str(Path(sys.executable).with_name("emcosim"))
CALLS = {"open", "exec", "eval", "__import__", "compile", "system", "getattr"}


def _payload(marker: Path) -> str:
    return f'open({str(marker)!r}, "a").write("ran")'


def _hostile(marker: Path) -> str:
    """The issue's file: a description that closes the generated docstring (one line: valid in the module and
    the class), and payloads in every other text field."""
    p = _payload(marker)
    text = MAGLEV.read_text()
    text = text.replace('description = "Magnetic levitation system (paper Section 7.2)"',
                        f'description = {_toml(f"x{chr(34) * 3}; {p}; {chr(34) * 3}y")}')
    text = text.replace('"position of the ball (magnet at q = c)"', _toml(f"a'''; {p}; '''b"))
    text = text.replace('"coil resistance"', _toml(f"# {p}"))
    text = text.replace('"mass of the ball"', _toml(f"\\{chr(34)}); {p}; ({chr(34)}"))
    return text


def _toml(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _calls(source: str) -> set[str]:
    """Names of the dangerous callables the source mentions as code (not inside string literals)."""
    tree = ast.parse(source)
    return {n.id for n in ast.walk(tree) if isinstance(n, ast.Name) and n.id in CALLS} | \
           {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr in CALLS}


# ---- item 1: text is data ------------------------------------------------------------------------

def test_hostile_text_stays_a_string_in_the_generated_module(tmp_path):
    marker = tmp_path / "MARK"
    desc = parse(_hostile(marker), "hostile.toml")
    source = codegen.module_source(desc)
    assert not _calls(source), "a payload became code"
    module = codegen.load_module(desc)
    assert not marker.exists()
    plant = getattr(module, desc.name)
    assert plant.name == desc.description and "open(" in plant.name        # kept exactly, as data
    assert module.VARIABLES["q"][0].description.startswith("a'''; open(")
    codegen.device(desc)
    assert not marker.exists()


def test_a_file_name_never_becomes_code(tmp_path):
    desc = parse(ISSUE_MAGLEV, "issue.toml")
    source = codegen.module_source(desc, 'evil"""\nimport os; os.system("true")\n""".toml')
    assert "import os" not in source and "evil" not in source and not _calls(source)


@pytest.mark.parametrize("field,old,new", [
    ("top level", 'description = "Magnetic levitation system (paper Section 7.2)"', 'description = "a\\nb"'),
    ("top level", 'description = "Magnetic levitation system (paper Section 7.2)"', 'description = "a\\u0000b"'),
    ("variables", '"position of the ball (magnet at q = c)"', '"x\\rimport os"'),
    ("variables", '"m",      "position', '"m\\"); import os; (\\"",      "position'),
    ("parameters", '"Ohm",   "coil resistance"', '"Ohm\\n",   "coil resistance"'),
    ("parameters", '"coil resistance"', '"coil \\u202eresistance"'),
    ("parameters", '"coil resistance"', '"coil \\u2028resistance"'),
    ("top level", 'description = "Magnetic levitation system (paper Section 7.2)"', f'description = "{"x" * 501}"'),
])
def test_text_with_line_breaks_or_control_characters_is_refused(field, old, new):
    text = MAGLEV.read_text()
    assert old in text
    with pytest.raises(DescriptionError, match=rf"^bad\.toml: \[{field}\] "):
        parse(text.replace(old, new), "bad.toml")


@pytest.mark.parametrize("name,kind,why", [
    ("device", "device", "generated model module"), ("Reference", "device", "Reference"),
    ("reference", "device", "Reference"), ("int", "device", "C keyword"), ("Time", "device", "FMI"),
    ("while", "name", "Python keyword"), ("match", "name", "Python keyword"), ("double", "name", "C keyword"),
    ("time", "name", "FMI"), ("y1", "name", "C library"), ("printf", "name", "C library"), ("H", "name", "emcosim FMU"),
    ("q_d", "name", "emcosim FMU"), ("R_e_bar_1_2", "name", "emcosim FMU"), ("strict", "name", "emcosim FMU"),
    ("a" * 33, "name", "longer"), ("x-y", "name", "not an identifier"), ("_x", "name", "not an identifier"),
    ("q_e", "device", "not an identifier"), ("é", "name", "not an identifier"),
])
def test_the_identifier_rule_refuses(name, kind, why):
    assert why in (identifier_problem(name, kind) or "")


@pytest.mark.parametrize("old,new,entry", [
    ('name = "Maglev"', 'name = "device"', r"\[top level\] name"),
    ('name = "Maglev"', 'name = "int"', r"\[top level\] name"),
    ('k   = [0.64042', 'time = [0.64042', r"\[parameters\] time"),
    ('k   = [0.64042', 'q_0 = [0.64042', r"\[parameters\] q_0"),
    ('["x_e", "Wb"', '["double", "Wb"', r"\[variables\] x_e\[0\]"),
])
def test_names_a_generated_source_or_fmu_cannot_hold_are_refused(old, new, entry):
    text = MAGLEV.read_text()
    assert old in text
    with pytest.raises(DescriptionError, match=rf"^bad\.toml: {entry}: "):
        parse(text.replace(old, new), "bad.toml")


@pytest.mark.slow
def test_plant_check_and_build_of_the_hostile_file_run_no_payload(tmp_path):
    """The issue's exploit end to end: check, build, and an FMU of the build instantiated and run."""
    from fmpy import read_model_description, simulate_fmu

    marker = tmp_path / "MARK"
    path = tmp_path / "hostile.toml"
    path.write_text(_hostile(marker))
    assert main(["plant", "check", str(path)]) == 0
    assert main(["plant", "build", str(path), "--out", str(tmp_path / "fmus")]) == 0
    fmu = tmp_path / "fmus" / "Maglev.fmu"
    md = read_model_description(str(fmu))
    assert md.description.startswith('x"""; open(')                       # the text, XML-escaped and back
    simulate_fmu(str(fmu), stop_time=0.01, output_interval=1e-3)
    assert not marker.exists()


# ---- item 4: bounded work ------------------------------------------------------------------------

def _with_V(v: str) -> str:
    return ISSUE_MAGLEV.replace('V   = "b*q"', f"V   = {_toml(v)}")


@pytest.mark.parametrize("v,match", [
    ("b*q + ((9**1000)**1000)**1000", "exponent"),
    ("b*q*(((q+1)**1000)**1000)", "exponent"),
    ("b*q + 9**1000", "not a finite real double"),
    ("b*q + 1e999999", "not finite as a double"),
    ("b*q*(1 + 1e-999999)", "subnormal"),
    ("b*q*(1 + 1e-320)", "subnormal"),
    ("b*q*(1 + exp(-1000))", "subnormal"),
    ("b*q*(1 + 1e-200*1e-200)", "subnormal"),
    ("b*q + exp(exp(exp(1000)))", r"exp\(1000\) is not a finite"),
    ("b*q + " + "+".join(["q"] * 600), "terms and operations"),
    ("b*q" + " " * 2000, "characters"),
    ("b*q + 1" + "0" * 50, "characters"),
])
def test_expressions_that_would_hang_or_lie_as_doubles_are_refused_at_once(v, match):
    start = time.monotonic()
    with pytest.raises(DescriptionError, match=r"^m\.toml: \[model\] V: .*(" + match + ")"):
        parse(_with_V(v), "m.toml")
    assert time.monotonic() - start < 3.0


def test_a_pole_at_the_default_parameters_is_named():
    """Issue item 7: V with a pole at a parameter value ended in KeyError: 'ComplexInfinity'."""
    with pytest.raises(DescriptionError, match=r"^m\.toml: \[model\] V: is not finite at the default parameter values"):
        parse(_with_V("b*q/(c - 0.005)"), "m.toml")


def test_too_many_positions_are_refused():
    from tests.description_samples import diagonal_device
    with pytest.raises(DescriptionError, match=r"\[variables\] q: 9 entries: at most 8"):
        parse(diagonal_device(9), "d.toml")


def test_a_symbolic_check_past_its_time_limit_falls_back_to_samples_and_says_so(monkeypatch):
    """The symbolic Sylvester check of an 8 x 8 diagonal M(q) took 6 s (59 s at n = 12, no end at n = 30):
    past SYMBOLIC_SECONDS the sampled test decides and the note says why."""
    from tests.description_samples import diagonal_device
    monkeypatch.setattr(description, "SYMBOLIC_SECONDS", 0.3)
    start = time.monotonic()
    desc = parse(diagonal_device(8), "d.toml")
    assert time.monotonic() - start < 30
    note = next(n for n in desc.notes if n.startswith("M:"))
    assert "stopped at its time limit of 0.3 s" in note and "sample points" in note


def test_time_limit_stops_python_work_that_catches_exception():
    start = time.monotonic()
    with bounded.time_limit(0.2) as limit:
        while True:
            try:
                sum(range(1000))
            except Exception:                      # sympy does this in places: the limit must still win
                pass
    assert limit.expired and time.monotonic() - start < 1.0
    with bounded.time_limit(5) as limit:
        pass
    assert not limit.expired


def test_the_worker_returns_raises_and_is_killed_at_its_limit():
    assert bounded.in_worker(sorted, [3, 1, 2]) == [1, 2, 3]
    with pytest.raises(DescriptionError, match="bad.toml"):
        bounded.in_worker(parse, "name = 1", "bad.toml")
    start = time.monotonic()
    with pytest.raises(bounded.WorkerTimeout, match="not finished after 0.5 s"):
        bounded.in_worker(pow, 9, 10 ** 9, seconds=0.5, what="9**10**9")           # inside C: no signal helps
    assert time.monotonic() - start < 2.5


@pytest.mark.parametrize("signum,code", [pytest.param(signal.SIGTERM, 143, marks=pytest.mark.slow),
                                         (signal.SIGINT, 130)])
def test_a_signal_stops_plant_check_at_once(tmp_path, signum, code):
    """A description whose symbolic checks run long (an 8 x 8 M(q)): SIGTERM gives 143, Ctrl-C 130, within a
    second, and no worker is left behind."""
    from tests.description_samples import diagonal_device
    path = tmp_path / "d.toml"
    path.write_text(diagonal_device(8))
    proc = subprocess.Popen([EMCOSIM, "plant", "check", str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    time.sleep(3.0)                                  # imports done, the worker inside sympy
    assert proc.poll() is None
    os.killpg(proc.pid, signum) if signum == signal.SIGINT else proc.send_signal(signum)
    sent = time.monotonic()
    assert proc.wait(timeout=10) == code
    assert time.monotonic() - sent < 2.0
    assert f"interrupted by {signal.Signals(signum).name}" in proc.stderr.read().decode()
    with pytest.raises(ProcessLookupError):          # the worker went with it
        os.killpg(proc.pid, 0)


# ---- item 5: no NaN decides a verdict --------------------------------------------------------------

def test_a_non_finite_sample_makes_assumption_3_not_decided():
    """M = 1e-320 made every sample non-finite and Assumption 3 'held' with alpha = inf, beta = -inf. Here
    hess V = exp(q) overflows at the samples q = 800: no verdict from them."""
    desc = parse(_with_V("b*q + exp(q)"), "m.toml")
    model = plant_check.Model(desc)
    points = [np.array([800.0, 0.0, 1.0]), np.array([0.001, 0.0, 1.0])]
    v = plant_check.assumption_3(model, points, "")
    test = v.tests[-1]
    assert test.verdict == plant_check.NOT_DECIDED and "not finite" in test.detail and "1 of 2" in test.detail


# ---- item 7: errors name the file and the entry -----------------------------------------------------

@pytest.mark.parametrize("old,new,entry", [
    ('name = "Maglev"', 'name = "device"', "[top level] name"),
    ('V   = "b*q"', 'V = "b*q/(c - 0.005)"', "[model] V"),
    ('V   = "b*q"', 'V = "b*q + exp(exp(exp(1000)))"', "[model] V"),
])
def test_the_issue_s_unclear_errors_name_the_file_and_the_entry(tmp_path, capsys, old, new, entry):
    path = tmp_path / "bad.toml"
    text = MAGLEV.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    assert main(["plant", "check", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"emcosim: error: {path}: {entry}: ") and "Traceback" not in "\n".join(err)


@pytest.mark.parametrize("text", ["a ---> <x/>", "--->", "end-", "a -- b", "x\n-->\n<y/>"])
def test_text_in_an_xml_comment_cannot_end_it(text):
    """Parameter descriptions reach the .ssv as comments (emcosim plant scenario): "--->" became "- -->" and
    ended the comment, putting the rest of the text into the XML."""
    from xml.etree import ElementTree as ET

    from emcosim.engine.ssd_writer import _comment
    body = _comment(text)
    assert "--" not in body and not body.endswith("-")
    root = ET.fromstring(f"<a><!-- {body} --></a>")
    assert len(root) == 0


def test_a_huge_or_binary_file_and_too_many_parameters_are_refused(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text(ISSUE_MAGLEV + "#" * (description.MAX_FILE + 1))
    with pytest.raises(DescriptionError, match=r"big\.toml: \[file\] big\.toml: larger than"):
        description.load(big)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"name = \"A\"\n\xff\xfe")
    with pytest.raises(DescriptionError, match=r"bin\.toml: \[file\] bin\.toml: not UTF-8"):
        description.load(binary)
    many = "\n".join(f'z{i} = [1.0, "1", "unused"]' for i in range(201))
    with pytest.raises(DescriptionError, match=r"\[parameters\] parameters: 207 parameters: at most 200"):
        parse(ISSUE_MAGLEV.replace("[parameters]     # name = [default, unit, description]",
                                   "[parameters]\n" + many), "m.toml")


def test_an_overflowing_force_gives_no_electrical_state_and_no_verdict():
    """A required force that overflowed (inf) gave x_e = sqrt(inf) and a set-point that 'held'."""
    model = plant_check.Model(parse(ISSUE_MAGLEV, "m.toml"))
    x, why = model.electrical_state(np.array([0.001]), np.array([np.inf]))
    assert x is None and why.startswith(plant_check.NOT_FINITE)

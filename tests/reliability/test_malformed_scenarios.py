"""Malformed scenarios: a small fuzzer mutates copies of real scenario folders (SystemStructure.ssd and
.ssv files): deleted elements and attributes, wrong types and values, dangling connections, an algebraic
cycle, unknown or broken FMUs, truncated and garbage XML, plus seeded random mutations. Every case runs
through `emcosim run` (emcosim.cli.main, all cases in one subprocess, stderr captured at the descriptor
level) and must end in exit status 1 with exactly one line 'emcosim: error: ...' and no traceback;
a mutation that leaves a valid scenario must run (exit 0, CSV written). Designed-invalid mutations
must fail."""
from __future__ import annotations

import json
import random
import shutil
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree as ET

import pytest

from emcosim.engine.ssd import NS

from .harness import ROOT
from .scenarios import one_line_error

pytestmark = pytest.mark.reliability

DRIVER = Path(__file__).with_name("_cli_driver.py")
BASES = {"mems_regulation_Dd0": "5e-5", "maglev_regulation_prop2": "5e-3"}      # stop times: 5 and 10 steps
SEED = 20240607
N_RANDOM = 40


def _q(tag: str) -> str:
    prefix, _, name = tag.partition(":")
    return f"{{{NS[prefix]}}}{name}"


def _xml_mutation(path: str, find: str, action):
    """A mutation of one XML file: `action(root, element)` on the first element matching `find`."""
    def apply(folder: Path) -> None:
        file = folder / path
        tree = ET.parse(file)
        root = tree.getroot()
        el = root if find == "." else root.find(find, NS)
        assert el is not None, (path, find)
        action(root, el)
        tree.write(file, xml_declaration=True, encoding="UTF-8")
    return apply


def delete_child(parent_find: str, child_find: str, path: str = "SystemStructure.ssd"):
    def action(root, parent):
        parent.remove(parent.find(child_find, NS))
    return _xml_mutation(path, parent_find, action)


def set_attr(find: str, name: str, value, path: str = "SystemStructure.ssd"):
    def action(root, el):
        if value is None:
            del el.attrib[name]
        else:
            el.set(name, value)
    return _xml_mutation(path, find, action)


def rename_tag(find: str, new_tag: str, path: str = "SystemStructure.ssd"):
    return _xml_mutation(path, find, lambda root, el: setattr(el, "tag", _q(new_tag)))


def add_connection(start: str, end: str):
    def action(root, connections):
        a, b = start.split("."), end.split(".")
        ET.SubElement(connections, _q("ssd:Connection"), startElement=a[0], startConnector=a[1],
                      endElement=b[0], endConnector=b[1])
    return _xml_mutation("SystemStructure.ssd", "ssd:System/ssd:Connections", action)


def remove_connection(end: str):
    def action(root, connections):
        for c in list(connections):
            if f"{c.get('endElement')}.{c.get('endConnector')}" == end:
                connections.remove(c)
    return _xml_mutation("SystemStructure.ssd", "ssd:System/ssd:Connections", action)


def text(path: str, transform):
    def apply(folder: Path) -> None:
        file = folder / path
        file.write_bytes(transform(file.read_bytes()))
    return apply


def remove_file(path: str):
    return lambda folder: (folder / path).unlink()


COMP = "ssd:System/ssd:Elements/ssd:Component"
PLANT = f"{COMP}[@name='plant']"
CTRL = f"{COMP}[@name='controller']"
CONN = "ssd:System/ssd:Connections/ssd:Connection"
ALGO = "ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation/osp:Algorithm/osp:FixedStepAlgorithm"
PARAM = "ssv:Parameters/ssv:Parameter[@name='m']"

def duplicate_parameter(root, parameters):
    """Set plant.m a second time, to another value, further down the same ParameterSet (issue 26, item 8)."""
    import copy
    twice = copy.deepcopy(parameters.find("ssv:Parameter[@name='m']", NS))
    real = twice.find("ssv:Real", NS)
    real.set("value", repr(1.5 * float(real.get("value"))))
    parameters.append(twice)


# name -> mutation; every one of these makes the scenario invalid
DESIGNED = {
    "parameter set twice": _xml_mutation("plant.ssv", "ssv:Parameters", duplicate_parameter),
    "delete System": delete_child(".", "ssd:System"),
    "delete Elements": delete_child("ssd:System", "ssd:Elements"),
    "delete the plant component": delete_child("ssd:System/ssd:Elements", "ssd:Component[@name='plant']"),
    "delete a connector": delete_child(f"{PLANT}/ssd:Connectors", "ssd:Connector[@name='q']"),
    "delete a connector's type": delete_child(f"{PLANT}/ssd:Connectors/ssd:Connector[@name='q']", "ssc:Real"),
    "delete component name": set_attr(PLANT, "name", None),
    "delete component source": set_attr(PLANT, "source", None),
    "delete connection startElement": set_attr(CONN, "startElement", None),
    "delete connection endConnector": set_attr(CONN, "endConnector", None),
    "delete connector kind": set_attr(f"{PLANT}/ssd:Connectors/ssd:Connector", "kind", None),
    "delete baseStepSize": set_attr(ALGO, "baseStepSize", None),
    "delete parameter value": set_attr(f"{PARAM}/ssv:Real", "value", None, "plant.ssv"),
    "delete parameter name": set_attr(PARAM, "name", None, "plant.ssv"),
    "Real value 'abc'": set_attr(f"{PARAM}/ssv:Real", "value", "abc", "plant.ssv"),
    "Real value ''": set_attr(f"{PARAM}/ssv:Real", "value", "", "plant.ssv"),
    "Real value 'nan'": set_attr(f"{PARAM}/ssv:Real", "value", "nan", "plant.ssv"),
    "Real value '-1'": set_attr(f"{PARAM}/ssv:Real", "value", "-1", "plant.ssv"),
    "Real value '1e999'": set_attr(f"{PARAM}/ssv:Real", "value", "1e999", "plant.ssv"),
    "parameter typed Integer '1.5'": _xml_mutation("plant.ssv", f"{PARAM}/ssv:Real",
                                                   lambda r, e: (setattr(e, "tag", _q("ssv:Integer")), e.set("value", "1.5"))),
    "parameter typed Boolean": rename_tag(f"{PARAM}/ssv:Real", "ssv:Boolean", "plant.ssv"),
    "parameter typed String": rename_tag(f"{PARAM}/ssv:Real", "ssv:String", "plant.ssv"),
    "unknown parameter": set_attr(PARAM, "name", "no_such_parameter", "plant.ssv"),
    "parameter set on an output": set_attr(PARAM, "name", "H", "plant.ssv"),
    "connector typed Integer": rename_tag(f"{PLANT}/ssd:Connectors/ssd:Connector[@name='q']/ssc:Real", "ssc:Integer"),
    "connector kind reversed": set_attr(f"{PLANT}/ssd:Connectors/ssd:Connector[@name='q']", "kind", "input"),
    "connector kind nonsense": set_attr(f"{PLANT}/ssd:Connectors/ssd:Connector[@name='q']", "kind", "sideways"),
    "stopTime 'abc'": set_attr("ssd:DefaultExperiment", "stopTime", "abc"),
    "stopTime 'inf'": set_attr("ssd:DefaultExperiment", "stopTime", "inf"),
    "baseStepSize '-1'": set_attr(ALGO, "baseStepSize", "-1"),
    "baseStepSize '0'": set_attr(ALGO, "baseStepSize", "0"),
    "dangling connection: no element": set_attr(CONN, "endElement", "nowhere"),
    "dangling connection: no connector": set_attr(CONN, "endConnector", "nothing"),
    "connection output to output": set_attr(CONN, "endConnector", "u"),
    "input fed twice": add_connection("plant.p", "controller.q"),
    "algebraic cycle": lambda f: (remove_connection("controller.q")(f), add_connection("controller.u", "controller.q")(f)),
    "unknown FMU": set_attr(PLANT, "source", "../../build/fmus/NoSuchModel.fmu"),
    "FMU that is not a zip": set_attr(PLANT, "source", "../../build/fmus/Garbage.fmu"),
    "FMU that is an empty zip": set_attr(PLANT, "source", "../../build/fmus/Empty.fmu"),
    "duplicate component names": set_attr(CTRL, "name", "plant"),
    "component name with a dot": set_attr(PLANT, "name", "pl.ant"),
    "unsupported element": rename_tag(PLANT, "ssd:SignalDictionary"),
    "wrong root element": rename_tag(".", "ssd:System"),
    "missing .ssv file": remove_file("plant.ssv"),
    "missing .ssd file": remove_file("SystemStructure.ssd"),
    "LinearTransformation factor 'x'": lambda f: _xml_mutation("SystemStructure.ssd", CONN, lambda r, e: ET.SubElement(
        e, _q("ssc:LinearTransformation"), factor="x"))(f),
    "truncated .ssd": text("SystemStructure.ssd", lambda b: b[: len(b) // 2]),
    "truncated .ssv": text("plant.ssv", lambda b: b[: len(b) - 30]),
    "empty .ssd": text("SystemStructure.ssd", lambda b: b""),
    "binary garbage .ssd": text("SystemStructure.ssd", lambda b: bytes(range(256)) * 4),
    "latin-1 bytes in .ssv": text("plant.ssv", lambda b: b.replace(b"<ssv:Parameters>",
                                                                   b"<!-- masse \xe9\xe8 --><ssv:Parameters>")),
    "undeclared namespace prefix": text("SystemStructure.ssd", lambda b: b.replace(b"<ssd:Connections>", b"<foo:Connections>")),
}
# the maglev base has no reference component: mutations on it use the same names where they apply
RANDOM_VALUES = ["", "abc", "-1", "0", "nan", "inf", "1e999", "1.5", "plant", "controller.u", "../x.fmu", " "]


def random_mutation(rng: random.Random):
    """Delete a random element, change or delete a random attribute, or truncate a random file."""
    kind = rng.choice(["delete element", "set attribute", "delete attribute", "truncate"])
    path = rng.choice(["SystemStructure.ssd", "SystemStructure.ssd", "plant.ssv", "controller.ssv"])
    pick, value = rng.random(), rng.choice(RANDOM_VALUES)

    def apply(folder: Path) -> None:
        file = folder / path
        if kind == "truncate":
            data = file.read_bytes()
            file.write_bytes(data[: int(pick * len(data))])
            return
        tree = ET.parse(file)
        elements = list(tree.getroot().iter())
        if kind == "delete element":
            parents = {c: p for p in elements for c in p}
            candidates = [e for e in elements if e in parents]
            victim = candidates[int(pick * len(candidates))]
            parents[victim].remove(victim)
        else:
            candidates = [(e, a) for e in elements for a in e.attrib]
            el, attr = candidates[int(pick * len(candidates))]
            if kind == "set attribute":
                el.set(attr, value)
            else:
                del el.attrib[attr]
        tree.write(file, xml_declaration=True, encoding="UTF-8")
    return f"random {kind} in {path} ({pick:.3f}, {value!r})", apply


@pytest.fixture(scope="module")
def fuzz_results(tmp_path_factory, reliability_fmus):
    """Build every mutated scenario and run them all through the CLI in one subprocess."""
    base = tmp_path_factory.mktemp("malformed")
    fmu_dir = base / "fmus"
    fmu_dir.mkdir()
    for path in reliability_fmus.values():
        (fmu_dir / path.name).symlink_to(path)
    (fmu_dir / "Garbage.fmu").write_bytes(b"this is not a zip archive\n" * 10)
    import zipfile
    zipfile.ZipFile(fmu_dir / "Empty.fmu", "w").close()
    rng = random.Random(SEED)
    cases, expect_failure = [], {}
    for scenario, stop in BASES.items():
        mutations = [(name, m) for name, m in DESIGNED.items()]
        mutations += [random_mutation(rng) for _ in range(N_RANDOM // len(BASES))]
        for i, (name, mutate) in enumerate(mutations):
            folder = base / f"{scenario}-{i:03d}"
            shutil.copytree(ROOT / "scenarios" / scenario, folder)
            label = f"{scenario}: {name}"
            try:
                mutate(folder)
            except (AssertionError, AttributeError, TypeError):        # the mutation does not apply to this base
                shutil.rmtree(folder)
                continue
            cases.append([label, ["run", str(folder), "--fmu-dir", str(fmu_dir), "--stop-time", stop,
                                  "-o", str(folder / "out.csv"), "--no-progress"]])
            expect_failure[label] = not name.startswith("random")
    cases_file, results_file = base / "cases.json", base / "results.json"
    cases_file.write_text(json.dumps(cases))
    proc = subprocess.run([sys.executable, str(DRIVER), str(cases_file), str(results_file)], capture_output=True,
                          text=True, cwd=str(ROOT), timeout=900)
    progress = Path(str(results_file) + ".progress")
    assert proc.returncode == 0, (f"the CLI process died (status {proc.returncode}) on case "
                                  f"{progress.read_text() if progress.exists() else '?'}: {proc.stderr[-2000:]}")
    results = json.loads(results_file.read_text())
    assert len(results) == len(cases)
    return results, expect_failure, dict(cases)


def test_every_malformed_scenario_ends_in_a_one_line_error(fuzz_results, tally):
    results, expect_failure, argv = fuzz_results
    problems = []
    for r in results:
        name = r["name"]
        try:
            if r["status"] == 0:
                assert not expect_failure[name], "a designed-invalid scenario ran"
                out = Path(argv[name][argv[name].index("-o") + 1])
                assert out.is_file() and out.stat().st_size > 0
                assert "Traceback" not in r["stderr"]
                tally.add("malformed_scenarios", "ssd/ssv", "correct")
            else:
                assert r["status"] == 1, f"exit status {r['status']}"
                one_line_error(r["stderr"])
                tally.add("malformed_scenarios", "ssd/ssv", "clean_error")
        except AssertionError as exc:
            problems.append(f"{name}: {exc}\n    stderr: {r['stderr'][-800:]}")
    tally.measurements["malformed_scenarios"] = {
        "cases": len(results), "designed": sum(expect_failure.values()),
        "random": len(results) - sum(expect_failure.values()),
        "stderr_with_fmu_log_lines": sum(1 for r in results if r["status"] == 1 and len(r["stderr"].strip().splitlines()) > 1),
        "seconds": round(sum(r["seconds"] for r in results), 1)}
    assert not problems, f"{len(problems)} of {len(results)} cases:\n" + "\n".join(problems)


def test_a_parameter_set_twice_is_refused_naming_both(fuzz_results):
    """Issue 26, item 8: an .ssv that set plant.m twice ran with the second value (other tools may take the
    first). Now the run is refused before anything is loaded, naming both entries and their values."""
    results, _, _ = fuzz_results
    found = [r for r in results if r["name"].endswith(": parameter set twice")]
    assert len(found) == len(BASES)
    for r in found:
        line = one_line_error(r["stderr"])
        assert "plant.ssv: parameter m is set twice: ssv:Parameter" in line and "keep one" in line, line
        first, second = line.split("(value ")[1:3]
        assert float(second.split("'")[1]) == 1.5 * float(first.split("'")[1]), line

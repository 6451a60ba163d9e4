"""The fuzz targets of tests/fuzz/fmi_fuzz.c (issue 40): which native FMU each harness drives, how its sources are
generated (fmus.native_build, components.c_codegen) and how the harness is compiled and run.

    python -m tests.fuzz.targets [--seconds S] [--jobs 1] [TARGET ...]   # a longer run, its numbers printed

Each target is one native FMU kind: the plants (n = 1: MEMS; n = 6 > 3 states: the levitated bar), a controller
of each family (Proposition 1, Theorem 2: MEMS; Proposition 2, Theorem 3: Maglev) and each operating-point rule
(closed form: the paper's; Newton: the levitated bar's Theorem 3; bias: the two-magnet ball's Proposition 2;
least_energy and least_input: the ball with a spring and damping, n_e = 2 > n_m = 1), and the Reference.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

HERE = Path(__file__).resolve().parent
HARNESS = HERE / "fmi_fuzz.c"
CORPUS = HERE / "corpus"
EXAMPLES = HERE.parents[1] / "examples"
CLANG_FLAGS = ("-std=c99", "-g", "-O1", "-fno-omit-frame-pointer", "-fsanitize=fuzzer,address,undefined",
               "-fno-sanitize-recover=all", "-Wall", "-Wextra", "-Werror")
TARGETS = ("plant_n1", "plant_n6", "proposition1", "theorem2", "proposition2", "theorem3", "newton", "bias",
           "least_energy", "least_input", "reference")
FINDINGS = ("crash-", "leak-", "timeout-", "oom-", "slow-unit-")


def _ball(rule: str) -> str:
    """The two-magnet ball with a spring and damping and the operating point `rule` (least_energy, least_input):
    n_e = 2 > n_m = 1, every branch of components.operating_point.solve in controller.c (as
    tests/test_native_fmus._damped_ball)."""
    text = (EXAMPLES / "two_magnet_ball" / "two_magnet_ball.toml").read_text()
    for old, new in (('rule = "bias"', f'rule = "{rule}"'), ("x_2 = 0.5 ", "# x_2 "), ('R_m = "0"', 'R_m = "d_m"'),
                     ('V   = "b*q"', 'V   = "b*q + k_s*(q - c/2)**2/2"'),
                     ('R_c = [2.25,', 'k_s = [50.0, "N/m", "spring", "> 0"]\nd_m = [0.5, "N.s/m", "damping", "> 0"]\n'
                                      'R_c = [2.25,')):
        assert old in text
        text = text.replace(old, new)
    return text


def build_fmu(target: str, folder: Path) -> tuple[Path, bool]:
    """Build the native FMU of `target` into `folder`: (its path, is it a controller)."""
    from fmus import native_build as nb

    folder.mkdir(parents=True, exist_ok=True)
    paper = {"plant_n1": "MEMS", "proposition1": "MEMS_Proposition1", "theorem2": "MEMS_Theorem2",
             "proposition2": "Maglev_Proposition2", "theorem3": "Maglev_Theorem3"}
    if target == "reference":
        return nb.build_native_reference(folder), False
    if target == "plant_n1":
        return nb.build_native("MEMS", folder), False
    if target in paper:
        return nb.build_native_controller(paper[target], folder), True
    if target == "plant_n6":
        return nb.build_native_description(EXAMPLES / "levitated_bar" / "levitated_bar.toml", folder), False
    if target in ("newton", "bias"):
        folder_name = "levitated_bar" if target == "newton" else "two_magnet_ball"
        toml = EXAMPLES / folder_name / f"{folder_name}.toml"
        design = "Theorem3" if target == "newton" else "Proposition2"
    elif target in ("least_energy", "least_input"):
        toml = folder / f"ball_{target}.toml"
        toml.write_text(_ball(target))
        design = "Theorem2" if target == "least_energy" else "Proposition1"
    else:
        raise ValueError(f"no fuzz target {target!r}: one of {', '.join(TARGETS)}")
    fmus = nb.build_native_description_fmus(toml, [design], folder / "fmus")
    return next(p for identifier, p in fmus.items() if identifier.endswith(design)), True


def fuzzer_available(work: Path) -> str | None:
    """None if clang builds and runs a libFuzzer program with ASan and UBSan here; else why not."""
    if shutil.which("clang") is None:
        return "needs clang (Debian: apt-get install clang)"
    work.mkdir(parents=True, exist_ok=True)
    probe = work / "probe.c"
    probe.write_text("#include <stddef.h>\n#include <stdint.h>\nint LLVMFuzzerTestOneInput(const uint8_t *d, size_t n);\n"
                     "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void)d; (void)n; return 0; }\n")
    run = subprocess.run(["clang", "-fsanitize=fuzzer,address,undefined", str(probe), "-o", str(work / "probe")],
                         capture_output=True, text=True)
    if run.returncode != 0:
        return f"clang has no libFuzzer runtime here (Debian: libclang-rt-14-dev): {run.stderr[-300:]}"
    if subprocess.run([str(work / "probe"), "-runs=1"], capture_output=True).returncode != 0:
        return "a libFuzzer program does not run here"
    return None


def compile_harness(fmu: Path, controller: bool, work: Path) -> Path:
    """The harness linked with the FMU's own sources/ (the <SourceFiles> of its modelDescription)."""
    from fmus.native_build import CONTROLLER_SOURCE_FILES, REFERENCE_SOURCE_FILES, SOURCE_FILES

    sources = work / "sources"
    sources.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/"):
                (sources / Path(member).name).write_bytes(z.read(member))
    files = (REFERENCE_SOURCE_FILES if fmu.stem == "Reference" else
             CONTROLLER_SOURCE_FILES if controller else SOURCE_FILES)
    exe = work / "fuzzer"
    command = ["clang", *CLANG_FLAGS, "-I", str(sources), str(HARNESS), *(str(sources / f) for f in files),
               "-o", str(exe), "-lm"]
    subprocess.run(command, check=True, capture_output=True, text=True)
    return exe


@dataclass
class FuzzRun:
    """One libFuzzer run: its exit status, the files it left (findings), its statistics, its log's tail."""
    returncode: int
    findings: list[Path]
    executions: int
    coverage: int                 # libFuzzer's "cov": edges covered
    features: int                 # "ft": features (edges with hit counts, value profiles)
    corpus: int
    log: str


def run_fuzzer(exe: Path, target: str, work: Path, seconds: int, seed: int = 1, extra: tuple[str, ...] = ()
               ) -> FuzzRun:
    """Run `exe` for `seconds` from the committed seeds (tests/fuzz/corpus/<target>, read only: new inputs go to a
    corpus in `work`); a finding is a non-zero exit or a crash, leak, timeout or oom file."""
    corpus = work / "corpus"
    artifacts = work / "artifacts"
    corpus.mkdir(parents=True, exist_ok=True)
    artifacts.mkdir(parents=True, exist_ok=True)
    command = [str(exe), f"-max_total_time={seconds}", f"-seed={seed}", "-timeout=20", "-rss_limit_mb=2048",
               "-max_len=4096", f"-dict={HERE / 'fmi.dict'}", "-print_final_stats=1",
               f"-artifact_prefix={artifacts}/", *extra, str(corpus),
               str(CORPUS / target)]
    run = subprocess.run(command, capture_output=True, text=True, timeout=seconds + 300,
                         env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1:symbolize=1",
                              "UBSAN_OPTIONS": "print_stacktrace=1:halt_on_error=1", "PATH": "/usr/bin:/bin"})
    log = run.stderr

    def last(pattern: str) -> int:
        found = re.findall(pattern, log)
        return int(found[-1]) if found else 0
    return FuzzRun(run.returncode, sorted(p for p in artifacts.iterdir() if p.name.startswith(FINDINGS)),
                   last(r"stat::number_of_executed_units:\s*(\d+)"), last(r"\bcov: (\d+)"), last(r"\bft: (\d+)"),
                   last(r"\bcorp: (\d+)/"), log[-6000:])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="A longer fuzz run of the native FMUs (docs/reliability.md, round 5).")
    ap.add_argument("targets", nargs="*", default=list(TARGETS))
    ap.add_argument("--seconds", type=int, default=55)
    ap.add_argument("--keep", default=None, help="keep the work folder (findings) here")
    args = ap.parse_args(argv)
    work = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="emcosim_fuzz_"))
    why = fuzzer_available(work)
    if why:
        print(why)
        return 1
    failed = 0
    for target in args.targets:
        fmu, controller = build_fmu(target, work / target / "fmu")
        exe = compile_harness(fmu, controller, work / target)
        run = run_fuzzer(exe, target, work / target, args.seconds)
        failed += bool(run.returncode or run.findings)
        print(f"{target}: exit {run.returncode}, {run.executions} executions, cov {run.coverage}, ft {run.features}, "
              f"corpus {run.corpus}, findings {[p.name for p in run.findings]}", flush=True)
        if run.findings:
            summary = [line for line in run.log.splitlines() if "ERROR" in line or "runtime error" in line
                       or "SUMMARY" in line or "oracle" in line]
            print("    " + "\n    ".join(summary[:6]), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())

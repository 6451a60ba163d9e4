"""The native FMUs C under AddressSanitizer and UndefinedBehaviorSanitizer: tests/native/sanitize_host.c (plants)
and sanitize_controller.c (controllers),
compiled with the sources of a native FMU (-fsanitize=address,undefined, no recovery), runs both
interfaces legally and every illegal call it knows; each status must be the expected one and the
sanitizers must stay silent."""
from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest

from fmus.native_build import CONTROLLER_SOURCE_FILES, SOURCE_FILES, build_native, build_native_controller

HOST = Path(__file__).resolve().parent / "native" / "sanitize_host.c"
CONTROLLER_HOST = Path(__file__).resolve().parent / "native" / "sanitize_controller.c"
pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="needs gcc")


def _sanitizers_work(tmp: Path) -> bool:
    (tmp / "probe.c").write_text("int main(void) { return 0; }\n")
    run = subprocess.run(["gcc", "-fsanitize=address,undefined", "probe.c", "-o", "probe"], cwd=tmp, capture_output=True)
    return run.returncode == 0 and subprocess.run([str(tmp / "probe")], capture_output=True).returncode == 0


# the controllers' hosts get a parameter and a value of it that violates a design condition (emc_ctrl_design):
# K_e = 1/rbar_e - 1/r_e < 0 (min eig, Jacobi), D_d = 50 leaves F_d not Hurwitz (Routh-Hurwitz, Durand-Kerner);
# the examples' n > 1 (the reference by Newton or the least operating point, then the design matrices at it):
# R_e_bar_2_2 = R_c = 2.25 leaves the levitated bar's K_e = 0 (Theorem 3 asks > 0), R_e_bar_1_1 = 2 < R_c gives the
# ball's K_e = -0.25 (tests/test_native_strict.py)
BROKEN = {"MEMS_Proposition1": ("rbar_e", "200"), "Maglev_Theorem3": ("D_d", "50"),
          "levitated_bar:Theorem3": ("R_e_bar_2_2", "2.25"), "two_magnet_ball:Proposition2": ("R_e_bar_1_1", "2")}


EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


# The quick set keeps one plant and one controller; CI (the whole set) runs every case.
@pytest.mark.parametrize("name", ["MEMS", pytest.param("Maglev", marks=pytest.mark.slow),
                                  pytest.param("MEMS_Proposition1", marks=pytest.mark.slow), "Maglev_Theorem3",
                                  # n_m = n_e = 2 (Newton in C) and n_e = 2 > n_m = 1 (a bias operating point)
                                  pytest.param("levitated_bar:Theorem3", marks=pytest.mark.slow),
                                  pytest.param("two_magnet_ball:Proposition2", marks=pytest.mark.slow)])
def test_sanitizers(tmp_path: Path, name: str) -> None:
    if not _sanitizers_work(tmp_path):
        pytest.skip("gcc cannot build or run AddressSanitizer programs here (libasan, libubsan)")
    controller = "_" in name or ":" in name
    if ":" in name:                          # an example device's controller (emcosim plant build --native)
        from fmus.native_build import build_native_description_fmus
        folder, design = name.split(":")
        fmu = next(path for identifier, path in build_native_description_fmus(
            EXAMPLES / folder / f"{folder}.toml", [design], tmp_path / "fmus").items() if identifier.endswith(design))
    else:
        fmu = (build_native_controller if controller else build_native)(name, tmp_path)
    sources = tmp_path / "sources"
    sources.mkdir()
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/"):
                (sources / Path(member).name).write_bytes(z.read(member))
    files = CONTROLLER_SOURCE_FILES if controller else SOURCE_FILES
    command = ["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-g", "-O1", "-fno-omit-frame-pointer",
               "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-I", str(sources),
               str(CONTROLLER_HOST if controller else HOST), *(str(sources / f) for f in files),
               "-o", str(tmp_path / "host"), "-lm"]
    subprocess.run(command, check=True, capture_output=True, text=True)
    run = subprocess.run([str(tmp_path / "host"), *BROKEN.get(name, ())], capture_output=True, text=True, timeout=120,
                         env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"})
    assert run.returncode == 0, run.stderr[-3000:]
    assert "runtime error" not in run.stderr and "AddressSanitizer" not in run.stderr
    assert "0 mismatches" in run.stderr
    if not controller:                             # messages are plain text, '%' doubled (emc_fmi2.c, log_to)
        assert f"{fmu.stem}: fmi2Instantiate: GUID {{50%n%s}} does not match" in run.stdout, run.stdout[-3000:]
    if controller:                                 # the refusal and the warning of the violated condition
        assert run.stdout.count("the parameters violate") == 4, run.stdout[-3000:]


@pytest.mark.parametrize("name", ["MEMS", pytest.param("Maglev", marks=pytest.mark.slow)])
def test_instances_are_independent_across_threads(tmp_path: Path, name: str) -> None:
    """tests/native/threads_host.c under ThreadSanitizer: four CS instances in four threads at once give the
    results each gives alone, bit for bit, and TSan reports no data race."""
    (tmp_path / "probe.c").write_text("int main(void) { return 0; }\n")
    probe = subprocess.run(["gcc", "-fsanitize=thread", "probe.c", "-o", "probe"], cwd=tmp_path, capture_output=True)
    if probe.returncode != 0 or subprocess.run([str(tmp_path / "probe")], capture_output=True).returncode != 0:
        pytest.skip("gcc cannot build or run ThreadSanitizer programs here")
    fmu = build_native(name, tmp_path)
    sources = tmp_path / "sources"
    sources.mkdir()
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/"):
                (sources / Path(member).name).write_bytes(z.read(member))
    host = Path(__file__).resolve().parent / "native" / "threads_host.c"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-g", "-O1", "-fsanitize=thread", "-pthread",
                    "-I", str(sources), str(host), *(str(sources / f) for f in SOURCE_FILES), "-o", str(tmp_path / "host"),
                    "-lm"], check=True, capture_output=True, text=True)
    run = subprocess.run([str(tmp_path / "host")], capture_output=True, text=True, timeout=120,
                         env={"TSAN_OPTIONS": "halt_on_error=1"})
    assert run.returncode == 0, run.stderr[-3000:]
    assert "ThreadSanitizer" not in run.stderr and "0 mismatches" in run.stderr


@pytest.mark.slow                          # ~3 CPU-s: the quick set has no room left
def test_reference_under_sanitizers(tmp_path: Path) -> None:
    """The Reference FMU's sources with tests/native/sanitize_reference.c under AddressSanitizer and
    UndefinedBehaviorSanitizer: both interfaces, bad kinds, types and arguments, the FMU-state pool, a corrupt
    serialized state; every status as expected and the sanitizers silent."""
    from fmus.native_build import REFERENCE_SOURCE_FILES, build_native_reference
    if not _sanitizers_work(tmp_path):
        pytest.skip("gcc cannot build or run AddressSanitizer programs here (libasan, libubsan)")
    fmu = build_native_reference(tmp_path)
    sources = tmp_path / "sources"
    sources.mkdir()
    with zipfile.ZipFile(fmu) as z:
        for member in z.namelist():
            if member.startswith("sources/"):
                (sources / Path(member).name).write_bytes(z.read(member))
    host = Path(__file__).resolve().parent / "native" / "sanitize_reference.c"
    subprocess.run(["gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-g", "-O1", "-fno-omit-frame-pointer",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-I", str(sources), str(host),
                    *(str(sources / f) for f in REFERENCE_SOURCE_FILES), "-o", str(tmp_path / "host"), "-lm"],
                   check=True, capture_output=True, text=True)
    run = subprocess.run([str(tmp_path / "host")], capture_output=True, text=True, timeout=120,
                         env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=0", "UBSAN_OPTIONS": "print_stacktrace=1"})
    assert run.returncode == 0, run.stderr[-3000:]
    assert "runtime error" not in run.stderr and "AddressSanitizer" not in run.stderr
    assert "0 mismatches" in run.stderr

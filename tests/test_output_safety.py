"""Issue 26, items 1-5: output handling never opens, renames or deletes a path that emcosim did not
create in that run or mark as its own. Each test reproduces an attack of the issue and fails on the
code before the fix (commit da16e3a).

Independent truths: byte-for-byte equality of files that must not change (a victim file outside the
output folder, a good result, a user's files), the set of names in a folder, and the text of the
lines a file holds. The kill -9 of an export is in tests/reliability/test_output_integrity.py."""
from __future__ import annotations

import io
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from emcosim.cli import main
from emcosim.engine.errors import ScenarioError
from emcosim.engine.results import read_csv

from .integrity_helpers import build_toys, emcosim, partial_note, partial_of, toy_loop

PAYLOAD = "\n* * * * * root echo injected\n"                  # a crontab line, as in the issue


@pytest.fixture(scope="module")
def toys(tmp_path_factory) -> dict[str, Path]:
    return build_toys(tmp_path_factory.mktemp("toys"))


@pytest.fixture
def loop(tmp_path, toys) -> Path:
    return toy_loop(tmp_path / "loop", toys)


@pytest.fixture
def victim(tmp_path) -> Path:
    """A file of the user's outside every output folder."""
    path = tmp_path / "home" / "victim.conf"
    path.parent.mkdir()
    path.write_text("setting = 1\n")
    return path


def run(args: list[str], capsys) -> tuple[int, str]:
    status = main(args + (["--no-progress"] if args[0] == "run" else []))
    return status, capsys.readouterr().err.strip()


def names(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()}


def tree(folder: Path) -> dict[str, bytes | None]:
    """Every path under `folder` (relative) with its bytes (None for a folder)."""
    return {str(p.relative_to(folder)): (None if p.is_dir() else p.read_bytes()) for p in sorted(folder.rglob("*"))}


# ---- 1. orphans: a marker inside the file, no symlinks, no text from names -----------------------

def test_orphan_marking_never_writes_through_a_symlink(loop, tmp_path, victim, capsys):
    """The issue's attack: a symlink to the user's file, named like an orphan whose "pid" is a crontab
    line. The run succeeds and the file behind the link is unchanged."""
    out = tmp_path / "x.csv"
    link = tmp_path / f"x.incomplete-{PAYLOAD}.csv"
    link.symlink_to(victim)
    status, err = run(["run", str(loop), "-o", str(out)], capsys)
    assert status == 0, err
    assert victim.read_text() == "setting = 1\n"
    assert link.is_symlink() and os.readlink(link) == str(victim)
    assert len(read_csv(out)["time"]) == 101


def test_a_file_emcosim_did_not_write_is_not_marked(tmp_path):
    """A user's own file named like an orphan, without emcosim's marker line: left byte for byte."""
    from emcosim.engine.outputs import mark_orphans

    user = tmp_path / "r.incomplete-999999.csv"
    user.write_bytes(b"time,a\n0.0,1.0\n0.5,2.0\n")
    assert mark_orphans(tmp_path / "r.csv") == []
    assert user.read_bytes() == b"time,a\n0.0,1.0\n0.5,2.0\n"


def test_an_orphans_comment_takes_no_text_from_its_name(tmp_path):
    """A file emcosim wrote, its run killed (the lock released), renamed so that its name holds a
    crontab line: marked partial, with the pid written inside the file, and no line of the name."""
    from emcosim.engine.outputs import ResultFile, mark_orphans

    sink = ResultFile(tmp_path / "r.csv", "toy")
    sink.start(["a"])
    for t in (0.0, 0.5):
        sink.write([t, 2 * t])
    sink.flush()
    os.close(sink.fd)                                                   # killed: the kernel drops the lock
    renamed = tmp_path / f"r.incomplete-{PAYLOAD}.csv"
    os.rename(sink.temp, renamed)
    notes = mark_orphans(tmp_path / "r.csv")
    assert len(notes) == 1 and "\n" not in notes[0] and f"(pid {os.getpid()})" in notes[0], notes
    text = renamed.read_text()
    assert "injected" not in text and f"pid {os.getpid()}" in text.splitlines()[0], text
    assert "ended without a clean exit" in partial_note(renamed) and "2 rows up to t = 0.5 s" in partial_note(renamed)
    assert read_csv(renamed)["a"].tolist() == [0.0, 1.0]


def test_folder_orphan_never_writes_through_a_dangling_symlink(tmp_path, victim):
    """The folder variant: OUT.incomplete-PID/ holding a marker and PARTIAL.txt as a dangling symlink."""
    from emcosim.engine.output_folder import OutputFolder

    planted = tmp_path / "out.incomplete-999999"
    planted.mkdir()
    (planted / ".emcosim").write_text("")
    target = victim.parent / "created-by-emcosim"
    (planted / "PARTIAL.txt").symlink_to(target)
    folder = OutputFolder(tmp_path / "out")
    folder.discard()
    assert not target.exists() and not target.is_symlink()
    assert names(planted) == {".emcosim", "PARTIAL.txt"} and (planted / "PARTIAL.txt").is_symlink()


def test_results_file_given_as_a_symlink_is_refused(loop, tmp_path, victim, capsys):
    """-o naming a symlink: refused before the run (neither its target written nor the link replaced)."""
    out = tmp_path / "x.csv"
    out.symlink_to(victim)
    status, err = run(["run", str(loop), "-o", str(out)], capsys)
    assert status == 1 and "symbolic link" in err.splitlines()[-1], err
    assert victim.read_text() == "setting = 1\n" and out.is_symlink()
    assert names(tmp_path) == {"loop", "home", "x.csv"}


# ---- 2. export: written beside the destination, renamed into place --------------------------------

def test_failed_export_keeps_the_old_fmu(loop, tmp_path, monkeypatch):
    """An export that fails while the container is built leaves the old loop.fmu as it was."""
    from emcosim.engine import container
    from emcosim.engine.ssd import read_scenario

    out = tmp_path / "loop.fmu"
    out.write_bytes(b"the user's old FMU")

    def fails(config, unzipdir, filename):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(container, "create_container_fmu", fails)
    with pytest.raises(ScenarioError, match="cannot write the container FMU: No space left on device"):
        container.export_container(read_scenario(loop), out)
    assert out.read_bytes() == b"the user's old FMU"
    assert names(tmp_path) == {"loop", "loop.fmu"}


def test_export_onto_another_filesystem(loop, tmp_path):
    """The issue's case: the temporary folder on one file system, -o on another (/dev/shm, tmpfs):
    the new FMU replaces the old one (it used to be deleted, then `Invalid cross-device link`)."""
    shm = Path("/dev/shm")
    if not shm.is_dir() or not os.access(shm, os.W_OK) or shm.stat().st_dev == tmp_path.stat().st_dev:
        pytest.skip("needs /dev/shm on a file system of its own")
    dest = Path(tempfile.mkdtemp(dir=shm, prefix="emcosim-test-"))
    try:
        out = dest / "loop.fmu"
        out.write_bytes(b"old")
        proc = emcosim(["export", str(loop), "-o", str(out)], timeout=120, env={"TMPDIR": str(tmp_path)})
        assert proc.returncode == 0, proc.stderr
        assert out.read_bytes()[:2] == b"PK" and names(dest) == {"loop.fmu"}
    finally:
        shutil.rmtree(dest)


def test_export_to_a_symlink_is_refused(loop, tmp_path, victim, capsys):
    out = tmp_path / "loop.fmu"
    out.symlink_to(victim)
    status, err = run(["export", str(loop), "-o", str(out)], capsys)
    assert status == 1 and "symbolic link" in err.splitlines()[-1], err
    assert victim.read_text() == "setting = 1\n" and out.is_symlink()


def test_stale_temp_folder_without_emcosim_marker_is_kept(tmp_path, monkeypatch):
    """clean_stale removes the temporary folders of dead emcosim processes, recognised by the marker
    emcosim puts inside, not a user's folder that only has the name."""
    from emcosim.engine import tempdirs

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    mine = tmp_path / "emcosim-999999-notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("keep me")
    made = tempdirs.make("export")
    dead = made.with_name(made.name.replace(f"emcosim-{os.getpid()}-", "emcosim-999998-"))
    os.rename(made, dead)                                       # a folder of a process that died
    removed = tempdirs.clean_stale()
    assert removed == [dead] and not dead.exists()
    assert (mine / "todo.txt").read_text() == "keep me"


# ---- 3. a folder is replaced only if it holds nothing but what emcosim wrote ----------------------

def users_folder(path: Path) -> dict[str, bytes | None]:
    """The issue's folder: the user's own sweep.csv, thesis/ch1.tex and precious.bin."""
    (path / "thesis").mkdir(parents=True)
    (path / "sweep.csv").write_text("k,result\n1,2\n")
    (path / "thesis" / "ch1.tex").write_text("\\chapter{One}\n")
    (path / "precious.bin").write_bytes(os.urandom(64))
    return tree(path)


def test_sweep_refuses_a_users_folder(loop, tmp_path):
    out = tmp_path / "mydata"
    before = users_folder(out)
    proc = emcosim(["sweep", str(loop), "--grid", "ctrl.k=-1,-0.5", "--workers", "1", "--no-plots",
                    "--no-progress", "--stop-time", "0.05", "--out", str(out)], timeout=240)
    assert proc.returncode == 1, proc.stderr
    line = proc.stderr.strip().splitlines()[-1]
    assert "not written by emcosim" in line and "precious.bin" in line and "Traceback" not in proc.stderr, line
    assert tree(out) == before and names(tmp_path) == {"loop", "mydata"}


def test_reproduce_refuses_a_users_folder(fmu_dir, tmp_path):
    """Refused before any scenario runs (the folder used to be accepted for its runs.json, and the
    user's files were deleted when the results replaced it)."""
    from emcosim.paper.reproduce import reproduce

    out = tmp_path / "results"
    users_folder(out)
    (out / "runs.json").write_text("{}")                    # the old recognised name: not enough
    before = tree(out)
    log = io.StringIO()
    with pytest.raises(ScenarioError, match="not written by emcosim.*precious.bin"):
        reproduce(out, stop_time=1e-4, out=log, fmu_dir=fmu_dir, jobs=1)
    assert "[1/10]" not in log.getvalue()
    assert tree(out) == before and names(tmp_path) == {"results"}


def written_folder(dest: Path, files: dict[str, str]) -> None:
    from emcosim.engine.output_folder import OutputFolder

    with OutputFolder(dest) as folder:
        for name, text in files.items():
            (folder.path / name).parent.mkdir(parents=True, exist_ok=True)
            (folder.path / name).write_text(text)


def test_a_folder_emcosim_wrote_is_replaced(tmp_path):
    out = tmp_path / "out"
    written_folder(out, {"a.csv": "1\n", "figs/b.png": "png"})
    written_folder(out, {"c.csv": "2\n"})
    assert {k for k, v in tree(out).items()} == {".emcosim", "c.csv"} and names(tmp_path) == {"out"}


@pytest.mark.parametrize("change", ["added", "edited"])
def test_a_folder_emcosim_wrote_then_changed_is_refused(tmp_path, change):
    """A file the user added to (or edited in) a results folder is never deleted without a word."""
    from emcosim.engine.output_folder import OutputFolder

    out = tmp_path / "out"
    written_folder(out, {"a.csv": "1\n"})
    if change == "added":
        (out / "notes.txt").write_text("mine")
    else:
        (out / "a.csv").write_text("1\nmy edit\n")
    before = tree(out)
    with pytest.raises(ScenarioError, match="not written by emcosim.*(notes.txt|a.csv)"):
        OutputFolder(out)
    assert tree(out) == before and names(tmp_path) == {"out"}


def test_a_file_added_during_the_run_is_not_deleted(tmp_path):
    """The check is repeated when the folder is replaced: a file added while the run went is kept,
    and the new results go to OUT.partial."""
    from emcosim.engine.output_folder import OutputFolder

    out = tmp_path / "out"
    written_folder(out, {"a.csv": "1\n"})
    folder = OutputFolder(out)
    (folder.path / "b.csv").write_text("2\n")
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ScenarioError, match="not written by emcosim.*notes.txt"):
        folder.commit()
    assert (out / "notes.txt").read_text() == "mine" and (out / "a.csv").read_text() == "1\n"
    assert (tmp_path / "out.partial" / "b.csv").read_text() == "2\n"
    assert names(tmp_path) == {"out", "out.partial"}


# ---- 4. earlier partial results are kept ----------------------------------------------------------

def test_second_failed_run_keeps_the_first_partial_file(loop, tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert run(["run", str(loop), "--set", "plant.fail_at=0.5", "-o", str(out)], capsys)[0] == 1
    first = partial_of(out).read_bytes()
    status, err = run(["run", str(loop), "--set", "plant.fail_at=0.2", "-o", str(out)], capsys)
    assert status == 1
    second = tmp_path / "r.partial-2.csv"
    assert f"21 rows up to t = 0.2 s saved to {second}" in err, err
    assert partial_of(out).read_bytes() == first
    assert len(read_csv(partial_of(out))["time"]) == 51 and len(read_csv(second)["time"]) == 21
    assert names(tmp_path) == {"loop", "r.partial.csv", "r.partial-2.csv", "r.partial.json", "r.partial-2.json"}


def test_second_failed_folder_keeps_the_first_partial_folder(tmp_path):
    from emcosim.engine.output_folder import OutputFolder

    out = tmp_path / "out"
    for n in (1, 2):
        folder = OutputFolder(out)
        (folder.path / "rows.csv").write_text(f"run {n}\n")
        folder.abandon(f"failure {n}")
    assert (tmp_path / "out.partial" / "rows.csv").read_text() == "run 1\n"
    assert (tmp_path / "out.partial-2" / "rows.csv").read_text() == "run 2\n"
    assert "failure 2" in (tmp_path / "out.partial-2" / "PARTIAL.txt").read_text()
    assert names(tmp_path) == {"out.partial", "out.partial-2"}


# ---- 5. figures follow the rules of results files; --plot is checked before the run ------------

def test_failed_run_keeps_the_good_figure(loop, tmp_path, capsys):
    """The figure of a failed run goes to NAME.partial.png, marked partial inside the file (its PNG
    description) and on the figure; the good figure of an earlier run is left as it was."""
    from PIL import Image

    out, fig = tmp_path / "r.csv", tmp_path / "r.png"
    assert run(["run", str(loop), "-o", str(out), "--plot", str(fig)], capsys)[0] == 0
    good = fig.read_bytes()
    status, err = run(["run", str(loop), "--set", "plant.fail_at=0.5", "-o", str(out), "--plot", str(fig)], capsys)
    assert status == 1, err
    partial = tmp_path / "r.partial.png"
    assert fig.read_bytes() == good and partial.is_file(), names(tmp_path)
    assert f"plot {partial}" in err.splitlines()[-1], err
    description = Image.open(partial).text.get("Description", "")
    assert description.startswith("emcosim: PARTIAL result") and "51 rows up to t = 0.5 s" in description, description
    assert names(tmp_path) == {"loop", "r.csv", "r.json", "r.png", "r.partial.csv", "r.partial.json", "r.partial.png"}


@pytest.mark.parametrize("plot, message", [("x.txt", "cannot draw a .txt file"), ("x", "no image format")])
def test_plot_format_is_checked_before_the_run(loop, tmp_path, capsys, plot, message):
    out = tmp_path / "r.csv"
    status, err = run(["run", str(loop), "-o", str(out), "--plot", str(tmp_path / plot)], capsys)
    assert names(tmp_path) == {"loop"}                                  # no run: no results file
    assert status == 1 and message in err.splitlines()[-1], err


def test_plot_to_a_symlink_is_refused_before_the_run(loop, tmp_path, victim, capsys):
    fig = tmp_path / "r.png"
    fig.symlink_to(victim)
    status, err = run(["run", str(loop), "-o", str(tmp_path / "r.csv"), "--plot", str(fig)], capsys)
    assert status == 1 and "symbolic link" in err.splitlines()[-1], err
    assert victim.read_text() == "setting = 1\n" and names(tmp_path) == {"loop", "home", "r.png"}

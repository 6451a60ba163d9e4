"""Run many `emcosim run` invocations in one process (emcosim.cli.main), capturing stderr at the file
descriptor level (so that anything an FMU or the interpreter writes is seen too).

Usage: python _cli_driver.py CASES.json RESULTS.json, CASES = [[name, [argv...]], ...]. Progress
(the case being run) is written to RESULTS.json.progress so that a crash names its case."""
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from emcosim.cli import main  # noqa: E402


def run(argv):
    with tempfile.TemporaryFile(mode="w+b") as capture:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(capture.fileno(), 2)
        tic = time.perf_counter()
        try:
            status = main(argv)
        except SystemExit as exc:               # argparse usage errors
            status = exc.code
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        capture.seek(0)
        return status, capture.read().decode("utf-8", "replace"), time.perf_counter() - tic


def main_driver():
    cases = json.loads(Path(sys.argv[1]).read_text())
    out = Path(sys.argv[2])
    progress = Path(str(out) + ".progress")
    results = []
    for name, argv in cases:
        progress.write_text(name)
        status, err, seconds = run(argv)
        results.append({"name": name, "status": status, "stderr": err, "seconds": seconds})
    out.write_text(json.dumps(results))


if __name__ == "__main__":
    main_driver()

"""Issue 15, `emcosim sweep`: an interrupted sweep keeps the runs that finished, and the sweep's Dask
cluster runs only its owner's code.

- Ctrl-C in a terminal sends SIGINT to every process of the group (the client and Dask's worker
  processes): the sweep exits 130 and OUT.partial/sweep.csv holds every run that had finished.
- The local cluster speaks TLS with credentials made for this sweep: another process of the same
  machine (no credentials, plain TCP, or credentials of its own) cannot connect, let alone run code
  (the test's "attack" would create a file).
- `--scheduler` takes the cluster's TLS files (as `dask scheduler --tls-ca-file ...` does)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from emcosim.engine.errors import ScenarioError
from emcosim.paper.sweep import dask_client
from emcosim.paper.sweep_output import read_table

from ..integrity_helpers import ROOT

pytestmark = pytest.mark.reliability


def finished_rows(folder: Path) -> int:
    """Data rows in the table of a sweep that is still running (sweep.incomplete-PID/sweep.csv)."""
    tables = list(folder.glob("sweep.incomplete-*/sweep.csv"))
    if not tables:
        return 0
    lines = [x for x in tables[0].read_text().splitlines() if x and not x.startswith("#")]
    return max(len(lines) - 1, 0)


def test_interrupted_sweep_keeps_the_finished_runs(fmu_dir, tmp_path, tally):
    out = tmp_path / "sweep"
    proc = subprocess.Popen([sys.executable, "-m", "emcosim.cli", "sweep", "mems_regulation_Dd0", "--stop-time", "1e-3",
                             "--grid", "controller.D_d=-1:0:40", "--step-size", "4e-6", "--workers", "1", "--out", str(out),
                             "--fmu-dir", str(fmu_dir)], cwd=str(ROOT), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 300
    while finished_rows(tmp_path) < 8:                 # the rows are appended to the table as runs finish
        assert proc.poll() is None, f"the sweep ended early: {proc.communicate()[1]}"
        assert time.monotonic() < deadline, "no 8 finished runs after 300 s"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)                 # as a terminal's Ctrl-C: the whole process group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert not out.exists()
    partial = tmp_path / "sweep.partial"
    assert "interrupted by SIGINT" in (partial / "PARTIAL.txt").read_text()
    rows = read_table(partial / "sweep.csv")
    assert len(rows) >= 8, rows
    grid = [-1 + k / 39 for k in range(40)]
    for row in rows:
        assert row["status"] == "ok" and row["controller.D_d"] == pytest.approx(grid[int(row["run"])], rel=1e-12)
        assert row["ise"] > 0
    assert f"{len(rows)} finished runs kept in {partial / 'sweep.csv'}" in err, err
    assert "Traceback" not in err, err
    tally.add("sweep_integrity", "Ctrl-C keeps finished runs", "clean_error")
    tally.measurements["sweep_integrity"]["rows_kept"] = len(rows)


ATTACK = """
import sys
from pathlib import Path
from dask.distributed import Client
from distributed.security import Security

marker = Path(sys.argv[1])
attempts = {"no credentials": (sys.argv[2], {}),
            "plain tcp": (sys.argv[2].replace("tls://", "tcp://"), {}),
            "own credentials": (sys.argv[2], {"security": Security.temporary()}),
            "worker, own credentials": (sys.argv[3], {"security": Security.temporary()})}
for label, (address, kwargs) in attempts.items():
    try:
        client = Client(address, timeout="5s", **kwargs)
        client.run(lambda: marker.write_text(label))
        print("RAN CODE", label)
    except Exception as exc:
        print("REFUSED", label, type(exc).__name__)

# a TLS client that trusts any server and shows a certificate of its own: the server must refuse it
import socket, ssl, tempfile
own = Security.temporary()
with tempfile.TemporaryDirectory() as d:
    cert, key = Path(d) / "c.pem", Path(d) / "k.pem"
    cert.write_text(own.tls_client_cert)
    key.write_text(own.tls_client_key)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    context.check_hostname, context.verify_mode = False, ssl.CERT_NONE
    context.load_cert_chain(cert, key)
    for label, address in (("raw TLS to scheduler", sys.argv[2]), ("raw TLS to worker", sys.argv[3])):
        host, port = address[len("tls://"):].rsplit(":", 1)
        try:
            with socket.create_connection((host, int(port)), timeout=5) as raw, \
                    context.wrap_socket(raw, server_hostname=host) as tls:
                tls.sendall(b"x")
                tls.recv(1)                       # TLS 1.3: the server's refusal arrives here
            print("HANDSHAKE ACCEPTED", label)
        except (ssl.SSLError, OSError) as exc:
            print("REFUSED", label, type(exc).__name__)
"""


def test_local_cluster_runs_only_its_owners_code(tmp_path, tally):
    marker = tmp_path / "attacker_was_here"
    with dask_client(workers=1) as client:
        scheduler = client.scheduler.address
        worker = next(iter(client.nthreads()))
        assert scheduler.startswith("tls://127.0.0.1:") and worker.startswith("tls://127.0.0.1:")
        assert client.submit(sum, [1, 2]).result() == 3          # the owner is served
        proc = subprocess.run([sys.executable, "-c", ATTACK, str(marker), scheduler, worker],
                              capture_output=True, text=True, timeout=120)
    lines = proc.stdout.splitlines()
    assert len(lines) == 6 and all(x.startswith("REFUSED") for x in lines), proc.stdout + proc.stderr
    assert not marker.exists()
    tally.add("sweep_integrity", "other process refused by the local cluster", "correct", 6)


def test_scheduler_option_takes_tls_credentials(tmp_path, tally):
    """A TLS scheduler (in this process, no workers needed to connect): reached with the cluster's
    CA, certificate and key given as files; refused without them."""
    from dask.distributed import LocalCluster
    from distributed.security import Security

    from emcosim.paper.sweep import security

    creds = Security.temporary()
    files = {}
    for name, pem in (("ca", creds.tls_ca_file), ("cert", creds.tls_client_cert), ("key", creds.tls_client_key)):
        files[name] = tmp_path / f"{name}.pem"
        files[name].write_text(pem)
    with LocalCluster(n_workers=0, processes=False, dashboard_address=None, host="127.0.0.1",
                      security=creds) as cluster:
        address = cluster.scheduler_address
        with dask_client(scheduler=address, security=security(str(files["ca"]), str(files["cert"]),
                                                              str(files["key"]))) as client:
            assert client.scheduler_info()["address"] == address
        with pytest.raises(ScenarioError, match="cannot connect"):
            with dask_client(scheduler=address):
                pass
    with pytest.raises(ScenarioError, match="--tls-key: needed with --tls-ca-file, --tls-cert"):
        security(str(files["ca"]), str(files["cert"]), None)
    with pytest.raises(ScenarioError, match="--tls-ca-file .*nowhere.pem: file not found"):
        security(str(tmp_path / "nowhere.pem"), str(files["cert"]), str(files["key"]))
    tally.add("sweep_integrity", "--scheduler with TLS files", "correct")

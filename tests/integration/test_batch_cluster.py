"""`ilcnc batch --scheduler` against a real Dask cluster started the way a shop starts one (issue 24 item 5).

A `dask scheduler` and two `dask worker` processes (one process and one thread each), on the loopback
interface only, started in a folder of their own: the workers have none of the client's relative paths, so
a part must travel as contents. The batch's outputs, states and summary must be those of the local run byte
for byte, also when one worker is killed (SIGKILL) while it learns a part: Dask runs that part again on the
other worker, and the summary says which parts were run again.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import OWN, REPO

pytest.importorskip("distributed", reason="dask.distributed is not installed (pip install -e '.[test]' installs it)")

#: Longest wait for the scheduler's address and for both workers to join, s (each takes ~2-5 s on a loaded machine).
START_TIMEOUT_S = 30.0
#: Longest wait for one `ilcnc batch` of the six parts, s (~3-8 s: each part is a few hundred ms of learning).
BATCH_TIMEOUT_S = 60.0


def _dask(*args: str, cwd: Path, log: Path) -> subprocess.Popen[bytes]:
    """A `dask ...` command in its own process group (a worker's nanny and its worker process die together)."""
    with open(log, "wb") as fh:
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=cwd, stdout=fh, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """End a process group this test started: SIGTERM, then SIGKILL after 10 s."""
    if proc.poll() is not None:
        return
    for sig, wait_s in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


class Cluster:
    """A scheduler and two workers on 127.0.0.1; ``workers[i]`` is worker i's process, ``scratch[i]`` its folder."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.procs: list[subprocess.Popen[bytes]] = []
        self.workers: list[subprocess.Popen[bytes]] = []
        self.scratch: list[Path] = []
        self.address = ""

    def start(self) -> None:
        run = self.root / "cluster"  # the processes' own folder: none of the client's relative paths works here
        run.mkdir()
        sched_file = run / "scheduler.json"
        self.procs.append(_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                "--scheduler-file", str(sched_file), cwd=run, log=run / "scheduler.log"))
        deadline = time.monotonic() + START_TIMEOUT_S
        while not sched_file.is_file() or not sched_file.read_text().strip():
            assert self.procs[0].poll() is None, (run / "scheduler.log").read_text()
            assert time.monotonic() < deadline, "the Dask scheduler did not start in time"
            time.sleep(0.1)
        time.sleep(0.2)  # the file is written in one go; a partial read is retried by json below
        self.address = json.loads(sched_file.read_text())["address"]
        assert self.address.startswith("tcp://127.0.0.1:")
        for i in range(2):
            scratch = run / f"worker{i}"
            scratch.mkdir()
            w = _dask("worker", self.address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                      "--no-dashboard", "--local-directory", str(scratch), "--death-timeout", "30", cwd=run,
                      log=run / f"worker{i}.log")
            self.procs.append(w)
            self.workers.append(w)
            self.scratch.append(scratch)
        from distributed import Client

        with Client(self.address, timeout=f"{START_TIMEOUT_S:.0f}s") as client:
            client.wait_for_workers(2, timeout=START_TIMEOUT_S)

    def stop(self) -> None:
        for p in reversed(self.procs):
            _stop(p)


@pytest.fixture
def cluster(tmp_path: Path) -> Iterator[Cluster]:
    c = Cluster(tmp_path)
    try:
        c.start()
        yield c
    finally:
        c.stop()


def _client_folder(root: Path) -> Path:
    """The client's folder: six parts (three programs twice) and the profile, named by relative paths."""
    client = root / "client"
    (client / "parts").mkdir(parents=True)
    (client / "configs").mkdir()
    shutil.copy(REPO / "configs" / "example-mill.yaml", client / "configs")
    for copy in ("a", "b"):
        for name in ("star.ngc", "circle.ngc", "square.ngc"):
            shutil.copy(OWN / name, client / "parts" / f"{copy}-{name}")
    return client


def _batch(client: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "ilcnc", "batch", "parts", "--profile", "configs/example-mill.yaml", "--out", "out",
            "--iterations", "2", "--json", *extra]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _without_attempts(summary: bytes) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(summary.decode())))
    assert rows[0][-1] == "attempts"
    return [r[:-1] for r in rows]


def test_cluster_batch_matches_the_local_run_and_retries_a_killed_workers_parts(cluster: Cluster, tmp_path: Path) -> None:
    client = _client_folder(tmp_path)
    local = subprocess.run(_batch(client), cwd=client, capture_output=True, timeout=BATCH_TIMEOUT_S, check=False)
    assert local.returncode == 0, local.stderr.decode()[-2000:]
    (client / "out").rename(client / "out-local")
    local_json = json.loads(local.stdout)

    run = subprocess.Popen(_batch(client, "--scheduler", cluster.address), cwd=client, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE)
    try:
        # kill worker 0 (its nanny and its worker process, SIGKILL) once it has started a part: a task's private
        # folder in its scratch space exists exactly while the task runs
        deadline = time.monotonic() + BATCH_TIMEOUT_S
        while not any(cluster.scratch[0].rglob("ilcnc-part-*")):
            assert run.poll() is None, "the batch ended before worker 0 started a part"
            assert time.monotonic() < deadline, "worker 0 started no part in time"
            time.sleep(0.01)
        os.killpg(cluster.workers[0].pid, signal.SIGKILL)
        out, err = run.communicate(timeout=BATCH_TIMEOUT_S)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert cluster.workers[0].wait(timeout=10) == -signal.SIGKILL
    assert run.returncode == 0, err.decode()[-2000:]
    data = json.loads(out)

    # the same files byte for byte (outputs, every state file), the summary's columns but attempts the same
    mine, theirs = _tree(client / "out"), _tree(client / "out-local")
    assert sorted(mine) == sorted(theirs) and len(mine) > 6 * 3
    assert {k for k in mine if mine[k] != theirs[k]} <= {"summary.csv"}
    assert _without_attempts(mine["summary.csv"]) == _without_attempts(theirs["summary.csv"])
    # the results name the client's paths (relative, as given), never the worker's folder
    strip = [{k: v for k, v in p.items() if k != "attempts"} for p in data["parts"]]
    assert strip == [{k: v for k, v in p.items() if k != "attempts"} for p in local_json["parts"]]
    assert all(p["output"].startswith("out/") and p["status"] != "error" for p in data["parts"])

    # the killed worker held the part it ran (and at most one more queued for it: Dask sends a one-thread worker
    # ceil(1.1 x 1) = 2 tasks at its default worker-saturation); those parts, and no others, ran again
    again = [p for p in data["parts"] if p["attempts"] > 1]
    assert 1 <= len(again) <= 2 and data["retried"] == len(again)
    assert all(p["attempts"] == 2 for p in again)
    assert all(p["attempts"] == 1 for p in local_json["parts"]) and local_json["retried"] == 0
    rows = list(csv.DictReader(io.StringIO(mine["summary.csv"].decode())))
    assert sorted(r["program"] for r in rows if r["attempts"] == "2") == sorted(p["program"] for p in again)

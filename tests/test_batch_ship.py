"""A batch part sent to a Dask worker as contents (issue 24 item 5): what the worker learns from the shipped
bytes, written back by the client, is what the local run writes, byte for byte and with the client's paths.

These run the worker's side in this process (no cluster): tests/integration/test_batch_cluster.py runs it on a
real `dask scheduler` with two `dask worker` processes.
"""

from __future__ import annotations

import dataclasses
import io
import shutil
import tempfile
from pathlib import Path

import pytest

from ilcnc import cli
from ilcnc.outcomes import PartStatus
from ilcnc.profile.schema import SPECS
from ilcnc.shop import batch
from ilcnc.shop.batch import (
    PartResult,
    ShippedPart,
    jobs_from_path,
    learn_one,
    learn_shipped,
    run_batch,
    ship_part,
    write_returned,
)
from tests.conftest import OWN, REPO

STEPPED = REPO / "configs" / "seed004-stepped-cut.yaml"
EXAMPLE = REPO / "configs" / "example-mill.yaml"


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def scratch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The worker's temporary folder (outside a Dask worker learn_shipped uses the system's): must end empty."""
    d = tmp_path / "scratch"
    d.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    return d


def _ship(jobs: list) -> list[PartResult]:
    """Every job shipped, learned from its contents, written back: the Dask path without the cluster."""
    out = []
    for job in jobs:
        part = ship_part(job)
        assert isinstance(part, ShippedPart), part
        out.append(write_returned(part, learn_shipped(part, threads=1)))
    return out


def test_profile_file_keys_are_every_key_that_names_a_file() -> None:
    # a key added to the schema that names a file must travel with the part, or a worker lacks the file
    named = {s.path for s in SPECS if "relative to the profile file" in s.doc}
    assert named == set(batch._PROFILE_FILE_KEYS)


def test_shipped_part_writes_what_the_local_run_writes(tmp_path: Path, monkeypatch, scratch) -> None:
    # the client's layout of the shop's repo: the profile names its stock file as ../samples/own/..., relative to it
    client = tmp_path / "client"
    for rel in ("configs/seed004-stepped-cut.yaml", "samples/own/seed004_stepped_omi.csv"):
        (client / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(REPO / rel, client / rel)
    (client / "parts").mkdir()
    shutil.copy(OWN / "seed004_stepped.h", client / "parts")
    shutil.copy(OWN / "seed002_circle.ngc", client / "parts")  # its path is beside the stock points: refused
    monkeypatch.chdir(client)
    jobs = jobs_from_path("parts", "configs/seed004-stepped-cut.yaml", "out", iterations=1)
    local = [r.to_json() for r in run_batch(jobs)]
    Path("out").rename("out-local")
    Path("out").mkdir()
    parts = [ship_part(j) for j in jobs]
    assert all(isinstance(p, ShippedPart) for p in parts)
    assert parts[0].profile_files[0][0] == "../samples/own/seed004_stepped_omi.csv"  # type: ignore[union-attr]
    shipped = [r.to_json() for r in _ship(jobs)]
    assert shipped == local
    assert _tree(client / "out") == _tree(client / "out-local") and len(_tree(client / "out")) >= 6
    by_name = {Path(r["program"]).name: r for r in shipped}
    good = by_name["seed004_stepped.h"]
    assert good["status"] != "error" and good["output"] == "out/seed004_stepped.ilc.h"
    # the message names the client's stock file as the local run does, never the worker's folder
    assert by_name["seed002_circle.ngc"]["error"].startswith("configs/../samples/own/seed004_stepped_omi.csv:7: stock point")
    assert list(scratch.iterdir()) == []  # the worker's private folders are gone


def test_shipped_part_continues_its_state_as_the_local_run(tmp_path: Path, monkeypatch, scratch) -> None:
    (tmp_path / "parts").mkdir()
    shutil.copy(OWN / "star.ngc", tmp_path / "parts")
    monkeypatch.chdir(tmp_path)
    jobs = jobs_from_path("parts", EXAMPLE, "out", iterations=1)
    Path("out").mkdir()
    assert all(r.status != "error" for r in (learn_one(j) for j in jobs))
    shutil.copytree("out", "out-shipped")
    first = _tree(tmp_path / "out")
    second = [learn_one(j) for j in jobs]  # the second run continues the state of the first
    Path("out").rename("out-local")
    Path("out-shipped").rename("out")
    part = ship_part(jobs[0])
    assert isinstance(part, ShippedPart) and part.state is not None and "state.json" in dict(part.state)
    again = _ship(jobs)
    assert [r.to_json() for r in again] == [r.to_json() for r in second]
    assert _tree(tmp_path / "out") == _tree(tmp_path / "out-local")
    # the second run added iterations to the state (it re-measured the best one): it continued, it did not restart
    assert set(first) < set(_tree(tmp_path / "out")) and first["star.ilc.ngc.state/state.json"] != _tree(tmp_path / "out")[
        "star.ilc.ngc.state/state.json"]


def test_state_changed_while_on_the_cluster_is_left_alone(tmp_path: Path, monkeypatch, scratch) -> None:
    (tmp_path / "parts").mkdir()
    shutil.copy(OWN / "star.ngc", tmp_path / "parts")
    monkeypatch.chdir(tmp_path)
    jobs = jobs_from_path("parts", EXAMPLE, "out", iterations=1)
    Path("out").mkdir()
    part = ship_part(jobs[0])
    back = learn_shipped(part, threads=1)  # type: ignore[arg-type]
    learn_one(jobs[0])  # meanwhile, on the client: another run of the part
    before = _tree(tmp_path / "out")
    res = write_returned(part, back)  # type: ignore[arg-type]
    assert res.status == PartStatus.ERROR and res.error.startswith("out/star.ilc.ngc.state: changed while the part was")
    assert _tree(tmp_path / "out") == before


def test_refusals_before_and_on_the_worker(tmp_path: Path, monkeypatch, scratch) -> None:
    monkeypatch.chdir(tmp_path)
    # a profile naming a file by an absolute path: the worker has no such file
    text = STEPPED.read_text().replace("../samples/own/seed004_stepped_omi.csv", str(OWN / "seed004_stepped_omi.csv"))
    Path("abs.yaml").write_text(text)
    shutil.copy(OWN / "seed004_stepped.h", ".")
    job = batch.BatchJob("seed004_stepped.h", "abs.yaml", "o.ilc.h", "o.ilc.h.state", 1)
    refused = ship_part(job)
    assert isinstance(refused, PartResult) and refused.status == PartStatus.ERROR
    assert refused.error.startswith("abs.yaml: cutting.stock: /") and "absolute path" in refused.error
    # an input the client cannot read is not shipped: the client learns (refuses) it with the local run's message
    assert ship_part(dataclasses.replace(job, program="missing.h")) is None
    # a worker with other versions than the client's refuses rather than write other bytes
    part = ship_part(batch.BatchJob("seed004_stepped.h", str(STEPPED), "o.ilc.h", "o.ilc.h.state", 1))
    assert isinstance(part, ShippedPart)
    other = dataclasses.replace(part, versions=("ilcnc 0.0.1", *part.versions[1:]))
    back = learn_shipped(other)
    assert back.output is None and back.state_names is None
    assert back.result.error is not None and "this Dask worker runs other versions" in back.result.error
    assert "on the client" in back.result.error and not Path("o.ilc.h").exists()


def test_table_says_which_parts_were_run_again(tmp_path: Path) -> None:
    from rich.console import Console

    rows = [PartResult(program=f"parts/p{i}.ngc", profile="m.yaml", status=PartStatus.CONVERGED, attempts=a)
            for i, a in enumerate((1, 2, 1, 3))]
    buf = io.StringIO()
    cli._print_batch(rows, Console(file=buf, width=80), tmp_path)
    text = buf.getvalue()
    assert max(len(line) for line in text.splitlines()) <= 80
    words = " ".join(text.split())  # the line wraps at 80 columns
    assert "retried: 2 parts whose worker was lost or whose task failed, run again: p1.ngc (2 attempts), p3.ngc (3" \
        " attempts)" in words
    summary = batch.summary_csv(rows).splitlines()
    assert summary[0].endswith(",attempts") and summary[2].endswith(",2")


def test_a_task_that_raises_is_retried_once_then_reported(tmp_path: Path, monkeypatch, scratch) -> None:
    distributed = pytest.importorskip("distributed", reason="dask.distributed is a test dependency ('.[test]')")
    (tmp_path / "parts").mkdir()
    shutil.copy(OWN / "star.ngc", tmp_path / "parts")
    monkeypatch.chdir(tmp_path)
    runs = tmp_path / "runs.txt"  # the task is pickled by value (a closure's list would be a copy): count in a file

    def full_disk(part: ShippedPart, threads: int | None = None) -> None:  # a worker whose scratch disk is full
        with open(runs, "a") as fh:
            fh.write(part.job.program + "\n")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(batch, "learn_shipped", full_disk)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as c, \
            distributed.Client(c) as client:
        res = run_batch(jobs_from_path("parts", EXAMPLE, "out", iterations=1), scheduler=client)
    assert runs.read_text().split() == ["parts/star.ngc"] * (1 + batch._RETRIES)
    assert res[0].status == PartStatus.ERROR and res[0].attempts == 1 + batch._RETRIES
    assert res[0].error == ("parts/star.ngc: the Dask cluster could not run this part: OSError: [Errno 28] No space left"
                            " on device")
    assert not Path("out/star.ilc.ngc").exists() and batch.retried(res) == res

"""Batch learning per part (folder, manifest, local workers, Dask) and the `check` regression gate."""

from __future__ import annotations

import json
import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from ilcnc import _threads
from ilcnc.cli import app
from ilcnc.contour import search as contour
from ilcnc.profile.load import load_profile
from ilcnc.shop import batch
from ilcnc.shop.batch import jobs_from_path, run_batch
from ilcnc.vcnc import drives
from tests.conftest import OWN, REPO, cli_output

SEED004 = REPO / "configs" / "seed004-ward-sopdt.yaml"
EXAMPLE = REPO / "configs" / "example-mill.yaml"
runner = CliRunner()


def _parts(tmp_path: Path) -> Path:
    d = tmp_path / "parts"
    d.mkdir()
    shutil.copy(REPO / "samples" / "jsdc.gcode", d)
    shutil.copy(OWN / "star.ngc", d)
    shutil.copy(OWN / "square.h", d)
    (d / "broken.ngc").write_text("G21 G90\nG1 X1 Y F100\nM2\n")
    (d / "notes.txt").write_text("not a program\n")
    return d


def test_folder_batch_reports_every_part_and_fails_on_the_broken_one(tmp_path) -> None:
    parts = _parts(tmp_path)
    out = tmp_path / "out"
    res = runner.invoke(app, ["batch", str(parts), "--profile", str(SEED004), "--out", str(out), "--iterations", "2",
                              "--json"])
    assert res.exit_code == 1, res.output
    data = json.loads(res.stdout)
    by_name = {Path(p["program"]).name: p for p in data["parts"]}
    assert set(by_name) == {"broken.ngc", "jsdc.gcode", "star.ngc", "square.h"}
    bad = by_name["broken.ngc"]
    assert bad["status"] == "error" and "broken.ngc:2:" in bad["error"]
    good = by_name["jsdc.gcode"]
    assert good["status"] in ("max_iterations", "stopped", "converged") and good["g01_commands"] == 2381
    assert good["contour_error_mm"]["after"] < 0.7 * good["contour_error_mm"]["before"]
    assert set(good) >= {"program", "profile", "status", "g01_commands", "iterations", "contour_error_mm", "clipped", "error"}
    assert (out / "jsdc.ilc.gcode").is_file() and (out / "square.ilc.h").is_file()
    summary = (out / "summary.csv").read_text().splitlines()
    assert len(summary) == 5 and summary[0].startswith("program,profile,status")


def test_manifest_pairs_programs_with_profiles(tmp_path) -> None:
    d = tmp_path / "job"
    d.mkdir()
    shutil.copy(OWN / "star.ngc", d)
    shutil.copy(OWN / "circle.ngc", d)
    (d / "cell.yaml").write_text(
        f"profiles: [{SEED004}]\niterations: 1\nparts:\n  - program: star.ngc\n"
        f"  - program: circle.ngc\n    profiles: [{SEED004}, {EXAMPLE}]\n")
    jobs = jobs_from_path(d / "cell.yaml", None, tmp_path / "o")
    assert [(Path(j.program).name, Path(j.profile).name) for j in jobs] == [
        ("star.ngc", SEED004.name), ("circle.ngc", SEED004.name), ("circle.ngc", EXAMPLE.name)]
    assert len({j.out for j in jobs}) == 3 and all(j.iterations == 1 for j in jobs)
    (d / "bad.yaml").write_text("parts: [{profiles: [a.yaml]}]\n")
    res = runner.invoke(app, ["batch", str(d / "bad.yaml"), "--out", str(tmp_path / "o2")])
    assert res.exit_code == 1 and "bad.yaml: part 1 has no 'program'" in res.output


def test_two_workers_and_dask_write_the_same_bytes(tmp_path) -> None:
    distributed = pytest.importorskip("distributed", reason="dask.distributed is a test dependency ('.[test]')")
    parts = tmp_path / "p"
    parts.mkdir()
    shutil.copy(OWN / "star.ngc", parts)
    shutil.copy(REPO / "samples" / "jsdc.gcode", parts)
    outs = {}
    for name, kw in (("serial", {"workers": 1}), ("pool", {"workers": 2}), ("one-thread", {"workers": 1, "threads": 1})):
        jobs = jobs_from_path(parts, SEED004, tmp_path / name, iterations=2)
        res = run_batch(jobs, **kw)
        assert all(r.status != "error" for r in res), res
        outs[name] = {Path(r.output).name: Path(r.output).read_bytes() for r in res}
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        jobs = jobs_from_path(parts, SEED004, tmp_path / "dask", iterations=2)
        res = run_batch(jobs, scheduler=client)
        outs["dask"] = {Path(r.output).name: Path(r.output).read_bytes() for r in res}
    assert outs["serial"] == outs["pool"] == outs["one-thread"] == outs["dask"]
    assert set(outs["dask"]) == {"star.ilc.ngc", "jsdc.ilc.gcode"}


def test_check_gate(tmp_path) -> None:
    ok = runner.invoke(app, ["check", str(REPO / "samples" / "jsdc.gcode"), "--profile", str(SEED004), "--max-error", "0.05"])
    assert ok.exit_code == 0 and cli_output(ok).startswith("ok: jsdc.gcode")
    bad = runner.invoke(app, ["check", str(REPO / "samples" / "jsdc.gcode"), "--profile", str(SEED004), "--max-error",
                              "0.01"])
    assert bad.exit_code == 1
    line = bad.output.strip()
    assert line.startswith("error: ") and "jsdc.gcode:" in line and "> 0.01 mm" in line and len(line.splitlines()) == 1
    js = runner.invoke(app, ["check", str(REPO / "samples" / "jsdc.gcode"), "--profile", str(SEED004), "--max-error",
                             "0.01", "--max-rms", "0.001", "--json"])
    data = json.loads(js.stdout)
    assert js.exit_code == 1 and data["passed"] is False and data["contour_error_mm"]["max"] > 0.01


# ------------------------------------------------------------------ threads per part (issue 10: batch scaling)


def _threads_seen(_: object = None) -> dict[str, object]:
    """What a process's pools may use, numpy and scipy's BLAS loaded now (after the pool's initializer)."""
    import scipy.linalg  # noqa: F401 - loads scipy's own BLAS too
    from threadpoolctl import threadpool_info

    return {"ilcnc": _threads.thread_limit(), "pid": os.getpid(), "omp": os.environ.get("OMP_NUM_THREADS"),
            "blas": sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"})}


class _Recorder:
    """Stand-in for ThreadPoolExecutor that records the pool sizes asked for."""

    def __init__(self, sizes: list[int]) -> None:
        self.sizes = sizes

    def __call__(self, max_workers: int):
        from concurrent.futures import ThreadPoolExecutor

        self.sizes.append(max_workers)
        return ThreadPoolExecutor(max_workers=max_workers)


def test_worker_processes_run_on_their_share_of_the_cores() -> None:
    cores = _threads.available_cores()
    assert _threads.threads_per_part(2, 2) == 1 and _threads.threads_per_part(2, 8) == 4
    assert _threads.threads_per_part(3, 2) == 1 and _threads.threads_per_part(1, 2) == 2
    for workers, threads, want in ((2, None, max(1, cores // 2)), (1, 1, 1)):
        with batch._process_pool(workers, threads) as pool:
            seen = [pool.submit(_threads_seen).result() for _ in range(2 * workers)]
        for s in seen:
            assert s["ilcnc"] == want and s["omp"] == str(want), s
            assert s["blas"] and max(s["blas"]) <= want, s  # numpy's and scipy's OpenBLAS
    # the parent keeps every core (a batch of workers=1 runs each part on all of them)
    assert _threads.thread_limit() == cores


def test_thread_limit_scope_is_per_thread_and_nests() -> None:
    cores = _threads.available_cores()
    seen: dict[str, int] = {}
    with _threads.thread_limit_scope(3) as n:
        assert n == 3 == _threads.thread_limit()
        t = threading.Thread(target=lambda: seen.setdefault("other", _threads.thread_limit()))
        t.start()
        t.join()
        with _threads.thread_limit_scope(1):
            assert _threads.thread_limit() == 1
        assert _threads.thread_limit() == 3
    assert seen["other"] == cores and _threads.thread_limit() == cores
    prev = _threads.set_thread_limit(5)
    try:
        assert _threads.thread_limit() == 5
        with _threads.thread_limit_scope(2):
            assert _threads.thread_limit() == 2
    finally:
        _threads.set_thread_limit(prev)
    with pytest.raises(ValueError):
        _threads.set_thread_limit(0)


def test_dask_task_takes_cores_over_worker_threads() -> None:
    distributed = pytest.importorskip("distributed", reason="dask.distributed is a test dependency ('.[test]')")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        assert client.submit(batch._dask_task_threads, pure=False).result() == _threads.threads_per_part(2)
        assert client.submit(batch._dask_task_threads, 3, pure=False).result() == 3
    assert batch._dask_task_threads() == _threads.available_cores()  # outside a worker: as one task per process


def test_contour_threads_do_not_change_the_result(monkeypatch) -> None:
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 6 * np.pi, 400)
    path = contour.PathGeometry.from_polyline(np.column_stack([20 * np.cos(t) + t, 20 * np.sin(t), 0.1 * t]))
    n = 50_000
    s = np.sort(rng.uniform(0, len(path) - 1, n))
    seg = np.minimum(s.astype(np.int64), len(path) - 1)
    ref = path.start_mm[seg] + (path.end_mm[seg] - path.start_mm[seg]) * (s - seg)[:, None]
    act = ref + rng.normal(0, 0.05, (n, 3))
    sizes: list[int] = []
    monkeypatch.setattr(contour, "ThreadPoolExecutor", _Recorder(sizes))
    outs = []
    for limit in (1, 2, 3):
        with _threads.thread_limit_scope(limit):
            outs.append(contour.contour_error(path, act, np.maximum(seg - 3, 0), reference_mm=ref, chunk=4096))
    assert sizes == [2, 3]  # the pools took the limit (1: no pool)
    for o in outs[1:]:
        for f in ("dist_mm", "foot_mm", "vector_mm", "seg", "u", "signed_mm"):
            np.testing.assert_array_equal(getattr(o, f), getattr(outs[0], f), err_msg=f)
        assert o.walked == outs[0].walked
    assert np.isfinite(outs[0].dist_mm).all()


def test_drive_threads_do_not_change_the_result(monkeypatch) -> None:
    prof = load_profile(SEED004)  # x and y
    n = max(drives._PARALLEL_SAMPLES, 120_000)
    t = np.arange(n) * prof.machine.servo_period_s
    ref = np.column_stack([30 * np.sin(0.7 * t), 20 * np.sin(1.3 * t) + 2 * t, np.zeros(n)])
    sizes: list[int] = []
    monkeypatch.setattr(drives, "ThreadPoolExecutor", _Recorder(sizes))
    with _threads.thread_limit_scope(1):
        one = drives.simulate_drives(ref, prof)
    with _threads.thread_limit_scope(2):
        two = drives.simulate_drives(ref, prof)
    assert sizes == [2]
    np.testing.assert_array_equal(one, two)


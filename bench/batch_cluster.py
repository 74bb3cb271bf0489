"""Benchmark: ``ilcnc batch`` on a real Dask cluster, one worker against two (issue 24 item 5).

Usage (from the repository root)::

    python bench/batch_cluster.py                # 200 parts (~3-6 min on the 2-core machine)
    python bench/batch_cluster.py --parts 40     # a smaller batch
    python bench/batch_cluster.py --check        # exit 1 when a target is missed

The parts: the small G-code programs of ``samples/own`` (:data:`PROGRAMS`, 5 to 74 commands, ~0.5 s each;
seed000_corner's 8,000 and seed003_line's 5,000 commands are left out) copied round-robin under new names into a temporary
client folder, with ``configs/example-mill.yaml`` beside them; every part is named by a path relative to
the client folder, and the cluster's processes run in another folder (a worker has none of these paths).

In one run: the local reference (``run_batch`` in this process, ``workers=1``); then a cluster started the way
a shop starts one -- ``dask scheduler --host 127.0.0.1`` and ``dask worker --nworkers 1 --nthreads 1`` -- with
one worker, then a second worker joining the same scheduler. Each part learns on one thread (``threads=1``),
so a worker uses one core. Before each timed batch every worker learns a few parts untimed (loading numba's
cached kernels is a worker's start-up, not the batch's). Timed: ``run_batch(jobs, scheduler=ADDRESS)`` as
``ilcnc batch --scheduler`` calls it (the client reads, ships and writes back every part).

Targets: every file of both cluster runs (outputs, learning states) identical to the local run's; the
efficiency of two workers ``T1 / (2 T2) >= 80 %``. The machine's load average is printed before and after:
on a machine whose cores others use, the efficiency measures them too.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ilcnc.shop.batch import jobs_from_path, run_batch  # noqa: E402

PROFILE = REPO / "configs" / "example-mill.yaml"
#: The parts' programs (samples/own).
PROGRAMS = ("circle.ngc", "seed002_circle.ngc", "square.ngc", "star.ngc", "square-incremental.nc")
#: The target efficiency of two workers against one (issue 24 item 5).
TARGET_EFFICIENCY = 0.80


def _dask(args: list[str], cwd: Path) -> subprocess.Popen[bytes]:
    with open(cwd / f"{args[0]}-{time.monotonic_ns()}.log", "wb") as log:  # the child keeps its own descriptor
        return subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=cwd, stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=15)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()


def _cpu(procs: list[subprocess.Popen[bytes]]) -> list[float]:
    """CPU seconds (user + system) of this process, then of each process group started (a worker: its nanny and
    its worker process), from psutil (a dependency of distributed)."""
    import psutil

    def tree(pid: int) -> float:
        try:
            p = psutil.Process(pid)
            return sum(sum(q.cpu_times()[:2]) for q in [p, *p.children(recursive=True)])
        except psutil.NoSuchProcess:
            return 0.0

    me = sum(psutil.Process().cpu_times()[:2])  # this process alone (the cluster's processes are its children)
    return [me, *(tree(p.pid) for p in procs)]


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _timed_batch(jobs: list, **kw) -> tuple[float, list]:
    t0 = time.perf_counter()
    res = run_batch(jobs, threads=1, **kw)
    return time.perf_counter() - t0, res


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--parts", type=int, default=200, help="parts in the batch (default 200)")
    ap.add_argument("--iterations", type=int, default=1, help="iterations per part (default 1)")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args()
    from distributed import Client

    programs = [REPO / "samples" / "own" / name for name in PROGRAMS]
    procs: list[subprocess.Popen[bytes]] = []
    with tempfile.TemporaryDirectory(prefix="ilcnc-bench-cluster-") as tmp:
        root = Path(tmp)
        client_dir, run_dir = root / "client", root / "cluster"
        (client_dir / "parts").mkdir(parents=True)
        (client_dir / "warm").mkdir()
        run_dir.mkdir()
        shutil.copy(PROFILE, client_dir / "mill.yaml")
        for i in range(args.parts):
            src = programs[i % len(programs)]
            shutil.copy(src, client_dir / "parts" / f"p{i:03d}-{src.name}")
        for src in programs[:4]:
            shutil.copy(src, client_dir / "warm" / src.name)
        os.chdir(client_dir)
        load0 = os.getloadavg()
        print(f"{args.parts} parts ({len(programs)} programs of samples/own round-robin), {PROFILE.name},"
              f" {args.iterations} iteration(s), one thread per part; {os.cpu_count()} cores;"
              f" load average {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}")
        jobs = jobs_from_path("parts", "mill.yaml", "out", iterations=args.iterations)
        run_batch(jobs_from_path("warm", "mill.yaml", "warm-out", iterations=1), threads=1)  # this process's kernels
        c0 = _cpu([])[0]
        t_local, local = _timed_batch(jobs)
        cpu_local = _cpu([])[0] - c0
        failed = [r for r in local if r.status == "error"]
        Path("out").rename("out-local")
        reference = _tree(client_dir / "out-local")
        print(f"local (this process, workers=1):   {t_local:7.2f} s  ({len(failed)} parts failed)")
        try:
            sched_file = run_dir / "scheduler.json"
            procs.append(_dask(["scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                "--scheduler-file", str(sched_file)], run_dir))
            deadline = time.monotonic() + 60
            while not (sched_file.is_file() and sched_file.read_text().strip()):
                if time.monotonic() > deadline:
                    raise SystemExit("the Dask scheduler did not start in 60 s")
                time.sleep(0.1)
            time.sleep(0.2)
            address = json.loads(sched_file.read_text())["address"]
            times: dict[int, float] = {}
            same: dict[int, bool] = {}
            with Client(address, timeout="60s") as client:
                for n in (1, 2):
                    procs.append(_dask(["worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                                        "--no-dashboard", "--local-directory", str(run_dir / f"worker{n}")], run_dir))
                    client.wait_for_workers(n, timeout=60)
                    # every worker loads its kernels before the timed batch: 2 warm-up parts per worker, untimed
                    shutil.rmtree("warm-out", ignore_errors=True)
                    run_batch(jobs_from_path("warm", "mill.yaml", "warm-out", iterations=1), scheduler=client, threads=1)
                    shutil.rmtree("out", ignore_errors=True)
                    cpu0 = _cpu(procs)
                    times[n], res = _timed_batch(jobs, scheduler=client)
                    cpu = [b - a for a, b in zip(cpu0, _cpu(procs), strict=True)]
                    mine = _tree(client_dir / "out")
                    same[n] = mine == reference and [r.to_json() for r in res] == [r.to_json() for r in local]
                    print(f"cluster, {n} worker{'s' if n > 1 else ' '} (dask scheduler):  {times[n]:7.2f} s  "
                          f"({len(mine)} files, {'all identical to the local run' if same[n] else 'DIFFERENT'})")
                    per = 1e3 / args.parts
                    print(f"  CPU per part: workers {sum(cpu[2:]) * per:.0f} ms, client {cpu[0] * per:.0f} ms,"
                          f" scheduler {cpu[1] * per:.0f} ms (local run: {cpu_local * per:.0f} ms)")
        finally:
            for p in reversed(procs):
                _stop(p)
            os.chdir(REPO)
    load1 = os.getloadavg()
    eff = times[1] / (2 * times[2])
    print(f"load average after: {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    print(f"two workers against one: T1 / (2 T2) = {times[1]:.2f} / (2 x {times[2]:.2f}) = {eff:.1%}"
          f" (target >= {TARGET_EFFICIENCY:.0%})  -> {'met' if eff >= TARGET_EFFICIENCY else 'NOT MET'}")
    print(f"cluster against local: one worker {times[1] / t_local:.2f}x the local time, two workers"
          f" {times[2] / t_local:.2f}x")
    print(f"byte for byte: {'met' if all(same.values()) else 'NOT MET'}")
    ok = all(same.values()) and eff >= TARGET_EFFICIENCY
    return 0 if ok or not args.check else 1


if __name__ == "__main__":
    raise SystemExit(main())

"""``ilcnc simulate`` of a whole program as a user waits for it: real time of the motion / wall time (issue 24).

Usage (from the repository root, in the project's environment)::

    python bench/simulate_cli.py                 # Gates_combined_R12.nc on configs/example-mill.yaml, warm
    python bench/simulate_cli.py --cold          # also one run with a fresh, empty NUMBA_CACHE_DIR
    python bench/simulate_cli.py PROG --runs 9   # another program, best of 9
    python bench/simulate_cli.py --check         # exit 1 when the warm ratio is below the target
    python bench/simulate_cli.py --before DIR    # also the ilcnc of another checkout (e.g. a git worktree of
                                                 # an older commit), same interpreter and packages

Every timed run is the whole command as its own process, as a user types it
(``ilcnc simulate PROG --profile PROFILE``, the table on stdout): interpreter start-up, imports, numba
loading its kernels from the cache, reading the profile and the program, the simulation, printing, and
the interpreter's exit. One untimed ``--json`` run first fills the caches and gives the cycle time of
the program (the real time its motion lasts on the machine). Warm: the best and the median of
``--runs``. Cold: one run with an empty ``NUMBA_CACHE_DIR`` in a temporary folder (the first run after
install compiles the kernels it needs; the folder is deleted afterwards).

``PYTHONDONTWRITEBYTECODE`` is dropped from the commands' environment: an installed package has its
``.pyc`` files (pip writes them), and without them every run compiles ilcnc's ~50 modules from source
(~0.17 s). The ratio real time / wall is printed with the target (>= 1,000x, issue 24 item 4) and, as
references from the same run, ``python -c pass`` and ``ilcnc --version``. ``--stages`` adds where the
time of one process goes (measured inside one process, see :data:`STAGES`). The machine's load average
is printed before and after: the machine is shared, compare ratios of one run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = ROOT / "samples" / "third_party" / "contour" / "Gates_combined_R12.nc"
PROFILE = ROOT / "configs" / "example-mill.yaml"
TARGET_RATIO = 1000.0

#: Run in a child process by ``--stages``: the steps of ``ilcnc simulate`` one after the other, timed.
STAGES = r"""
import gc, sys, time, json
t0 = time.perf_counter()
marks = []
def mark(name, t=[t0]):
    now = time.perf_counter(); marks.append((name, now - t[0])); t[0] = now
gc.set_threshold(50_000, 10, 10)  # as ilcnc.cli.main
import numpy; mark("import numpy")
import ilcnc.cli; mark("import ilcnc.cli (typer, rich)")
import typer._adapters; mark("import pydantic (typer parses options with it)")
from ilcnc.profile.load import load_profile
from ilcnc.program import read_program
from ilcnc.vcnc.run import simulate_figures
mark("import profile, program, vcnc")
prof = load_profile(sys.argv[2]); mark("load_profile")
prog = read_program(sys.argv[1], default_units=prof.machine.units); mark("read_program")
from ilcnc._jit import _load_numba
_load_numba(); mark("import numba")
from numba.core.registry import cpu_target
cpu_target.target_context.refresh(); mark("numba's set-up before a first kernel")
first = simulate_figures(prog, prof); mark("simulate (loads its kernels)")
t = time.perf_counter(); again = simulate_figures(prog, prof); mark("simulate again (kernels loaded)")
json.dumps(again.to_json(prog))
print(json.dumps({"marks": marks, "first": first.timings_s, "again": again.timings_s}))
"""


def _ilcnc() -> list[str]:
    """The command a user types: the console script next to this interpreter, else ``python -m ilcnc``."""
    script = Path(sys.executable).parent / "ilcnc"
    return [str(script)] if script.exists() else [sys.executable, "-m", "ilcnc"]


#: CPU time (user + system) of the last :func:`_run`'s process, s.
last_cpu_s = 0.0


def _run(argv: list[str], env: dict[str, str], cwd: Path = ROOT) -> tuple[float, subprocess.CompletedProcess[str]]:
    """Wall time and result of one process (its CPU time in :data:`last_cpu_s`)."""
    global last_cpu_s
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    res = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=cwd)
    dt = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    last_cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if res.returncode != 0:
        raise SystemExit(f"{' '.join(argv)}: exit {res.returncode}: {res.stderr.strip()[-500:]}")
    return dt, res


def _load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("program", nargs="?", type=Path, default=PROGRAM)
    ap.add_argument("--profile", type=Path, default=PROFILE)
    ap.add_argument("--runs", type=int, default=5, help="timed warm runs (default 5)")
    ap.add_argument("--cold", action="store_true", help="also one run with a fresh, empty NUMBA_CACHE_DIR")
    ap.add_argument("--stages", action="store_true", help="also where the time of one process goes")
    ap.add_argument("--check", action="store_true", help="exit 1 when the warm ratio misses the target")
    ap.add_argument("--before", type=Path, help="a checkout of another ilcnc (its root): timed as 'before' in the same"
                    " run (python -m ilcnc with PYTHONPATH=DIR; its numba cache is filled by the warm-up)")
    args = ap.parse_args(argv)
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    cmd = [*_ilcnc(), "simulate", str(args.program.resolve()), "--profile", str(args.profile.resolve())]
    print(f"load average before: {_load()} (1 / 5 / 15 min; {os.cpu_count()} cores)")
    _dt, res = _run([*cmd, "--json"], env)  # fills the numba and .pyc caches; gives the cycle time
    figures = json.loads(res.stdout)
    cycle = float(figures["cycle_time_s"])
    print(f"program  {args.program.name}: cycle time {cycle:,.1f} s ({figures['samples']:,} samples), "
          f"contour error max {figures['contour_error_mm']['max'] * 1e3:.2f} um")
    print(f"command  {' '.join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))}")
    rows: list[tuple[str, list[float], list[float]]] = []
    timed = [("python -c pass", [sys.executable, "-c", "pass"], env, ROOT),
             ("ilcnc --version", [*_ilcnc(), "--version"], env, ROOT)]
    if args.before is not None:
        # run in that checkout (python -m puts the working folder first on sys.path) with it on PYTHONPATH
        old_root = args.before.resolve()
        old_env = dict(env, PYTHONPATH=str(old_root))
        old_cmd = [sys.executable, "-m", "ilcnc", *cmd[len(_ilcnc()):]]
        where = _run([sys.executable, "-c", "import ilcnc; print(ilcnc.__file__)"], old_env, old_root)[1].stdout.strip()
        if not where.startswith(str(old_root)):
            raise SystemExit(f"--before {old_root}: python imports ilcnc from {where}")
        _dt, res = _run([*old_cmd, "--json"], old_env, old_root)
        same = json.loads(res.stdout) == figures
        print(f"before   {where}: the same figures: {same}")
        timed.append(("before: simulate", old_cmd, old_env, old_root))
    timed.append(("ilcnc simulate", cmd, env, ROOT))
    for name, argv_, run_env, cwd in timed:
        _run(argv_, run_env, cwd)  # warm-up
        walls, cpus = [], []
        for _ in range(max(args.runs, 1)):
            walls.append(_run(argv_, run_env, cwd)[0])
            cpus.append(last_cpu_s)
        rows.append((name, walls, cpus))
    print(f"\nwarm: wall time of the whole process, s (best / median / max of {max(args.runs, 1)}), its CPU time"
          " (user + system) and real time / wall")
    for name, times, cpus in rows:
        best, med = min(times), statistics.median(times)
        print(f"  {name:18s} {best:6.3f} {med:6.3f} {max(times):6.3f}   CPU {min(cpus):6.3f}-{max(cpus):6.3f}   "
              f"best {cycle / best:7.0f}x, median {cycle / med:7.0f}x")
    sim = rows[-1][1]
    best = min(sim)
    ratio = cycle / best
    met = ratio >= TARGET_RATIO
    print(f"target >= {TARGET_RATIO:,.0f}x real time (best of {len(sim)}): {ratio:,.0f}x = {best:.3f} s for "
          f"{cycle:,.1f} s of motion (needs <= {cycle / TARGET_RATIO:.3f} s) -> {'met' if met else 'NOT MET'}")
    if args.cold:
        with tempfile.TemporaryDirectory(prefix="ilcnc-numba-cold-") as tmp:
            cold_env = dict(env, NUMBA_CACHE_DIR=tmp)
            dt, res = _run(cmd, cold_env)
            said = "compiling the numba kernels" in res.stderr
            print(f"cold (empty NUMBA_CACHE_DIR): {dt:.2f} s = {cycle / dt:,.0f}x real time"
                  f"{'; says on stderr that it compiles' if said else ''}")
            shutil.rmtree(tmp, ignore_errors=True)
    if args.stages:
        _dt, res = _run([sys.executable, "-c", STAGES, str(args.program), str(args.profile)], env)
        st = json.loads(res.stdout.strip().splitlines()[-1])
        print("\nstages of one process (perf_counter inside it; interpreter start-up and exit not included), s")
        total = 0.0
        for name, secs in st["marks"][:-1]:
            total += secs
            print(f"  {name:46s} {secs:6.3f}")
        print(f"  {'sum (what one command does)':46s} {total:6.3f}")
        print(f"  {st['marks'][-1][0]:46s} {st['marks'][-1][1]:6.3f}")
        for key in ("first", "again"):
            print(f"  simulate {key:5s}: " + "  ".join(f"{k} {v:.3f}" for k, v in st[key].items()))
    print(f"load average after: {_load()}")
    return 0 if met or not args.check else 1


if __name__ == "__main__":
    sys.exit(main())

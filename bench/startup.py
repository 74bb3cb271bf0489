"""Start-up as a user waits for it: whole ``ilcnc`` commands on small programs, cold and warm (issue 24).

Usage (from the repository root)::

    python bench/startup.py                 # warm: 5 runs of each command, the numba cache as it is
    python bench/startup.py --cold          # also cold: each command once with a fresh, empty NUMBA_CACHE_DIR
    python bench/startup.py --runs 9        # more runs per command
    python bench/startup.py --check         # exit 1 when a target is missed (with --cold: the cold ones too)

Each command runs as its own process, as a shell script or a CI job runs it. In one run it prints
the wall time of each command (minimum, median and maximum of ``--runs``) next to two references
measured in the same run: ``python -c pass`` (the interpreter alone) and ``ilcnc --version`` (the
command line without any work). Ratios against those references carry over from machine to
machine; the seconds do not. Two more references say where the floor is: ``import numpy`` and
``numba: 1 cached kernel`` (importing numba and loading one kernel from its cache, numba's own set-up
that any command running a compiled kernel pays).

A small program's kernels run as Python and numba is never imported (``ilcnc._jit.kernels_for``); the
reference row ``simulate star.ngc, numba`` is the same command with ``ILCNC_SMALL_WORK=0`` (every kernel
compiled, numba imported as before). Each row also gives the CPU time (user + system) of its runs: on a
shared machine the wall time grows with the load, the CPU time much less. The load average is printed
before and after.

``PYTHONDONTWRITEBYTECODE`` is dropped from the commands' environment (as ``bench/simulate_cli.py`` does): an
installed package has its ``.pyc`` files (pip writes them); without them every run compiles ilcnc's modules
from source.

Targets (issue 24): every command on a small program < 0.5 s warm (the median); the first run after
install (cold) < 10 s, or it says on stderr what it is doing (ilcnc's compile notice). Cold,
``ilcnc selftest`` (the install step that compiles the kernels ahead) is timed too.
"""

from __future__ import annotations

import argparse
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
PROFILE = ROOT / "configs" / "example-mill.yaml"
STAR = ROOT / "samples" / "own" / "star.ngc"
TARGET_WARM_S = 0.5
TARGET_COLD_S = 10.0
#: How ilcnc's compile notice starts (ilcnc._jit.COMPILE_NOTICE; not imported: this script times the package).
NOTICE = "ilcnc: compiling the numba kernels"
#: Reference rows: not commands a user waits for, so no target.
REFERENCES = ("python -c pass", "ilcnc --version", "import numpy", "numba: 1 cached kernel",
              "simulate star.ngc, numba")


def commands(tmp: Path) -> list[tuple[str, list[str]]]:
    """(name, argv) of the timed commands; their outputs go to ``tmp``."""
    ilcnc = [sys.executable, "-m", "ilcnc"]
    return [
        ("python -c pass", [sys.executable, "-c", "pass"]),
        ("ilcnc --version", [*ilcnc, "--version"]),
        ("import numpy", [sys.executable, "-c", "import numpy"]),
        ("numba: 1 cached kernel", [sys.executable, "-c", "from ilcnc._jit import set_component as f; f(1., 2., 3., 0, 4.)"]),
        ("inspect star.ngc", [*ilcnc, "inspect", str(STAR)]),
        ("check star.ngc", [*ilcnc, "check", str(STAR), "--profile", str(PROFILE), "--max-error", "0.05"]),
        ("simulate star.ngc", [*ilcnc, "simulate", str(STAR), "--profile", str(PROFILE)]),
        ("simulate star.ngc, numba", ["env", "ILCNC_SMALL_WORK=0", *ilcnc, "simulate", str(STAR), "--profile",
                                      str(PROFILE)]),
        ("learn star.ngc (1 iteration)", [*ilcnc, "learn", str(STAR), "--profile", str(PROFILE), "--out",
                                          str(tmp / "star.ilc.ngc"), "--iterations", "1", "--force"]),
    ]


def cold_commands(tmp: Path) -> list[tuple[str, list[str]]]:
    """The cold rows: the commands, and ``ilcnc selftest`` (the install step)."""
    return [*commands(tmp), ("ilcnc selftest", [sys.executable, "-m", "ilcnc", "selftest"])]


def time_once(argv: list[str], env: dict[str, str]) -> tuple[float, float, int, list[str]]:
    """Wall time, CPU time (user + system), exit code and stderr lines of one run."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    res = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, res.returncode, res.stderr.strip().splitlines()


def load_average() -> str:
    """The 1, 5 and 15 minute load averages."""
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="runs per command (default 5)")
    ap.add_argument("--cold", action="store_true", help="also time every command with an empty numba cache")
    ap.add_argument("--cold-runs", type=int, default=1, help="runs per command when cold (default 1: ~20 s each)")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args()
    ok = True
    with tempfile.TemporaryDirectory(prefix="ilcnc-startup-") as tmp_s:
        tmp = Path(tmp_s)
        env = dict(os.environ)
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        print(f"load average before: {load_average()} (1 / 5 / 15 min; {os.cpu_count()} cores)")
        modes = [("warm", None)] + ([("cold", "fresh")] if args.cold else [])
        for mode, cache in modes:
            runs = args.runs if mode == "warm" else args.cold_runs
            print(f"\n{mode}: wall time of the whole process, s (min / median / max of {runs} runs), CPU time"
                  " (user + system, min-max)")
            ref: dict[str, float] = {}
            for name, argv in (commands(tmp) if mode == "warm" else cold_commands(tmp)):
                times, cpus = [], []
                said = True  # every cold run of the command said what it was doing
                for _ in range(runs):
                    run_env = dict(env)
                    if cache == "fresh":
                        d = Path(tempfile.mkdtemp(prefix="numba-cache-", dir=tmp))
                        run_env["NUMBA_CACHE_DIR"] = str(d)
                    elif mode == "warm" and not times:
                        time_once(argv, run_env)  # one untimed run fills the cache for the warm figures
                    dt, cpu, rc, err = time_once(argv, run_env)
                    if rc != 0:
                        print(f"  {name}: exit {rc}: {err[-1] if err else ''}")
                        return 1
                    times.append(dt)
                    cpus.append(cpu)
                    said &= any(line.startswith(NOTICE) for line in err)
                    if cache == "fresh":
                        shutil.rmtree(run_env["NUMBA_CACHE_DIR"], ignore_errors=True)
                med = statistics.median(times)
                ref.setdefault(name, med)
                base = ref.get("python -c pass", med)
                cli = ref.get("ilcnc --version", med)
                work = name not in REFERENCES
                if mode == "warm":
                    met = med < TARGET_WARM_S
                    verdict = f"target < {TARGET_WARM_S:g} s: {'met' if met else 'NOT MET'}"
                else:
                    met = med < TARGET_COLD_S or said
                    verdict = (f"target < {TARGET_COLD_S:g} s or says so: "
                               + ("met (< 10 s)" if med < TARGET_COLD_S else "met (says so on stderr)" if said
                                  else "NOT MET"))
                ok &= met or not work
                print(f"  {name:28s} {min(times):6.3f} {med:6.3f} {max(times):6.3f}  CPU {min(cpus):5.3f}-{max(cpus):5.3f}"
                      f"  {med / base:5.1f}x python, {med / cli:4.1f}x --version" + (f"  {verdict}" if work else ""))
        print(f"load average after: {load_average()}")
    return 0 if ok or not args.check else 1


if __name__ == "__main__":
    sys.exit(main())

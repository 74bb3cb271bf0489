"""Start-up as a user waits for it: whole ``ilcnc`` commands on small programs, cold and warm (issue 24).

Usage (from the repository root)::

    python bench/startup.py                 # warm: 5 runs of each command, the numba cache as it is
    python bench/startup.py --cold          # also cold: each command once with a fresh, empty NUMBA_CACHE_DIR
    python bench/startup.py --runs 9        # more runs per command
    python bench/startup.py --check         # exit 1 when a target is missed

Each command runs as its own process, as a shell script or a CI job runs it. In one run it prints
the wall time of each command (minimum, median and maximum of ``--runs``) next to two references
measured in the same run: ``python -c pass`` (the interpreter alone) and ``ilcnc --version`` (the
command line without any work). Ratios against those references carry over from machine to
machine; the seconds do not.

Targets (issue 24): every command on a small program < 0.5 s warm; the first run after install
(cold) < 10 s, or it says on stderr what it is doing.
"""

from __future__ import annotations

import argparse
import os
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


def commands(tmp: Path) -> list[tuple[str, list[str]]]:
    """(name, argv) of the timed commands; their outputs go to ``tmp``."""
    ilcnc = [sys.executable, "-m", "ilcnc"]
    return [
        ("python -c pass", [sys.executable, "-c", "pass"]),
        ("ilcnc --version", [*ilcnc, "--version"]),
        ("inspect star.ngc", [*ilcnc, "inspect", str(STAR)]),
        ("check star.ngc", [*ilcnc, "check", str(STAR), "--profile", str(PROFILE), "--max-error", "0.05"]),
        ("simulate star.ngc", [*ilcnc, "simulate", str(STAR), "--profile", str(PROFILE)]),
        ("learn star.ngc (1 iteration)", [*ilcnc, "learn", str(STAR), "--profile", str(PROFILE), "--out",
                                          str(tmp / "star.ilc.ngc"), "--iterations", "1", "--force"]),
    ]


def time_once(argv: list[str], env: dict[str, str]) -> tuple[float, int, str]:
    t = time.perf_counter()
    res = subprocess.run(argv, env=env, capture_output=True, text=True, cwd=ROOT)
    return time.perf_counter() - t, res.returncode, res.stderr.strip().splitlines()[-1] if res.stderr.strip() else ""


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
        modes = [("warm", None)] + ([("cold", "fresh")] if args.cold else [])
        for mode, cache in modes:
            runs = args.runs if mode == "warm" else args.cold_runs
            print(f"\n{mode}: wall time of the whole process, s (min / median / max of {runs} runs)")
            ref = {}
            for name, argv in commands(tmp):
                times = []
                for _ in range(runs):
                    run_env = dict(env)
                    if cache == "fresh":
                        d = Path(tempfile.mkdtemp(prefix="numba-cache-", dir=tmp))
                        run_env["NUMBA_CACHE_DIR"] = str(d)
                    elif mode == "warm" and not times:
                        time_once(argv, run_env)  # one untimed run fills the cache for the warm figures
                    dt, rc, err = time_once(argv, run_env)
                    if rc != 0:
                        print(f"  {name}: exit {rc}: {err}")
                        return 1
                    times.append(dt)
                    if cache == "fresh":
                        shutil.rmtree(run_env["NUMBA_CACHE_DIR"], ignore_errors=True)
                med = statistics.median(times)
                ref.setdefault(name, med)
                base = ref.get("python -c pass", med)
                cli = ref.get("ilcnc --version", med)
                target = TARGET_WARM_S if mode == "warm" else TARGET_COLD_S
                work = name not in ("python -c pass", "ilcnc --version")
                met = med < target
                ok &= met or not work
                print(f"  {name:32s} {min(times):7.3f} {med:7.3f} {max(times):7.3f}   {med / base:6.1f}x python,"
                      f" {med / cli:5.1f}x --version" + (f"   target < {target:g} s: {'met' if met else 'NOT MET'}"
                                                         if work else ""))
    return 0 if ok or not args.check else 1


if __name__ == "__main__":
    sys.exit(main())

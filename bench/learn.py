"""Benchmark: time per learning iteration on the largest shipped program.

Usage::

    python bench/learn.py                                   # samples/third_party/large/stellabee1.ngc
    python bench/learn.py PROG --profile configs/x.yaml --iterations 2
    python bench/learn.py --check                           # exit 1 when the target is missed

One run measures, on the same program and profile:

* ``reference``: one plain virtual-CNC run (``simulate_program``), the work
  every iteration must do at least;
* ``learn``: ``learn_virtual`` with N iterations (iteration 0 is the
  uncompensated run), and for each iteration the share of plan / drives /
  contour / error estimate / law / write (rewrite + re-read of the program).

It prints the time per learning iteration, its ratio to the reference run
and to the 30 s target of issue 6, and the peak resident memory.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.learning.learner import learn_virtual  # noqa: E402
from ilcnc.profile.load import load_profile, profile_from_dict  # noqa: E402
from ilcnc.program import read_program  # noqa: E402
from ilcnc.vcnc.simulate import simulate_program  # noqa: E402

TARGET_S = 30.0
STAGES = ("plan", "drives", "contour", "error", "law", "write")


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("program", nargs="?", default=str(ROOT / "samples" / "third_party" / "large" / "stellabee1.ngc"))
    ap.add_argument("--profile", default=str(ROOT / "configs" / "example-mill.yaml"))
    ap.add_argument("--iterations", type=int, default=1)
    ap.add_argument("--check", action="store_true", help="exit 1 when the per-iteration target is missed")
    args = ap.parse_args()

    prof = load_profile(args.profile)
    d = prof.to_dict()
    d["learning"]["iterations"] = args.iterations
    prof = profile_from_dict(d)
    t0 = time.perf_counter()
    prog = read_program(args.program, default_units=prof.machine.units)
    t_read = time.perf_counter() - t0
    print(f"program  {Path(args.program).name}: {prog.n_lines:,} lines, {prog.n_commands:,} G01 commands "
          f"(read in {t_read:.2f} s)")

    # warm-up: compile the numba kernels on a small program, so neither line pays for it
    warm = read_program(ROOT / "samples" / "own" / "star.ngc")
    learn_virtual(warm, prof, iterations=1, stop_on_stall=False)
    t0 = time.perf_counter()
    c0 = time.process_time()
    sim = simulate_program(prog, prof)
    ref_s = time.perf_counter() - t0
    ref_cpu = time.process_time() - c0
    n = sim.reference.n_samples
    print(f"reference  one virtual-CNC run: {ref_s:.2f} s wall, {ref_cpu:.2f} s CPU, {n:,} samples "
          f"({n / ref_s / 1e6:.2f} M samples/s); peak memory so far {_peak_gb():.2f} GB")
    del sim

    t0 = time.perf_counter()
    res = learn_virtual(prog, prof, iterations=args.iterations, stop_on_stall=False)
    total = time.perf_counter() - t0
    print(f"learn      {len(res.iterations)} runs (iteration 0 + {len(res.iterations) - 1}) in {total:.2f} s; "
          f"status {res.status}; RMS {res.iterations[0].stats['rms'] * 1e3:.2f} -> "
          f"{res.best_record.stats['rms'] * 1e3:.2f} µm")
    worst = 0.0
    for r in res.iterations[1:]:
        tm = r.timings_s
        it_s = sum(tm.get(s, 0.0) for s in STAGES)
        worst = max(worst, it_s)
        shares = "  ".join(f"{s} {tm.get(s, 0.0):6.2f} s ({tm.get(s, 0.0) / it_s:4.0%})" for s in STAGES)
        print(f"  iteration {r.iteration}: {it_s:6.2f} s = {shares}")
    print(f"peak memory {_peak_gb():.2f} GB")
    ratio_ref = worst / ref_s if ref_s > 0 else float("nan")
    met = worst < TARGET_S
    print(f"per iteration {worst:.2f} s = {ratio_ref:.2f} x the reference run; target < {TARGET_S:.0f} s: "
          f"{worst / TARGET_S:.2f} x target -> {'met' if met else 'NOT MET'}")
    return 0 if met or not args.check else 1


if __name__ == "__main__":
    raise SystemExit(main())

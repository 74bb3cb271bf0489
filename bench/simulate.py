"""Benchmark the virtual CNC: plan + drives + contour error, samples per second, CPU time and peak memory.

Usage (from the repository root)::

    python bench/simulate.py                       # the whole largest sample (stellabee1: 57.7 M samples)
    python bench/simulate.py --hours 1             # its first hour of motion only
    python bench/simulate.py PROG.ngc --runs 1     # another program, one timed run
    python bench/simulate.py --check               # exit 1 when a target is missed

In one run it measures:

* ``simulate_program`` on the whole program with the linear SOPDT drives of
  ``configs/example-mill.yaml``, ``--runs`` times (default 2; the first run
  of a process maps its memory fresh, later ones re-use what the previous run
  freed, as the iterations of the learning loop do): wall and CPU time (user
  and system) of every stage, samples/s, peak memory (``ru_maxrss`` of the
  process and ``tracemalloc``'s peak of the run, numpy's arrays included);
* the compiled kernels against the numpy path they replace, on the same
  reference cut to ``--ref-hours`` of motion (default 1 h): the numpy
  planner (``ilcnc.vcnc.plan._plan(kernel=False)``), ``lfilter`` per axis
  (``axis_response``), the numpy contour search (``_USE_KERNEL = False``);
  CPU time of each, the ratio, and whether the results are identical;
* the friction model of ``configs/seed001-duong-p-ff-friction.yaml`` (numba
  loop) on the whole reference;
* two references for the drive stage on the first ``--ref-samples`` samples:
  a plain per-sample Python loop of the same discrete model, and
  ``scipy.signal.lsim`` of the continuous model.

Targets: the whole of stellabee1 simulated in < 20 s (a learning iteration
must stay < 30 s), >= 5 million samples/s end to end for linear drives,
>= 2 million for the friction model, peak memory < 2 GB per hour of motion.
Timings are of a shared 2-core machine: compare the ratios measured in one
run, not figures of different runs.
"""

from __future__ import annotations

import argparse
import itertools
import resource
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import ilcnc.contour.search as contour_mod  # noqa: E402
import ilcnc.vcnc.plan as plan_mod  # noqa: E402
import ilcnc.vcnc.simulate as sim_mod  # noqa: E402
from ilcnc.contour.path import PathGeometry  # noqa: E402
from ilcnc.contour.search import contour_error  # noqa: E402
from ilcnc.profile.load import load_profile  # noqa: E402
from ilcnc.program import read_program  # noqa: E402
from ilcnc.vcnc.discrete import discrete_model  # noqa: E402
from ilcnc.vcnc.drives import axis_response, simulate_drives  # noqa: E402
from ilcnc.vcnc.plan import PlanLimits, plan_program  # noqa: E402

LARGEST = REPO / "samples" / "third_party" / "large" / "stellabee1.ngc"
WARM_UP = REPO / "samples" / "own" / "star.ngc"
TARGET_WHOLE_S = 20.0


def _truncate_to_hours(path: Path, hours: float, profile) -> Path:
    """A copy of the program cut where its planned motion reaches about ``hours``.

    The planned time of the whole program is not computed (for the largest
    sample it is 16 h: 58 M samples); the time per line of a planned prefix
    is extrapolated, then the cut program is planned for real by the benchmark.
    """
    if hours <= 0:
        return path
    lines = path.read_text(encoding="latin-1").split("\n")
    probe = min(len(lines), 20_000)
    tmp = Path(tempfile.mkdtemp()) / path.name
    tmp.write_text("\n".join([*lines[:probe], "M2", ""]), encoding="latin-1")
    ref = plan_program(read_program(tmp, default_units=profile.machine.units), profile)
    per_line = ref.duration_s / probe
    keep = int(hours * 3600.0 / max(per_line, 1e-9))
    if keep >= len(lines):
        return path
    tmp.write_text("\n".join([*lines[:keep], "M2", ""]), encoding="latin-1")
    return tmp


def _usage() -> tuple[float, float, float]:
    """Wall time, user and system CPU time of the process, s."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return time.perf_counter(), ru.ru_utime, ru.ru_stime


def _timed_simulation(prog, prof) -> tuple[Any, dict[str, tuple[float, float, float]], int]:
    """``simulate_program`` with wall, user and system time per stage (plan, drives, contour, stats, total)
    and tracemalloc's peak, bytes."""
    marks: list[tuple[str, tuple[float, float, float]]] = []
    feed_stats = sim_mod._feed_stats

    def stats_mark(*args):  # the statistics stage has no progress call: mark it here
        marks.append(("stats", _usage()))
        return feed_stats(*args)

    sim_mod._feed_stats = stats_mark
    tracemalloc.start()
    try:
        start = _usage()
        res = sim_mod.simulate_program(prog, prof, progress=lambda stage: marks.append((stage, _usage())))
        end = _usage()
        _cur, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
        sim_mod._feed_stats = feed_stats
    marks.append(("end", end))
    stages = {name: tuple(b - a for a, b in zip(u0, u1, strict=True)) for (name, u0), (_n, u1) in itertools.pairwise(marks)}
    stages["total"] = tuple(b - a for a, b in zip(start, end, strict=True))
    return res, stages, peak


def _cpu(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    """Result, wall and CPU time (user + system, all threads) of ``fn()``."""
    w0, u0, s0 = _usage()
    out = fn()
    w1, u1, s1 = _usage()
    return out, w1 - w0, (u1 - u0) + (s1 - s0)


def _python_loop(b: np.ndarray, a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The same discrete filter, one Python iteration per sample (the naive reference)."""
    b = [float(x) / a[0] for x in b]
    a = [float(x) / a[0] for x in a]
    nb, na = len(b), len(a)
    y = [0.0] * len(u)
    uu = u.tolist()
    for k in range(len(uu)):
        acc = 0.0
        for i in range(nb):
            if k - i >= 0:
                acc += b[i] * uu[k - i]
        for i in range(1, na):
            if k - i >= 0:
                acc -= a[i] * y[k - i]
        y[k] = acc
    return np.array(y)


def _kernels_vs_numpy(prog, prof) -> None:
    """CPU time of each compiled stage against the numpy path it replaced, same input, same run."""
    lim = PlanLimits.from_profile(prof)
    pl = prof.planner

    def numpy_plan():
        return plan_mod._plan(prog.moves, lim, prof.machine.servo_period_s, pl.profile, pl.corner_tolerance_mm,
                              pl.jerk_time_constant_s, plan_mod.IN_POSITION_S, 12, kernel=False)

    ref, _t_k, c_k = _cpu(lambda: plan_program(prog, prof))
    ref_np, _t_n, c_n = _cpu(numpy_plan)
    same = all(np.array_equal(getattr(ref, f), getattr(ref_np, f)) for f in ("pos_mm", "move", "command", "line"))
    n = ref.n_samples
    print(f"  plan     kernel {c_k:6.2f} s CPU ({n / c_k / 1e6:5.1f} M/s)   numpy {c_n:6.2f} s CPU -> "
          f"{c_n / c_k:4.1f}x   identical: {same}")
    del ref_np
    period = prof.machine.servo_period_s
    act, t_k, c_k = _cpu(lambda: simulate_drives(ref.pos_mm, prof))
    act_np, _t_n, c_n = _cpu(lambda: np.column_stack([axis_response(prof.axes[a].drive, ref.pos_mm[:, i], period)
                                                      for i, a in enumerate("xyz")]))
    print(f"  drives   kernel {c_k:6.2f} s CPU ({n / c_k / 1e6:5.1f} M/s)   lfilter {c_n:6.2f} s CPU -> "
          f"{c_n / c_k:4.1f}x   identical: {np.array_equal(act, act_np)}   (kernel wall {t_k:.2f} s, axes in threads)")
    del act_np
    path = PathGeometry.from_moves(prog.moves)
    err, _t_k, c_k = _cpu(lambda: contour_error(path, act, ref.move))
    contour_mod._USE_KERNEL = False
    try:
        err_np, _t_n, c_n = _cpu(lambda: contour_error(path, act, ref.move))
    finally:
        contour_mod._USE_KERNEL = True
    same = all(np.array_equal(getattr(err, f), getattr(err_np, f), equal_nan=True)
               for f in ("dist_mm", "foot_mm", "vector_mm", "u", "signed_mm", "seg"))
    print(f"  contour  kernel {c_k:6.2f} s CPU ({n / c_k / 1e6:5.1f} M/s)   numpy {c_n:6.2f} s CPU -> "
          f"{c_n / c_k:4.1f}x   identical: {same}   ({int(path.is_arc.sum())} arcs of {len(path)} segments)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("program", nargs="?", type=Path, default=LARGEST)
    ap.add_argument("--profile", type=Path, default=REPO / "configs" / "example-mill.yaml")
    ap.add_argument("--friction-profile", type=Path, default=REPO / "configs" / "seed001-duong-p-ff-friction.yaml")
    ap.add_argument("--hours", type=float, default=0.0, help="cut the program after this much planned motion (0: whole)")
    ap.add_argument("--runs", type=int, default=2, help="timed runs of the whole simulation")
    ap.add_argument("--ref-hours", type=float, default=1.0, help="motion the numpy-path comparison runs on (0: skip)")
    ap.add_argument("--ref-samples", type=int, default=200_000, help="samples for the Python-loop and lsim references")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args(argv)

    prof = load_profile(args.profile)
    src = _truncate_to_hours(args.program, args.hours, prof)
    prog = read_program(src, default_units=prof.machine.units)
    print(f"program: {args.program} ({prog.n_lines:,} lines used, {prog.n_commands:,} G01 commands)")

    # the first call of a process loads the compiled kernels from numba's cache (or compiles them)
    _r, t_warm, _c = _cpu(lambda: sim_mod.simulate_program(read_program(WARM_UP), prof))
    print(f"warm-up (imports, numba cache load or compile) {t_warm:.2f} s")

    best: dict[str, tuple[float, float, float]] | None = None
    n = 0
    peak_traced = 0
    ref_pos = None
    for run in range(max(args.runs, 1)):
        res, st, peak = _timed_simulation(prog, prof)
        n = res.reference.n_samples
        peak_traced = max(peak_traced, peak)
        if run == 0:
            print(f"samples: {n:,} ({n * prof.machine.servo_period_s / 3600:.2f} h of motion at "
                  f"{prof.machine.servo_period_s * 1e3:g} ms); contour RMS {res.stats['rms'] * 1e3:.3f} um, "
                  f"max {res.stats['max'] * 1e3:.3f} um")
            print("  stage       wall     CPU (user + sys)    M samples/s (wall)")
        for name in ("plan", "drives", "contour", "stats", "total"):
            w, u, s = st[name]
            print(f"  {name:8s} {w:6.2f} s  {u + s:6.2f} s ({u:5.2f} + {s:5.2f})   {n / w / 1e6:7.2f}")
        print(f"  run {run + 1}: {st['total'][0]:.2f} s wall, peak traced {peak / 1024**3:.2f} GB, "
              f"max RSS so far {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2:.2f} GB")
        if best is None or st["total"][0] < best["total"][0]:
            best = st
        if run == max(args.runs, 1) - 1:
            ref_pos = res.reference.pos_mm
        del res
    assert best is not None and ref_pos is not None
    sps = n / best["total"][0]

    if args.ref_hours > 0:
        cut = _truncate_to_hours(args.program, args.ref_hours, prof) if args.hours <= 0 else src
        cprog = read_program(cut, default_units=prof.machine.units)
        print(f"compiled kernels vs the numpy path, {args.ref_hours:g} h of motion ({cprog.n_lines:,} lines):")
        _kernels_vs_numpy(cprog, prof)

    fric_prof = load_profile(args.friction_profile)
    simulate_drives(ref_pos[:1000], fric_prof)  # compile / load
    _q, t_fric, c_fric = _cpu(lambda: simulate_drives(ref_pos, fric_prof))
    del _q
    t_rest = best["plan"][0] + best["contour"][0] + best["stats"][0]
    sps_fric = n / (t_rest + t_fric)
    print(f"friction model: drives {t_fric:.2f} s wall ({c_fric:.2f} s CPU) -> end to end {sps_fric / 1e6:.2f} M samples/s")

    # references for the drive stage: x axis of the linear model on the first samples
    m = min(args.ref_samples, n)
    drive = prof.axes["x"].drive
    model = discrete_model(drive, prof.machine.servo_period_s)
    u = ref_pos[:m, 0] - ref_pos[0, 0]
    _q, _w, c_ours = _cpu(lambda: simulate_drives(ref_pos[:m], prof))
    c_ours /= 3.0  # three axes
    _q, _w, c_loop = _cpu(lambda: _python_loop(np.asarray(model.b), np.asarray(model.a), u))
    c_lsim = float("nan")
    try:
        tt = np.arange(m) * prof.machine.servo_period_s
        if getattr(drive, "model", "") == "sopdt" and getattr(drive, "position_gain_1_s", None) is None:
            # velocity drive fed with the planned velocity, position = its integral (delay left out: lsim has none)
            w0, z, k = drive.omega0_rad_s, drive.zeta, drive.gain
            num, den = [k * w0 * w0], [1.0, 2 * z * w0, w0 * w0, 0.0]
            inp = np.gradient(u, prof.machine.servo_period_s)
        else:
            from ilcnc.vcnc.discrete import closed_continuous

            num, den = closed_continuous(drive)
            inp = u
        _q, _w, c_lsim = _cpu(lambda: signal.lsim((num, den), inp, tt))
    except Exception as exc:
        print(f"lsim reference skipped: {exc}")
    print(f"drive stage, {m:,} samples, one axis: ilcnc {c_ours * 1e3:.1f} ms, Python loop {c_loop * 1e3:.0f} ms "
          f"({c_loop / c_ours:.0f}x), scipy.signal.lsim {c_lsim * 1e3:.0f} ms ({c_lsim / c_ours:.0f}x)")

    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    hours = n * prof.machine.servo_period_s / 3600
    print(f"peak memory: {peak_traced / 1024**3:.2f} GB traced in one run ({peak_traced / 1024**3 / max(hours, 1e-9):.2f} GB "
          f"per hour of motion), {rss_gb:.2f} GB max RSS of the process")
    ok = True
    whole = args.hours <= 0 and args.program == LARGEST
    if whole:
        met = best["total"][0] < TARGET_WHOLE_S
        ok &= met
        print(f"target < {TARGET_WHOLE_S:.0f} s for the whole of {LARGEST.name}: {best['total'][0]:.2f} s (best run) -> "
              f"{'met' if met else 'NOT MET'}")
    for name, value, target in (("linear end to end", sps, 5e6), ("friction end to end", sps_fric, 2e6)):
        met = value >= target
        ok &= met
        print(f"target {target / 1e6:.0f} M samples/s ({name}): {value / 1e6:.2f} M/s -> {'met' if met else 'NOT MET'}")
    per_hour = peak_traced / 1024**3 / max(hours, 1.0)
    mem_ok = per_hour < 2.0
    print(f"target < 2 GB per hour of motion: {per_hour:.2f} GB/h -> {'met' if mem_ok else 'NOT MET'}")
    ok &= mem_ok
    return 0 if (ok or not args.check) else 1


if __name__ == "__main__":
    raise SystemExit(main())

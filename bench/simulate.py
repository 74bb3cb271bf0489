"""Benchmark the virtual CNC: plan + drives + contour error, samples per second and peak memory.

Usage (from the repository root)::

    python bench/simulate.py                       # largest sample, first hour of motion
    python bench/simulate.py PROG.ngc --hours 0    # a whole program
    python bench/simulate.py --check               # exit 1 when a target is missed

In one run it measures, on the same planned reference:

* ilcnc end to end (plan, drives, exact contour error) with the linear SOPDT
  drives of ``configs/example-mill.yaml`` and with the friction model of
  ``configs/seed001-duong-p-ff-friction.yaml`` (numba loop);
* two references for the drive stage on the first ``--ref-samples`` samples:
  a plain per-sample Python loop of the same discrete model, and
  ``scipy.signal.lsim`` of the continuous model;
* peak memory of the whole run (``ru_maxrss``) and of the pipeline
  (``tracemalloc``, numpy's allocations included).

Targets (issue 5): >= 5 million samples/s end to end for linear drives,
>= 2 million for the friction model, peak memory < 2 GB for a one-hour program.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy import signal

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ilcnc.contour import PathGeometry, contour_error  # noqa: E402
from ilcnc.drives import discrete_model, simulate_drives  # noqa: E402
from ilcnc.plan import plan_program  # noqa: E402
from ilcnc.profile import load_profile  # noqa: E402
from ilcnc.program import read_program  # noqa: E402
from ilcnc.program.model import MOVE_RAPID  # noqa: E402

LARGEST = REPO.parent / "shared" / "samples" / "large" / "stellabee1.ngc"


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


def _pipeline(prog, profile) -> dict[str, float]:
    t0 = time.perf_counter()
    ref = plan_program(prog, profile)
    t1 = time.perf_counter()
    act = simulate_drives(ref.pos_mm, profile)
    t2 = time.perf_counter()
    path = PathGeometry.from_moves(prog.moves)
    err = contour_error(path, act, np.maximum(ref.move, 0))
    t3 = time.perf_counter()
    feed = (ref.move >= 0) & (prog.moves.kind[np.maximum(ref.move, 0)] != MOVE_RAPID)
    rms = float(np.sqrt(np.nanmean(err.dist_mm[feed] ** 2)))
    return {"samples": ref.n_samples, "plan": t1 - t0, "drives": t2 - t1, "contour": t3 - t2, "total": t3 - t0,
            "rms_um": rms * 1e3, "ref": ref.pos_mm}


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("program", nargs="?", type=Path, default=LARGEST)
    ap.add_argument("--profile", type=Path, default=REPO / "configs" / "example-mill.yaml")
    ap.add_argument("--friction-profile", type=Path, default=REPO / "configs" / "seed001-duong-p-ff-friction.yaml")
    ap.add_argument("--hours", type=float, default=1.0, help="cut the program after this much planned motion (0: whole)")
    ap.add_argument("--ref-samples", type=int, default=200_000, help="samples for the Python-loop and lsim references")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args(argv)

    prof = load_profile(args.profile)
    src = _truncate_to_hours(args.program, args.hours, prof)
    prog = read_program(src, default_units=prof.machine.units)
    print(f"program: {args.program} ({prog.n_lines} lines used, {prog.n_commands} G01 commands)")

    _pipeline(prog, prof)  # warm-up (numba compilation, caches)
    tracemalloc.start()
    lin = _pipeline(prog, prof)
    _cur, peak_py = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    n = lin["samples"]
    sps = n / lin["total"]
    print(f"samples: {n:,} ({n * 1e-3 / 3600:.2f} h of motion at 1 ms)")
    print(f"ilcnc linear drives : {lin['total']:.2f} s = plan {lin['plan']:.2f} + drives {lin['drives']:.2f} + "
          f"contour {lin['contour']:.2f}  -> {sps / 1e6:.2f} M samples/s  (contour RMS {lin['rms_um']:.2f} um)")

    fric_prof = load_profile(args.friction_profile)
    ref = lin["ref"]
    simulate_drives(ref[:1000], fric_prof)  # compile
    t0 = time.perf_counter()
    simulate_drives(ref, fric_prof)
    t_fric = time.perf_counter() - t0
    sps_fric = n / (lin["plan"] + t_fric + lin["contour"])
    print(f"ilcnc friction model: drives {t_fric:.2f} s -> end to end {sps_fric / 1e6:.2f} M samples/s")

    # references for the drive stage: x axis of the linear model on the first samples
    m = min(args.ref_samples, n)
    drive = prof.axes["x"].drive
    model = discrete_model(drive, prof.machine.servo_period_s)
    u = ref[:m, 0] - ref[0, 0]
    t0 = time.perf_counter()
    simulate_drives(ref[:m], prof)
    t_ours = (time.perf_counter() - t0) / 3.0  # three axes
    t0 = time.perf_counter()
    _python_loop(np.asarray(model.b), np.asarray(model.a), u)
    t_loop = time.perf_counter() - t0
    t_lsim = float("nan")
    try:
        tt = np.arange(m) * prof.machine.servo_period_s
        if getattr(drive, "model", "") == "sopdt" and getattr(drive, "position_gain_1_s", None) is None:
            # velocity drive fed with the planned velocity, position = its integral (delay left out: lsim has none)
            w0, z, k = drive.omega0_rad_s, drive.zeta, drive.gain
            num, den = [k * w0 * w0], [1.0, 2 * z * w0, w0 * w0, 0.0]
            inp = np.gradient(u, prof.machine.servo_period_s)
        else:
            from ilcnc.drives import _closed_continuous  # continuous model of the same drive

            num, den = _closed_continuous(drive)
            inp = u
        t0 = time.perf_counter()
        signal.lsim((num, den), inp, tt)
        t_lsim = time.perf_counter() - t0
    except Exception as exc:
        print(f"lsim reference skipped: {exc}")
    print(f"drive stage, {m:,} samples, one axis: ilcnc {t_ours * 1e3:.1f} ms, Python loop {t_loop * 1e3:.0f} ms "
          f"({t_loop / t_ours:.0f}x), scipy.signal.lsim {t_lsim * 1e3:.0f} ms ({t_lsim / t_ours:.0f}x)")

    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(f"peak memory: {peak_py / 1024**3:.2f} GB traced in the pipeline, {rss_gb:.2f} GB max RSS of the process")
    ok = True
    for name, value, target in (("linear end to end", sps, 5e6), ("friction end to end", sps_fric, 2e6)):
        met = value >= target
        ok &= met
        print(f"target {target / 1e6:.0f} M samples/s ({name}): {value / 1e6:.2f} M/s -> {'met' if met else 'NOT MET'}")
    hours = n * prof.machine.servo_period_s / 3600
    mem_ok = peak_py / 1024**3 < 2.0 * max(hours, 1e-9) / max(hours, 1.0) if hours >= 0.9 else True
    print(f"target < 2 GB for a one-hour program: {peak_py / 1024**3:.2f} GB for {hours:.2f} h -> "
          f"{'met' if mem_ok else 'NOT MET'}")
    ok &= mem_ok
    return 0 if (ok or not args.check) else 1


if __name__ == "__main__":
    raise SystemExit(main())

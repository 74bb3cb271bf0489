"""Benchmark: ``tune`` (time-domain design) on a 3-axis profile.

Usage::

    python bench/tune.py                                   # configs/seed000-hendrawan-mass-damper-pid.yaml
    python bench/tune.py --profile configs/x.yaml --repeat 5
    python bench/tune.py --lifted                          # also the lifted check of seed 004 on jsdc.gcode
    python bench/tune.py --schedule                        # also the seed 001 schedule on the stand-in path
    python bench/tune.py --check                           # exit 1 when the 5 s target is missed

One run measures, on the same profile:

* ``reference``: one sweep of the objective -- ``epsilon_of`` (closed loop, learning operator and
  ``|1 − z^η T K_l|`` on the dense grid) once per axis and lead, the work a single evaluation of
  every design case costs;
* ``tune``: ``tune_profile(profile)`` (load, design every axis for leads 0..3, report; nothing
  written), best of R.

It prints both, the ratio tune / reference and the ratio to the 5 s target of issue 7.
Imports and numba compilation are done before anything is timed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.learning.time_design import design_time_domain, epsilon_of  # noqa: E402
from ilcnc.learning.tune import tune_profile  # noqa: E402
from ilcnc.profile.load import load_profile  # noqa: E402

TARGET_S = 5.0


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default=str(ROOT / "configs" / "seed000-hendrawan-mass-damper-pid.yaml"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--lifted", action="store_true", help="also time the lifted check (seed 004, jsdc.gcode window)")
    ap.add_argument("--schedule", action="store_true", help="also time the seed 001 schedule on the stand-in path")
    ap.add_argument("--check", action="store_true", help="exit 1 when the 5 s target is missed")
    args = ap.parse_args()

    prof = load_profile(args.profile)
    # warm-up: imports (scipy.signal, scipy.optimize) and the first design
    res = design_time_domain(prof)
    leads = range(len(next(iter(res.axes.values())).options))

    def sweep() -> None:
        for a, d in res.axes.items():
            for o in d.options:
                epsilon_of(prof, a, o.kp, o.ki, o.kd, o.lead)

    ref_s = _best(sweep, args.repeat)
    n_eval = len(res.axes) * len(leads)
    print(f"reference  one objective sweep ({n_eval} evaluations of ε on the dense grid): {ref_s:.3f} s")
    rep = None

    def tune() -> None:
        nonlocal rep
        rep = tune_profile(args.profile)

    tune_s = _best(tune, args.repeat)
    assert rep is not None
    eps = ", ".join(f"{a} {d.epsilon:.3g}" for a, d in rep.result.axes.items())
    print(f"tune       {Path(args.profile).name}: {len(rep.result.axes)} axes, leads 0..{len(leads) - 1},"
          f" best of {args.repeat}: {tune_s:.3f} s (lead {rep.result.lead_samples}; ε {eps})")
    met = tune_s < TARGET_S
    print(f"tune = {tune_s / ref_s:.1f} x the reference sweep; target < {TARGET_S:.0f} s: "
          f"{tune_s / TARGET_S:.2f} x target -> {'met' if met else 'NOT MET'}")

    if args.lifted:
        from ilcnc.learning.lifted_check import check_lifted
        from ilcnc.program import read_program

        prog = read_program(ROOT / "samples" / "third_party" / "gcode" / "jsdc.gcode")
        p4 = load_profile(ROOT / "configs" / "seed004-ward-sopdt.yaml")
        t0 = time.perf_counter()
        chk = check_lifted(prog, p4)
        t = time.perf_counter() - t0
        m = chk.model
        print(f"lifted     jsdc.gcode commands {m.window[0]}-{m.window[1] - 1} ({m.n} coordinates): {t:.2f} s"
              f" (G {m.elapsed_s:.2f} s, {len(chk.candidates)} candidates); chosen Γ {chk.gamma:g},"
              f" Q {chk.q_filter_hz} Hz, {chk.chosen.status}, norm {chk.chosen.norm:.4f},"
              f" ρ {chk.chosen.spectral_radius:.6f}")
    if args.schedule:
        from ilcnc.learning.gain_schedule import schedule_gains
        from ilcnc.program import read_program

        prog = read_program(ROOT / "tests" / "data" / "tune" / "seed001-standin-xz.ngc")
        p1 = load_profile(ROOT / "configs" / "seed001-duong-p-ff-friction.yaml")
        schedule_gains(prog, p1, horizon=2)  # compile the kernel
        t0 = time.perf_counter()
        s = schedule_gains(prog, p1)
        t = time.perf_counter() - t0
        print(f"schedule   stand-in path, {s.t_s.size} periods, Np {s.horizon}: {t:.2f} s; MSE "
              f"{s.mse_before_um2:.1f} -> {s.mse_after_um2:.1f} µm² ({s.reduction:.1%})")
    return 0 if met or not args.check else 1


if __name__ == "__main__":
    raise SystemExit(main())

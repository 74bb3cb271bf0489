"""Benchmark: the measured learning workflow on LinuxCNC with a real CAM program (issue 9).

Usage::

    python bench/linuxcnc_loop.py                       # KB-219 (gSender example, 7,464 G01s), 4 iterations
    python bench/linuxcnc_loop.py PROG.ngc --iterations 4 --profile configs/linuxcnc-sim.yaml
    python bench/linuxcnc_loop.py --check               # exit 1 when a target is missed
    python bench/linuxcnc_loop.py PROG.ngc --refine      # refined from the first log (learn --refine, issue 18)
    python bench/linuxcnc_loop.py PROG.ngc --as-is       # without prepare's path-control edits
    python bench/linuxcnc_loop.py PROG.ngc --q-filter 60 # the profile with learning.q_filter_hz: 60 (a copy)

One run does what a shop does, on LinuxCNC's own interpreter, planner and motion controller
(``configs/linuxcnc-sim``, time-scaled ×8):

    ``ilcnc linuxcnc prepare --out`` → run the program → ``ilcnc learn --log`` → compensated program → run it →
    next log → …

for N learning iterations, and ``ilcnc simulate --compare`` on the first log (how well the virtual CNC
predicts LinuxCNC). It prints the contour error (RMS, max) of every run, its change over the N
iterations against issue 9's target (−60 % RMS), the fidelity against its targets (correlation ≥ 0.9,
difference ≤ 20 % of the error), and the wall time of the LinuxCNC runs and of the learning steps.

The default program is ``samples/third_party/gcode/KB-219 test.gcode`` (an insole, Sienci-Labs/gsender,
GPL-3.0-only, see samples/MANIFEST.tsv), run as a copy made LinuxCNC-ready: its grbl
homing line ``$H`` and its ``G10 L20 P1 X0 Y0 Z50`` (which would shift the work offset, while the log
is in machine coordinates) become comments, and ``M2`` is appended (LinuxCNC refuses a file without a
program end). Line numbers are kept. Then, as docs/linuxcnc.md section 4.1 tells a shop,
``ilcnc linuxcnc prepare --out`` makes prepare's path-control edits (a program without path control gets a
``G64 P0.01 Q0`` line before its first move: LinuxCNC's start-up ``G64`` without P rounds corners as far as
the axes allow); ``--as-is`` skips this. That program is the drawing. ~12 min on the 2-core machine.

Needs LinuxCNC (Debian: ``apt-get install linuxcnc-uspace``); one run at a time per machine.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "samples" / "third_party" / "gcode" / "KB-219 test.gcode"
PROFILE = ROOT / "configs" / "linuxcnc-sim.yaml"
SIM_INI = ROOT / "configs" / "linuxcnc-sim" / "sim.ini"
TARGET_REDUCTION = 0.60
TARGET_CORRELATION = 0.9
TARGET_DIFFERENCE = 0.2


def linuxcnc_ready(src: Path, dest: Path) -> Path:
    """A copy of ``src`` LinuxCNC runs: grbl ``$``-lines, ``G10 L20`` and a closing ``%`` without an opening one
    commented out, ``M2`` at the end."""
    lines = src.read_text(encoding="latin-1").splitlines()
    first = next((ln.strip() for ln in lines if ln.strip()), "")
    out = []
    for line in lines:
        s = line.strip()
        if s == "%" and first != "%":
            # a closing '%' without an opening one (compass.ngc): LinuxCNC refuses it ("Bad character '%'")
            out.append("(ilcnc bench: a closing % without an opening % removed for LinuxCNC)")
        elif s.startswith("$"):
            out.append(f"(ilcnc bench: grbl line {s!r} removed for LinuxCNC)")
        elif s.upper().startswith("G10 L20"):
            out.append(f"(ilcnc bench: {s!r} removed: the log is in machine coordinates)")
        else:
            out.append(line)
    if not any(s.strip().upper().startswith(("M2", "M30")) for s in out):
        out.append("M2")
    dest.write_text("\n".join(out) + "\n", encoding="latin-1")
    return dest


def cli(*args: object) -> dict:
    """``python -m ilcnc ARGS --json``; a failure ends the benchmark with its message."""
    res = subprocess.run([sys.executable, "-m", "ilcnc", *map(str, args), "--json"], capture_output=True, text=True,
                         cwd=ROOT)
    if res.returncode != 0:
        sys.exit(f"ilcnc {' '.join(map(str, args))} failed: {res.stderr.strip() or res.stdout.strip()}")
    return json.loads(res.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("program", nargs="?", type=Path, default=SAMPLE)
    ap.add_argument("--profile", type=Path, default=PROFILE)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--time-scale", type=int, default=8)
    ap.add_argument("--keep", type=Path, help="Keep the programs, logs and state here (default: a temporary folder).")
    ap.add_argument("--check", action="store_true", help="Exit 1 when a target is missed.")
    ap.add_argument("--refine", action="store_true", help="Refine from the first log (learn --refine).")
    ap.add_argument("--as-is", dest="as_is", action="store_true",
                    help="Run the program without linuxcnc prepare's path-control edits.")
    ap.add_argument("--q-filter", dest="q_filter", type=float,
                    help="learning.q_filter_hz of a copy of the profile (default: the profile's).")
    a = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="ilcnc-lcnc-bench-") as tmp:
        d = a.keep or Path(tmp)
        d.mkdir(parents=True, exist_ok=True)
        part = linuxcnc_ready(a.program, d / (a.program.stem.replace(" ", "_") + ".ngc"))
        if a.q_filter is not None:
            import yaml

            data = yaml.safe_load(a.profile.read_text())
            data["learning"]["q_filter_hz"] = a.q_filter
            src, a.profile = a.profile, d / f"profile-q{a.q_filter:g}.yaml"
            a.profile.write_text(yaml.safe_dump(data, sort_keys=False))
            print(f"profile: learning.q_filter_hz {a.q_filter:g} (a copy of {src.name})", flush=True)
        if not a.as_is:
            ready = part.with_name(part.stem + ".ready.ngc")
            prep = cli("linuxcnc", "prepare", part, "--profile", a.profile, "--ini", SIM_INI, "--out", ready)
            print(f"prepare: {len(prep['edits'])} path-control edit(s): " + ("; ".join(prep["changes"]) or "none"),
                  flush=True)
            part = ready
        state = d / "state"
        program = part
        t_run = t_learn = 0.0
        result: dict = {}
        fid: dict = {}
        for i in range(a.iterations + 1):
            log = d / f"run{i}.csv"
            t0 = time.perf_counter()
            run = cli("linuxcnc", "run", program, "--log-out", log, "--time-scale", a.time_scale, "--timeout", 36000)
            t_run += time.perf_counter() - t0
            if i == 0:
                fid = cli("simulate", part, "--profile", a.profile, "--compare", log)["fidelity"]
            t0 = time.perf_counter()
            program = d / f"{part.stem}.ilc{i + 1}.ngc"
            extra = ["--refine"] if a.refine and i == 0 else []
            result = cli("learn", part, "--profile", a.profile, "--log", log, "--state", state, "--out", program, *extra)
            if i == 0 and result.get("refined"):
                rf = result["refined"]
                settles = (f", {rf['settles']} settles before feeds after rapids ({rf['settle_s']:.3f} s)"
                           if rf.get("settles") else "")
                print(f"refined: {rf['inserted_lines']} lines inserted{settles}", flush=True)
            t_learn += time.perf_counter() - t0
            it = result["iterations"][i]
            ce = it["contour_error_mm"]
            print(f"run {i}: {run.get('program_s', float('nan')):.1f} s of motion; cutting moves' contour error RMS"
                  f" {ce['rms'] * 1e3:.2f} µm, max {ce['max'] * 1e3:.1f} µm; kept {it['kept']}", flush=True)
            if result["status"] != "stepped":
                print(f"learning ended: {result['status']}: {result.get('message', '')}")
                break

    rms = [it["contour_error_mm"]["rms"] for it in result["iterations"] if it.get("contour_error_mm")]
    mx = [it["contour_error_mm"]["max"] for it in result["iterations"] if it.get("contour_error_mm")]
    kept_max = [it["contour_error_mm"]["max"] for it in result["iterations"] if it.get("contour_error_mm") and it["kept"]]
    print(f"cutting max {mx[0] * 1e3:.1f} -> best kept {min(kept_max) * 1e3:.1f} µm ({min(kept_max) / mx[0] - 1:+.0%})")
    change = 1.0 - rms[-1] / rms[0]
    kept_best = 1.0 - min(rms) / rms[0]
    ok_learn = change >= TARGET_REDUCTION
    ok_fid = fid["correlation"] >= TARGET_CORRELATION and fid["relative_difference"] <= TARGET_DIFFERENCE
    print(f"\n{a.program.name}: RMS " + " → ".join(f"{r * 1e3:.2f}" for r in rms) + " µm")
    print(f"change after {len(rms) - 1} iterations: {-change:+.1%} (best {-kept_best:+.1%});"
          f" target -{TARGET_REDUCTION:.0%} -> {'met' if ok_learn else 'NOT MET'}")
    print(f"fidelity on run 0: correlation {fid['correlation']:.3f} (target >= {TARGET_CORRELATION}),"
          f" difference {fid['relative_difference']:.0%} of the error (target <= {TARGET_DIFFERENCE:.0%})"
          f" -> {'met' if ok_fid else 'NOT MET'}")
    print(f"wall time: LinuxCNC runs {t_run:.0f} s, learning steps {t_learn:.0f} s (ratio {t_learn / t_run:.2f})")
    return 0 if (ok_learn and ok_fid) or not a.check else 1


if __name__ == "__main__":
    sys.exit(main())

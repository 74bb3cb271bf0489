"""The refinement acceptance of issue 18 on the virtual CNC, as a user runs it (on demand, not a test).

For each program: ``ilcnc learn PROG --profile configs/example-mill.yaml --out OUT --refine --iterations 5``,
then the output judged independently by ``ilcnc simulate OUT --against PROG`` and the original by
``ilcnc simulate PROG``; prints the cutting moves' max and RMS before and after, their change, and the
cycle time change, without and with ``--refine`` (the same run, so the ratios compare like with like)::

    python bench/refine.py [PROG ...]          # default: the four programs of the issue
    python bench/refine.py --arcs [PROG ...]   # refine with learning.refine.arcs: on (a profile copy)
    python bench/refine.py --gamma 1 [PROG ...]  # refine with learning.gains.gamma: 1 (a profile copy)
    python bench/refine.py --feed [PROG ...]   # refine with learning.refine.feed: on (a profile copy)
    python bench/refine.py --arc-radial 0.01 [PROG ...]  # learning.arc_start_radial_mm: 0.01 (plain and refine)
    python bench/refine.py --error path [PROG ...]  # learning.error: path (refine's default is lifted)
    python bench/refine.py --budget 3 [PROG ...]  # refine with learning.cycle_budget_pct: 3 (a profile copy)
    python bench/refine.py --tolerance on|off [PROG ...]  # refine with learning.refine.tolerance on/off (a profile copy)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROFILE = ROOT / "configs" / "example-mill.yaml"
DEFAULT = [ROOT / "samples" / "third_party" / "contour" / "Gates_combined_R12.nc", ROOT / "samples" / "compass.ngc",
           ROOT / "samples" / "third_party" / "contour" / "locket_outside.ngc", ROOT / "samples" / "jsdc.gcode"]


def _ilcnc(*args: object) -> dict:
    r = subprocess.run([sys.executable, "-m", "ilcnc", *map(str, args), "--json"], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"ilcnc {' '.join(map(str, args))}: {r.stderr.strip()}")
    return json.loads(r.stdout)


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("programs", nargs="*", type=Path, help="default: the four programs of the issue")
    ap.add_argument("--arcs", action="store_true", help="learning.refine.arcs: on")
    ap.add_argument("--feed", action="store_true", help="learning.refine.feed: on")
    ap.add_argument("--gamma", type=float, help="learning.gains.gamma")
    ap.add_argument("--arc-radial", dest="radial", type=float, help="learning.arc_start_radial_mm")
    ap.add_argument("--error", help="learning.error")
    ap.add_argument("--budget", type=float, help="learning.cycle_budget_pct, %% (refine only)")
    ap.add_argument("--tolerance", choices=("on", "off"), help="learning.refine.tolerance (refine only)")
    args = ap.parse_args(argv)
    arcs, feed, gamma, radial, error, budget = args.arcs, args.feed, args.gamma, args.radial, args.error, args.budget
    tolerance = args.tolerance
    programs = args.programs or DEFAULT
    resolution_um = 1.0  # configs/example-mill.yaml machine.resolution_mm
    print(f"{'program':28s} {'mode':8s} {'max um':>16s} {'max':>6s} {'RMS um':>14s} {'RMS':>6s} {'cycle':>7s} {'lines+':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        profile = PROFILE
        variant = arcs or feed or gamma is not None or budget is not None or tolerance is not None
        if variant or radial is not None or error is not None:
            import yaml

            data = yaml.safe_load(PROFILE.read_text())
            if arcs:
                data["learning"].setdefault("refine", {})["arcs"] = "on"
            if feed:
                data["learning"].setdefault("refine", {})["feed"] = "on"
            if gamma is not None:
                data["learning"]["gains"] = {"gamma": gamma}
            if radial is not None:
                data["learning"]["arc_start_radial_mm"] = radial
            if error is not None:
                data["learning"]["error"] = error
            if budget is not None:
                data["learning"]["cycle_budget_pct"] = budget
            if tolerance is not None:
                data["learning"].setdefault("refine", {})["tolerance"] = tolerance
            profile = Path(tmp) / "example-mill-variant.yaml"
            profile.write_text(yaml.safe_dump(data))
        for prog in programs:
            base = _ilcnc("simulate", prog, "--profile", profile)
            b = base["contour_error_mm"]
            for mode in (("refine",) if variant else ("plain", "refine")):
                out = Path(tmp) / f"{mode}-{prog.stem}{prog.suffix}"
                extra = ["--refine"] if mode == "refine" else []
                run = _ilcnc("learn", prog, "--profile", profile, "--out", out, "--iterations", 5, *extra)
                judged = _ilcnc("simulate", out, "--profile", profile, "--against", prog)
                a = judged["contour_error_mm"]
                inserted = (run.get("refined") or {}).get("inserted_lines", 0)
                floor = " (at the floor)" if a["max"] * 1e3 <= 2 * resolution_um else ""
                label = ("arcs " if arcs else "") + ("feed " if feed else "") + (
                    f"g={gamma:g}" if gamma is not None else "") + (
                    f"b={budget:g}%" if budget is not None else "") + (
                    f"tol {tolerance}" if tolerance is not None else "") or mode
                if radial is not None:
                    label = f"{label} r{radial:g}"
                if error is not None:
                    label = f"{label} {error}"
                slowed = len((run.get("feed") or {}).get("slowed_moves", []))
                tol = ((run.get("refined") or {}).get("tolerance") or {})
                print(f"{prog.name[:28]:28s} {label:8s} {b['max'] * 1e3:7.2f} -> {a['max'] * 1e3:6.2f}"
                      f" {a['max'] / b['max'] - 1:+6.0%} {b['rms'] * 1e3:6.2f} -> {a['rms'] * 1e3:5.2f}"
                      f" {a['rms'] / b['rms'] - 1:+6.0%} {judged['cycle_time_s'] / base['cycle_time_s'] - 1:+7.2%}"
                      f" {inserted:6d}{floor}" + (f" slowed {slowed}" if feed else "")
                      + (f" G64 P at {tol['corners']} corners" if tol.get("corners") else ""), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])

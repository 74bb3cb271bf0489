"""Reproduce the figures of docs/papers.md (seeds 000-004) in one run; ``--check``: exit 1 when one is off.

Usage (from the repository root, ~2.5 min on the 2-core development machine)::

    python bench/papers.py              # print every figure, the paper's next to it, and the command behind it
    python bench/papers.py --check      # the same; exit 1 when a figure differs from docs/papers.md's
    python bench/papers.py --seed 003   # one seed only

The product's figures come from the CLI itself (``ilcnc learn ... --json`` run as a subprocess on the shipped
programs and profiles, guarded as a user runs it). The rest are the variants docs/papers.md discusses (the
paper's three updates without the guard, other estimates and gains, the CCC with θ from its reference): they
run ``ilcnc.learning.learner.learn_virtual`` in-process on the same shipped program and profile with the one
change each line names. Seed 001's figures come from ``ilcnc tune PROG --method schedule --json`` on the shipped
stand-in path and profile. Seed 004's max and RMS per iteration come from ``ilcnc learn ... --json``; its zone
form errors (the mean wall deviation per immersion zone, which the CLI does not print) from the same learning
run in-process (``learn_virtual`` with ``keep_runs``), measured as tests/test_machine_errors.py measures them.

Every figure is compared with :data:`EXPECTED` (the figures docs/papers.md prints) within :data:`TOL_REL`
(relative) or :data:`TOL_ABS_MM` (1e-9 mm): above the noise of the deterministic simulation (two runs give
the same bytes) and below the last digit docs/papers.md prints.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.learning.learner import LearnResult, learn_virtual  # noqa: E402
from ilcnc.learning.time_design import design_time_domain  # noqa: E402
from ilcnc.profile.load import load_profile, profile_from_dict  # noqa: E402
from ilcnc.profile.sections import MachineProfile  # noqa: E402
from ilcnc.program import read_program  # noqa: E402

CONFIGS = ROOT / "configs"
OWN = ROOT / "samples" / "own"
S000_PROG = OWN / "seed000_corner.ngc"
S000_PROF = CONFIGS / "seed000-paper-corner.yaml"
S003_PROG = OWN / "seed003_line.ngc"
S003_PROF = CONFIGS / "seed003-paper-line.yaml"
S003_IND = CONFIGS / "seed003-paper-line-independent.yaml"
S002_PROG = OWN / "seed002_circle.ngc"
S002_PROF = CONFIGS / "seed002-lu-volumetric.yaml"
S001_PROG = ROOT / "tests" / "data" / "tune" / "seed001-standin-xz.ngc"
S001_PROF = CONFIGS / "seed001-duong-p-ff-friction.yaml"
S004_PROG = OWN / "seed004_stepped.h"
S004_PROF = CONFIGS / "seed004-stepped-cut.yaml"
#: Y ranges (mm) of seed 004's three stock zones (75 / 50 / 25 % immersion), 2 mm clear of the steps
S004_ZONES_MM = ((2.0, 76.5), (80.5, 155.5), (159.5, 234.0))
#: the paper's measured zone form errors of the default program (µm)
S004_PAPER_ZONES_UM = (8.41, 11.96, 17.21)

TOL_REL = 2e-3
TOL_ABS_MM = 1e-9

#: name -> the figure docs/papers.md prints (mm, or a fraction for reductions, or a status word).
EXPECTED: dict[str, Any] = {
    # seed 000, the product (CLI, guarded, the profile's 3 updates)
    "000.cli.max": [0.10897, 0.05394, 0.02648, 0.02262],
    "000.cli.reduction": 0.792,
    "000.cli.clipped": [0, 0, 0, 0],
    "000.cli.status": "max_iterations",
    # seed 000 variants (learn_virtual)
    "000.tangent.max": [0.10897, 0.06255, 0.12231, 0.12231],
    "000.tangent.clipped": [0, 0, 3, 3],
    "000.guarded5.max": [0.10897, 0.05394, 0.02648, 0.02262, 0.03035, 0.02262],
    "000.guarded5.rms": [0.04869, 0.02585, 0.01376, 0.00734, 0.00394, 0.00563],
    "000.guarded5.kept": [True, True, True, True, False, True],
    "000.analytic.max": [0.10897, 0.00098],
    "000.analytic.status": "converged",
    "000.tune.max": [0.10897, 0.00068094, 0.0000042581, 0.00000020044],
    # seed 001, the product (CLI: tune --method schedule; MSE in µm², max in µm)
    "001.cli.kp_fixed": 1.6,
    "001.cli.mse": [1.1957, 0.28122],
    "001.cli.reduction": 0.76482,
    "001.cli.max": [5.2768, 3.4930],
    "001.cli.within_limits": [True, True],
    "001.cli.c1_scan_mse_1.6_2.7": [1.1957, 5.7856],
    "001.cli.guarded_infeasible": [580, 0],
    # seed 001 variants (schedule_gains in-process)
    "001.lam0.mse": 0.28122,
    "001.predicted.mse": 0.28122,
    # seed 003, the product (CLI, guarded, 10 iterations)
    "003.ccc.max": [0.02044, 0.01963, 0.01878, 0.01793, 0.01711, 0.01636, 0.01568, 0.0151, 0.01461, 0.01421,
                    0.01389],
    "003.ccc.rms": [0.01476, 0.01116],
    "003.ccc.clipped": 0,
    "003.ccc.status": "stopped",
    "003.independent.max": [0.37003, 0.32077, 0.27199, 0.22623, 0.18516, 0.14965, 0.11991, 0.09566, 0.07631,
                            0.0611, 0.04926],
    # seed 003 variants (learn_virtual, unguarded)
    "003.theta_reference.max": [0.02044, 0.019874, 0.071495, 0.21695],
    "003.second_order.max": [0.02044, 0.0085578],
    # seed 002: plain virtual learning through the CLI (path RMS and max between the points)
    "002.cli.rms": [0.002662, 0.001571, 0.001001, 0.000719, 0.000592, 0.000536, 0.000511, 0.000522],
    "002.cli.max": [0.007040, 0.005931, 0.005273, 0.004892, 0.004735, 0.004764, 0.004769, 0.004775],
    "002.cli.kept": [True, True, True, True, True, True, False, False],
    "002.cli.status": "diverged",
    "002.points.norm": [0.011078, 0.0055349, 0.002762, 0.0013761, 0.00068917, 0.00034593, 0.00017099, 0.000088264,
                        0.000046748, 0.000030824, 0.000030824],
    "002.points.chord_rms": [0.0026591, 0.0013569, 0.00071056, 0.00039709, 0.00025332, 0.0001933, 0.00016929,
                             0.00016044, 0.00015662, 0.00015518, 0.00015518],
    "002.cli.ek_rms": [0.0024167, 0.0013554, 0.00077383, 0.00045237, 0.00027664, 0.00018063, 0.00013168,
                       0.00015427],
    # seed 004: the product (CLI, guarded, Gamma 0.5, learning.error surface); mm
    "004.cli.max": [0.015048, 0.0075975, 0.0038771, 0.0021335, 0.0012613, 0.00077723],
    "004.cli.mean": [0.014035, 0.0070535, 0.0035612, 0.0017684, 0.00090363, 0.00042327],
    "004.cli.rms": [0.01422, 0.0071458, 0.0036072, 0.001791, 0.0009152, 0.00042882],
    "004.cli.kept": [True, True, True, True, True, True],
    "004.cli.status": "converged",
    # seed 004: zone form errors (75 / 50 / 25 % immersion) per iteration, the same run in-process; mm
    "004.zones": [[0.014051, 0.014568, 0.015048], [0.0070973, 0.007296, 0.0075497], [0.0036197, 0.0037095, 0.0037506],
                  [0.001832, 0.0018169, 0.0018511], [0.00093773, 0.00092032, 0.00095141],
                  [0.00044136, 0.00042207, 0.00045154]],
    # the default program's zones within a factor 2 of the paper's measured 8.41 / 11.96 / 17.21 um
    "004.zones0_within_2x_paper": [True, True, True],
}


def _cli(args: list[str]) -> dict[str, Any]:
    """``ilcnc ARGS --json`` in a scratch folder; the JSON it prints."""
    with tempfile.TemporaryDirectory() as tmp:
        # this checkout's ilcnc, whatever the environment has installed (a shared venv's editable install may be
        # another checkout's: from a scratch folder it would run that code)
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]))
        out = subprocess.run([sys.executable, "-m", "ilcnc", *args, "--json"], cwd=tmp, capture_output=True,
                             text=True, check=False, env=env)
    if out.returncode != 0:
        raise SystemExit(f"ilcnc {' '.join(args)} failed ({out.returncode}): {out.stderr.strip()}")
    return json.loads(out.stdout)


def _learn_cli(program: Path, profile: Path, *extra: str) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        return _cli(["learn", str(program), "--profile", str(profile), "--out", str(Path(tmp) / program.name),
                     *extra])


def _with(profile: Path, change: Callable[[dict[str, Any]], None]) -> MachineProfile:
    d = load_profile(profile).to_dict()
    change(d)
    return profile_from_dict(d, path=profile)


def _mx(r: LearnResult) -> list[float]:
    return [rec.stats["max"] for rec in r.iterations]


def _cli_max(j: dict[str, Any], key: str = "max") -> list[float]:
    return [it["contour_error_mm"][key] for it in j["iterations"]]


def seed000() -> dict[str, Any]:
    got: dict[str, Any] = {}
    cmd = f"ilcnc learn {S000_PROG.relative_to(ROOT)} --profile {S000_PROF.relative_to(ROOT)} --out corner-c.ngc"
    j = _learn_cli(S000_PROG, S000_PROF)
    got["000.cli.max"] = _cli_max(j)
    got["000.cli.reduction"] = 1.0 - got["000.cli.max"][-1] / got["000.cli.max"][0]
    got["000.cli.clipped"] = [it["clipped"] for it in j["iterations"]]
    got["000.cli.status"] = j["status"]
    print(f"[000] {cmd}")
    prog = read_program(S000_PROG)
    tangent = _with(S000_PROF, lambda d: d["learning"].update(error="tangent"))
    r = learn_virtual(prog, tangent, iterations=3, guard=False, stop_on_stall=False)
    got["000.tangent.max"] = _mx(r)
    got["000.tangent.clipped"] = [len(rec.clipped) for rec in r.iterations]
    r = learn_virtual(prog, load_profile(S000_PROF), iterations=5, stop_on_stall=False)
    got["000.guarded5.max"] = _mx(r)
    got["000.guarded5.rms"] = [rec.stats["rms"] for rec in r.iterations]
    got["000.guarded5.kept"] = [rec.kept for rec in r.iterations]
    base = load_profile(S000_PROF)

    def analytic(d: dict[str, Any]) -> None:
        kp, kd = {}, {}
        for a in ("x", "y", "z"):
            drive = base.axes[a].drive
            kp[a] = 1.0 + drive.damping_v_s_mm / drive.kd
            kd[a] = drive.mass_v_s2_mm / drive.kd
        d["learning"]["gains"] = {"kp": kp, "kd": kd, "ki": 0.0, "lead_samples": 1}

    r = learn_virtual(prog, _with(S000_PROF, analytic), iterations=3)
    got["000.analytic.max"] = _mx(r)
    got["000.analytic.status"] = r.status
    design = design_time_domain(base)

    def tuned(d: dict[str, Any]) -> None:
        d["learning"]["gains"] = {"kp": {a: design.axes[a].kp for a in ("x", "y", "z")},
                                  "kd": {a: design.axes[a].kd for a in ("x", "y", "z")}, "ki": 0.0,
                                  "lead_samples": design.lead_samples}
        d["learning"]["stop_tolerance_mm"] = 0.0

    r = learn_virtual(prog, _with(S000_PROF, tuned), iterations=3, guard=False, stop_on_stall=False)
    got["000.tune.max"] = _mx(r)
    return got


def seed001() -> dict[str, Any]:
    from ilcnc.learning.gain_schedule import schedule_gains

    got: dict[str, Any] = {}
    j = _cli(["tune", str(S001_PROG), "--profile", str(S001_PROF), "--method", "schedule"])["schedule"]
    got["001.cli.kp_fixed"] = j["baseline_scan"] and min((b for b in j["baseline_scan"] if b["within_limits"]),
                                                         key=lambda b: b["mse_um2"])["kp"]
    got["001.cli.mse"] = [j["mse_before_um2"], j["mse_after_um2"]]
    got["001.cli.reduction"] = j["reduction"]
    got["001.cli.max"] = [j["max_before_um"], j["max_after_um"]]
    got["001.cli.within_limits"] = [j["within_limits_before"], j["within_limits_after"]]
    scan = {round(b["kp"], 3): b["mse_um2"] for b in j["baseline_scan"]}
    got["001.cli.c1_scan_mse_1.6_2.7"] = [scan[1.6], scan[2.7]]
    got["001.cli.guarded_infeasible"] = [j["guarded"], j["infeasible"]]
    print(f"[001] ilcnc tune {S001_PROG.relative_to(ROOT)} --profile {S001_PROF.relative_to(ROOT)} --method schedule")
    prog, prof = read_program(S001_PROG), load_profile(S001_PROF)
    got["001.lam0.mse"] = schedule_gains(prog, prof, lam=0.0).mse_after_um2
    got["001.predicted.mse"] = schedule_gains(prog, prof, kinematics="predicted").mse_after_um2
    return got


def seed003() -> dict[str, Any]:
    got: dict[str, Any] = {}
    j = _learn_cli(S003_PROG, S003_PROF)
    got["003.ccc.max"] = _cli_max(j)
    rms = _cli_max(j, "rms")
    got["003.ccc.rms"] = [rms[0], rms[-1]]
    got["003.ccc.clipped"] = sum(it["clipped"] for it in j["iterations"])
    got["003.ccc.status"] = j["status"]
    print(f"[003] ilcnc learn {S003_PROG.relative_to(ROOT)} --profile {S003_PROF.relative_to(ROOT)} --out line-c.ngc")
    j = _learn_cli(S003_PROG, S003_IND)
    got["003.independent.max"] = _cli_max(j)
    print(f"[003] ilcnc learn {S003_PROG.relative_to(ROOT)} --profile {S003_IND.relative_to(ROOT)} --out line-i.ngc")
    prog = read_program(S003_PROG)
    ref = _with(S003_PROF, lambda d: d["controller"].update(theta="reference"))
    r = learn_virtual(prog, ref, iterations=3, guard=False, stop_on_stall=False)
    got["003.theta_reference.max"] = _mx(r)
    second = _with(S003_PROF, lambda d: d["learning"]["gains"].update(p1=1.2, p2=-0.2, q1={"x": 0.6, "y": 0.8}, q2=0.0))
    r = learn_virtual(prog, second, iterations=10, guard=False, stop_on_stall=False)
    got["003.second_order.max"] = [_mx(r)[0], _mx(r)[-1]]
    return got


def seed002() -> dict[str, Any]:
    got: dict[str, Any] = {}
    j = _learn_cli(S002_PROG, S002_PROF)
    got["002.cli.rms"] = _cli_max(j, "rms")
    got["002.cli.max"] = _cli_max(j)
    got["002.cli.kept"] = [it["kept"] for it in j["iterations"]]
    got["002.cli.status"] = j["status"]
    print(f"[002] ilcnc learn {S002_PROG.relative_to(ROOT)} --profile {S002_PROF.relative_to(ROOT)} --out circle-c.ngc")
    # the per-command error the law sees (E(k), path estimate), per iteration: same run, in-process
    r = learn_virtual(read_program(S002_PROG), load_profile(S002_PROF))
    got["002.cli.ek_rms"] = [float(np.sqrt(np.mean(np.sum(rec.signal.e_mm**2, axis=1)))) for rec in r.iterations]
    return got


def _probe_points(ran: Path, original: Any, geometry: Any, out: Path) -> tuple[Path, float]:
    """A virtual CMM: the part cut by ``ran`` measured at the original command points (measured − nominal, mm)."""
    commanded = read_program(ran).command_end_mm
    dev = commanded + geometry.error_mm(commanded) - original.command_end_mm
    out.write_text("k,dx,dy,dz\n" + "".join(f"{k},{d[0]:.7f},{d[1]:.7f},{d[2]:.7f}\n" for k, d in enumerate(dev)))
    return out, float(np.linalg.norm(dev))


def _chord_rms_mm(ran: Path, original: Any, geometry: Any) -> float:
    """RMS contour error between the command points: every chord that ran, sampled every 0.1 mm, moved by the
    volumetric error, against the original polygon (as tests/test_machine_errors.py measures it)."""
    from ilcnc.contour.path import PathGeometry
    from ilcnc.contour.search import contour_error

    mv = read_program(ran).moves
    pts, hint = [], []
    for i in np.flatnonzero(mv.command >= 0):
        a, b = mv.start_mm[i], mv.end_mm[i]
        n = max(int(np.linalg.norm(b - a) / 0.1), 1)
        pts.append(a + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a))
        hint.append(np.full(n + 1, i))
    q = np.vstack(pts)
    err = contour_error(PathGeometry.from_moves(original.moves), q + geometry.error_mm(q), np.concatenate(hint))
    return float(np.sqrt(np.mean(err.dist_mm**2)))


def seed002_points() -> dict[str, Any]:
    """The shop loop of seed 002: cut, probe the 11 points, ``ilcnc learn --points``, 10 times."""
    from ilcnc.vcnc.volumetric import load_volumetric

    prof = load_profile(S002_PROF)
    geometry = load_volumetric(prof.resolve(prof.geometry.map))
    original = read_program(S002_PROG)
    norms, chords = [], []
    with tempfile.TemporaryDirectory() as tmp:
        ran = S002_PROG
        for i in range(11):
            pts, norm = _probe_points(ran, original, geometry, Path(tmp) / f"probe{i}.csv")
            norms.append(norm)
            chords.append(_chord_rms_mm(ran, original, geometry))
            if i == 10:
                break
            out = Path(tmp) / f"circle.ilc{i + 1}.ngc"
            j = _cli(["learn", str(ran), "--profile", str(S002_PROF), "--out", str(out), "--points", str(pts),
                      "--state", str(Path(tmp) / "st")])
            assert j["status"] == "stepped", j
            ran = out
    print(f"[002] per iteration: cut, probe, ilcnc learn PROG --profile {S002_PROF.relative_to(ROOT)} --points"
          " probe.csv --state st --out next.ngc")
    return {"002.points.norm": norms, "002.points.chord_rms": chords}


def _zones_mm(run: Any) -> list[float]:
    """Mean wall deviation (mm) of the cutting moves in each of seed 004's stock zones."""
    y = run.actual_mm[:, 1]
    return [float(np.mean(run.error.dist_mm[run.feed_mask & (y > a) & (y < b)])) for a, b in S004_ZONES_MM]


def seed004() -> dict[str, Any]:
    got: dict[str, Any] = {}
    j = _learn_cli(S004_PROG, S004_PROF)
    got["004.cli.max"] = _cli_max(j)
    got["004.cli.mean"] = _cli_max(j, "mean")
    got["004.cli.rms"] = _cli_max(j, "rms")
    got["004.cli.kept"] = [it["kept"] for it in j["iterations"]]
    got["004.cli.status"] = j["status"]
    print(f"[004] ilcnc learn {S004_PROG.relative_to(ROOT)} --profile {S004_PROF.relative_to(ROOT)} --out stepped-c.h")
    r = learn_virtual(read_program(S004_PROG), load_profile(S004_PROF), keep_runs=True)
    got["004.zones"] = [_zones_mm(rec.run) for rec in r.iterations]
    got["004.zones0_within_2x_paper"] = [p / 2 <= z * 1e3 <= 2 * p
                                         for z, p in zip(got["004.zones"][0], S004_PAPER_ZONES_UM, strict=True)]
    print("[004] zones: the same learning run in-process (learn_virtual, keep_runs), mean wall deviation per zone")
    return got


SEEDS: dict[str, Callable[[], dict[str, Any]]] = {
    "000": seed000, "001": seed001, "002": lambda: {**seed002_points(), **seed002()}, "003": seed003,
    "004": seed004}


def _same(want: Any, have: Any) -> bool:
    if isinstance(want, list):
        return isinstance(have, list) and len(want) == len(have) and all(
            _same(a, b) for a, b in zip(want, have, strict=True))
    if isinstance(want, (bool, str, int)):
        return want == have
    return abs(have - want) <= max(TOL_REL * abs(want), TOL_ABS_MM)


def _fmt(v: Any) -> str:
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when a figure differs from docs/papers.md's")
    ap.add_argument("--seed", choices=sorted(SEEDS), action="append", help="only this seed (repeatable)")
    args = ap.parse_args(argv)
    bad = []
    for seed in args.seed or sorted(SEEDS):
        for name, have in SEEDS[seed]().items():
            want = EXPECTED[name]
            ok = _same(want, have)
            if not ok:
                bad.append(name)
            print(f"  {name:28s} {_fmt(have)}" + ("" if ok else f"   OFF: docs/papers.md has {_fmt(want)}"))
    if bad:
        print(f"{len(bad)} figure(s) off: {', '.join(bad)}")
    else:
        print("every figure as docs/papers.md prints it")
    return 1 if (bad and args.check) else 0


if __name__ == "__main__":
    sys.exit(main())

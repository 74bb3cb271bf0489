"""Issue 21's acceptance figure: of the programs LinuxCNC's ``rs274`` runs, how many ilcnc reads, and whether any
read differently.

    nice python bench/interp_coverage.py [--json] [FOLDER ...]

Default folders: LinuxCNC's shipped examples (``/usr/share/doc/linuxcnc/examples/nc_files``, every ``*.ngc``
below it) and ``../shared/samples/{gcode,contour,interp,large}``. A program counts when rs274 runs it to the end
(exit 0, on an ``N``-prefixed copy in a private directory, every tool of zero size: the set-up of
``tests/test_linuxcnc_interp.py``, whose comparison this reuses). ilcnc *reads* it when its interpreter does not
stop (``Program.unsupported`` is None); every move ilcnc reads (all of them, or those before the line where it
stops) is compared with rs274's, line, kind, end point, arc centre and the machine point with offsets and
rotation, within rs274's 4 printed decimals. Prints the read %, each refused program with ilcnc's one-line
reason, and every disagreement (must be none).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ilcnc.errors import ProgramError  # noqa: E402
from tests.test_linuxcnc_interp import (  # noqa: E402 - the suite's own LinuxCNC runner and comparison
    RS274,
    LinuxCNC,
    _compare,
    _drop_zero_length,
    _ours,
    _ours_motion,
    _split_splines,
)

LINUXCNC_EXAMPLES = Path("/usr/share/doc/linuxcnc/examples/nc_files")
SHARED = ROOT.parent / "shared" / "samples"


def programs(folders: list[Path]) -> list[Path]:
    """Every G-code program below the folders (suffixes ilcnc reads as G-code), sorted."""
    from ilcnc.program import GCODE_SUFFIXES

    out: list[Path] = []
    for f in folders:
        out.extend(sorted(p for p in f.rglob("*") if p.is_file() and p.suffix.lower() in GCODE_SUFFIXES))
    return out


def judge(path: Path, lcnc: LinuxCNC) -> dict[str, object] | None:
    """None when rs274 does not run the program; else whether ilcnc reads it, why not, and any disagreement."""
    oracle = lcnc.rs274(path)
    if not oracle.ok or oracle.motion is None:
        return None
    ours = _ours(path)
    if isinstance(ours, ProgramError):
        return {"program": str(path), "read": False, "reason": str(ours), "disagreements": []}
    src = ours.text.split("\n")
    mine, theirs = _drop_zero_length(_ours_motion(ours), oracle.motion)
    mine, theirs, problems = _split_splines(ours, mine, theirs, src, oracle.name)
    reason = ""
    if ours.unsupported is not None:
        line, problem = ours.unsupported
        reason = f"{path}:{line}: {problem}"
        theirs = theirs.take(np.arange(len(theirs)) < len(mine))  # only the moves ilcnc read
    problems += _compare(mine, theirs, oracle.name, src, "moves", full=True)
    return {"program": str(path), "read": ours.unsupported is None, "reason": reason, "disagreements": problems}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="*", type=Path)
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    args = ap.parse_args(argv)
    if RS274 is None:
        print("error: rs274 (LinuxCNC's standalone interpreter) is not on PATH", file=sys.stderr)
        return 2
    folders = args.folders or [LINUXCNC_EXAMPLES] + [SHARED / d for d in ("gcode", "contour", "interp", "large")]
    folders = [f for f in folders if f.is_dir()]
    with tempfile.TemporaryDirectory(prefix="ilcnc-cov-") as tmp:
        lcnc = LinuxCNC(Path(tmp))
        results = [r for r in (judge(p, lcnc) for p in programs(folders)) if r is not None]
    n = len(results)
    read = [r for r in results if r["read"]]
    refused = [r for r in results if not r["read"]]
    bad = [r for r in results if r["disagreements"]]
    summary = {
        "folders": [str(f) for f in folders],
        "rs274_runs": n,
        "ilcnc_reads": len(read),
        "read_percent": round(100.0 * len(read) / n, 1) if n else 0.0,
        "refused": [{"program": r["program"], "reason": r["reason"]} for r in refused],
        "disagreements": [{"program": r["program"], "problems": r["disagreements"]} for r in bad],
    }
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"rs274 runs {n} programs; ilcnc reads {len(read)} ({summary['read_percent']} %); "
              f"disagreements: {len(bad)}")
        for r in refused:
            print(f"  refused  {r['reason']}")
        for r in bad:
            print(f"  DISAGREES {r['program']}:\n    " + "\n    ".join(str(p) for p in r["disagreements"]))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

"""Fingerprint what the CLI prints and writes, to prove a refactoring changed no behaviour.

Runs a fixed set of ``ilcnc`` commands on shipped and shared samples (inspect, simulate, check, learn with and
without refinement, export, tune, identify, and bad input), each in a fresh folder, and records per command
the exit code, the SHA-256 of stdout and stderr and of every file it wrote. Wall-clock figures (``... s``
timings) are masked before hashing, as they differ from run to run.

    python bench/cli_outputs.py --save before.json      # on the old code
    python bench/cli_outputs.py --check before.json     # on the new code: exit 1 on any difference

Not a test: the whole set takes a few minutes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "samples"
PROFILE = REPO / "configs" / "example-mill.yaml"

#: (name, arguments); {own}, {samples}, {shared}, {profile}, {data} are substituted.
COMMANDS: list[tuple[str, list[str]]] = [
    ("inspect-star", ["inspect", "{own}/star.ngc", "--json"]),
    ("inspect-star-h", ["inspect", "{own}/star.h"]),
    ("inspect-compass", ["inspect", "{samples}/compass.ngc", "--profile", "{profile}"]),
    ("simulate-star", ["simulate", "{own}/star.ngc", "--profile", "{profile}", "--json"]),
    ("simulate-square-h", ["simulate", "{own}/square.h", "--profile", "{profile}", "--log-out", "log.csv"]),
    ("simulate-jsdc", ["simulate", "{samples}/jsdc.gcode", "--profile", "{profile}"]),
    ("check-compass", ["check", "{samples}/compass.ngc", "--profile", "{profile}", "--max-error", "0.005"]),
    ("learn-star", ["learn", "{own}/star.ngc", "--profile", "{profile}", "--iterations", "2", "--out", "star-c.ngc",
                    "--json"]),
    ("learn-square-h", ["learn", "{own}/square.h", "--profile", "{profile}", "--iterations", "2", "--out",
                        "square-c.h"]),
    ("learn-compass-refine", ["learn", "{samples}/compass.ngc", "--profile", "{profile}", "--iterations", "2",
                              "--refine", "--out", "compass-c.ngc", "--report", "rep"]),
    ("export-star-h", ["export", "{own}/star.ngc", "--out", "star-x.h"]),
    ("export-circle-inch", ["export", "{samples}/circle-inch.gcode", "--out", "circle-x.ngc"]),
    ("tune", ["tune", "--profile", "{profile}"]),
    ("tune-lifted", ["tune", "{own}/square.ngc", "--profile", "{profile}", "--method", "lifted"]),
    ("identify", ["identify", "{data}/identify/tncscope_x_sopdt.csv", "--axis", "x", "--json"]),
    ("bad-program", ["inspect", "{data}/../../configs/example-mill.yaml"]),
    ("bad-option", ["identify", "{data}/identify/linuxcnc_x_step.hal.log", "--axis", "x", "--log-period", "-1"]),
    ("bad-profile", ["simulate", "{own}/star.ngc", "--profile", "{own}/star.ngc"]),
]

_TIMING = re.compile(rb"\d+(\.\d+)?\s?(ms|s)\b|\"[a-z_]*(time|wall|elapsed)[a-z_]*_s\": [0-9.e-]+")


def _sha(data: bytes) -> str:
    return hashlib.sha256(_TIMING.sub(b"<t>", data)).hexdigest()[:16]


def run_all() -> dict[str, dict[str, object]]:
    subs = {"own": str(REPO / "samples" / "own"), "samples": str(REPO / "samples"), "shared": str(SHARED),
            "profile": str(PROFILE), "data": str(REPO / "tests" / "data")}
    out: dict[str, dict[str, object]] = {}
    env = dict(os.environ, COLUMNS="100", NO_COLOR="1", TERM="dumb")
    for name, args in COMMANDS:
        with tempfile.TemporaryDirectory() as tmp:
            argv = [sys.executable, "-m", "ilcnc", *(a.format(**subs) for a in args)]
            cp = subprocess.run(argv, cwd=tmp, capture_output=True, env=env, timeout=600)
            files = {}
            for f in sorted(Path(tmp).rglob("*")):
                if f.is_file():
                    files[str(f.relative_to(tmp))] = _sha(f.read_bytes())
            out[name] = {"rc": cp.returncode, "stdout": _sha(cp.stdout), "stderr": _sha(cp.stderr.replace(
                tmp.encode(), b"TMP")), "files": files}
            print(f"{name:24s} rc={cp.returncode} files={len(files)}", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", type=Path)
    g.add_argument("--check", type=Path)
    a = ap.parse_args()
    got = run_all()
    if a.save:
        a.save.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        return 0
    want = json.loads(a.check.read_text())
    bad = 0
    for name in sorted(set(want) | set(got)):
        if want.get(name) != got.get(name):
            bad += 1
            print(f"DIFFERENT {name}:\n  before {want.get(name)}\n  now    {got.get(name)}")
    print("same outputs" if not bad else f"{bad} commands differ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: restarts after dwells on the headless LinuxCNC simulation, time-scaled against real time.

Usage::

    python bench/linuxcnc_dwell.py                    # configs/linuxcnc-sim, k = 1 and 8
    python bench/linuxcnc_dwell.py --config DIR       # another configuration (e.g. a copy from an older commit)
    python bench/linuxcnc_dwell.py --block-mm 0.3     # shorter blocks (task's refill at k = 8 then shows)
    python bench/linuxcnc_dwell.py --check            # exit 1 when a restart differs from k = 1

The program (written to a temporary folder): a rapid, ``G4 P0.2``, a plunge and 300 wavy ``G1`` blocks of
``--block-mm`` at F3000 under ``G64 P0.01``, a retract and rapid, ``G4 P0.15``, a plunge and 300 more
blocks. It runs once at each time scale with ``retry_low_queue`` on, as ``ilcnc linuxcnc run`` does, and
prints per run the wall time, the time scale the log came from (a run whose queue ran low is repeated at
a smaller one), the driver's dwell report, and per restart (the plunge after each dwell) the standstill
before it in samples and how far the commanded path of the time-scaled run departs from k = 1's from the
restart on (the first sample where they differ by more than 1 nm, counted from the restart). ``--check``
passes when both restarts of every time-scaled run follow k = 1 over at least ``--restart-samples``
samples (default 150: the plunge and the first blocks) and no run was repeated at a smaller scale.

Needs LinuxCNC (Debian: ``apt-get install linuxcnc-uspace``); one run at a time per machine.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.shop.linuxcnc import DEFAULT_CONFIG_DIR, run_program  # noqa: E402


def program(block_mm: float) -> tuple[str, list[int]]:
    """The test program's text and the lines of the plunges that follow its two dwells."""
    lines = ["G21 G90 G17 G94", "G64 P0.01", "G0 X0 Y0 Z5", "G0 X10 Y0 Z1", "G4 P0.2", "G1 Z0 F3000"]
    restarts = [len(lines)]
    lines += [f"G1 X{10 + block_mm * i:.4f} Y{0.5 * math.sin(i * 0.2):.4f}" for i in range(1, 301)]
    lines += ["G0 Z5", "G0 X0 Y20", "G0 Z1", "G4 P0.15", "G1 Z0 F3000"]
    restarts.append(len(lines))
    lines += [f"G1 X{block_mm * i:.4f} Y{20 + 0.5 * math.cos(i * 0.15):.4f}" for i in range(1, 301)]
    lines += ["G0 Z5", "M2"]
    return "\n".join(lines) + "\n", restarts


def standstill(ref: np.ndarray, i: int) -> int:
    """Samples before ``i`` at which the commanded position stood where it stands at ``i - 1``."""
    m = i
    while m > 0 and np.all(np.abs(ref[m - 1] - ref[i - 1]) < 1e-9):
        m -= 1
    return i - m


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG_DIR)
    ap.add_argument("--scales", type=int, nargs="+", default=[1, 8])
    ap.add_argument("--block-mm", type=float, default=1.0)
    ap.add_argument("--restart-samples", type=int, default=150)
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args(argv)
    text, restarts = program(a.block_mm)
    ok = True
    with tempfile.TemporaryDirectory(prefix="ilcnc-dwell-") as d:
        prog = Path(d) / "dwell.ngc"
        prog.write_text(text)
        logs = {}
        for k in a.scales:
            t0 = time.monotonic()
            r = run_program(prog, a.config, Path(d) / f"k{k}.log", time_scale=k, retry_low_queue=True)
            wall = time.monotonic() - t0
            repeated = [m for m in r.messages if "repeated at time scale" in m]
            print(f"k = {k}: wall {wall:6.1f} s, log from time scale {r.time_scale}, {r.log.n_samples} samples, "
                  f"{len(repeated)} repeat(s); messages: {r.messages or 'none'}")
            ok &= r.time_scale == k
            logs[k] = r.log
        base = logs[a.scales[0]]
        for k in a.scales[1:]:
            log = logs[k]
            for line in restarts:
                i = int(np.flatnonzero(base.line == line)[0])
                j = int(np.flatnonzero(log.line == line)[0])
                n = min(base.n_samples - i, log.n_samples - j)
                d_ref = np.abs(base.ref_mm[i:i + n] - log.ref_mm[j:j + n]).max(axis=1)
                off = np.flatnonzero(d_ref > 1e-6)
                same = int(off[0]) if off.size else n
                print(f"  restart at line {line}: standstill {standstill(base.ref_mm, i)} samples at k = "
                      f"{a.scales[0]}, {standstill(log.ref_mm, j)} at k = {k}; commanded path as at k = "
                      f"{a.scales[0]} for {same} samples" + (" (to the end)" if same == n else ""))
                ok &= same >= a.restart_samples
    if a.check:
        print("check:", "met" if ok else "NOT MET")
        return 0 if ok else 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

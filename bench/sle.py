#!/usr/bin/env python
"""Benchmark: surface location error (SLE) of every command of the largest contour sample (issue 8).

Usage::

    python bench/sle.py                       # the contour sample with the most G01 commands
    python bench/sle.py PROG.ngc --repeat 5
    python bench/sle.py --scale 100           # the same radial depths tiled 100 times (~1 M commands)
    python bench/sle.py --check               # exit 1 when the 10 s target is missed

One run measures, with the seed 004 tool and cutting coefficients (``seed004_tool()``,
``seed004_cutting()``) and a synthetic radial depth per command (a slow sweep 0.6-11.4 mm
of the 12 mm tool plus jitter, so nearly every command has its own depth):

* ``read``: ``read_program`` and the command table (not part of the target);
* ``sle``: ``sle_per_command_mm`` on every command, best of R;
* ``naive``: ``sle_frequency_domain_mm`` (FFT, FRF product, inverse FFT) called once per
  command on the first ``--naive`` commands, extrapolated to all of them, and the largest
  difference from ``sle``.

It prints the times, commands/s and the ratio to the 10 s target.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ilcnc.program import read_program  # noqa: E402
from ilcnc.vcnc.deflection import (  # noqa: E402
    feed_per_tooth_mm,
    seed004_cutting,
    seed004_tool,
    sle_frequency_domain_mm,
    sle_per_command_mm,
)

TARGET_S = 10.0
CONTOUR = ROOT / "samples" / "third_party" / "contour"


def largest_contour_sample() -> Path:
    """The file under samples/third_party/contour with the most G01 commands."""
    best, n_best = None, -1
    for p in sorted(CONTOUR.iterdir()):
        if not p.is_file() or p.suffix.lower() in (".tsv", ".md"):
            continue
        n = read_program(p).n_commands
        if n > n_best:
            best, n_best = p, n
    if best is None:
        raise SystemExit(f"no program under {CONTOUR}")
    return best


def synthetic_radial_depth(k: int, diameter_mm: float, seed: int = 8) -> np.ndarray:
    """A slow sweep over 5-95 % of the diameter with ±2 % jitter, one value per command."""
    i = np.arange(k)
    sweep = 0.5 + 0.45 * np.sin(2.0 * np.pi * i / 997.0)
    jitter = np.random.default_rng(seed).uniform(-0.02, 0.02, k)
    return diameter_mm * np.clip(sweep + jitter, 0.05, 0.95)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("program", nargs="?", help="part program (default: the largest contour sample)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--scale", type=int, default=1, help="tile the commands this many times")
    ap.add_argument("--naive", type=int, default=200, help="commands for the per-command FFT reference")
    ap.add_argument("--check", action="store_true", help="exit 1 when the 10 s target is missed")
    args = ap.parse_args()

    path = Path(args.program) if args.program else largest_contour_sample()
    t0 = time.perf_counter()
    prog = read_program(path)
    feed = prog.command_feed_mm_min
    read_s = time.perf_counter() - t0
    tool, cut = seed004_tool(), seed004_cutting()
    k = prog.n_commands * args.scale
    ae = synthetic_radial_depth(k, tool.diameter_mm)
    c = np.tile(feed_per_tooth_mm(feed, cut.spindle_rpm, tool.teeth), args.scale)
    c = np.where(np.isfinite(c) & (c > 0), c, 0.1)
    print(f"program    {path.name}: {prog.n_commands:,} G01 commands (x{args.scale} -> {k:,}); read {read_s:.2f} s")
    print(f"           radial depth {ae.min():.2f}-{ae.max():.2f} mm, {np.unique(ae).size:,} distinct;"
          f" feed per tooth {c.min():.4f}-{c.max():.4f} mm; {cut.mode}-milling, {tool.teeth} teeth")

    sle_per_command_mm(ae[:10], c[:10], tool, cut)  # warm-up: imports
    best = float("inf")
    sle = None
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        sle = sle_per_command_mm(ae, c, tool, cut)
        best = min(best, time.perf_counter() - t0)
    assert sle is not None
    print(f"sle        sle_per_command_mm, best of {args.repeat}: {best:.3f} s ({k / best:,.0f} commands/s);"
          f" SLE {sle.min() * 1e3:.2f} .. {sle.max() * 1e3:.2f} µm")

    n = min(args.naive, k)
    if n:
        t0 = time.perf_counter()
        ref = np.array([sle_frequency_domain_mm(a, cc, tool, cut) for a, cc in zip(ae[:n], c[:n], strict=True)])
        naive_s = time.perf_counter() - t0
        diff = float(np.max(np.abs(ref - sle[:n])))
        print(f"naive      sle_frequency_domain_mm per command on {n}: {naive_s:.3f} s -> {naive_s / n * k:.1f} s"
              f" extrapolated ({naive_s / n * k / best:,.0f}x slower); largest difference {diff:.2e} mm")

    met = best < TARGET_S
    print(f"target < {TARGET_S:.0f} s: {best:.3f} s = {best / TARGET_S:.4f} x target -> {'met' if met else 'NOT MET'}")
    return 0 if met or not args.check else 1


if __name__ == "__main__":
    raise SystemExit(main())

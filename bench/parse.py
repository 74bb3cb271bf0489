#!/usr/bin/env python
"""Parse benchmark: ilcnc's G-code reader against pygcode and LinuxCNC's rs274, in one run.

    python bench/parse.py [FILE] [--pygcode-lines N] [--repeat R] [--check]

Measures, on FILE (default samples/third_party/large/stellabee1.ngc, 169,220 lines):

* ilcnc: ``read_program(path)`` plus the command table (k, line, end point,
  feed), best of R runs (default 3);
* pygcode: ``Line(text)`` + ``Machine.process_block(line.block)`` on the first
  N lines (default 20,000; pygcode needs ~25 s for the whole file), timed per
  line and extrapolated to the file;
* ``rs274 -g FILE /dev/null`` (LinuxCNC's stand-alone interpreter, a
  subprocess, best of R) when it is installed;

and prints lines/s of each, the ratios and whether the targets are met
(1,000,000 lines/s; at least 30x pygcode; faster than rs274). ``--check``
makes the exit code 1 when a target is missed.

It also runs a differential check on the first N lines: after every block
that pygcode executes as a G1 with axis words, its machine position (work
coordinates, program units) is compared with ilcnc's command end point on
that line. pygcode misreads some constructs, so disagreements are reported,
not judged.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import importlib
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_FILE = REPO / "samples" / "third_party" / "large" / "stellabee1.ngc"
TARGET_LINES_PER_S = 1_000_000
TARGET_VS_PYGCODE = 30.0
TARGET_VS_RS274 = 1.0

sys.path.insert(0, str(REPO))


def count_lines(data: bytes) -> int:
    return data.count(b"\n") + (1 if data and not data.endswith(b"\n") else 0)


# --------------------------------------------------------------------------- ilcnc


@dataclass
class OursResult:
    seconds: float
    runs: list[float]
    n_commands: int
    n_moves: int
    unsupported: tuple[int, str] | None
    program: object


def time_ours(path: Path, repeat: int) -> OursResult:
    """``read_program(path)`` and the command table, best of ``repeat``."""
    from ilcnc.program import read_program

    for module in ("ilcnc.program.gcode", "ilcnc.program.heidenhain"):  # lazy imports out of the timing
        with contextlib.suppress(ImportError):
            importlib.import_module(module)
    runs = []
    prog = None
    for _ in range(repeat):
        prog = None
        gc.collect()
        t0 = time.perf_counter()
        prog = read_program(path)
        # the command table: k = 0..N-1 with its line, end point and feed
        _ = (prog.command_line, prog.command_end_mm, prog.command_feed_mm_min)
        runs.append(time.perf_counter() - t0)
    assert prog is not None
    return OursResult(min(runs), runs, prog.n_commands, len(prog.moves), prog.unsupported, prog)


# --------------------------------------------------------------------------- pygcode


@dataclass
class PygcodeResult:
    lines: int
    seconds: float
    errors: list[tuple[int, str, str]] = field(default_factory=list)
    n_errors: int = 0
    g1_positions: dict[int, tuple[float, float, float]] = field(default_factory=dict)

    @property
    def per_line(self) -> float:
        return self.seconds / max(self.lines, 1)


def time_pygcode(text_lines: list[str], n: int) -> PygcodeResult | None:
    """pygcode ``Line`` + ``Machine.process_block`` on the first ``n`` lines (timed per line)."""
    try:
        from pygcode import Line, Machine
        from pygcode.gcodes import GCodeLinearMove
    except ImportError:
        return None
    machine = Machine()
    res = PygcodeResult(lines=min(n, len(text_lines)), seconds=0.0)
    clock = time.perf_counter
    total = 0.0
    for lineno, s in enumerate(text_lines[:n], start=1):
        t0 = clock()
        try:
            line = Line(s)
            machine.process_block(line.block)
        except Exception as exc:  # pygcode raises on what it does not know; count and go on
            total += clock() - t0
            res.n_errors += 1
            if len(res.errors) < 5:
                res.errors.append((lineno, s.strip(), f"{type(exc).__name__}: {exc}"))
            continue
        total += clock() - t0
        block = line.block
        explicit = any(isinstance(g, GCodeLinearMove) and any(a in g.params for a in "XYZ") for g in block.gcodes)
        modal = (isinstance(machine.mode.motion, GCodeLinearMove)
                 and any(w.letter in "XYZ" for w in block.modal_params))
        if explicit or modal:
            p = machine.pos
            res.g1_positions[lineno] = (float(p.X), float(p.Y), float(p.Z))
    res.seconds = total
    return res


# --------------------------------------------------------------------------- rs274


def time_rs274(path: Path, repeat: int) -> tuple[float | None, str]:
    """``rs274 -g FILE /dev/null``, best of ``repeat``; (None, reason) when it cannot run."""
    exe = shutil.which("rs274")
    if exe is None:
        return None, "rs274 is not installed (LinuxCNC's stand-alone interpreter, Debian package linuxcnc-uspace)"
    runs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        r = subprocess.run([exe, "-g", str(path), "/dev/null"], stdin=subprocess.DEVNULL, capture_output=True,
                           timeout=600)
        runs.append(time.perf_counter() - t0)
        if r.returncode != 0:
            err = (r.stderr or r.stdout).decode("utf-8", "replace").strip().splitlines()
            return None, f"rs274 failed (exit {r.returncode}): {err[-1] if err else ''}"
    return min(runs), exe


# --------------------------------------------------------------------------- differential check


@dataclass
class Differential:
    compared: int = 0
    disagree: int = 0
    examples: list[str] = field(default_factory=list)
    only_pygcode: int = 0
    only_ours: int = 0


def differential(ours: OursResult, py: PygcodeResult, text_lines: list[str], n: int, tol: float = 1e-6,
                 show: int = 5) -> Differential:
    """Compare pygcode's position after each G1 block with our command end points (program units)."""
    import numpy as np

    prog = ours.program
    mv = prog.moves  # type: ignore[attr-defined]
    idx = prog.command_moves  # type: ignore[attr-defined]
    lines = mv.line[idx]
    keep = lines <= n
    idx, lines = idx[keep], lines[keep]
    ends = (mv.end_mm[idx] - mv.offset_mm[idx]) / mv.unit_mm[idx][:, None]
    d = Differential()
    ours_lines = set()
    for line, end in zip(lines.tolist(), ends, strict=True):
        ours_lines.add(line)
        ref = py.g1_positions.get(line)
        if ref is None:
            d.only_ours += 1
            continue
        d.compared += 1
        ref_a = np.asarray(ref)
        if not np.all(np.abs(end - ref_a) <= tol * np.maximum(1.0, np.abs(ref_a))):
            d.disagree += 1
            if len(d.examples) < show:
                fmt = ", ".join(f"{v:.6g}" for v in end)
                pfmt = ", ".join(f"{v:.6g}" for v in ref)
                d.examples.append(f"line {line}: {text_lines[line - 1].strip()[:60]!r}: ilcnc ({fmt}), pygcode ({pfmt})")
    d.only_pygcode = sum(1 for line in py.g1_positions if line not in ours_lines)
    return d


# --------------------------------------------------------------------------- report


def _rate(lines: int, seconds: float) -> str:
    return f"{lines / seconds:>12,.0f} lines/s" if seconds > 0 else "           - lines/s"


def _times(ratio: float) -> str:
    """'12.3x faster' or '2.10x slower' for a ratio of their time over ours."""
    return f"{ratio:.1f}x faster" if ratio >= 1 else f"{1 / ratio:.2f}x slower"


def _verdict(ok: bool) -> str:
    return "met" if ok else "NOT MET"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("file", nargs="?", type=Path, default=DEFAULT_FILE, help="G-code file (default: %(default)s)")
    ap.add_argument("--pygcode-lines", type=int, default=20_000, metavar="N",
                    help="run pygcode (and the differential check) on the first N lines (default 20000; 0 = all)")
    ap.add_argument("--repeat", type=int, default=3, metavar="R", help="best of R runs for ilcnc and rs274 (default 3)")
    ap.add_argument("--no-pygcode", action="store_true", help="skip pygcode and the differential check")
    ap.add_argument("--no-rs274", action="store_true", help="skip rs274")
    ap.add_argument("--check", action="store_true", help="exit 1 when a target is missed")
    args = ap.parse_args(argv)

    path: Path = args.file
    if not path.is_file():
        print(f"error: {path}: file not found", file=sys.stderr)
        return 1
    data = path.read_bytes()
    n_lines = count_lines(data)
    text_lines = data.decode("latin-1").split("\n")
    n_py = n_lines if args.pygcode_lines <= 0 else min(args.pygcode_lines, n_lines)

    print(f"file: {path} ({n_lines:,} lines, {len(data) / 1e6:.1f} MB)")
    print()

    ours = time_ours(path, max(1, args.repeat))
    runs = ", ".join(f"{t:.3f}" for t in ours.runs)
    print(f"ilcnc   read_program + command table     {ours.seconds:8.3f} s  {_rate(n_lines, ours.seconds)}"
          f"   (best of {len(ours.runs)}: {runs} s; {ours.n_commands:,} G01 commands, {ours.n_moves:,} moves)")
    if ours.unsupported is not None:
        print(f"        note: the interpreter stopped at line {ours.unsupported[0]}: {ours.unsupported[1]}")

    py = None if args.no_pygcode else time_pygcode(text_lines, n_py)
    if py is None:
        print("pygcode skipped" + ("" if args.no_pygcode else " (not installed: pip install pygcode)"))
    else:
        whole = py.per_line * n_lines
        what = "whole file" if py.lines >= n_lines else f"first {py.lines:,} lines, extrapolated per line"
        print(f"pygcode Line + Machine.process_block     {whole:8.3f} s  {_rate(n_lines, whole)}"
              f"   ({what}: {py.seconds:.3f} s = {py.per_line * 1e6:.1f} us/line)")
        if py.n_errors:
            print(f"        pygcode raised on {py.n_errors:,} of those lines, e.g.:")
            for lineno, s, err in py.errors[:3]:
                print(f"          line {lineno}: {s[:50]!r}: {err[:100]}")

    rs = None
    if args.no_rs274:
        print("rs274   skipped (--no-rs274)")
    else:
        rs, info = time_rs274(path, max(1, args.repeat))
        if rs is None:
            print(f"rs274   skipped: {info}")
        else:
            print(f"rs274   -g FILE /dev/null (subprocess)   {rs:8.3f} s  {_rate(n_lines, rs)}   ({info}, best of {args.repeat})")

    print()
    ours_rate = n_lines / ours.seconds
    failed = []
    ok = ours_rate >= TARGET_LINES_PER_S
    failed += [] if ok else ["1M lines/s"]
    print(f"target {TARGET_LINES_PER_S:,} lines/s:  {ours_rate:,.0f} lines/s  -> {_verdict(ok)}")
    if py is not None:
        ratio = (py.per_line * n_lines) / ours.seconds
        ok = ratio >= TARGET_VS_PYGCODE
        failed += [] if ok else ["30x pygcode"]
        print(f"ilcnc vs pygcode:  {_times(ratio)} (target: >= {TARGET_VS_PYGCODE:.0f}x faster)  -> {_verdict(ok)}")
    if rs is not None:
        ratio = rs / ours.seconds
        ok = ratio > TARGET_VS_RS274
        failed += [] if ok else ["faster than rs274"]
        print(f"ilcnc vs rs274:    {_times(ratio)} (target: faster)  -> {_verdict(ok)}")

    if py is not None:
        d = differential(ours, py, text_lines, py.lines)
        print()
        print(f"differential check on the first {py.lines:,} lines (end points of G1 blocks, program units, "
              f"relative tolerance 1e-6):")
        print(f"  {d.compared:,} compared, {d.disagree:,} disagree; {d.only_ours:,} ilcnc commands without a "
              f"pygcode G1 position, {d.only_pygcode:,} pygcode G1 blocks that are not ilcnc commands")
        for ex in d.examples:
            print(f"  {ex}")
        if d.disagree:
            print("  (pygcode is a reference, not the truth: it misreads some constructs)")

    if failed:
        print()
        print(f"targets missed: {', '.join(failed)}")
    return 1 if (args.check and failed) else 0


if __name__ == "__main__":
    sys.exit(main())

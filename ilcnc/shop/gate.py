"""The CI gate of ``ilcnc check`` over many programs: thresholds, a stored baseline, JUnit XML.

Each program runs on the virtual CNC once (:func:`check_program`); its cutting moves' max and RMS contour
error and its cycle time are judged (:func:`judge`) against fixed thresholds (``--max-error``,
``--max-rms``) and against a baseline of the same figures stored by an earlier run (``--baseline``):
a figure regresses when it grew by more than the tolerance (``tolerance_mm`` for the errors, default the
profile's ``machine.resolution_mm``, the least step the control can make; ``tolerance_s`` for the cycle
time, default one servo period, the step of the run's clock). :func:`junit_xml` writes one ``<testcase>``
per program, the format GitLab, GitHub and Jenkins read.
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ilcnc.errors import IlcncError, InputError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.jsonout import json_float
from ilcnc.outcomes import CheckStatus
from ilcnc.profile.sections import MachineProfile

__all__ = ["BASELINE_FORMAT", "Baseline", "ProgramCheck", "check_program", "expand_programs",
           "figures_line", "judge", "junit_xml", "read_baseline", "write_baseline"]

#: ``format`` of a baseline file.
BASELINE_FORMAT = "ilcnc-check-baseline"
_VERSION = 1


@dataclass(kw_only=True)
class ProgramCheck:
    """One program's figures and verdict.

    Attributes
    ----------
    name : str
        The program as given (its key in the baseline).
    path : Path
        The file.
    max_mm, rms_mm : float or None
        The cutting moves' max and RMS contour error, mm (None when unreadable).
    cycle_s : float or None
        Cycle time, s.
    line : int or None
        Source line of the largest error.
    wall_s : float
        Wall time the check of this program took, s.
    baseline : dict or None
        The baseline's entry (``max_mm``, ``rms_mm``, ``cycle_s``), None when the baseline has none.
    failures : list of str
        Each figure over its threshold or regressed, one line each naming it.
    error : str or None
        Why the program could not be read.
    notes : list of str
        Anything else worth a line (not in the baseline, improved).
    """

    name: str
    path: Path
    max_mm: float | None = None
    rms_mm: float | None = None
    cycle_s: float | None = None
    line: int | None = None
    wall_s: float = 0.0
    baseline: dict[str, float] | None = None
    failures: list[str] = field(default_factory=list)
    error: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def status(self) -> CheckStatus:
        if self.error is not None:
            return CheckStatus.UNREADABLE
        return CheckStatus.FAILED if self.failures else CheckStatus.PASSED

    def figures(self) -> dict[str, float | None]:
        """The baseline entry of this run."""
        return {"max_mm": self.max_mm, "rms_mm": self.rms_mm, "cycle_s": self.cycle_s}

    def to_json(self) -> dict[str, Any]:
        return {"program": self.name, "status": self.status.value, "max_mm": json_float(self.max_mm),
                "rms_mm": json_float(self.rms_mm), "cycle_s": json_float(self.cycle_s), "line": self.line,
                "baseline": self.baseline, "failures": list(self.failures), "error": self.error,
                "notes": list(self.notes)}


def expand_programs(paths: list[Path]) -> list[Path]:
    """The programs of ``paths``: a file as given, a folder's program files (``ilcnc batch``'s suffixes,
    sorted), each once, in the order given.

    Raises
    ------
    InputError
        A folder without programs.
    """
    from ilcnc.shop.batch import folder_programs

    out: list[Path] = []
    seen: set[str] = set()
    for p in paths:
        for q in (folder_programs(p) if p.is_dir() else [p]):
            key = os.path.normpath(str(q))
            if key not in seen:
                seen.add(key)
                out.append(q)
    return out


def check_program(path: Path, profile: MachineProfile) -> ProgramCheck:
    """Read ``path`` and run it on the virtual CNC of ``profile``; an unreadable program is a result too."""
    from ilcnc.program import read_program
    from ilcnc.vcnc.run import simulate_figures

    t0 = time.perf_counter()
    res = ProgramCheck(name=os.path.normpath(str(path)), path=path)
    try:
        prog = read_program(path, default_units=profile.machine.units)
        run = simulate_figures(prog, profile)
    except IlcncError as exc:
        res.error = exc.format()
        res.wall_s = time.perf_counter() - t0
        return res
    res.wall_s = time.perf_counter() - t0
    res.cycle_s = float(run.cycle_time_s)
    if run.worst_sample < 0:
        res.failures.append(f"no cutting move: {run.cutting.describe()}; nothing to judge")
        return res
    res.max_mm = float(run.stats.max_mm)
    res.rms_mm = float(run.stats.rms_mm)
    res.line = int(run.worst(prog)["line"])
    return res


def judge(res: ProgramCheck, *, max_error_mm: float | None, max_rms_mm: float | None,
          baseline: dict[str, float] | None, tolerance_mm: float, tolerance_s: float) -> ProgramCheck:
    """Add to ``res.failures`` every figure over its threshold or regressed against ``baseline`` (in place)."""
    if res.status is CheckStatus.UNREADABLE:
        return res
    res.baseline = baseline
    if res.max_mm is not None and max_error_mm is not None and res.max_mm > max_error_mm:
        res.failures.append(f"max contour error {res.max_mm * 1e3:.2f} µm > --max-error {max_error_mm * 1e3:g} µm"
                            f" (line {res.line})")
    if res.rms_mm is not None and max_rms_mm is not None and res.rms_mm > max_rms_mm:
        res.failures.append(f"RMS contour error {res.rms_mm * 1e3:.2f} µm > --max-rms {max_rms_mm * 1e3:g} µm")
    if baseline is None:
        return res
    for key, label, tol, scale, unit in (("max_mm", "max contour error", tolerance_mm, 1e3, "µm"),
                                         ("rms_mm", "RMS contour error", tolerance_mm, 1e3, "µm"),
                                         ("cycle_s", "cycle time", tolerance_s, 1.0, "s")):
        new, old = getattr(res, key), baseline.get(key)
        if new is None or old is None:
            continue
        if new > old + tol:
            res.failures.append(f"{label} regressed: {new * scale:.3f} {unit} > baseline {old * scale:.3f} {unit}"
                                f" + tolerance {tol * scale:g} {unit}")
        elif new < old - tol:
            res.notes.append(f"{label} improved: {new * scale:.3f} {unit} < baseline {old * scale:.3f} {unit}")
    return res


@dataclass(kw_only=True)
class Baseline:
    """A stored baseline: per program (its path as given) the figures of a run."""

    programs: dict[str, dict[str, float]]
    profile: str | None = None
    profile_sha256: str | None = None


def read_baseline(path: Path) -> Baseline:
    """Read a baseline file.

    Raises
    ------
    InputError
        Not JSON, not a baseline, or a figure that is not a finite number.
    """
    try:
        data = json.loads(read_bytes(path).decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(path, None, f"not an ilcnc check baseline (JSON): {exc}") from None
    if not isinstance(data, dict) or data.get("format") != BASELINE_FORMAT:
        raise InputError(path, None, f"not an ilcnc check baseline (no \"format\": \"{BASELINE_FORMAT}\")")
    if data.get("version") != _VERSION:
        raise InputError(path, None, f"baseline version {data.get('version')!r}; this ilcnc reads {_VERSION}")
    progs = data.get("programs")
    if not isinstance(progs, dict):
        raise InputError(path, None, "\"programs\" must be an object of program -> figures")
    out: dict[str, dict[str, float]] = {}
    for name, fig in progs.items():
        if not isinstance(fig, dict):
            raise InputError(path, None, f"program {name!r}: figures must be an object")
        entry = {}
        for key in ("max_mm", "rms_mm", "cycle_s"):
            v = fig.get(key)
            if v is None:
                continue
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v < 0:
                raise InputError(path, None, f"program {name!r}: {key} must be a finite number >= 0, got {v!r}")
            entry[key] = float(v)
        out[str(name)] = entry
    return Baseline(programs=out, profile=data.get("profile"), profile_sha256=data.get("profile_sha256"))


def write_baseline(path: Path, results: list[ProgramCheck], *, previous: Baseline | None, profile: Path,
                   profile_sha256: str, protect: tuple[Path, ...] = ()) -> Path:
    """Write the baseline of ``results`` atomically; an unreadable program keeps its previous entry."""
    progs: dict[str, dict[str, float]] = {}
    for r in results:
        if r.status is CheckStatus.UNREADABLE:
            if previous is not None and r.name in previous.programs:
                progs[r.name] = previous.programs[r.name]
            continue
        progs[r.name] = {k: v for k, v in r.figures().items() if v is not None}
    data = {"format": BASELINE_FORMAT, "version": _VERSION, "profile": str(profile),
            "profile_sha256": profile_sha256, "programs": progs}
    return write_atomic(path, json.dumps(data, indent=1, sort_keys=True) + "\n", protect=protect)


def junit_xml(results: list[ProgramCheck], *, suite: str = "ilcnc check") -> bytes:
    """JUnit XML of the results: ``<testsuites>`` holding one ``<testsuite>`` with one ``<testcase>`` per
    program (``classname`` ``ilcnc.check``, ``name`` the program, ``time`` s), a ``<failure>`` whose message
    names each figure that failed or regressed, an ``<error>`` for a program that could not be read, and the
    figures in ``<system-out>``."""
    failures = sum(r.status is CheckStatus.FAILED for r in results)
    errors = sum(r.status is CheckStatus.UNREADABLE for r in results)
    total = sum(r.wall_s for r in results)
    counts = {"tests": str(len(results)), "failures": str(failures), "errors": str(errors), "skipped": "0",
              "time": f"{total:.3f}"}
    root = ET.Element("testsuites", {"name": suite, **counts})
    ts = ET.SubElement(root, "testsuite", {
        "name": suite, **counts,
        "timestamp": datetime.now(timezone.utc).replace(microsecond=0).isoformat().replace("+00:00", ""),
        "hostname": socket.gethostname()})
    for r in results:
        tc = ET.SubElement(ts, "testcase", {"classname": "ilcnc.check", "name": r.name, "file": str(r.path),
                                            "time": f"{r.wall_s:.3f}"})
        if r.status is CheckStatus.UNREADABLE:
            el = ET.SubElement(tc, "error", {"message": f"could not be read: {r.error}", "type": "unreadable"})
            el.text = r.error
        elif r.failures:
            el = ET.SubElement(tc, "failure", {"message": "; ".join(r.failures), "type": "regression"
                                               if any("regressed" in f for f in r.failures) else "threshold"})
            el.text = "\n".join(r.failures)
        out = ET.SubElement(tc, "system-out")
        out.text = figures_line(r)
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def figures_line(r: ProgramCheck) -> str:
    """The figures of one program (and its baseline's, when it has an entry), µm and s, in one line, and its
    notes on the next lines; an unreadable program's error."""
    if r.status is CheckStatus.UNREADABLE:
        return str(r.error)

    def f(v: float | None, scale: float, unit: str) -> str:
        return "-" if v is None else f"{v * scale:.3f} {unit}"

    base = r.baseline

    def b(key: str, scale: float, unit: str) -> str:
        return "" if base is None else f" (baseline {f(base.get(key), scale, unit)})"

    return (f"max {f(r.max_mm, 1e3, 'µm')}{b('max_mm', 1e3, 'µm')}, RMS {f(r.rms_mm, 1e3, 'µm')}"
            f"{b('rms_mm', 1e3, 'µm')}, cycle {f(r.cycle_s, 1.0, 's')}{b('cycle_s', 1.0, 's')}"
            + "".join(f"\n{n}" for n in r.notes))

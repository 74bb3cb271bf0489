"""``ilcnc learn`` as a shop runs it: virtual learning, one step from a machine log or probe points, the state.

Two ways to learn a part:

* **on the virtual CNC** (no measurement given): :func:`ilcnc.learning.learner.learn_virtual`
  runs all iterations; every iteration's program, corrections and errors go
  into the state directory (default ``OUT.state/`` beside the output) as they
  are made;
* **on the machine** (``--log`` or ``--points``, ``--state`` required): one
  step per call. The first call starts the state with the original program
  (the log is a run of it); each call measures the program the state says
  the machine ran last, checks the measurement belongs to it
  (:mod:`ilcnc.shop.measure`), applies the guard and writes the next program.

Correcting twice is the classic failure of G-code rewriters: a program that
is an output of a learning run (its hash is in the state, or it carries the
``--stamp`` provenance comment) is refused as the start of a new run; given
with the ``--state`` of its run it continues that run.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ilcnc.errors import InputError, LogError, StateError, UsageError
from ilcnc.fileio import inside, read_bytes, remove_stale_temporaries, same_file, write_atomic
from ilcnc.learning.cycle_hold import motion_time_s
from ilcnc.learning.guard import LearningGuard
from ilcnc.learning.learner import (
    Clip,
    IterationRecord,
    Learner,
    cycle_budget,
    frozen_reasons,
    hold_step,
    learn_virtual,
    model_assisted_correction,
    program_with_corrections,
    refine_for_learning,
    refine_from_errors,
    require_learnable,
)
from ilcnc.outcomes import GuardVerdict, LearnMode, LearnStatus
from ilcnc.profile.load import load_profile
from ilcnc.profile.sections import MachineProfile
from ilcnc.program import read_program
from ilcnc.program.comments import comment_first_line
from ilcnc.program.model import Program
from ilcnc.shop.measure import path_position_mm
from ilcnc.shop.state import IterationEntry, LearnState, sha256_bytes, state_lock
from ilcnc.vcnc.command_error import CommandSignal, error_kind
from ilcnc.wording import plural

__all__ = ["LearnOutcome", "LearnRequest", "find_stamp", "learn_part", "stamp_text", "unstamp_text"]

_STAMP = re.compile(r"ilcnc: learned from (?P<name>\S+) sha256:(?P<sha>[0-9a-f]{16}) iteration (?P<it>\d+)")


def find_stamp(text: str) -> dict[str, Any] | None:
    """The provenance stamp of an ilcnc output in a program text (first 50 lines), or None."""
    for i, line in enumerate(text.splitlines()[:50], start=1):
        m = _STAMP.search(line)
        if m:
            return {"name": m["name"], "sha": m["sha"], "iteration": int(m["it"]), "line": i}
    return None


def stamp_text(text: str, dialect: str, *, name: str, sha256: str, iteration: int) -> str:
    """Add the provenance comment to a program without moving any line.

    G-code: ``(ilcnc: learned from NAME sha256:… iteration N)`` at the end of
    the first line that is not ``%``; Klartext: ``; ilcnc: …`` at the end of
    the ``BEGIN PGM`` line. Line numbers stay the same, so logs and reports
    of the stamped program still match the original's lines.
    """
    note = f"ilcnc: learned from {name.replace(' ', '_')} sha256:{sha256[:16]} iteration {iteration}"
    return comment_first_line(text, note, klartext=dialect == "heidenhain")


def unstamp_text(text: str) -> str:
    """The program text without the provenance stamp :func:`stamp_text` added (unchanged if it has none)."""
    st = find_stamp(text)
    if st is None:
        return text
    lines = text.split("\n")
    i = st["line"] - 1
    m = _STAMP.search(lines[i])
    assert m is not None
    note = m.group(0)
    for added in (f" ({note})", f" ; {note}", f" {note}"):
        if added in lines[i]:
            lines[i] = lines[i].replace(added, "", 1)
            break
    return "\n".join(lines)


@dataclass(slots=True)
class LearnRequest:
    """What ``ilcnc learn`` was asked to do (paths as given)."""

    program: Path
    profile: Path
    out: Path
    iterations: int | None = None
    log: Path | None = None
    points: Path | None = None
    state: Path | None = None
    report: Path | None = None
    stamp: bool = False
    log_format: str = "auto"
    log_units: str = "mm"
    log_period_s: float | None = None
    points_reach_mm: float | None = None
    log_columns: str | None = None
    log_offset: tuple[float, float, float] | None = None
    force: bool = False
    cutting_below_z_mm: float | None = None
    refine: bool = False
    relearn: bool = False
    new_profile: bool = False


@dataclass(slots=True, kw_only=True)
class LearnOutcome:
    """The result of one ``ilcnc learn`` call (printed, or ``--json``)."""

    mode: LearnMode
    program: Path
    output: Path | None
    state_dir: Path
    iterations: list[dict[str, Any]]
    status: LearnStatus
    message: str
    clips: list[Clip] = field(default_factory=list)
    frozen: int = 0
    frozen_reasons: dict[str, int] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    report_files: list[Path] = field(default_factory=list)
    reduction_rms: float = 0.0
    air_commands: int = 0
    cutting_rule: str = ""
    cutting: dict[str, Any] | None = None
    refined: dict[str, Any] | None = None
    feed: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "program": str(self.program),
            "output": str(self.output) if self.output is not None else None,
            "mode": self.mode,
            "state": str(self.state_dir),
            "iterations": self.iterations,
            "status": self.status,
            "message": self.message,
            "clipped": [{"k": c.k, "line": c.line, "axis": c.axis, "wanted_mm": c.wanted_mm, "applied_mm": c.applied_mm,
                         "cause": c.cause} for c in self.clips],
            "frozen_commands": self.frozen,
            "frozen_reasons": self.frozen_reasons,
            "air_commands": self.air_commands,
            "cutting_rule": self.cutting,
            "refined": self.refined,
            "feed": self.feed,
            "notes": self.notes,
        }


# ---------------------------------------------------------------------------------------------


def _out_suffix_matches(program: Program, out: Path) -> None:
    from ilcnc.errors import InputError
    from ilcnc.program import GCODE_SUFFIXES, HEIDENHAIN_SUFFIXES

    suf = out.suffix.lower()
    klartext = program.dialect == "heidenhain"
    if (suf in HEIDENHAIN_SUFFIXES and not klartext) or (suf in GCODE_SUFFIXES and klartext):
        raise InputError(out, None, f"--out {out.name} is a {'Klartext' if suf in HEIDENHAIN_SUFFIXES else 'G-code'} file"
                         f" but {program.path.name} is {'Klartext' if klartext else 'G-code'}: learn in the program's"
                         " own dialect, then convert with ilcnc export")
    if suf not in GCODE_SUFFIXES + HEIDENHAIN_SUFFIXES:
        raise InputError(out, None, f"unknown program suffix {out.suffix!r} for --out")


def _default_state_dir(out: Path) -> Path:
    return out.with_name(out.name + ".state")


#: The files a learning state holds (``state.json`` aside), and the atomic writer's temporary files.
_STATE_FILE_NAME = re.compile(r"(original|refined|iter-\d{3,})\.[\w.]+|\..+\.tmp")


def _new_state(directory: Path, program: Program, data: bytes, profile: MachineProfile, profile_sha: str, *,
               refined: bool = False) -> LearnState:
    if directory.exists() and not directory.is_dir():
        raise StateError(directory, None, "exists and is not a directory")
    if not directory.parent.is_dir():
        raise StateError(directory, None, f"parent directory {directory.parent} does not exist")
    directory.mkdir(exist_ok=True)
    left = list(directory.iterdir())
    if left and all(_STATE_FILE_NAME.fullmatch(p.name) and p.is_file() for p in left):
        # what a run killed before its first state.json left (issue 25 item 11): its own files, and no index that
        # names them; no other run uses them (the state is locked), so the new run replaces them
        for p in left:
            p.unlink()
    elif left:
        raise StateError(directory, None, "is not empty and holds no learning state: choose a new --state directory")
    suffix = program.path.suffix or ".nc"
    st = LearnState(directory, {"name": program.path.name, "sha256": sha256_bytes(data), "file": f"original{suffix}",
                                "dialect": program.dialect, "units": program.units, "commands": program.n_commands,
                                "suffix": suffix},
                    profile.learning.law, error_kind(profile, refined=refined), profile_sha)
    st.write_file(st.part["file"], data)
    return st


def _resolve_part(req: LearnRequest, data: bytes, state: LearnState | None) -> tuple[str, IterationEntry | None]:
    """How PROG relates to the state: ``original``, ``output`` (with its entry) or ``new``; refuse mismatches."""
    sha = sha256_bytes(data)
    text = data.decode("latin-1")
    stamp = find_stamp(text)
    if state is not None:
        if sha == state.part["sha256"]:
            return "original", None
        # an output is recognised by its hash, with or without the stamp it was written with
        for h in (sha, sha256_bytes(unstamp_text(text).encode("latin-1"))):
            entry = state.find_program(h)
            if entry is not None:
                return "output", entry
        raise StateError(req.state, None, f"this learning state belongs to {state.part['name']} (sha256"
                         f" {state.part['sha256'][:16]}), not to {req.program.name}: use the state of this part or a new"
                         " --state directory")
    if req.relearn:
        return "new", None
    if stamp is not None:
        raise StateError(req.program, stamp["line"], f"is iteration {stamp['iteration']} of an ilcnc learning run on"
                         f" {stamp['name']} (provenance stamp): correcting it again would correct twice; learn the"
                         " original program, continue that run with its --state directory, or --relearn")
    # an unstamped output: recognised by its hash in the state a run keeps beside it (OUT.state)
    sibling = _default_state_dir(req.program)
    if LearnState.exists(sibling):
        try:
            earlier = LearnState.load(sibling)
        except StateError:
            return "new", None  # a damaged state beside it is not this program's record
        for h in (sha, sha256_bytes(unstamp_text(text).encode("latin-1"))):
            entry = earlier.find_program(h)
            if entry is not None and entry.iteration > 0:
                raise StateError(req.program, None, f"is iteration {entry.iteration} of the learning run in {sibling}"
                                 f" on {earlier.part['name']}: learning it again would correct it twice; learn"
                                 f" {earlier.part['name']}, continue that run with --state {sibling}, or --relearn")
    return "new", None


def _write_output(req: LearnRequest, text: str, program: Program, part_sha: str, iteration: int) -> Path:
    if req.stamp:
        text = stamp_text(text, program.dialect, name=program.path.name, sha256=part_sha, iteration=iteration)
    protect: tuple[Path, ...] = (req.program, req.profile, *(p for p in (req.log, req.points) if p is not None))
    return write_atomic(req.out, text.encode("latin-1"), protect=protect)


def _entry_json(e: IterationEntry) -> dict[str, Any]:
    out = {"iteration": e.iteration, "contour_error_mm": e.stats, "clipped": e.clipped, "kept": e.kept,
           "gain_scale": e.gain_scale, "program": e.program, "measured_from": (e.measured_from or {}).get("kind")}
    shares = (e.measured_from or {}).get("error_shares_mm")
    if shares:
        out["error_shares_mm"] = shares
    for key in ("air_error_mm", "cycle_time_s", "log_motion_s"):
        value = (e.measured_from or {}).get(key)
        if value is not None:
            out[key] = value
    return out


# ---------------------------------------------------------------------------------------------
# virtual learning
# ---------------------------------------------------------------------------------------------


def _record_writer(state: LearnState, program: Program, *, profile_sha: str, first: int,
                   rerun_of: int | None) -> Callable[[IterationRecord], None]:
    """Write each iteration of a virtual run into the state as a new entry (``first``: a continued run's re-run of
    its best iteration ``rerun_of``)."""
    suffix = state.part.get("suffix", ".nc")

    def write(rec: IterationRecord) -> None:
        it = rec.iteration
        if any(e.iteration == it for e in state.iterations):
            raise StateError(state.path, None, f"iteration {it} is recorded already: the learning state is damaged")
        name = f"iter-{it:03d}{suffix}"
        raw = rec.text.encode("latin-1")
        sha = state.write_file(name, raw)
        entry = IterationEntry(it, name, sha, state.write_corrections(it, rec.corrections_mm),
                               profile_sha256=state.profile_record(profile_sha))
        state.iterations.append(entry)
        sig = rec.signal
        if sig is not None:
            entry.errors = state.write_errors(it, sig.e_mm, sig.t_s, sig.valid)
        entry.stats = dict(rec.stats)
        entry.kept = rec.kept
        entry.gain_scale = rec.gain_scale
        entry.clipped = len(rec.clipped)
        entry.measured_from = {"kind": "virtual", "path": None, "sha256": None}
        if it == first and rerun_of is not None:
            entry.measured_from["rerun_of"] = rerun_of  # the program of that iteration, measured again
        if rec.shares:
            entry.measured_from["error_shares_mm"] = rec.shares
        if rec.air_stats is not None:
            entry.measured_from["air_error_mm"] = rec.air_stats.to_json()
        if rec.cycle_time_s is not None:
            entry.measured_from["cycle_time_s"] = rec.cycle_time_s
        state.gain_scale = min(state.gain_scale, rec.gain_scale)
        state.save()

    return write


def _virtual(req: LearnRequest, profile: MachineProfile, profile_sha: str, data: bytes, state: LearnState | None,
             relation: str, progress: Callable[[int, int, str], None] | None) -> LearnOutcome:
    state_dir = req.state or _default_state_dir(req.out)
    if state is None and LearnState.exists(state_dir):
        if not req.force:
            raise StateError(state_dir, None, f"already holds a learning run: continue it with --state {state_dir},"
                             " replace it with --force, or choose another --out / --state")
        with _replacing(state_dir, req, data):
            return _virtual_run(req, profile, profile_sha, data, None, relation, progress, state_dir)
    return _virtual_run(req, profile, profile_sha, data, state, relation, progress, state_dir)


@contextlib.contextmanager
def _replacing(state_dir: Path, req: LearnRequest, data: bytes) -> Iterator[None]:
    """``--force``: set the earlier run's state aside, drop it once the new run is written, restore it on failure
    (``data``: the bytes of ``req.program``)."""
    for p in (req.program, req.profile):
        if inside(p, state_dir):
            raise StateError(p, None, f"is inside the state {state_dir} that --force would replace: copy it out first")
    try:
        earlier = LearnState.load(state_dir)
    except StateError:
        earlier = None  # a damaged state is replaced like any other
    if earlier is not None:
        text = data.decode("latin-1")
        for h in (sha256_bytes(data), sha256_bytes(unstamp_text(text).encode("latin-1"))):
            if h != earlier.part["sha256"] and earlier.find_program(h) is not None:
                raise StateError(req.program, None, f"is an output of the run in {state_dir}: --force would correct it"
                                 " twice; learn the original program")
    aside = state_dir.with_name(f".{state_dir.name}.replaced-{os.getpid()}")
    os.replace(state_dir, aside)
    try:
        yield
    except BaseException:
        shutil.rmtree(state_dir, ignore_errors=True)
        os.replace(aside, state_dir)
        raise
    shutil.rmtree(aside, ignore_errors=True)


def _virtual_run(req: LearnRequest, profile: MachineProfile, profile_sha: str, data: bytes, state: LearnState | None,
                 relation: str, progress: Callable[[int, int, str], None] | None, state_dir: Path) -> LearnOutcome:
    notes: list[str] = []
    refine = req.refine or profile.learning.refine.enabled == "on"
    if state is not None:
        where = req.program if relation == "original" else state.file(state.part["file"])
        original = read_program(where, default_units=profile.machine.units, data=state.read_original_bytes())
        if req.refine and not state.part.get("refined"):
            raise StateError(state.directory, None, "holds a run without refinement: --refine refines at the start of"
                             " a run (the refined program is its learning index); start a new run with --force")
        _out_suffix_matches(original, req.out)
        best = state.best()
        u0 = state.read_corrections(best) if best is not None else None
        # a continued run re-measures its best program as a new iteration: no record is ever written over
        first = state.iterations[-1].iteration + 1 if state.iterations else 0
        rerun_of = best.iteration if best is not None else None
    else:
        original = read_program(req.program, default_units=profile.machine.units, data=data)
        _out_suffix_matches(original, req.out)  # before refining: a refusal costs no run
        require_learnable(original)  # before the state: a refusal leaves nothing behind
        refinement = refine_for_learning(original, profile) if refine else None  # before the state: a refusal makes none
        state = _new_state(state_dir, original, data, profile, profile_sha,
                           refined=refinement is not None and refinement.changed)
        if refinement is not None:
            _store_refinement(state, refinement)
            notes.extend(refinement.notes())
        u0, first, rerun_of = None, 0, None
    # what the reader read but does not model (rotary words, dwells, cycles, ...): in sight, not only in inspect
    notes[:0] = [f"reader: {w}" for w in original.warnings[:5]]
    learning = _learning_program(state, original, profile)
    writer = _record_writer(state, learning, profile_sha=profile_sha, first=first, rerun_of=rerun_of)
    f0 = None
    if profile.learning.refine.feed == "on" and u0 is not None:
        f0 = _stored_feed_scale(state, learning)
    result = learn_virtual(learning, profile, iterations=req.iterations, keep_runs=req.report is not None,
                           initial_corrections_mm=u0, first_iteration=first, progress=progress, on_record=writer,
                           error=state.error, initial_feed_scale=f0,
                           cycle_spent_s=float(((state.part.get("refined") or {}).get("tolerance") or {}).get("spent_s", 0.0)))
    if result.feed is not None:
        notes.extend(result.feed.notes())
    best_rec = result.best_record
    for e in state.iterations:
        if e.iteration == best_rec.iteration:
            e.output = str(req.out)
    state.status = result.status
    state.save()  # the state names the output before it exists: a kill between leaves no output it does not list
    out = _write_output(req, best_rec.text, original, state.part["sha256"], best_rec.iteration)
    rule = result.cutting
    outcome = LearnOutcome(mode=LearnMode.VIRTUAL, program=req.program, output=out, state_dir=state.directory,
                           iterations=[r.to_json() for r in result.iterations], status=result.status,
                           message=result.message, clips=result.clips, frozen=result.frozen, notes=notes,
                           reduction_rms=result.reduction("rms"), air_commands=result.air_commands,
                           cutting_rule="" if rule is None else rule.describe(),
                           cutting=None if rule is None else rule.to_json(), refined=state.part.get("refined"))
    outcome.feed = None if result.feed is None else result.feed.to_json()
    outcome.frozen_reasons = dict(result.frozen_reasons)
    if req.report is not None:
        outcome.report_files = _report_virtual(req, learning, result, best_rec)
    return outcome


def _stored_feed_scale(state: LearnState, learning: Program) -> NDArray[np.float64]:
    """The feed factor of every move of the state's best program (``learning.refine.feed``: the feeds it wrote),
    against the learning program's; 1 where a move runs as programmed."""
    best = state.best()
    assert best is not None
    prog = read_program(learning.path, default_units=learning.units, data=state.read_program_bytes(best))
    a, b = learning.moves.feed_mm_min, prog.moves.feed_mm_min
    if a.shape != b.shape:
        raise StateError(state.file(best.program), None, "damaged state file: its moves are not the learning"
                         " program's")
    ok = np.isfinite(a) & np.isfinite(b) & (a > 0)
    return np.where(ok & (b < a), b / np.where(ok, a, 1.0), 1.0)


def _refine_from_log(req: LearnRequest, profile: MachineProfile, original: Program
                     ) -> tuple[Any, Any, NDArray[np.int64]]:
    """The first measured step of a refined run: refine where the log of the original program erred (no extra
    machine run), that log read as a run of the refined program, and the refined commands whose samples lie in a
    settle's window (:func:`ilcnc.shop.measure.settle_windows`: the first step does not learn from them)."""
    from ilcnc.axislog.detect import read_log
    from ilcnc.shop.measure import check_log_memory, log_on_refined, measure_log, settle_windows

    assert req.log is not None
    period = req.log_period_s if req.log_period_s is not None else profile.machine.servo_period_s
    check_log_memory(req.log)
    log = read_log(req.log, fmt=req.log_format, period_s=period, units=req.log_units, columns=req.log_columns,
                   offset=req.log_offset)
    meas = measure_log(log, original, original, profile, error_kind(profile), source=req.log, units=req.log_units)
    assert meas.seg is not None and meas.u is not None and meas.contour_mm is not None and meas.feed_mask is not None
    dist = np.where(meas.feed_mask, meas.contour_mm, np.nan)
    refinement = refine_from_errors(original, profile, dist_mm=dist, seg=meas.seg, u=meas.u, first_stats=meas.stats)
    if not refinement.changed:
        return refinement, log, np.zeros(0, dtype=np.int64)
    on_refined = log_on_refined(log, original, refinement.program, refinement.inserted)
    k = on_refined.k[settle_windows(log, original, refinement.inserted.settled)]
    return refinement, on_refined, np.unique(k[k >= 0]).astype(np.int64)


def _store_refinement(state: LearnState, refinement: Any) -> None:
    """Keep the refined program in the state: it is the learning index of every iteration of the run."""
    if not refinement.changed:
        state.part["refined"] = {"file": None, **refinement.to_json()}
        return
    name = f"refined{state.part['suffix']}"
    sha = state.write_file(name, refinement.program.text.encode("latin-1"))
    state.part["refined"] = {"file": name, "sha256": sha, "commands": refinement.program.n_commands,
                             **refinement.to_json()}


def _learning_program(state: LearnState, original: Program, profile: MachineProfile) -> Program:
    """The program whose commands the run learns: the refined one when the run was refined, else the original."""
    ref = state.part.get("refined")
    if not ref or not ref.get("file"):
        return original
    data = read_bytes(state.file(ref["file"]))
    if sha256_bytes(data) != ref["sha256"]:
        raise StateError(state.file(ref["file"]), None, "changed since ilcnc wrote it (hash mismatch): the learning"
                         " state is damaged")
    return read_program(original.path, default_units=original.units, data=data)


def _report_virtual(req: LearnRequest, original: Program, result: Any, best_rec: IterationRecord) -> list[Path]:
    from ilcnc.shop.report import ReportRun, write_report

    runs = []
    for r in result.iterations:
        sim = r.run
        runs.append(ReportRun(iteration=r.iteration, kept=r.kept, stats_mm=dict(r.stats), clipped=len(r.clipped),
                              gain_scale=r.gain_scale, actual_mm=None if sim is None else sim.actual_mm,
                              contour_mm=None if sim is None else sim.error.dist_mm,
                              signed_mm=None if sim is None else sim.error.signed_mm,
                              path_pos_mm=None if sim is None else path_position_mm(sim.error),
                              feed_mask=None if sim is None else sim.feed_mask,
                              foot_mm=None if sim is None else sim.error.foot_mm))
    clipped = np.zeros(original.n_commands, bool)
    for c in result.clips:
        clipped[c.k] = True
    files = write_report(req.report, program_name=original.path.name, path_mm=_path_polyline(original), runs=runs,
                         diff=_diff(original, best_rec.text, clipped), status=result.status, message=result.message,
                         best_iteration=best_rec.iteration)
    from ilcnc.program.insert import inserted_moves

    ins = inserted_moves(original)[original.command_moves]
    best_run = next((r for r in runs if r.iteration == best_rec.iteration), None)
    if ins.any() and best_run is not None and runs[0].actual_mm is not None:
        from ilcnc.shop.report import plot_refined_corner

        out_prog = read_program(original.path, default_units=original.units, data=best_rec.text.encode("latin-1"))
        png = plot_refined_corner(program_name=original.path.name, path_mm=_path_polyline(original), first=runs[0],
                                  best=best_run, commands_mm=out_prog.command_end_mm, inserted=ins)
        files.append(write_atomic(req.report / "refined-corner.png", png))
    return files


def _path_polyline(program: Program) -> NDArray[np.float64]:
    """The programmed feed path as a polyline (arcs sampled), NaN rows where a rapid breaks it."""
    from ilcnc.contour.path import PathGeometry

    path = PathGeometry.from_moves(program.moves)
    pts: list[NDArray[np.float64]] = []
    last_end: NDArray[np.float64] | None = None
    for i in np.flatnonzero(path.active):
        n = 1 if program.moves.kind[i] == 1 else 16
        fr = np.linspace(0.0, 1.0, n + 1)
        seg_pts = path.point_at(np.full(fr.size, i), fr)
        if last_end is None or not np.allclose(seg_pts[0], last_end):
            if pts:
                pts.append(np.full((1, 3), np.nan))
            pts.append(seg_pts)
        else:
            pts.append(seg_pts[1:])
        last_end = seg_pts[-1]
    return np.vstack(pts) if pts else np.zeros((0, 3))


def _diff(original: Program, text: str, clipped: NDArray[np.bool_]) -> Any:
    from ilcnc.shop.report import CommandDiff

    new = read_program(original.path, default_units=original.units, data=text.encode("latin-1"))
    k = np.arange(original.n_commands)
    return CommandDiff(k=k, line=original.command_line.astype(np.int64), old_mm=original.command_end_mm,
                       new_mm=new.command_end_mm, clipped=clipped)


# ---------------------------------------------------------------------------------------------
# one step from a measurement
# ---------------------------------------------------------------------------------------------


def _measured(req: LearnRequest, profile: MachineProfile, profile_sha: str, data: bytes, state: LearnState | None,
              relation: str, entry_of_prog: IterationEntry | None) -> LearnOutcome:
    made: list[Path] = []  # the state directory made by this call (until its first measurement is accepted)
    try:
        return _measured_step(req, profile, profile_sha, data, state, relation, entry_of_prog, made)
    except BaseException:
        # a refused first measurement leaves no half-made state behind (a retry would find it "not empty")
        for d in made:
            if d.is_dir() and not (d / "state.json").exists():
                shutil.rmtree(d)  # made empty by this call (_new_state refuses a non-empty directory)
        raise


def _measured_step(req: LearnRequest, profile: MachineProfile, profile_sha: str, data: bytes, state: LearnState | None,
                   relation: str, entry_of_prog: IterationEntry | None, made: list[Path]) -> LearnOutcome:
    from ilcnc.axislog.detect import read_log
    from ilcnc.axislog.points import read_points
    from ilcnc.shop.log_identity import samples_fingerprint
    from ilcnc.shop.measure import check_log_memory, measure_log, measure_points

    if req.state is None:
        raise UsageError("--log/--points", "make one learning step per run on the machine: give --state DIR to keep the"
                         " learning state between runs")
    source = req.log if req.log is not None else req.points
    assert source is not None
    src_bytes = read_bytes(source)
    src_sha = sha256_bytes(src_bytes)
    refined_log = None
    settled_k = np.zeros(0, dtype=np.int64)
    if state is None:
        original = read_program(req.program, default_units=profile.machine.units, data=data)
        _out_suffix_matches(original, req.out)
        refinement = None
        if req.refine or (profile.learning.refine.enabled == "on" and req.log is not None):
            refinement, refined_log, settled_k = _refine_from_log(req, profile, original)  # refused before any state is made
        state = _new_state(req.state, original, data, profile, profile_sha,
                           refined=refinement is not None and refinement.changed)
        made.append(req.state)
        first_data = data
        if refinement is not None:
            _store_refinement(state, refinement)
            if refinement.changed:
                first_data = refinement.program.text.encode("latin-1")  # the refined program runs what ran
        name = f"iter-000{state.part['suffix']}"
        sha = state.write_file(name, first_data)
        original = _learning_program(state, original, profile)  # the refined program when refined
        state.iterations.append(IterationEntry(0, name, sha, state.write_corrections(0, np.zeros((original.n_commands,
                                                                                                  3)))))
    else:
        original = read_program(req.program if relation == "original" else state.file(state.part["file"]),
                                default_units=profile.machine.units, data=state.read_original_bytes())
        _out_suffix_matches(original, req.out)
        # a refined run (refined on the virtual CNC) learns its refined commands on the machine too: its
        # programs are judged against the refined program, which runs the original's path
        original = _learning_program(state, original, profile)
        if state.status == LearnStatus.DIVERGED:
            best = state.best()
            raise StateError(state.path, None, "this learning run stopped because the error grew twice: keep running"
                             f" {best.program if best else 'the original'} (no further step)")
    used = state.used_measurement(src_sha)
    if used is not None:
        rewritten = _rewrite_interrupted_output(req, state, used, original)
        if rewritten is not None:
            return rewritten
        raise LogError(source, None, f"this measurement was already used for iteration {used.iteration}: record a new"
                       " run of the latest program")
    entry = state.pending()
    if entry is None:
        raise StateError(state.path, None, "no program is waiting for a measurement (the run has ended with status"
                         f" {state.status})")
    if req.refine and refined_log is None:
        raise StateError(state.directory, None, "--refine refines at the start of a run (from the log of the original"
                         " program); this state holds a run already")
    if relation == "output" and entry_of_prog is not None and entry_of_prog is not entry:
        raise StateError(req.program, None, f"is the program of iteration {entry_of_prog.iteration}, but the state waits"
                         f" for a measurement of iteration {entry.iteration} ({entry.program}): run that one")
    ran = read_program(state.file(entry.program), default_units=profile.machine.units, data=state.read_program_bytes(entry))
    kind = state.error
    log_fp: str | None = None  # the log's samples' fingerprint (a log used once is known again in other text)
    if req.log is not None:
        period = req.log_period_s if req.log_period_s is not None else profile.machine.servo_period_s
        if refined_log is None:
            check_log_memory(req.log)
        log = refined_log if refined_log is not None else read_log(
            req.log, fmt=req.log_format, period_s=period, units=req.log_units, columns=req.log_columns,
            offset=req.log_offset)
        log_fp = samples_fingerprint(log) if refined_log is None else None
        again = state.used_measurement(src_sha, samples_sha=log_fp)
        if again is not None and again.measured_from:  # the same samples in other text (a comment, other numbers)
            raise LogError(source, None, f"this log holds the samples of the log of iteration {again.iteration}"
                           f" ({Path(str(again.measured_from.get('path'))).name}), only written differently: record a"
                           " new run of the latest program")
        # the programs a log of the wrong run would most likely be of: the original and the last three before
        earlier_runs = [e for e in state.iterations if e is not entry and e.program_sha256 != entry.program_sha256]
        earlier = [(f"the program of iteration {e.iteration} ({e.program})",
                    read_program(state.file(e.program), default_units=profile.machine.units,
                                 data=state.read_program_bytes(e)))
                   for e in earlier_runs if e.iteration == 0 or e in earlier_runs[-3:]]
        try:
            meas = measure_log(log, ran, original, profile, kind, source=req.log, units=req.log_units,
                               earlier=earlier)
        except MemoryError:  # the estimate of check_log_memory fell short: still one line, the state untouched
            raise LogError(req.log, None, f"ran out of memory measuring this log ({log.n_samples:,} samples): record a"
                           " shorter run, or keep every n-th sample") from None
    else:
        assert req.points is not None
        meas = measure_points(read_points(req.points), original, profile, source=req.points,
                              reach_mm=req.points_reach_mm)
    if settled_k.size:  # the log holds the rapid's lag there, which the settles remove: no update from it
        meas.signal.e_mm[settled_k] = 0.0
        meas.notes.append(f"settle: the first step learns nothing at {plural(int(settled_k.size), 'command')} right"
                          " after the settles (the log of the original holds the rapid's lag there, which they"
                          " remove; the next measured run shows what is left)")
    # the measurement of this iteration (written before the index that names it)
    entry.errors = state.write_errors(entry.iteration, meas.signal.e_mm, meas.signal.t_s, meas.signal.valid)
    entry.stats = meas.stats.to_json()
    entry.measured_from = {"kind": meas.kind, "path": str(source), "sha256": src_sha}
    entry.profile_sha256 = state.profile_record(profile_sha)  # measured under this profile (--new-profile: another)
    if log_fp is not None:
        entry.measured_from["samples_sha256"] = log_fp
    if meas.air_stats is not None:
        entry.measured_from["air_error_mm"] = meas.air_stats.to_json()
    # learning.cycle_budget_pct: the program that ran and the original, planned on the profile's planner model
    budget = cycle_budget(original, profile)
    entry.measured_from["cycle_time_s"] = cycle_ran = budget.planned_s(ran)
    motion = motion_time_s(log.t_s, log.ref_mm) if req.log is not None else None
    if motion is not None:
        entry.measured_from["log_motion_s"] = motion
    best = state.best()
    # the guard of the run (halved = the gain was halved at an earlier refusal: state.gain_scale < 1)
    guard = LearningGuard(resolution_mm=profile.machine.resolution_mm, gain_scale=state.gain_scale,
                          halved=state.gain_scale < 1.0)
    worse, ref_stats = guard.compare(meas.stats, [e.stats for e in state.kept(profile_sha256=profile_sha)
                                                  if e.stats is not None and e is not entry])
    if ref_stats is not None and cycle_ran > budget.limit_s():
        worse.append("cycle")  # held back as far as the limiter goes, still over the budget (as virtual learning)
    entry.kept = not worse
    notes = list(meas.notes)
    if motion is not None:  # the planned cycle time next to the one the log measured (points measure no time)
        notes.append("cycle time: " + budget.note(f"iteration {entry.iteration}", cycle_ran, motion))
    if profile.learning.refine.feed == "on":
        notes.append("feed: learning.refine.feed lowers feeds on the virtual CNC only (learn without --log); this"
                     " measured step changes coordinates alone")
    if refined_log is not None and state.part.get("refined"):
        rf = state.part["refined"]
        settles = (f", {plural(rf['settles'], 'settle')} ({rf['settle_s']:.3f} s) before feeds after rapids"
                   if rf.get("settles") else "")
        notes.insert(0, f"refined from the log of the original program: {rf['inserted_lines']}"
                        f" lines inserted{settles} (docs/learning.md, Refinement)")
    status, message = LearnStatus.STEPPED, ""
    out: Path | None = None
    clips: list[Clip] = []
    n_iter = req.iterations if req.iterations is not None else profile.learning.iterations
    if worse:
        assert ref_stats is not None
        what = " and ".join(budget.over_message(cycle_ran) if w == "cycle" else guard.grown(w, ref_stats, meas.stats)
                            for w in worse)
        match guard.refuse():
            case GuardVerdict.STOPPED:
                state.status = LearnStatus.DIVERGED
                state.save()
                message = (guard.stopped_message(entry.iteration, what) + ": learning stopped; keep running"
                           f" {best.program}, the best program")  # type: ignore[union-attr]
                return _measured_outcome(req, state, LearnStatus.DIVERGED, message, None, [], notes)
            case GuardVerdict.HALVED:
                state.gain_scale = guard.gain_scale
        notes.append(f"iteration {entry.iteration} made the error worse ({what}): not kept; the next program starts from"
                     f" iteration {best.iteration} with the gain halved")  # type: ignore[union-attr]
    stats_now = state.best().stats  # type: ignore[union-attr]
    if stats_now["max"] <= profile.learning.stop_tolerance_mm:
        state.status = LearnStatus.CONVERGED
        state.save()
        message = (f"max error {stats_now['max'] * 1e3:.3f} µm is within the stop tolerance: keep running"
                   f" {state.best().program}")  # type: ignore[union-attr]
        return _measured_outcome(req, state, LearnStatus.CONVERGED, message, None, [], notes)
    if entry.iteration >= n_iter:
        state.status = LearnStatus.MAX_ITERATIONS
        state.save()
        message = f"{plural(entry.iteration, 'iteration')} made (the limit): keep running {state.best().program}"  # type: ignore[union-attr]
        return _measured_outcome(req, state, LearnStatus.MAX_ITERATIONS, message, None, [], notes)
    learner = Learner.for_program(original, profile)
    best = state.best()
    assert best is not None
    kept = [e for e in state.kept() if e.iteration <= best.iteration][-learner.law.memory:]  # the step starts at the best
    u_hist = [state.read_corrections(e) for e in kept]
    s_hist = []
    for e in kept:
        ee, tt, vv = state.read_errors(e)
        s_hist.append(CommandSignal(ee, tt, vv, kind))
    u_new, clips = learner.propose(u_hist, s_hist, scale=state.gain_scale)
    steps = profile.learning.model_steps
    if steps and meas.kind != "log":
        notes.append("no model-assisted step: probed points measure end points, not the path error the virtual CNC"
                     " predicts")
    elif steps:
        # the history holds the state's error estimate (a log measures it; points do not: above)
        u_new, clips, ms = model_assisted_correction(learner, u_hist[-1], s_hist[-1], u_new, clips, steps,
                                                     scale=state.gain_scale)
        why = ms.why(profile.learning.law, state.error)
        notes.append(f"model-assisted step: {ms.made} of {steps} virtual-CNC steps kept{why}; RMS |E(k)| measured"
                     f" {ms.predicted_rms_mm[0] * 1e3:.2f} µm, predicted "
                     + " → ".join(f"{r * 1e3:.2f}" for r in ms.predicted_rms_mm[1:]) + " µm")
    nxt = entry.iteration + 1
    u_new, held, held_all, hold = hold_step(budget, u_hist[-1], u_new)  # the cycle-time budget, as virtual learning
    clips = clips + held
    if held_all is not None:
        state.status = LearnStatus.STOPPED
        state.save()
        message = f"{held_all}: learning stopped; keep running {best.program}, the best program"
        return _measured_outcome(req, state, LearnStatus.STOPPED, message, None, clips, notes)
    if held or not hold.within:
        notes.append(f"cycle-time budget: {plural(len(held), 'coordinate')} held back (clip 'cycle time'); "
                     + budget.note(f"iteration {nxt}", hold.cycle_time_s)
                     + ("" if hold.within else ": still over the budget, the guard will refuse its run (no correction"
                        " left near a move the planner slowed)"))
    text, _prog = program_with_corrections(original, u_new, profile)
    name = f"iter-{nxt:03d}{state.part['suffix']}"
    sha = state.write_file(name, text.encode("latin-1"))
    new_entry = IterationEntry(nxt, name, sha, state.write_corrections(nxt, u_new), gain_scale=state.gain_scale,
                               clipped=len(clips), output=str(req.out),
                               profile_sha256=state.profile_record(profile_sha))
    state.iterations.append(new_entry)
    state.save()  # the state names the output before it exists: a kill between leaves no output it does not list
    out = _write_output(req, text, original, state.part["sha256"], nxt)
    message = (f"iteration {entry.iteration} measured ({meas.kind}): max {meas.stats['max'] * 1e3:.2f} µm, RMS"
               f" {meas.stats['rms'] * 1e3:.2f} µm; wrote iteration {nxt}: run {req.out.name} on the machine and"
               " measure it next")
    oc = _measured_outcome(req, state, status, message, out, clips, notes, meas)
    # the commands this step left as programmed, counted as the virtual learning counts them (air moves apart)
    air = learner.air_kept if learner.air_kept is not None else np.zeros(original.n_commands, bool)
    oc.frozen = int(np.count_nonzero(~learner.shaper.correctable & ~air))
    oc.frozen_reasons = dict(frozen_reasons(original, air))
    return oc


def _rewrite_interrupted_output(req: LearnRequest, state: LearnState, used: IterationEntry,
                                original: Program) -> LearnOutcome | None:
    """The step made from this measurement was interrupted after the state named its output, before the output was
    written (a kill, a full disk): write it now. None when there is nothing to resume (the output is there)."""
    nxt = state.pending()
    if nxt is None or nxt.iteration != used.iteration + 1 or nxt.output is None or not same_file(nxt.output, req.out):
        return None
    text = state.read_program_bytes(nxt).decode("latin-1")
    want = text if not req.stamp else stamp_text(text, original.dialect, name=original.path.name,
                                                 sha256=state.part["sha256"], iteration=nxt.iteration)
    if req.out.is_file() and read_bytes(req.out) == want.encode("latin-1"):
        return None  # written already: the measurement is simply given again
    out = _write_output(req, text, original, state.part["sha256"], nxt.iteration)
    message = (f"iteration {used.iteration} was measured from this log before, and iteration {nxt.iteration} made, but"
               f" its output was not written (the run was interrupted): wrote it now; run {req.out.name} on the machine"
               " and measure it next")
    return _measured_outcome(req, state, LearnStatus.STEPPED, message, out, [], [])


def _measured_outcome(req: LearnRequest, state: LearnState, status: str, message: str, out: Path | None,
                      clips: list[Clip], notes: list[str], meas: Any = None) -> LearnOutcome:
    its = [_entry_json(e) for e in state.iterations]
    first = state.iterations[0].stats if state.iterations else None
    best = state.best()
    red = 0.0
    if first and best is not None and best.stats and first["rms"] > 0:
        red = 1.0 - best.stats["rms"] / first["rms"]
    mode = LearnMode.LOG if req.log is not None else LearnMode.POINTS
    oc = LearnOutcome(mode=mode, program=req.program, output=out, state_dir=state.directory, iterations=its,
                      status=status, message=message, clips=clips, frozen=0, notes=notes, reduction_rms=red,
                      refined=state.part.get("refined"))
    if req.report is not None:
        oc.report_files = _report_measured(req, state, meas, clips)
    return oc


def _report_measured(req: LearnRequest, state: LearnState, meas: Any, clips: list[Clip]) -> list[Path]:
    from ilcnc.shop.report import ReportRun, write_report

    original = read_program(state.file(state.part["file"]), data=state.read_original_bytes())
    runs = []
    for e in state.iterations:
        if e.stats is None:
            continue
        this = meas is not None and e is [x for x in state.iterations if x.stats is not None][-1]
        runs.append(ReportRun(iteration=e.iteration, kept=bool(e.kept), stats_mm=dict(e.stats), clipped=e.clipped,
                              gain_scale=e.gain_scale, actual_mm=meas.actual_mm if this else None,
                              contour_mm=meas.contour_mm if this else None, signed_mm=meas.signed_mm if this else None,
                              path_pos_mm=meas.path_pos_mm if this else None, feed_mask=meas.feed_mask if this else None,
                              foot_mm=meas.foot_mm if this else None))
    last = state.iterations[-1]
    text = state.read_program_bytes(last).decode("latin-1")
    clipped = np.zeros(original.n_commands, bool)
    for c in clips:
        clipped[c.k] = True
    return write_report(req.report, program_name=original.path.name, path_mm=_path_polyline(original), runs=runs,
                        diff=_diff(original, text, clipped), status=state.status)  # best: the lowest measured kept


# ---------------------------------------------------------------------------------------------


def _check_output_paths(req: LearnRequest) -> None:
    """Refuse, before any work, outputs that would write over an input or into the learning state (issue 25
    items 6 and 7): ``--out`` is no input and not inside ``--state``; ``--report DIR`` holds no input."""
    inputs = [("the program", req.program), ("the profile", req.profile)]
    inputs += [(what, p) for what, p in (("the log", req.log), ("the points", req.points)) if p is not None]
    for what, p in inputs:
        if same_file(req.out, p):
            raise InputError(req.out, None, f"is {what} of this run: choose another output path (--out)")
    if req.state is not None and inside(req.out, req.state):
        raise InputError(req.out, None, f"is inside the learning state {req.state}, which ilcnc keeps intact: choose"
                         " an output path outside it (--out)")
    if req.report is not None:
        from ilcnc.shop.report import is_report_file

        for what, p in inputs:
            if p.exists() and p.resolve().parent == req.report.resolve() and is_report_file(p.name):
                raise InputError(req.report, None, f"holds {what} as {p.name}, a file the report writes: choose another"
                                 " folder for --report")
        if req.state is not None and inside(req.report, req.state):
            raise InputError(req.report, None, f"is inside the learning state {req.state}: choose a folder outside it")


def learn_part(req: LearnRequest, *, progress: Callable[[int, int, str], None] | None = None) -> LearnOutcome:
    """Run ``ilcnc learn``: virtual learning, or one step from a measurement; keep the state.

    Raises
    ------
    InputError
        Bad program, profile, measurement or state (one-line message).
    """
    if req.log is not None and req.points is not None:
        raise UsageError("--log", "and --points do not go together: give either, not both")
    _check_output_paths(req)
    state_dir = req.state or _default_state_dir(req.out)
    with state_lock(state_dir):
        # what a killed run's atomic writes left (their process gone): the state's files and this output's
        if state_dir.is_dir():
            remove_stale_temporaries(state_dir)
        remove_stale_temporaries(req.out.parent, req.out.name)
        return _learn_part(req, progress)


def _learn_part(req: LearnRequest, progress: Callable[[int, int, str], None] | None) -> LearnOutcome:
    """:func:`learn_part` with the state held."""
    profile = load_profile(req.profile).with_cutting_top(req.cutting_below_z_mm)
    profile_sha = sha256_bytes(read_bytes(req.profile))
    data = read_bytes(req.program)
    if req.refine and req.points is not None:
        raise InputError(req.points, None, "--refine needs the error along the path: a log of the original program"
                         " (--log), or a virtual run; measured points hold it at the end points only")
    if req.force and (req.log is not None or req.points is not None):
        raise InputError(None, None, "--force starts a new virtual run; a step from --log/--points continues its --state")
    fresh = req.force or req.state is None or not LearnState.exists(req.state)
    state = None if fresh else LearnState.load(req.state)
    if state is not None and profile_sha != state.current_profile_sha256:
        if not req.new_profile:
            # continuing means the same machine model and law: figures made with another are not comparable
            raise StateError(req.profile, None, f"is not the profile this learning run goes on with (sha256"
                             f" {state.current_profile_sha256[:16]}, this file {profile_sha[:16]}): continue with that"
                             " profile, or give --new-profile to go on from the run's best iteration under this one"
                             " (a new branch of its history; the guard compares iterations of one profile only)")
        # a new branch: the guard's halving and its stop were judgements of the other profile's law
        state.gain_scale = 1.0
        if state.pending() is None:
            state.status = LearnStatus.LEARNING
    relation, entry = _resolve_part(req, data, state)
    if req.log is None and req.points is None:
        return _virtual(req, profile, profile_sha, data, state, relation, progress)
    return _measured(req, profile, profile_sha, data, state, relation, entry)

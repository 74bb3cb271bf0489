"""The visual diff and ``report.html`` of a learning run, from its state directory (``ilcnc report STATE``).

:func:`write_state_report` reads a state (:class:`ilcnc.shop.state.LearnState`,
every file checked against its hash), and writes into a report folder:

* ``corrections.png``, ``corrections-zoom.png``, ``corrections-along-path.png``
  (:mod:`ilcnc.shop.report_diff`);
* ``report.html`` (:mod:`ilcnc.shop.html_report`): those figures and any
  other PNGs given (``learn --report`` passes its path and error plots), the
  iteration table, the worst commands with their source lines, and the diff of
  the shown program against the original (:func:`ilcnc.shop.diff.diff_programs`).

The program shown is the one the shop runs next: a measured run's pending
iteration (written, not yet measured), else the best kept iteration (the
output of a virtual run), else iteration 0. The worst commands are the
cutting commands of largest ``|E(k)|`` in the first measured iteration
(without a measurement, of largest correction).

Which commands cut follows :mod:`ilcnc.contour.air`: the profile's rule when
a profile is given (``learn --report`` gives the run's), else
``--cutting-below-z``, else work Z0 (the state does not record the rule).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ilcnc.contour.air import CuttingRule, cutting_rule, move_classes, rule_air_commands
from ilcnc.errors import InputError
from ilcnc.fileio import read_bytes, write_atomic
from ilcnc.program import read_program
from ilcnc.program.model import Program
from ilcnc.shop.diff import diff_programs
from ilcnc.shop.html_report import DIFF_ROWS, HtmlFigure, HtmlReport, IterationRow, WorstRow, render_html
from ilcnc.shop.report_diff import CorrectionFigures, correction_figures
from ilcnc.shop.state import IterationEntry, LearnState

__all__ = ["REPORT_HTML", "WORST_ROWS", "StateReport", "default_report_dir", "write_state_report"]

REPORT_HTML = "report.html"

#: Commands the worst-commands table lists.
WORST_ROWS = 25

_CAPTIONS = {
    "corrections.png": "the original path and the rewritten one with the corrections as arrows, magnified by the"
                       " factor in the title; cutting moves solid, air moves dashed, rapids dotted",
    "corrections-zoom.png": "the worst cutting spot, zoomed: the error E(k) of the first iteration and the correction"
                            " of each command as arrows, with the program line numbers (N)",
    "corrections-along-path.png": "correction length and |E(k)| per command along the feed path, corners marked",
    "error-vs-iteration.png": "max, mean and RMS contour error per iteration",
    "error-along-path.png": "the contour error of every run along the path",
    "refined-corner.png": "the first run's worst spot with the points the refinement inserted",
}


@dataclass(frozen=True, slots=True, kw_only=True)
class StateReport:
    """What :func:`write_state_report` wrote.

    Attributes
    ----------
    files : list of Path
        The files written, in order.
    shown_iteration : int
        The iteration whose program the figures and the diff show.
    figures : CorrectionFigures
    worst_line : int or None
        Source line of the zoom's command.
    diff_rows, diff_changed : int
        Changed lines the page lists, and changed lines in all.
    rule : str
        The cutting rule applied, one line.
    """

    files: list[Path]
    shown_iteration: int
    figures: CorrectionFigures
    worst_line: int | None
    diff_rows: int
    diff_changed: int
    rule: str

    def to_json(self) -> dict[str, object]:
        f = self.figures
        return {"files": [str(p) for p in self.files], "shown_iteration": self.shown_iteration,
                "magnify": f.magnify, "zoom_magnify": f.zoom_magnify, "arrows_drawn": f.arrows_drawn,
                "arrows_total": f.arrows_total, "worst_line": self.worst_line, "zoom_half_mm": f.zoom_half_mm,
                "corners": f.corners, "diff_rows": self.diff_rows, "diff_changed": self.diff_changed,
                "cutting_rule": self.rule}


def default_report_dir(state_dir: Path) -> Path:
    """``part.ngc.state`` -> ``part.ngc.report`` beside it (any other name: NAME.report)."""
    name = state_dir.name[: -len(".state")] if state_dir.name.endswith(".state") else state_dir.name
    return state_dir.parent / f"{name}.report"


def _inside(p: Path, d: Path) -> bool:
    p, d = p.resolve(), d.resolve()
    return p == d or d in p.parents


def _norm(e: NDArray[np.float64] | None, valid: NDArray[np.bool_] | None) -> NDArray[np.float64] | None:
    if e is None or valid is None:
        return None
    return np.where(valid, np.sqrt(np.sum(e**2, axis=1)), np.nan)


def _errors(state: LearnState, entry: IterationEntry | None) -> tuple[NDArray[np.float64] | None,
                                                                      NDArray[np.bool_] | None]:
    if entry is None or entry.errors is None:
        return None, None
    e, _t, valid = state.read_errors(entry)
    return e, valid


def _rows(state: LearnState, best: IterationEntry | None, shown: IterationEntry) -> list[IterationRow]:
    rows = []
    for e in state.iterations:
        m = e.measured_from or {}
        air = m.get("air_error_mm") or {}
        cyc = m.get("cycle_time_s")
        st = e.stats
        rows.append(IterationRow(
            iteration=e.iteration, status="not measured yet" if st is None else "kept" if e.kept else "not kept",
            cutting_mm=None if st is None else (float(st["max"]), float(st["mean"]), float(st["rms"])),
            air_max_mm=float(air["max"]) if "max" in air else None,
            cycle_time_s=float(cyc) if isinstance(cyc, int | float) else None, clipped=int(e.clipped),
            gain_scale=float(e.gain_scale), measured_from=str(m.get("kind", "")), best=e is best, output=e is shown))
    return rows


def _worst(learning: Program, u_mm: NDArray[np.float64], air: NDArray[np.bool_],
           e_first: NDArray[np.float64] | None, e_best: NDArray[np.float64] | None) -> tuple[list[WorstRow], str]:
    n = learning.n_commands
    cut = ~air
    if e_first is not None and np.isfinite(np.where(cut, e_first, np.nan)).any():
        key = np.where(cut & np.isfinite(e_first), e_first, -np.inf)
        note = (f"The {WORST_ROWS} cutting commands with the largest error |E(k)| in the first measured iteration,"
                " largest first; ΔX ΔY ΔZ: the change of the command's end point in the shown program.")
    else:
        key = np.where(cut, np.sqrt(np.sum(u_mm**2, axis=1)), -np.inf)
        note = (f"No measured error: the {WORST_ROWS} cutting commands with the largest correction, largest first.")
    order = np.argsort(-key, kind="stable")[:WORST_ROWS]
    order = order[np.isfinite(key[order])]
    nan = np.full(n, np.nan)
    ef = nan if e_first is None else e_first
    eb = nan if e_best is None else e_best
    rows = [WorstRow(k=int(k), line=int(learning.command_line[k]), text=learning.line_text(int(learning.command_line[k]))[1],
                     error_first_um=1000.0 * float(ef[k]), error_best_um=1000.0 * float(eb[k]),
                     correction_um=1000.0 * u_mm[k], air=bool(air[k])) for k in order]
    return rows, note


def write_state_report(state_dir: Path, out_dir: Path, *, profile_path: Path | None = None,
                       cutting_below_z_mm: float | None = None, images: list[Path] | None = None) -> StateReport:
    """Write the visual diff and ``report.html`` of the run in ``state_dir`` into ``out_dir`` (module docstring).

    Parameters
    ----------
    state_dir : Path
        A learning state directory.
    out_dir : Path
        The report folder; created when missing (its parent must exist); never inside the state.
    profile_path : Path, optional
        The run's machine profile: its units and cutting rule.
    cutting_below_z_mm : float, optional
        The stock top, mm (``--cutting-below-z``).
    images : list of Path, optional
        Further PNGs to embed in the page (``learn --report``'s plots), in this order after the visual diff.

    Raises
    ------
    StateError
        The state is damaged or not a learning state.
    InputError
        ``out_dir`` cannot be made or is inside the state.
    """
    state = LearnState.load(state_dir)
    out_dir = Path(out_dir)
    if _inside(out_dir, state.directory):
        raise InputError(out_dir, None, f"is inside the learning state {state.directory}: choose a folder outside it")
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(out_dir, None, "report output exists and is not a directory")
    parent = out_dir.parent if str(out_dir.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(out_dir, None, f"cannot create the report directory: {parent} does not exist")
    try:
        out_dir.mkdir(exist_ok=True)
    except OSError as exc:
        raise InputError(out_dir, None, f"cannot create the report directory: {exc.strerror}") from None

    units = str(state.part.get("units", "mm"))
    resolution = 0.0
    profile = None
    if profile_path is not None:
        from ilcnc.profile.load import load_profile

        profile = load_profile(profile_path).with_cutting_top(cutting_below_z_mm)
        units, resolution = profile.machine.units, profile.machine.resolution_mm
    original = read_program(state.file(state.part["file"]), default_units=units, data=state.read_original_bytes())
    learning = original
    ref = state.part.get("refined") or {}
    if ref.get("file"):
        learning = read_program(state.file(ref["file"]), default_units=units, data=read_bytes(state.file(ref["file"])))
    if profile is not None:
        from ilcnc.contour.air import profile_cutting_rule

        rule: CuttingRule = profile_cutting_rule(original, profile)
    else:
        rule = cutting_rule(original, option_z_mm=cutting_below_z_mm)
    classes = move_classes(learning, rule, resolution_mm=resolution)
    air = rule_air_commands(learning, rule, classes, resolution_mm=resolution)

    measured = [e for e in state.iterations if e.stats is not None]
    best = state.best()
    shown = state.pending() or best or state.iterations[0]
    first = next((e for e in measured if e.errors is not None), None)
    e_first, v_first = _errors(state, first)
    e_best, v_best = _errors(state, best)
    out_prog = read_program(state.file(shown.program), default_units=units, data=state.read_program_bytes(shown))
    figs = correction_figures(program_name=original.path.name if state.part.get("name") is None else
                              str(state.part["name"]), learning=learning, output=out_prog, move_class=classes,
                              air_command=air, output_iteration=shown.iteration, error_first_mm=e_first,
                              error_first_valid=v_first, first_iteration=0 if first is None else first.iteration,
                              error_best_mm=e_best, error_best_valid=v_best,
                              best_iteration=None if best is None else best.iteration)
    written: list[Path] = []
    html_figs: list[HtmlFigure] = []
    for name, png in figs.files():
        written.append(write_atomic(out_dir / name, png))
        html_figs.append(HtmlFigure(name, _CAPTIONS[name], png))
    for p in images or []:
        if p.suffix == ".png" and p.is_file():
            cap = _CAPTIONS.get(p.name, "the path with the actual contour magnified (see the title)"
                                if p.name.startswith("path-") else "the contour error along the path")
            html_figs.append(HtmlFigure(p.name, cap, read_bytes(p)))

    diff = diff_programs(original, out_prog)
    u = out_prog.command_end_mm - learning.command_end_mm
    worst, note = _worst(learning, u, air, _norm(e_first, v_first), _norm(e_best, v_best))
    if ref.get("file"):
        note += f" Lines are those of the refined program {ref['file']} in the state, which the run learned."
    name = str(state.part.get("name") or original.path.name)
    red = "n/a"
    if best is not None and measured and measured[0].stats and best.stats and measured[0].stats["rms"] > 0:
        red = f"{100.0 * (1.0 - best.stats['rms'] / measured[0].stats['rms']):.1f} %"
    facts = [("program", name), ("state", str(state.directory)), ("status", str(state.status)),
             ("law / error estimate", f"{state.law} / {state.error}"),
             ("shown program", f"iteration {shown.iteration} ({shown.program})"
              + ("" if shown.output is None else f", written to {shown.output}")),
             ("best kept iteration", "none" if best is None else str(best.iteration)),
             ("cutting RMS reduction (first → best)", red),
             ("cutting rule", rule.describe()),
             ("magnification", f"overview ×{figs.magnify:g}, zoom ×{figs.zoom_magnify:g}")]
    page = HtmlReport(program_name=name, facts=facts, iterations=_rows(state, best, shown), figures=html_figs,
                      worst=worst, worst_note=note, diff=diff,
                      diff_command=f"ilcnc diff {state.file(state.part['file'])} {state.file(shown.program)}")
    written.append(write_atomic(out_dir / REPORT_HTML, render_html(page)))
    worst_line = None if figs.worst_k is None else int(learning.command_line[figs.worst_k])
    listed = min(len(diff.changed), DIFF_ROWS)
    return StateReport(files=written, shown_iteration=shown.iteration, figures=figs, worst_line=worst_line,
                       diff_rows=listed, diff_changed=len(diff.changed), rule=rule.describe())
